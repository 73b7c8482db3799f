"""The actuators' response in a calibration from motion (:mod:`platkit.calibrate.motion`): its kind
chosen from the data, a response the data do not determine said, and the response as the report
gives it.

Rules:
- the kind (``kind='auto'``, the default): the first order is fitted (tau x' + x = r: the
  actuator's lag); the second order is then tried from it (each time constant halved, damping 1:
  the same lag at low frequency, 2 zeta tau). An actuator keeps the second order only where its
  time constant and damping are each determined (estimated, both at least Z_DETERMINED standard
  deviations from zero) and physical (:func:`not_determined`); the others follow the first order
  within it (refitted so, where some keep it and some do not). The model with second-order
  actuators is kept only where its whole fit's Bayesian information criterion (:func:`information`)
  is lower than the first order's and its fit leaves the stream's fast content (:func:`fast_content`)
  no worse than the first order's but for one noise variance per damping it adds
  (:func:`kind_verdict`): the second order holds the first within it, so a drive that is second
  order is fitted at least as well there, and a second order that wins the whole fit while losing
  the fast content took a smooth misfit (a static effect left out); otherwise the first order.
  The fast content is judged on the samples whose commands the log holds (:func:`known_samples`):
  past a streamed log's last command both fits read that command held, which is what the stand
  did where the log brought it to rest, and a guess where the log stops in motion (a log cut
  short), whose later samples follow commands not logged: a fit whose lag reads further past the
  log's end would be charged for the guess. A kind the caller names is fitted as named;
- a response not determined (:func:`not_determined`): a time constant at or under the response's
  floor (TAU_MIN_S) or under TAU_SAMPLE_SHARE of the motion capture's sample interval (faster
  than the samples can show), a damping at or under its floor (ZETA_MIN) or above DAMPING_MAX
  (no drive is that overdamped: a second order that far overdamped is a first order, of lag
  2 zeta tau, whose fast pole the data do not see), or an overdamped one whose fast pole's time
  constant, tau (zeta - sqrt(zeta^2 - 1)), is under the same floor as a time constant's. Said per actuator in the report and as a
  warning; a slow stream, which fixes each actuator's lag alone, leaves the second order's time
  constant and damping free along that lag, and a fit walks to these floors.
"""
from __future__ import annotations

import numpy as np

from platkit.calibrate.problem import Progress
from platkit.calibrate.response import TAU_MIN_S, ZETA_MIN, ResponseModel, lags
from platkit.calibrate.stream import log_end
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec

__all__ = ["DAMPING_MAX", "TAU_SAMPLE_SHARE", "Z_DETERMINED", "bic", "fast_content", "fit_progress", "fitted_kind",
           "held_names", "information",
           "kind_verdict", "known_samples", "not_determined", "response_from_report", "response_report", "second_order_kept",
           "theta_by_name"]

#: a damping above this is no drive's (a first order's lag taken by a second order far overdamped)
DAMPING_MAX = 10.0
#: a time constant under this share of the motion capture's sample interval is faster than the
#: samples show
TAU_SAMPLE_SHARE = 0.25
#: an actuator keeps the second order where its time constant and damping are each this many
#: standard deviations from zero
Z_DETERMINED = 3.0


def information(cal: Calibration, n_ref: int) -> float:
    """The Bayesian information criterion of a fit on ``n_ref`` observations (coordinates): n_ref
    ln(sigma^2) + k ln(n_ref), sigma^2 the fit's weighted residual variance per coordinate (its
    noise_sigma squared: the robust weights' sum of squares over its degrees of freedom), k its
    unknowns estimated. Two fits of one stream are compared on the same n_ref (the first's
    observations), each by its own variance: a fit that rejects fewer observations is not
    charged for the residuals it keeps."""
    k = int(np.sum(cal.fit.active)) if cal.fit is not None and cal.fit.active is not None else 0
    return bic(n_ref, float(cal.noise_sigma) ** 2, k)


def bic(n: int, variance: float, k: int) -> float:
    """The Bayesian information criterion of ``n`` observations of residual ``variance`` with ``k``
    unknowns: n ln(variance) + k ln(n)."""
    return float(n * np.log(max(variance, 1e-300)) + k * np.log(max(n, 2)))


def held_names(cal: Calibration) -> set[str]:
    """The names of the parameters identifiability held at their start (nominal)."""
    return {h["name"] for h in cal.identifiability.get("held_at_nominal", [])}


