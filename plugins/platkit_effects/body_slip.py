"""A rigid body that moved on the platform at one instant, as the ``marker_slip`` it is (the spec's
name: something of the motion capture moved on the platform during the session), located at the
body (``where['rigid_body']``).

Diagnosis reads a body T as its three points ``T.o``, ``T.x``, ``T.y`` (platkit.diagnose.bodies).
They are the body's own report, not markers of their own: a body knocked on the stand moves all
three by one rotation and translation, and one of them cannot move alone. So on a body's points
the slip is the body's (:class:`BodySlipTerm`): the three points each stepped from one time t_s on,
the time where their residuals, stacked, change together (the same change-point statistic as one
marker's, :func:`platkit_effects.recording.change_point`, beyond :func:`step_level`), and no slip
of one point is offered there. The term gives each point its own step (9 parameters): a term sees the session and its own
theta, not the fitted places of the points, so the lever from the origin to the tips in the moving
frame, which a rotation about the origin needs, is not available to it; a rigid motion's steps
(6 numbers) lie within the 9, and the placement after the slip is read back rigidly from the three
points (:func:`platkit.bodies.bodies_from_points`). Each step stays in the written calibration
(``moved_markers``): the body's placement there is the one after the slip.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.bodies import FRAME_POINT_SUFFIXES, frame_point_indices
from platkit.effects import history, stored_number, stored_where
from platkit.errors import BadInput
from platkit.terms import ModelTerm
from platkit_effects.recording import SLIP_DOMINANCE, MarkerSlip, change_point

__all__ = ["SPLIT_LEVEL", "BodySlipTerm", "MarkerOrBodySlip", "body_steps", "step_level"]


def body_steps(residuals: np.ndarray, k: int, points: list[int], dominance: float = SLIP_DOMINANCE) -> bool:
    """Whether at split k (rows k.. after it) of ``residuals`` (N, M, 3, moving frame, time order)
    the largest step of the body's ``points`` is at least ``dominance`` times the step of every
    other channel: a body that moved leaves the markers and the other bodies consistent; a step all
    channels share (the frame, a drift of the stand) is no slip."""
    with np.errstate(invalid="ignore"):
        step = np.linalg.norm(np.nanmean(residuals[k:], axis=0) - np.nanmean(residuals[:k], axis=0), axis=1)
    own = step[points]
    others = np.delete(step, points)
    others = others[np.isfinite(others)]
    return bool(np.all(np.isfinite(own)) and (others.size == 0 or np.max(own) >= dominance * np.max(others)))


#: a body's step is a candidate where its change point's F is beyond this level
SPLIT_LEVEL = 0.01


def step_level(n: int, d: int = 9, level: float = SPLIT_LEVEL) -> float:
    """The F a step of a body's ``d`` residual coordinates over ``n`` poses in time order must reach
    at its best split (:func:`platkit_effects.recording.change_point`) to be a slip's candidate: the
    F quantile at ``level``. A body's three points carry nine coordinates, so whatever the stand
    leaves in them (a play in a joint) steps somewhere; only a step that stands out of them is a
    slip. The splits tried are not counted: the geometry fitted before the slip is named absorbs
    part of every step, which leaves the statistic well under its F distribution where nothing
    slipped (docs/effects-body-slip.md)."""
    from scipy.stats import f  # here, not at the top: every stand lookup loads this plugin

    return float(f.ppf(1.0 - level, d, max(n - 2 * d, 1)))


@dataclass
class BodySlipTerm(ModelTerm):
    """The body's three points (``points``: indices of ``B.o``, ``B.x``, ``B.y``) each stepped by
    its own (3,) m in the moving frame from ``t_slip`` (s since the first command) on; theta (9,):
    the steps of o, x, y in that order."""

    points: list[int] = field(default_factory=list)
    t_slip: float = 0.0
    uses_kinematics = False

    def marker_offset(self, theta, poses, *args):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        after = history(poses, "elapsed") >= self.t_slip
        out[np.ix_(after, self.points)] = np.asarray(theta, float).reshape(3, 3)
        return out


class MarkerOrBodySlip(MarkerSlip):
    """``marker_slip`` on markers (:class:`platkit_effects.recording.MarkerSlip`) and on rigid
    bodies: a body's points slip together as the body (:class:`BodySlipTerm`), never one apart."""

    def moved_marker(self, term, theta, std):
        if isinstance(term, BodySlipTerm):
            return None  # three points: moved_markers
        return super().moved_marker(term, theta, std)

    def moved_markers(self, term, theta, std):
        if not isinstance(term, BodySlipTerm):
            return super().moved_markers(term, theta, std)
        th = np.asarray(theta, float).reshape(3, 3)
        sd = np.asarray(std, float).reshape(3, 3) if std is not None else np.full((3, 3), np.nan)
        return [(int(m), th[j], sd[j]) for j, m in enumerate(term.points)]

    def correction(self, where, unwritten=None):
        body = where.get("rigid_body")
        if body is None:
            return super().correction(where, unwritten)
        fitted = f"in the data: rigid body {body} is fitted at both placements (its three points stepped together)"
        if unwritten is None:
            return f"{fitted}; calibration.yaml holds its placement after the slip"
        return (f"{fitted}; fitting both placements predicts the held-out poses from the slip on at {unwritten}: "
                f"calibration.yaml is the fit without the slip")

    def body_term(self, body: str, points: list[int], t_slip: float) -> BodySlipTerm:
        names = [f"{s}_{a}" for s in FRAME_POINT_SUFFIXES for a in ("dx", "dy", "dz")]
        return BodySlipTerm(self.name, names, np.zeros(9), ["m"] * 9,
                            {"rigid_body": str(body), "point_indices": [int(p) for p in points],
                             "from_time_s": float(t_slip)},
                            points=[int(p) for p in points], t_slip=float(t_slip))

    def candidates(self, spec, poses, residuals=None):
        bodies = frame_point_indices(list(poses.marker_names))
        on_body = {poses.marker_names[i] for pts in bodies.values() for i in pts}
        out = [t for t in super().candidates(spec, poses, residuals) if t.where.get("marker") not in on_body]
        if residuals is None:
            return out
        t = history(poses, "elapsed")
        order = np.argsort(t, kind="stable")
        ts, r = t[order], residuals[order]
        for body, pts in bodies.items():
            k, F = change_point(r[:, pts, :].reshape(len(ts), -1))
            if k <= 0 or F < step_level(len(ts)) or not body_steps(r, k, pts):
                continue
            # as a marker's: the geometry absorbs part of the step, so the neighbouring rows compete
            for j in (k - 1, k, k + 1):
                if 1 <= j < len(ts):
                    out.append(self.body_term(body, pts, 0.5 * (ts[j - 1] + ts[j])))
        return out

    def from_dict(self, data, spec=None):
        where = stored_where(data)
        if "rigid_body" not in where:
            return super().from_dict(data, spec)
        pts = where.get("point_indices")
        if not isinstance(pts, list) or len(pts) != 3 or any(isinstance(p, bool) or not isinstance(p, int) or p < 0
                                                              for p in pts):
            raise BadInput("effect 'marker_slip': where.point_indices of a rigid body must be three integers >= 0")
        return self.body_term(where["rigid_body"], pts, stored_number(where, "from_time_s", self.name))
