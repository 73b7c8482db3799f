"""The virtual servo along a dense Cartesian trajectory ("linear interpolation"): waypoints
densified (linear in position, SLERP in rotation, bounded steps), each sample reached by the
tracking servo of :mod:`platkit.chains.servo` from the previous one, optionally in a moving frame.

Units: metres and radians; time in seconds.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from platkit.chains.chain import KinematicChain
from platkit.chains.servo import Servo
from platkit.chains.tasks import ServoOptions, Task, failure_message
from platkit.chains.transforms import interpolate_pose
from platkit.errors import BadInput, OutOfWorkspace
from platkit.geometry import rotvec_from_matrix


@dataclass
class TrajectoryResult:
    """Joint path along a trajectory: sample times (s,), configurations (s, n), and the pose
    errors (m, rad) at each sample, plus the index of the waypoint segment of each sample."""

    times: np.ndarray
    thetas: np.ndarray
    position_errors: np.ndarray
    rotation_errors: np.ndarray
    segment: np.ndarray
    iterations: int


def densify(times: np.ndarray, poses: np.ndarray, max_linear: float, max_angular: float):
    """Samples between waypoints: linear in position, SLERP in rotation, each step at most
    ``max_linear`` m and ``max_angular`` rad. ``times`` (k,), ``poses`` (k, 4, 4) ->
    (times (s,), poses (s, 4, 4), segment index (s,))."""

    out_t, out_p, seg = [float(times[0])], [poses[0]], [0]
    for k in range(len(times) - 1):
        a, b = poses[k], poses[k + 1]
        dist = float(np.linalg.norm(b[:3, 3] - a[:3, 3]))
        ang = float(np.linalg.norm(rotvec_from_matrix(b[:3, :3] @ a[:3, :3].T)))
        n = max(1, int(np.ceil(max(dist / max_linear, ang / max_angular))))
        for i in range(1, n + 1):
            s = i / n
            out_t.append(float((1 - s) * times[k] + s * times[k + 1]))
            out_p.append(interpolate_pose(a, b, s))
            seg.append(k)
    return np.array(out_t), np.array(out_p), np.array(seg)


def _densify_moving(st, sp, seg, moving_frame, max_linear, max_angular):
    """Carry local samples into the moving frame, adding samples where its own motion makes a
    step longer than the limits (the frame may move between two equal local poses)."""

    out_t, out_p, out_s = [st[0]], [moving_frame(st[0]) @ sp[0]], [seg[0]]
    for k in range(1, len(st)):
        a = moving_frame(st[k - 1]) @ sp[k - 1]
        b = moving_frame(st[k]) @ sp[k]
        dist = float(np.linalg.norm(b[:3, 3] - a[:3, 3]))
        ang = float(np.linalg.norm(rotvec_from_matrix(b[:3, :3] @ a[:3, :3].T)))
        n = max(1, int(np.ceil(max(dist / max_linear, ang / max_angular))))
        for i in range(1, n + 1):
            s = i / n
            t = (1 - s) * st[k - 1] + s * st[k]
            out_t.append(t)
            out_p.append(moving_frame(t) @ interpolate_pose(sp[k - 1], sp[k], s))
            out_s.append(seg[k])
    return np.array(out_t), np.array(out_p), np.array(out_s)


def follow_trajectory(chain: KinematicChain, link: str, times: np.ndarray, poses: np.ndarray, *,
                      frame: str = "world", theta0: np.ndarray | None = None, weights: np.ndarray | None = None,
                      basis: str = "reference", options: ServoOptions | None = None,
                      moving_frame: Callable[[float], np.ndarray] | None = None,
                      max_linear_step: float = 0.005, max_angular_step: float = 0.02,
                      sample_iterations: int = 100) -> TrajectoryResult:
    """Follow waypoints ``poses`` (k, 4, 4) at ``times`` (k,) by the virtual servo.

    The trajectory is resampled densely (:func:`densify`); the servo runs to each sample from
    the previous solution. ``frame``: the link the poses are given in (a moving local frame if
    joints move it); ``moving_frame``: t -> frame_from_poses (4, 4), an extra, externally moving
    frame (a conveyor, a head) whose placement at time t carries the poses into ``frame``.
    Raises OutOfWorkspace naming the time and waypoint segment of the first missed sample.
    """
    times = np.asarray(times, float)
    poses = np.asarray(poses, float)
    if times.ndim != 1 or poses.shape != (times.size, 4, 4) or times.size < 1:
        raise BadInput("trajectory: expected k times and k 4x4 poses")
    if np.any(np.diff(times) < 0):
        raise BadInput("trajectory: times must not decrease")
    options = options or ServoOptions()
    w = np.ones(6) if weights is None else np.asarray(weights, float)
    st, sp, seg = densify(times, poses, max_linear_step, max_angular_step)
    if moving_frame is not None:
        st, sp, seg = _densify_moving(st, sp, seg, moving_frame, max_linear_step, max_angular_step)
    theta = chain.neutral() if theta0 is None else chain.check_configuration(theta0, "starting configuration")
    first_opts = ServoOptions(**{**options.__dict__})
    sample_opts = ServoOptions(**{**options.__dict__, "max_iterations": sample_iterations})
    thetas, pos, rot = [], [], []
    total = 0
    for i, (t, P) in enumerate(zip(st, sp)):
        task = Task(link, P, frame=frame, weights=w, basis=basis)
        servo = Servo(chain, [task], first_opts if i == 0 else sample_opts)
        res = servo.run(theta)
        total += res.iterations
        if not res.converged:
            where = "the first waypoint" if i == 0 else f"t = {t:.6g} s (between waypoints {seg[i]} and {seg[i] + 1})"
            raise OutOfWorkspace(f"trajectory not followed at {where}: " + failure_message([task], res))
        theta = res.theta
        thetas.append(theta.copy())
        pos.append(res.position_error)
        rot.append(res.rotation_error)
    return TrajectoryResult(st, np.array(thetas), np.array(pos), np.array(rot), seg, total)