def not_determined(rmodel: ResponseModel, spec: PlatformSpec, cal: Calibration, sample_dt: float) -> dict[str, str]:
    """{actuator: why} for the actuators whose fitted response (``cal.theta[0]``) is degenerate
    (module docstring): a time constant or damping estimated at a floor, or outside what the
    samples show or any drive has. Parameters held at their start are not judged."""
    theta = np.asarray(cal.theta[0], float)
    par = rmodel.split(theta)
    held = held_names(cal)
    tau_floor = max(TAU_MIN_S, TAU_SAMPLE_SHARE * sample_dt)
    out = {}
    for j, c in enumerate(spec.control_names):
        why = []
        tau = float(par["tau_s"][j])
        if f"term.actuator_response.tau_s.{c}" not in held and tau <= tau_floor:
            why.append(f"time constant {1e3 * tau:.3g} ms at or under {1e3 * tau_floor:.3g} ms (the response's floor "
                       f"or {TAU_SAMPLE_SHARE:g} of the {1e3 * sample_dt:.3g} ms sample interval)")
        if rmodel.has("damping", j) and f"term.actuator_response.damping.{c}" not in held:
            zeta = float(par["damping"][j])
            fast = tau * (zeta - np.sqrt(zeta * zeta - 1.0)) if zeta > 1.0 else tau
            if zeta <= ZETA_MIN or zeta > DAMPING_MAX:
                why.append(f"damping {zeta:.3g} outside ({ZETA_MIN:g}, {DAMPING_MAX:g}]")
            elif fast <= tau_floor:
                why.append(f"overdamped (damping {zeta:.3g}): its fast pole's time constant {1e3 * fast:.3g} ms at or "
                           f"under {1e3 * tau_floor:.3g} ms, faster than the samples show (a first order of lag "
                           f"{1e3 * 2 * zeta * tau:.3g} ms)")
        if why:
            out[c] = "; ".join(why)
    return out


