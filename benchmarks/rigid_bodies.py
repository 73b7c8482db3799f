"""Rigid bodies measured in 6 DOF: how close the fit comes to its Cramer-Rao bound, how well the
rotation weight rho is estimated, and the same data given as four markers.

    .venv/bin/python benchmarks/rigid_bodies.py [--platform stewart] [--seeds 8] [--poses 60]

Per seed, settled poses of one body are drawn by the additive simulator (platkit.simulate,
``n_bodies=1``, markers left out; 0.1 mm and 0.05 deg per sample, averaged over each hold):
1. declared noise: the fit's prediction error of the body at 40 new commands against the
   noise-free truth, beside the error its covariance expects (the CRB with the noise declared
   right), for the origin and the rotation (x rho) channels: the ratio should be near 1;
2. undeclared noise: rho estimated from the residuals, as a ratio to the true
   sigma_position / sigma_rotation;
3. the same poses given as four markers (the body's origin and axis tips at 0.1 m): the RMS
   distance between the two fits' predicted body origins, beside the body fit's CRB.
Single process, a few seconds per seed.
"""
from __future__ import annotations

import argparse

import numpy as np

from platkit.calibrate.estimate import calibrate, predict_bodies, predict_markers
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate import simulate


def bodies_only(poses: PoseSet, declared: bool) -> PoseSet:
    return PoseSet(poses.platform, poses.controls, np.zeros((poses.n_poses, 0, 3)), [], t=poses.t,
                   bodies=poses.bodies, body_names=list(poses.body_names), n_body_samples=poses.n_body_samples,
                   body_noise=dict(poses.body_noise) if declared else {}, length_unit=poses.length_unit)


def as_markers(poses: PoseSet, arm_m: float) -> PoseSet:
    o, R = poses.bodies[:, 0, :3], matrix_from_quat(poses.bodies[:, 0, 3:])
    Y = np.stack([o] + [o + arm_m * R[..., :, k] for k in range(3)], axis=1)
    return PoseSet(poses.platform, poses.controls, Y, ["O", "X", "Y", "Z"], t=poses.t, length_unit=poses.length_unit)


def truth_bodies(sim, U) -> np.ndarray:
    """(N, 1, 7) the noise-free body at controls U, from the simulation's truth."""
    spec, tr = sim.spec, sim.truth
    fb = PlatformModel(spec).forward_batch(U, tr.td, strict=False)
    T = tr.mocap_from_base
    R = T[:3, :3] @ matrix_from_quat(fb.q)
    o = fb.X @ T[:3, :3].T + T[:3, 3] + np.einsum("nab,b->na", R, tr.body_origins[0])
    q = quat_from_matrix(R @ matrix_from_rotvec(tr.body_rotvecs[0]))
    return np.concatenate([o, q], axis=1)[:, None, :]


def crb_ratio(cal, sim, U):
    test = PoseSet(cal.platform, U, np.zeros((len(U), 0, 3)), [], bodies=truth_bodies(sim, U), body_names=["T1"])
    problem, z, active = cal.fit.problem, cal.fit.z, cal.fit.active
    st = problem.evaluate(z, with_jac=True, poses=test)
    J = st.J[..., active]
    var = np.einsum("nmaj,jk,nmak->nm", J, cal.fit.cov, J)
    err = np.sqrt(np.mean(np.sum(st.r ** 2, axis=2), axis=0))
    return err, np.sqrt(np.mean(var, axis=0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--platform", default="stewart")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--poses", type=int, default=60)
    args = ap.parse_args()
    spec = get_platform(args.platform)
    print(f"{args.platform}, {args.poses} settled poses of one rigid body per seed")
    print("seed  err/CRB origin  err/CRB rotation  rho_est/rho_true  |origin(body) - origin(4 markers)| / CRB")
    rows = []
    for seed in range(1, args.seeds + 1):
        sim = simulate(spec, seed=seed, n_poses=args.poses, raw=False, n_bodies=1)
        rho_true = sim.truth.body_noise["position_m"] / sim.truth.body_noise["rotation_rad"]
        U_new = sim.poses.controls[np.random.default_rng(seed).permutation(sim.poses.n_poses)[:40]]
        declared = calibrate(bodies_only(sim.poses, True), spec)
        err, crb = crb_ratio(declared, sim, U_new)
        estimated = calibrate(bodies_only(sim.poses, False), spec)
        markers = calibrate(as_markers(sim.poses, 0.1), spec)
        _, q, X, _ = predict_markers(declared, U_new)
        o_body = predict_bodies(declared, q, X)[:, 0, :3]
        o_markers = predict_markers(markers, U_new)[0][:, 0]
        d = np.sqrt(np.mean(np.sum((o_body - o_markers) ** 2, axis=1)))
        row = (err[0] / crb[0], err[1] / crb[1], estimated.body_rho / rho_true, d / crb[0])
        rows.append(row)
        print(f"{seed:4d}  {row[0]:14.2f}  {row[1]:16.2f}  {row[2]:16.3f}  {row[3]:10.2f}")
    a = np.array(rows)
    print(f"range {a.min(axis=0).round(2).tolist()} .. {a.max(axis=0).round(2).tolist()} "
          "(reference: 1, 1, 1, below 1)")


if __name__ == "__main__":
    main()
