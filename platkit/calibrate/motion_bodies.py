"""Rigid bodies in a calibration from motion (:mod:`platkit.calibrate.motion`): which body samples
serve, how a window reduced to nodes reduces them, and what is said of the others.

The stream's samples serve as the rows of :class:`platkit.calibrate.stream.StreamWindows`: the
windows kept as samples (each row one sample, its model the stand at the controls the response
reached then: exact, no reduction) and the nodes of the others (each marker coordinate fitted by a
polynomial in time). A body sample (origin and orientation, :mod:`platkit.bodies`) serves as the
markers do (:func:`bodies_at_samples`):
- in a window kept as samples, at its row (a marker seen there): its link's pose at that sample;
- in a window reduced to nodes, where the body is seen in at least MIN_SEEN_SHARE of the window's
  samples (and 2 ``nodes``) and on both sides of every node
  (:func:`platkit.calibrate.stream.seen_around_nodes`), as the body's pose at the window's nodes: its origin fitted by the
  markers' polynomial in time (:func:`platkit.calibrate.stream.window_fit` from the samples where
  it is seen), its orientation as the mean rotation of those samples (scipy's
  ``Rotation.mean``, the chordal L2 mean) times the same polynomial fit of each sample's rotation
  vector from that mean (the tangent space there), and each node worth the samples it stands for
  (the inverse of the fit's variance there, as a marker's node is weighted). The markers' nodes
  are corrected for the kinematics' curvature; a body's are not (the correction needs the body's
  placement, which the fit estimates): that error is second order in the window's motion.
Nothing is dropped silently: :func:`body_samples_said` counts the body samples used and those not
used, by cause, per body; the caller puts that in the report (``motion.samples.rigid_bodies``) and,
where some are not used, in a warning (:func:`say_bodies`). A session with bodies and no markers is
refused here (:func:`platkit.calibrate.stream.check_motion_session`): it is calibrated with each body
read as three points (:mod:`platkit.calibrate.motion_points`).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from platkit.calibrate.stream import MIN_SEEN_SHARE, StreamWindows, seen_around_nodes, window_fit
from platkit.io.calibration import Calibration
from platkit.io.session import Session

__all__ = ["bodies_at_samples", "body_samples_said", "say_bodies"]

#: which body samples serve (said in the report)
RULE = ("a body sample (origin and orientation) serves as the markers' samples do: in a window kept as samples, at "
        "its row (a marker seen there), as its link's pose at the controls the response reached then; in a window "
        f"reduced to nodes where the body is seen in at least {MIN_SEEN_SHARE:.0%} of the samples and on both sides "
        "of every node, as the body's pose at the nodes: its origin by the markers' "
        "polynomial in time, its orientation as the samples' mean rotation times the same polynomial fit of each "
        "sample's rotation vector from it, each node weighted by the samples it stands for; not used: those before "
        "the second command (the stand's place is not logged there), in the first command's transient, past the end "
        "of a command log cut in motion (the commands the stand followed there are not logged), in windows "
        "left out (too short to fit, or kept raw with no marker seen), in windows where the body is seen too "
        "little, and in windows kept raw at samples with no marker seen")

#: the causes a body sample is not used for (body_samples_said's keys)
CAUSES = ("n_before_second_command", "n_in_start_transient", "n_past_the_log", "n_in_windows_left_out",
          "n_seen_too_little", "n_at_samples_with_no_marker")


def _node_pose(t: np.ndarray, k: np.ndarray, samples: np.ndarray, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """A body's pose at the nodes (nodes, 7) (origin; qw, qx, qy, qz, qw >= 0) of the window whose
    samples are at times ``t``, from its samples (len(k), 7) at the window's samples ``k`` (those
    where it is seen), and what each node is worth in samples (nodes,) (module docstring)."""
    A, n_eff = window_fit(t, nodes, k)
    rot = Rotation.from_quat(samples[:, 3:], scalar_first=True)
    mean = rot.mean()
    at_nodes = mean * Rotation.from_rotvec(A @ (mean.inv() * rot).as_rotvec())
    q = at_nodes.as_quat(canonical=True, scalar_first=True)
    return np.concatenate([A @ samples[:, :3], q], axis=1), n_eff


def _reduced(session: Session, win: StreamWindows) -> tuple[np.ndarray, np.ndarray, dict]:
    """The body samples on the rows of ``win``: bodies (P, B, 7), what each is worth in samples
    (P, B), and per cause a mask (K, B) over the session's samples (``n_used`` and CAUSES'
    window-made ones)."""
    bodies_in = np.asarray(session.bodies, float)
    K, B = bodies_in.shape[:2]
    seen = np.isfinite(bodies_in).all(axis=2)
    P = len(win.t)
    bodies, counts = np.full((P, B, 7), np.nan), np.zeros((P, B))
    masks = {k: np.zeros((K, B), bool) for k in ("n_used", "n_seen_too_little", "n_at_samples_with_no_marker")}
    ends = [blk[0] for blk in win.blocks[1:]] + [P]
    for (p, a, n, per), end in zip(win.blocks, ends):
        if per is None:  # kept as samples: one row per sample with a marker seen
            k = win.first + win.proj.indices[win.proj.indptr[p:end]]
            bodies[p:end] = np.where(seen[k][:, :, None], bodies_in[k], np.nan)
            counts[p:end] = seen[k]
            masks["n_used"][k] = seen[k]
            masks["n_at_samples_with_no_marker"][a:a + n] = seen[a:a + n]
            masks["n_at_samples_with_no_marker"][k] = False
            continue
        for j in range(B):
            k = np.nonzero(seen[a:a + n, j])[0]
            if not seen_around_nodes(session.marker_t[a:a + n], k, win.nodes):
                masks["n_seen_too_little"][a + k, j] = True
                continue
            bodies[p:p + win.nodes, j], counts[p:p + win.nodes, j] = _node_pose(
                session.marker_t[a:a + n], k, bodies_in[a + k, j], win.nodes)
            masks["n_used"][a + k, j] = True
    return bodies, counts, masks


def bodies_at_samples(session: Session, win: StreamWindows) -> dict:
    """The PoseSet fields (``bodies``, ``body_names``, ``n_body_samples``, ``body_noise``) that put
    the session's body samples on the rows of ``win`` (module docstring): a raw row's worth one
    sample, a node's the samples it stands for. Empty without bodies."""
    if not session.body_names or session.bodies is None:
        return {}
    bodies, counts, _ = _reduced(session, win)
    return {"bodies": bodies, "body_names": list(session.body_names), "n_body_samples": counts,
            "body_noise": dict(session.body_noise)}


