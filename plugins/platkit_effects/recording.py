"""Artefacts of the recording rather than of the stand: settling_lag (poses taken before the
stand came to rest, short of the command by a fraction of the last step) and marker_slip (a
marker that moved on the platform at a change point)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import Effect, SizeHelp, history, planted, stored_number, stored_where
from platkit.errors import BadInput
from platkit.terms import ModelTerm
from platkit_effects.physics import MarkerSlipPhysics, SlowActuator


@dataclass
class SettlingTerm(ModelTerm):
    def control_offset(self, theta, poses, n_u):
        return -theta[0] * history(poses, "last_step")


class SettlingLag(Effect):
    name = "settling_lag"
    summary = "the pose was recorded before the platform settled"
    recording = True
    unsettled_holds = True
    simulation_size = SizeHelp("the fraction of the last step not yet made", "")
    physics_size = SizeHelp("the time constant of one slow actuator, as a share of the hold (default 0.5)", "")

    def correction(self, where, unwritten=None):
        return ("in the data: the lag is fitted so that the geometry sees where the stand settles; "
                "calibration.yaml leaves it out (predict gives the settled pose)")

    def term(self):
        return SettlingTerm(self.name, ["lag_fraction"], np.zeros(1), ["1"],
                            {"actuator": "all", "along": "the last move, a fraction of its size"})

    def candidates(self, spec, poses, residuals=None):
        return [self.term()] if poses.n_poses > 2 else []

    def regressor(self, term, spec, poses):
        lo, hi = spec.control_bounds()
        span = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
        return np.linalg.norm(history(poses, "last_step") / span, axis=1)

    def regressor_label(self, term):
        return "size of the last move (fraction of the strokes)"

    def from_dict(self, data, spec=None):
        return self.term()

    def simulation_term(self, spec, size, rng, commands):
        return self.term(), np.array([0.003 if size is None else float(size)])

    def physics(self, spec, size, rng, plan):
        i = planted(spec, rng, int(rng.integers(spec.n_u)), list(range(spec.n_u)), self.name)
        share = 0.5 if size is None else float(size)
        if not share > 0:
            raise BadInput("effect settling_lag: the slow actuator's time constant must be a positive share of the hold")
        return SlowActuator(i, spec.control_names[i], share * plan.hold_s, share)


def change_point(series: np.ndarray, min_segment: int = 3) -> tuple[int, float]:
    """The split k (rows k.. after it) that best separates the means of ``series`` (N, d) rows in
    time order: (k, F statistic of the step with d and n - 2d degrees of freedom); (-1, 0) when
    too short. Rows with NaN are skipped (k indexes the original rows)."""
    ok = np.all(np.isfinite(series), axis=1)
    idx = np.nonzero(ok)[0]
    x = series[ok] - series[ok].mean(axis=0)
    n, d = x.shape
    if n < 2 * min_segment + 1:
        return -1, 0.0
    csum = np.cumsum(x, axis=0)
    j = np.arange(min_segment, n - min_segment + 1)
    explained = np.sum(csum[j - 1] ** 2, axis=1) * n / (j * (n - j))
    b = int(np.argmax(explained))
    best = float(explained[b])
    F = (best / d) / max((np.sum(x**2) - best) / max(n - 2 * d, 1), 1e-300)
    return int(idx[j[b]]), float(F)


#: a slip moves one marker: at its split, its step is at least this many times any other marker's
SLIP_DOMINANCE = 3.0


def one_marker_steps(residuals: np.ndarray, k: int, m: int, dominance: float = SLIP_DOMINANCE) -> bool:
    """Whether the step at split k (rows k.. after it) of marker m's residuals (N, M, 3, moving
    frame, time order) is at least ``dominance`` times every other marker's step there: a slip
    moves one marker and leaves the others consistent; a step all markers share (the frame, a
    drift of the stand's actuators) is no slip."""
    with np.errstate(invalid="ignore"):
        step = np.linalg.norm(np.nanmean(residuals[k:], axis=0) - np.nanmean(residuals[:k], axis=0), axis=1)
    others = np.delete(step, m)
    others = others[np.isfinite(others)]
    return bool(np.isfinite(step[m]) and (others.size == 0 or step[m] >= dominance * np.max(others)))


@dataclass
class MarkerSlipTerm(ModelTerm):
    marker: int = 0
    t_slip: float = 0.0

    def marker_offset(self, theta, poses, *args):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[history(poses, "elapsed") >= self.t_slip, self.marker] = np.asarray(theta)[:3]
        return out


class MarkerSlip(Effect):
    name = "marker_slip"
    summary = "a marker moved on the platform during the session"
    recording = True
    simulation_size = SizeHelp("the jump, halfway through the session, of a random marker", "mm")
    physics_size = SizeHelp("the jump of a random marker, at a random instant in the middle half of the session", "mm")

    def onset(self, term):
        return float(term.where["from_time_s"])

    def moved_marker(self, term, theta, std):
        sd = np.asarray(std, float)[:3] if std is not None else np.full(3, np.nan)
        return int(term.where["marker_index"]), np.asarray(theta, float)[:3], sd

    def correction(self, where, unwritten=None):
        marker = f"in the data: marker {where.get('marker')} is fitted at both places"
        if unwritten is None:
            return f"{marker}; calibration.yaml holds its place after the slip"
        return (f"{marker}; the fit without the slip had already placed it where it was after the slip (its earlier "
                f"half left out as outliers), and fitting both places predicts the held-out poses from the slip on at "
                f"{unwritten}: calibration.yaml is the fit without the slip, the marker at its place after it")

    def term(self, name, m, t_slip):
        return MarkerSlipTerm(self.name, ["dx", "dy", "dz"], np.zeros(3), ["m"] * 3,
                              {"marker": str(name), "marker_index": int(m), "from_time_s": float(t_slip)},
                              marker=int(m), t_slip=float(t_slip))

    def candidates(self, spec, poses, residuals=None):
        if residuals is None or poses.n_markers < 2:
            return []
        t = history(poses, "elapsed")
        order = np.argsort(t, kind="stable")
        out = []
        ts = t[order]
        for m in range(poses.n_markers):
            k, _ = change_point(residuals[order, m, :])
            if k > 0 and not one_marker_steps(residuals[order], k, m):
                continue
            # the geometry absorbs part of a step, which can move the residual's change point by
            # a row: the neighbours are candidates too, and the score test picks among them
            for j in (k - 1, k, k + 1):
                if k > 0 and 1 <= j < len(ts):
                    out.append(self.term(poses.marker_names[m], m, 0.5 * (ts[j - 1] + ts[j])))
        return out

    def regressor(self, term, spec, poses):
        return (history(poses, "elapsed") >= term.t_slip).astype(float)

    def regressor_label(self, term):
        return f"before (0) or after (1) {term.t_slip:.4g} s"

    def from_dict(self, data, spec=None):
        where = stored_where(data)
        m = where.get("marker_index")
        if isinstance(m, bool) or not isinstance(m, int) or m < 0:
            raise BadInput("effect 'marker_slip': where.marker_index must be an integer >= 0")
        return self.term(where.get("marker", m), m, stored_number(where, "from_time_s", self.name))

    def simulation_term(self, spec, size, rng, commands):
        m = int(rng.integers(commands.n_markers))
        t = history(commands, "elapsed")
        t_slip = 0.5 * (t[len(t) // 2 - 1] + t[len(t) // 2])
        d = rng.normal(size=3)
        d *= (2.0 if size is None else float(size)) * 1e-3 / np.linalg.norm(d)
        return self.term(commands.marker_names[m], m, t_slip), d

    def physics(self, spec, size, rng, plan):
        m = int(rng.integers(len(plan.marker_names)))
        t0 = float(plan.command_t[0])
        t_s = float(rng.uniform(t0 + 0.25 * (plan.end_s - t0), t0 + 0.75 * (plan.end_s - t0)))
        d = rng.normal(size=3)
        d *= (2.0 if size is None else float(size)) * 1e-3 / np.linalg.norm(d)
        return MarkerSlipPhysics(m, plan.marker_names[m], t_s, d)
