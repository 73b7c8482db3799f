"""Rigid bodies in a calibration from motion (:mod:`platkit.calibrate.motion`): which body samples
serve, and what is said of the others.

The stream's samples serve as the rows of :class:`platkit.calibrate.stream.StreamWindows`: the
windows kept as samples (each row one sample, its model the stand at the controls the response
reached then: exact, no reduction) and the nodes of the others (each marker coordinate fitted by a
polynomial in time, corrected for the kinematics' curvature). A body sample (origin and
orientation, :mod:`platkit.bodies`) serves where its sample is a row of a window kept as samples:
it gives its link's pose there, a position and an orientation observation each worth one sample
(the estimator weighs the orientation by rho, declared or estimated, as for settled poses). A
body's orientation has no reduction to the nodes here, so the body samples in windows reduced to
nodes are not used; nothing is dropped silently: :func:`body_samples_said` counts the body
samples used and those not used, by cause, per body; the caller puts that in the report
(``motion.samples.rigid_bodies``) and, where some are not used, in a warning
(:func:`say_bodies`). A session with bodies and no markers is refused
(:func:`platkit.calibrate.stream.check_motion_session`).
"""
from __future__ import annotations

import numpy as np

from platkit.calibrate.stream import StreamWindows
from platkit.io.calibration import Calibration
from platkit.io.session import Session

__all__ = ["bodies_at_samples", "body_samples_said", "say_bodies"]

#: which body samples serve (said in the report)
RULE = ("a body sample (origin and orientation) serves where its sample is kept as a sample (a window kept raw, a "
        "marker seen there): its link's pose at the controls the response reached then, a position and an "
        "orientation observation each worth one sample; a body's orientation has no reduction to the windows' nodes "
        "(each marker coordinate's polynomial in time, corrected for the kinematics' curvature), so the body samples "
        "of the windows reduced to nodes are not used, nor those before the second command (the stand's place is "
        "not logged there)")


def _raw_rows(win: StreamWindows) -> np.ndarray:
    """The rows of ``win`` that are samples (windows kept raw), in order."""
    ends = [b[0] for b in win.blocks[1:]] + [len(win.t)]
    return np.array([r for (p, _, _, per), end in zip(win.blocks, ends) if per is None for r in range(p, end)], int)


def _row_samples(win: StreamWindows, rows: np.ndarray) -> np.ndarray:
    """The stream's sample (index into the session's samples) of each raw row: its one column of proj."""
    return win.first + win.proj.indices[win.proj.indptr[rows]]


def bodies_at_samples(session: Session, win: StreamWindows) -> dict:
    """The PoseSet fields (``bodies``, ``body_names``, ``n_body_samples``, ``body_noise``) that put
    the session's body samples on the rows of ``win`` kept as samples, each worth one sample; the
    nodes carry none (module docstring). Empty without bodies."""
    if not session.body_names or session.bodies is None:
        return {}
    P, B = len(win.t), len(session.body_names)
    bodies, counts = np.full((P, B, 7), np.nan), np.zeros((P, B))
    rows = _raw_rows(win)
    if len(rows):
        bodies[rows] = session.bodies[_row_samples(win, rows)]
        counts[rows] = np.isfinite(bodies[rows]).all(axis=2)
        bodies[counts == 0] = np.nan  # a body partly written is not seen
    return {"bodies": bodies, "body_names": list(session.body_names), "n_body_samples": counts,
            "body_noise": dict(session.body_noise)}


def body_samples_said(session: Session, win: StreamWindows) -> dict | None:
    """The session's body samples (a body seen at a sample: origin and orientation finite), per
    body and in all: ``n_samples`` in the stream, ``n_used`` (:func:`bodies_at_samples`), and those
    not used: ``n_before_second_command``, ``n_in_start_transient`` (the first command's
    transient, left out of the stream) and ``n_not_kept_as_samples`` (after it, in windows
    reduced to nodes, too short to fit, or at a sample with no marker seen). None without bodies."""
    if not session.body_names or session.bodies is None:
        return None
    seen = np.isfinite(np.asarray(session.bodies, float)).all(axis=2)  # (K, B)
    raw = np.zeros(len(seen), bool)
    raw[_row_samples(win, _raw_rows(win))] = True
    idx = np.arange(len(seen))
    second = win.second if win.second >= 0 else win.first
    before = (idx < second)[:, None]
    transient = ((idx >= second) & (idx < win.first))[:, None]  # the first command's transient, left out
    parts = {"n_samples": seen, "n_used": seen & raw[:, None], "n_before_second_command": seen & before,
             "n_in_start_transient": seen & transient, "n_not_kept_as_samples": seen & ~raw[:, None] & ~before & ~transient}
    per_body = {str(b): {k: int(v[:, j].sum()) for k, v in parts.items()} for j, b in enumerate(session.body_names)}
    return {"bodies": list(per_body), **{k: int(v.sum()) for k, v in parts.items()}, "per_body": per_body,
            "rule": RULE}


def say_bodies(session: Session, win: StreamWindows, cal: Calibration) -> None:
    """The session's body samples, used and not (:func:`body_samples_said`), said in ``cal``: in
    its report (``motion.samples.rigid_bodies``) and, where some are not used, in a warning;
    nothing where it has no bodies."""
    said = body_samples_said(session, win)
    if said is None:
        return
    cal.motion.setdefault("samples", {})["rigid_bodies"] = said
    left = said["n_samples"] - said["n_used"]
    if left:
        cal.warnings.append(
            f"rigid bodies {', '.join(said['bodies'])}: {said['n_used']} of {said['n_samples']} body samples used (the "
            f"samples of the windows kept as samples); {left} not used ({said['n_not_kept_as_samples']} in windows "
            f"reduced to nodes, where a body's orientation has no reduction, or at samples with no marker seen; "
            f"{said['n_before_second_command']} before the second command, {said['n_in_start_transient']} in the first "
            "command's transient) (report: motion.samples.rigid_bodies)")