def body_samples_said(session: Session, win: StreamWindows) -> dict | None:
    """The session's body samples (a body seen at a sample: origin and orientation finite), per
    body and in all: ``n_samples`` in the stream, ``n_used`` (:func:`bodies_at_samples`), and those
    not used, by cause (CAUSES): before the second command, in the first command's transient (left
    out of the stream), past the end of a command log cut in motion (left out of the stream:
    :func:`platkit.calibrate.stream.past_log_end`), in windows left out (too short to fit, the stream's end, or kept raw with no
    marker seen), in windows reduced to nodes where the body is seen too little, and in windows
    kept raw at samples with no marker seen. The causes and ``n_used`` add up to ``n_samples``.
    None without bodies."""
    if not session.body_names or session.bodies is None:
        return None
    seen = np.isfinite(np.asarray(session.bodies, float)).all(axis=2)  # (K, B)
    _, _, masks = _reduced(session, win)
    idx = np.arange(len(seen))
    second = win.second if win.second >= 0 else win.first
    end = len(seen) if win.end is None else win.end
    in_block = np.zeros(len(seen), bool)
    for _, a, n, _ in win.blocks:
        in_block[a:a + n] = True
    parts = {"n_samples": seen, "n_used": masks["n_used"], "n_before_second_command": seen & (idx < second)[:, None],
             "n_in_start_transient": seen & ((idx >= second) & (idx < win.first))[:, None],
             "n_past_the_log": seen & (idx >= end)[:, None],
             "n_in_windows_left_out": seen & ((idx >= win.first) & (idx < end) & ~in_block)[:, None],
             "n_seen_too_little": masks["n_seen_too_little"],
             "n_at_samples_with_no_marker": masks["n_at_samples_with_no_marker"]}
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
            f"rigid bodies {', '.join(said['bodies'])}: {said['n_used']} of {said['n_samples']} body samples used; "
            f"{left} not used ({said['n_before_second_command']} before the second command, "
            f"{said['n_in_start_transient']} in the first command's transient, {said['n_past_the_log']} past the end "
            f"of the command log, {said['n_in_windows_left_out']} in "
            f"windows left out, {said['n_seen_too_little']} in windows where the body is seen too little, "
            f"{said['n_at_samples_with_no_marker']} at samples with no marker seen) "
            "(report: motion.samples.rigid_bodies)")
