"""Holds that never settled (platkit.settle): which actuators and markers still moved,
their time constant, what remained, and the sentence that says so."""
from __future__ import annotations

import numpy as np
from scipy.stats import fisher_exact

from platkit.settle._approach import Approach
from platkit.settle._attribution import attribute_actuators
from platkit.settle._report import _finite
from platkit.settle._still import last_step


def _unsettled_summary(rows: list[int], fits: dict[int, Approach], U: np.ndarray, control_names: list[str],
                       marker_names: list[str], hold_s: np.ndarray, n_commands: int,
                       other_drops: set[int] | None = None, slow_taus: dict[int, float] | None = None,
                       slow_left: dict[int, float] | None = None, held: np.ndarray | None = None,
                       tails: dict[int, np.ndarray] | None = None) -> dict:
    """Which actuators and markers are still moving in the holds ``rows`` that never settled, and
    with what time constant; ``sentence`` says it in one line.

    An actuator is named when what is left of the holds' approaches lies along its own column of
    the stand's Jacobian, read from the session (:func:`attribute_actuators`: ``held`` (N, M, 3)
    where the markers were held, ``tails`` row -> (M, 3) the markers at the end of the hold less
    where they were heading, or any vector along it: what they moved late in the hold, reversed);
    else when the holds after it moved (by more than 5% of its travel in the
    session) never settle significantly more often than the others (one-sided Fisher exact test,
    Bonferroni over the actuators at 0.01), and its excess is at least 0.7 of the largest; when
    none is (every hold unsettled: no contrast), when the distance left at the end of the holds
    grows with its step (a regression on every actuator's step, t > 4, at least half the largest).
    """
    if not rows:
        return {}
    un = np.zeros(len(U), bool)
    un[rows] = True
    use = np.ones(len(U), bool)
    if other_drops:
        use[sorted(other_drops)] = False
    steps = np.abs(last_step(U))
    span = np.ptp(U, axis=0)
    moved = steps / np.where(span > 0, span, 1.0) > 0.05
    attributed: list[int] = []
    left_by: dict = {}
    if held is not None and tails:
        attributed, table = attribute_actuators(U, held, tails)
        left_by = {control_names[j]: _finite(table["moved_late_m"][j]) for j in range(len(control_names))}
    scored = []
    for j in range(len(control_names)):
        m = moved[:, j] & use
        o = ~moved[:, j] & use
        if m.sum() < 3 or o.sum() < 3:
            continue
        table = [[int((un & m).sum()), int((~un & m).sum())], [int((un & o).sum()), int((~un & o).sum())]]
        p = fisher_exact(table, alternative="greater")[1]
        excess = un[m].mean() - un[o].mean()
        if p < 0.01 / len(control_names) and excess > 0:
            scored.append((float(excess), j))
    scored.sort(reverse=True)
    named = attributed or ([j for e, j in scored if e >= 0.7 * scored[0][0]] if scored else [])
    rem_of = dict(slow_left) if slow_left else {i: float(np.nanmax(fits[i].remaining_m)) for i in rows if i in fits}
    if not named and len(rem_of) >= 2 * U.shape[1] + 4:
        # every hold unsettled, no contrast: the distance left at the end grows with the slow
        # actuator's step, whatever the others (correlated in most plans) do
        idx = sorted(rem_of)
        A = np.column_stack([np.ones(len(idx)), steps[idx] / np.where(span > 0, span, 1.0)])
        y = np.array([rem_of[i] for i in idx])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        s2 = float(np.sum((y - A @ coef) ** 2)) / max(len(y) - A.shape[1], 1)
        se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(A.T @ A))[1:], 1e-300))
        strong = [j for j in range(U.shape[1]) if coef[1 + j] > 0 and coef[1 + j] / se[j] > 4.0]
        if strong:
            top = max(coef[1 + j] for j in strong)
            named = [j for j in sorted(strong, key=lambda j: -coef[1 + j]) if coef[1 + j] >= 0.5 * top]
    actuators = [control_names[j] for j in named]
    # the end of the approach, where the slowest actuator is alone, when it was seen; else the fits
    tau_of = dict(slow_taus) if slow_taus else {i: fits[i].tau for i in rows if i in fits}
    which = [i for i in rows if i in tau_of and (not named or moved[i, named].any())] or [i for i in rows if i in tau_of]
    taus = np.array([tau_of[i] for i in which])
    rem = np.array([fits[i].remaining_m for i in rows if i in fits])
    markers = []
    if rem.size:
        med = np.nanmedian(rem, axis=0)
        markers = [marker_names[m] for m in np.argsort(-med) if med[m] >= 0.5 * np.nanmax(med)]
    tau_med = float(np.median(taus)) if taus.size else float("nan")
    tau_lo, tau_hi = (float(np.percentile(taus, 25)), float(np.percentile(taus, 75))) if taus.size else (np.nan, np.nan)
    who = (f"actuator{'s' if len(actuators) > 1 else ''} {', '.join(actuators)}" if actuators
           else "the stand (no one actuator stands out)")
    tc = (f"approaching rest with a time constant of {tau_med:.3g} s (quartiles {tau_lo:.3g}-{tau_hi:.3g} s)"
          if taus.size else "its approach not fitted")
    sentence = (f"{len(rows)} of {n_commands} holds never settled: {who} still moving at the next command "
                f"(markers {', '.join(markers) or 'all'}), {tc} against holds of {float(np.median(hold_s)):.3g} s")
    return {"rows": list(rows), "n": len(rows), "n_commands": n_commands, "actuators": actuators, "markers": markers,
            "time_constant_s": tau_med, "time_constant_quartiles_s": [tau_lo, tau_hi],
            "hold_s": float(np.median(hold_s)), "moved_late_along_actuator_m": left_by,
            "remaining_m": float(np.nanmedian(np.nanmax(rem, axis=1))) if rem.size else float("nan"),
            "sentence": sentence}


def refusal(reason: str, summary: dict, n_commands: int, n_settled: int, **counts) -> dict:
    """The ``settling`` a refusal (platkit.settle.HoldsNeverSettle, NeverSettles) carries: ``reason``
    (one clause, with the counts), the summary of the holds that never settled, the commands, the
    holds that settled, and ``counts`` (keyword: the numbers the rule that refused read)."""
    return {"reason": reason, "unsettled": dict(summary or {}), "n_commands": int(n_commands),
            "n_settled": int(n_settled), **counts}


def _who(summary: dict) -> str:
    """' (actuator B still moving, time constant 0.801 s)': the summary's where and size, '' without."""
    acts = summary.get("actuators") or []
    tau = summary.get("time_constant_s")
    parts = ([f"actuator{'s' if len(acts) > 1 else ''} {', '.join(acts)} still moving"] if acts else []) + (
        [f"time constant {tau:.3g} s"] if tau is not None and np.isfinite(tau) else [])
    return f" ({', '.join(parts)})" if parts else ""