def second_order_kept(rmodel: ResponseModel, spec: PlatformSpec, cal: Calibration, sample_dt: float,
                      moved: np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
    """Which actuators of a second-order fit keep the second order ((n_u,) bool) and why each
    other one does not ({actuator: why}): moved, time constant and damping estimated, each at
    least Z_DETERMINED standard deviations from zero, and not degenerate (:func:`not_determined`)."""
    theta = np.asarray(cal.theta[0], float)
    std = np.asarray(cal.theta_std[0], float)
    held = held_names(cal)
    bad = not_determined(rmodel, spec, cal, sample_dt)
    keep = np.zeros(spec.n_u, bool)
    why = {}
    for j, c in enumerate(spec.control_names):
        if not moved[j]:
            why[c] = "never moved under the markers"
            continue
        if c in bad:
            why[c] = bad[c]
            continue
        if {f"term.actuator_response.{b}.{c}" for b in ("tau_s", "damping")} <= held:
            why[c] = "held at its start (the markers do not see its response)"
            continue
        z = []
        for blk in ("tau_s", "damping"):
            k = rmodel.index(blk, j)
            if f"term.actuator_response.{blk}.{c}" in held or not np.isfinite(std[k]) or std[k] <= 0:
                z.append(0.0)
            else:
                z.append(abs(theta[k]) / std[k])
        if min(z) < Z_DETERMINED:
            why[c] = (f"time constant and damping not determined apart (z {z[0]:.2g} and {z[1]:.2g}, under "
                      f"{Z_DETERMINED:g}): the data fix the lag alone")
            continue
        keep[j] = True
    return keep, why


def theta_by_name(rmodel: ResponseModel, control_names: list[str], *sources: dict[str, float],
                  default: float = 1.0) -> np.ndarray:
    """A response vector for ``rmodel`` from values by parameter name (``sources``: the first that
    has the name serves), ``default`` where none has it."""
    out = []
    for name in rmodel.names(control_names):
        out.append(next((float(s[name]) for s in sources if name in s), default))
    return np.array(out, float)


def response_report(rmodel: ResponseModel, spec: PlatformSpec, cal: Calibration, T: np.ndarray, U: np.ndarray,
                    sample_dt: float | None = None) -> dict:
    """The fitted response as the report gives it: per actuator its kind, each parameter with its
    std or 'held_at_start' (held by identifiability), a delay's lag (what the markers fix), a
    streamed rate limit's share of the log's steps it cuts ('does_not_bind' where none), and
    ``determined`` False with the reason where the response is degenerate (:func:`not_determined`,
    with ``sample_dt`` the motion capture's sample interval); the shift. ``kind``: 'first_order',
    'second_order', or 'per_actuator' (some of each)."""
    held = held_names(cal)
    theta, theta_std = np.asarray(cal.theta[0], float), np.asarray(cal.theta_std[0], float)
    par = rmodel.split(theta)
    sd = rmodel.split(np.where(np.isfinite(theta_std), theta_std, np.nan))
    bad = not_determined(rmodel, spec, cal, sample_dt) if sample_dt is not None else {}
    per = {}
    for j, c in enumerate(spec.control_names):
        entry: dict = {"kind": rmodel.kinds[j]}
        for blk in rmodel.blocks:
            if not rmodel.has(blk, j):
                continue
            name = f"{blk}.{c}"
            held_here = f"term.actuator_response.{name}" in held
            entry[blk] = {"value": float(par[blk][j]), "std": None if held_here or not np.isfinite(sd[blk][j])
                          else float(sd[blk][j]), "status": "held_at_start" if held_here else "estimated"}
        if rmodel.delays:
            entry["lag_s"] = {"value": float(lags(rmodel, theta)[j]), "note": "shift + delay_s: what the markers fix"}
        if rmodel.slewed:  # a limit above every step the log asks is not seen: a lower bound, said so
            need = np.abs(np.diff(U[:, j])) / np.diff(T)
            entry["rate"]["binds_share"] = float(np.mean(need > par["rate"][j])) if len(need) else 0.0
            if entry["rate"]["binds_share"] == 0:
                entry["rate"].update(status="does_not_bind", std=None, note=(
                    f"above the log's fastest step over its interval ({float(need.max()) if len(need) else 0.0:.4g} "
                    "per s): the limit is not seen"))
        entry["determined"] = c not in bad
        if c in bad:
            entry["note"] = f"not determined: {bad[c]}"
        per[c] = entry
    shift_held = "term.actuator_response.shift_s" in held
    shift = {"value": float(par["shift_s"]), "std": None if shift_held or not np.isfinite(sd["shift_s"])
             else float(sd["shift_s"]), "status": "held_at_start" if shift_held else "estimated",
             "note": "the motion capture's clock minus the commands', with the stand's common delay"}
    return {"kind": rmodel.kind_label, "reference": rmodel.reference,
            "units": "s for times; controls' internal units (m for length controls) per s for rates",
            "delays": bool(rmodel.delays), "rate_limit": bool(rmodel.reference == "profile" or rmodel.slewed),
            "shift_s": shift, "actuators": per, "not_determined": bad}


def response_from_report(r: dict, spec: PlatformSpec, where: str) -> tuple[ResponseModel, np.ndarray]:
    """The response model and its vector from a report's ``motion.response`` (calibration.yaml's
    ``actuator_response.response``): each actuator's kind where the report gives it (an older file
    gives one kind for all). BadInput-like failures are the caller's: KeyError on a missing field,
    ValueError naming ``where`` for an actuator that is not the stand's."""
    per = r["actuators"]
    missing = [c for c in spec.control_names if c not in per]
    if missing:
        raise ValueError(f"{where}: the calibration's actuator_response has no actuator {missing[0]!r}")
    first = tuple(j for j, c in enumerate(spec.control_names) if per[c].get("kind") == "first_order")
    kind = "second_order" if len(first) < spec.n_u and r["kind"] != "first_order" else "first_order"
    rmodel = ResponseModel(kind, r["reference"], spec.n_u, bool(r.get("delays")),
                           bool(r.get("rate_limit")) and r["reference"] == "step", first if kind == "second_order" else ())
    values = {"shift_s": float(r["shift_s"]["value"])}
    for j, c in enumerate(spec.control_names):
        for blk in rmodel.blocks:
            if rmodel.has(blk, j):
                values[f"{blk}.{c}"] = float(per[c][blk]["value"])
    return rmodel, theta_by_name(rmodel, list(spec.control_names), values)


def known_samples(t: np.ndarray, T: np.ndarray, U: np.ndarray, lag_s: np.ndarray) -> np.ndarray:
    """(N,) bool: the samples at times ``t`` (the motion capture's clock) whose commands the
    streamed log (``T`` (K,), ``U`` (K, n_u)) holds under every lag in ``lag_s`` (s, each fit's
    and actuator's: a sample at t reads the command of t - lag). Where the log ends at rest (no
    actuator's last step over REST_SHARE of its median step) every sample: the last command held
    is what the stand was told. Where it ends in motion, a sample whose latest reading,
    t - min(lag_s), lies past the last command by more than the log's median interval follows
    commands the log does not have: not known (:func:`platkit.calibrate.stream.log_end`)."""
    t = np.asarray(t, float)
    end = log_end(T, U)
    if end is None:
        return np.ones(len(t), bool)
    return t - float(np.min(lag_s)) <= end


def fast_content(cals: list[Calibration], win, known: np.ndarray | None = None) -> tuple[list[float], int]:
    """The fits' residuals in the stream's fast content, on the same observations: in every window
    kept as its samples (``win``: :class:`platkit.calibrate.stream.StreamWindows`), each marker
    coordinate's residuals less their own polynomial in time of the windows' degree (nodes - 1),
    the observations every fit kept (seen, not rejected) at the samples ``known`` ((N,) bool,
    default all; :func:`known_samples`). Returns each fit's sum of squares and
    the observations' count less the polynomials' coefficients. A static effect left out of the
    model (a sag, a geometry error: functions of the configuration, which a stream moves slowly)
    lies mostly in the polynomials; the response's order shapes what is left."""
    R = [c.fit.residuals_after for c in cals]
    W = [c.fit.weights for c in cals]
    used = np.all([np.isfinite(r).all(axis=2) & (w > 0) for r, w in zip(R, W)], axis=0)  # (N, C)
    if known is not None:
        used &= np.asarray(known, bool)[:, None]
    rss = [0.0] * len(cals)
    n = 0
    ends = [b[0] for b in win.blocks[1:]] + [len(win.t)]
    for (p, _, _, per), end in zip(win.blocks, ends):
        if per is not None or end - p <= win.nodes:
            continue
        t = win.t[p:end]
        x = 2.0 * (t - t[0]) / max(float(t[-1] - t[0]), 1e-12) - 1.0
        V = np.vander(x, win.nodes)
        for m in range(used.shape[1]):
            k = np.nonzero(used[p:end, m])[0]
            if len(k) <= 2 * win.nodes:
                continue
            Q, _ = np.linalg.qr(V[k])
            n += 3 * (len(k) - win.nodes)
            for i, r in enumerate(R):
                y = r[p + k, m]  # (len(k), 3)
                e = y - Q @ (Q.T @ y)
                rss[i] += float(np.sum(e ** 2))
    return rss, n


def kind_verdict(fast: tuple[list[float], int], added: int, bics: tuple[float, float],
                 label: str, unknown: int = 0) -> tuple[bool, str, dict]:
    """Whether the second order (``label``: second_order or per_actuator) is kept over the first
    (module docstring): ``fast`` :func:`fast_content`'s sums of squares of the two fits (first,
    second) and its count on the samples whose commands the log holds (``unknown``: the samples
    kept as samples left out, past the end of a log that stops in motion; :func:`known_samples`),
    ``added`` the dampings the second estimates, ``bics`` the whole fits'
    (first, second) :func:`information`. Without fast content (no window kept as samples) the
    whole fit's criterion alone. Returns the verdict, its figures in words, and the report's
    ``criterion`` with the fast content's figures."""
    (rss1, rss2), n_fast = fast
    words = f"BIC of the whole fit {bics[1]:.1f} against {bics[0]:.1f}"
    if not (n_fast and rss1 > 0 and rss2 > 0):
        return bics[1] < bics[0], words, {"criterion": "BIC of the whole fit (no window kept as samples: no fast "
                                                       "content to judge a static effect by)"}
    worse = float(n_fast * np.log(rss2 / rss1))
    out = {"criterion": ("BIC of the whole fit (every unknown charged), and the fit's fast content (the windows kept as "
                         "samples, each marker coordinate less its polynomial in time per window) no worse than the "
                         f"first order's but for one noise variance per damping added ({added}), on the samples "
                         "whose commands the log holds (not those past the end of a log that stops in motion)"),
           "fast_content": {"n": int(n_fast), "first_order_rss_m2": rss1, f"{label}_rss_m2": rss2,
                            "worse_in_noise_variances": worse, "allowed": added,
                            "samples_past_the_log": int(unknown)}}
    words += f"; fast content {'worse' if worse > 0 else 'better'} by {abs(worse):.3g} noise variances, {added} allowed"
    return bics[1] < bics[0] and worse <= added, words, out


def fitted_kind(rmodel: ResponseModel) -> str:
    """The kind of response ``rmodel`` fits, as a fit's progress names it: 'first_order',
    'second_order', or 'per_actuator' (a second order with some actuators first order in it), as
    the report names it (:attr:`ResponseModel.kind_label`)."""
    return rmodel.kind_label


def fit_progress(progress: Progress | None, rmodel: ResponseModel) -> Progress | None:
    """``progress`` for one fit of the stream: every event's info says the response's kind that fit
    fits (``response_kind``, :func:`fitted_kind`), so that a reader need not infer it."""
    if progress is None:
        return None
    kind = fitted_kind(rmodel)

    def told(stage: str, info: dict) -> None:
        progress(stage, {**info, "response_kind": kind})

    return told
