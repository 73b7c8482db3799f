"""Calibration from motion of rigid bodies alone (platkit.calibrate.motion_points: each body read as
three points) against the same stream with its markers (platkit.calibrate.motion, markers and
bodies), on the same samples.

For each seed: the physical simulator streams a continuous path on the Stewart stand without holds
(simulate_physics(motion='path', n_bodies=--bodies), --duration-s at 100 Hz, the nuisances it draws:
latency, clock offset, coloured noise, occlusion bursts); "markers": calibrate_motion on the session
as recorded (5 markers and the bodies); "bodies alone": the same session with the markers removed,
calibrate_motion_bodies. Each calibration predicts --test random reachable commands (not in the
stream: held out); printed, RMS over the commands in mm against the true stand (geometry, frame and
body placements from the simulator):
- body: each body's frame points (origin and axis tips at 0.1 m) predicted, what a user of the
  bodies alone gets;
- markers: the session's 5 markers predicted, with the bodies alone through the body's fitted link
  frame (the markers' true places on the link, carried through each calibration's own body
  placement: true marker seen from the true body, put on the fitted body), i.e. how well the stand's
  motion is predicted away from the bodies;
and the ratio bodies alone / markers of each, the fits' rms_after and their time.

    .venv/bin/python benchmarks/motion_bodies_alone.py [--seeds 2700001,2700002] [--bodies 1]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from platkit.bodies import AXIS_LENGTH_M
from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_points import calibrate_motion_bodies
from platkit.calibrate.plan import feasible
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.io.session import load_session
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session

#: a body's frame points in its frame: origin, the tips of its x and y axes
IN_BODY = np.array([[0.0, 0.0, 0.0], [AXIS_LENGTH_M, 0.0, 0.0], [0.0, AXIS_LENGTH_M, 0.0]])


def true_points(sim, U, body_points) -> np.ndarray:
    """The true stand's points (moving frame (P, 3) m) in the mocap frame at commands U (N, P, 3)."""
    fb = PlatformModel(sim.spec).forward_batch(U, td=sim.td, strict=False)
    T = sim.mocap_from_base
    return (fb.X[:, None, :] + np.einsum("kij,mj->kmi", matrix_from_quat(fb.q), body_points)) @ T[:3, :3].T + T[:3, 3]


def predicted_points(cal, U, points) -> np.ndarray:
    """``cal``'s prediction (N, P, 3) m at U of points given in its moving frame (P, 3) m."""
    one = replace(cal, marker_names=[f"p{k}" for k in range(len(points))], marker_positions=np.asarray(points, float),
                  marker_std=np.zeros((len(points), 3)), n_markers=len(points), body_names=[],
                  body_positions=np.zeros((0, 3)), body_rotvecs=np.zeros((0, 3)), body_std=np.zeros((0, 6)))
    return predict_markers(one, U)[0]


def rms_mm(a, b) -> float:
    return 1e3 * float(np.sqrt(np.nanmean(np.sum((a - b) ** 2, axis=2))))


def errors(cal, sim, U) -> tuple[float, float]:
    """RMS (mm) over U of the bodies' frame points, and of the markers carried on the fitted bodies."""
    body_true, body_pred, mk_true, mk_pred = [], [], [], []
    for j in range(len(sim.bodies.names)):
        Rt, ot = matrix_from_rotvec(sim.bodies.rotvecs[j]), sim.bodies.origins[j]
        Rf, of = matrix_from_rotvec(cal.body_rotvecs[j]), cal.body_positions[j]
        body_true.append(true_points(sim, U, ot + IN_BODY @ Rt.T))
        body_pred.append(predicted_points(cal, U, of + IN_BODY @ Rf.T))
        in_body = (sim.marker_body - ot) @ Rt  # each true marker seen from the true body
        mk_true.append(true_points(sim, U, sim.marker_body))
        mk_pred.append(predicted_points(cal, U, of + in_body @ Rf.T))
    return (rms_mm(np.concatenate(body_pred, 1), np.concatenate(body_true, 1)),
            rms_mm(np.concatenate(mk_pred, 1), np.concatenate(mk_true, 1)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="2700001,2700002")
    ap.add_argument("--bodies", type=int, default=1)
    ap.add_argument("--duration-s", type=float, default=40.0)
    ap.add_argument("--test", type=int, default=200)
    ap.add_argument("--kind", default="first_order")
    args = ap.parse_args()
    spec = get_platform("stewart")
    print("seed  fit            rms_after_mm  body_mm  markers_mm  time_s   [bodies alone / markers: body, markers]")
    for seed in (int(s) for s in args.seeds.split(",")):
        sim = simulate_physics(spec, seed=seed, motion="path", duration_s=args.duration_s, n_bodies=args.bodies)
        rng = np.random.default_rng([seed, 99])
        lo, hi = spec.control_bounds()
        U = spec.neutral_u() + (rng.uniform(size=(4 * args.test, spec.n_u)) - 0.5) * 0.6 * (hi - lo)
        U = U[feasible(spec, U, sim.td)[0]][:args.test]
        with tempfile.TemporaryDirectory() as tmp:
            write_physical_session(sim, Path(tmp) / "s")
            session = load_session(Path(tmp) / "s")
            alone = replace(session, marker_names=[], markers=np.zeros((len(session.marker_t), 0, 3)))
            got = {}
            for label, fit, s in (("markers", calibrate_motion, session), ("bodies alone", calibrate_motion_bodies, alone)):
                t0 = time.perf_counter()
                cal, _ = fit(s, spec, kind=args.kind)
                dt = time.perf_counter() - t0
                got[label] = errors(cal, sim, U)
                print(f"{seed}  {label:<13}  {1e3 * cal.rms_after:>11.4f}  {got[label][0]:>7.4f}  {got[label][1]:>10.4f}  "
                      f"{dt:>6.1f}", flush=True)
            a, m = got["bodies alone"], got["markers"]
            print(f"{seed}  ratio bodies alone / markers: body {a[0] / m[0]:.2f}, markers {a[1] / m[1]:.2f}", flush=True)


if __name__ == "__main__":
    main()
