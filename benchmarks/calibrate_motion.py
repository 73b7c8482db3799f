"""Calibration from motion beside the hold-based path, on the same stand (physical simulator).

For each seed (unseen while developing: 2600001 on), on the stewart stand with the nuisances the
simulator draws (latency, clock offset, coloured noise, occlusion bursts):
- holds: a session of --poses held commands, settled and calibrated (platkit.calibrate.estimate);
- no holds: a streamed session a third as long, calibrated from motion (platkit.calibrate.motion),
  its commands by --motion: ``multisine`` the simulator's random multisine (drawn from the seed),
  ``designed`` `plan --motion`'s D-optimal excitation (platkit.calibrate.excitation: the plan
  command's family (--period-s, --harmonics), margin and evaluations, designed once from
  --design-seed, whatever the session seed) within the rate and acceleration the simulator's
  slowest drives allow (a full stroke in the longest stroke time it draws, that rate reached in
  the longest acceleration time), kept to the share of them the simulator's own multisine keeps;
  ``via`` `plan --motion --family via`'s sweep (platkit.calibrate.via_points: D-optimal via points
  joined by time-optimal moves, designed for each session's length from --design-seed) within the
  same limits, ``via-random`` the same sweep through random candidates; several, comma-separated,
  side by side;
- slow actuator: the holds session with one actuator's time constant half the hold
  (settling_lag physics): settling refuses it; calibrated from motion.
Each calibration predicts --test random reachable commands; the error is against the true stand
(its geometry, markers and frame from the simulator), RMS over markers in mm. Prints per seed the
errors, each no-holds / holds ratio (goal <= 1.5; the seeds meeting it counted at the end), the
slow actuator's error (goal <= 0.01 mm) and its fitted time constant over the truth (goal within
10%; --no-slow leaves it out), and the share of each stroke every session's commands span (the
smallest over the controls).

    .venv/bin/python benchmarks/calibrate_motion.py [--seeds 2600001,2600002] [--poses 80]
        [--motion multisine,designed,via,via-random] [--no-slow]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.calibrate.excitation import MotionInformation, design_excitation
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.plan import default_marker_layout, feasible
from platkit.calibrate.sweeps import design_sweep
from platkit.calibrate.trajectories import FourierFamily, drive_limits, limit_violations, trajectory
from platkit.calibrate.via_points import design_via, via_trajectory
from platkit.errors import PlatkitError
from platkit.geometry import matrix_from_quat
from platkit.io.session import load_session
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.settle import load_poses
from platkit.simulate.continuous import LIMIT_SHARE
from platkit.simulate.nuisance import RANGES
from platkit.simulate.physics import simulate_physics, write_physical_session

#: `plan --motion`'s defaults: the family, the margin, the evaluations; commands per s
PERIOD_S, HARMONICS, MARGIN, EVALUATIONS, COMMAND_RATE_HZ = 40.0, 8, 0.1, 200, 20.0
MOTIONS = ("multisine", "designed", "via", "via-random")


def truth_error(cal, sim, U) -> float:
    """RMS (m) of the calibration's markers against the true stand's at commands U."""
    fb = PlatformModel(sim.spec).forward_batch(U, td=sim.td, strict=False)
    T = sim.mocap_from_base
    true = (fb.X[:, None, :] + np.einsum("kij,mj->kmi", matrix_from_quat(fb.q), sim.marker_body)) @ T[:3, :3].T + T[:3, 3]
    pred, _, _, _ = predict_markers(cal, U)
    return float(np.sqrt(np.nanmean(np.sum((pred - true) ** 2, axis=2))))


def session_of(sim, tmp: Path, name: str):
    folder = tmp / name
    write_physical_session(sim, folder)
    return load_session(folder)


class Designed:
    """`plan --motion`'s excitation for ``spec``, designed once: the rate limit a full stroke in the
    longest stroke time the simulator draws, the acceleration that rate in the longest acceleration
    time, both times LIMIT_SHARE (as the simulator's multisine keeps of its drawn drives')."""

    def __init__(self, spec, design_seed: int, period_s: float = PERIOD_S, harmonics: int = HARMONICS):
        lo, hi = spec.control_bounds()
        rate = LIMIT_SHARE * (hi - lo) / RANGES["stroke_time_s"][1]
        accel = LIMIT_SHARE * (hi - lo) / RANGES["stroke_time_s"][1] / RANGES["accel_time_s"][1]
        self.spec, self.limits = spec, drive_limits(spec, rate, accel, MARGIN)
        self.family = FourierFamily(period_s, harmonics, spec.n_u)
        info = MotionInformation(spec, default_marker_layout(spec, 5, np.random.default_rng(0)))
        t0 = time.perf_counter()
        self.design = design_excitation(spec, self.family, self.limits, info, COMMAND_RATE_HZ,
                                        np.random.default_rng(design_seed), evaluations=EVALUATIONS)
        print(f"designed excitation: period {period_s:g} s, {harmonics} harmonics, seed {design_seed}, {EVALUATIONS} "
              f"evaluations in {time.perf_counter() - t0:.0f} s, limits {rate[0] * 1e3:.0f} mm/s and "
              f"{accel[0] * 1e3:.0f} mm/s^2, margin {MARGIN}; criterion "
              f"{self.design.criterion_start:.2f} (its random start) -> {self.design.criterion:.2f}", flush=True)

    def commands(self, duration_s: float) -> tuple[np.ndarray, dict]:
        """The design's commands for ``duration_s`` s, and how much of the limits they use."""
        U, _ = trajectory(self.spec, self.family, self.design.coef, self.limits, duration_s, COMMAND_RATE_HZ)
        return U, limit_violations(U, COMMAND_RATE_HZ, self.limits)


class Swept:
    """`plan --motion --family via`'s sweep for ``spec`` within the same limits as :class:`Designed`,
    designed for each session's duration from ``design_seed`` (whatever the session seed):
    D-optimal via points, or (``random``) the candidates as drawn."""

    def __init__(self, spec, design_seed: int, random: bool = False):
        lo, hi = spec.control_bounds()
        rate = LIMIT_SHARE * (hi - lo) / RANGES["stroke_time_s"][1]
        accel = LIMIT_SHARE * (hi - lo) / RANGES["stroke_time_s"][1] / RANGES["accel_time_s"][1]
        self.spec, self.limits, self.seed, self.random = spec, drive_limits(spec, rate, accel, MARGIN), design_seed, random
        self.markers = default_marker_layout(spec, 5, np.random.default_rng(0))
        self.information = None if random else MotionInformation(spec, self.markers)

    def commands(self, duration_s: float) -> tuple[np.ndarray, dict]:
        if self.random:  # random candidates in the whole box
            d = design_via(self.spec, self.limits, self.markers, duration_s, COMMAND_RATE_HZ,
                           np.random.default_rng(self.seed), d_optimal_choice=False)
            U, scale = via_trajectory(d.path, self.limits, COMMAND_RATE_HZ)[0], 1.0
        else:  # plan --motion --family via's choice (platkit.calibrate.sweeps.design_sweep)
            chosen, _ = design_sweep(self.spec, self.limits, self.information, duration_s, COMMAND_RATE_HZ, 100.0, 1.0,
                                     2e-4, self.seed)
            d, U, scale = chosen.design, chosen.U, chosen.scale
        return U, {**limit_violations(U, COMMAND_RATE_HZ, self.limits), **d.info, "box_share": scale}


def stroke_share(spec, U) -> float:
    """The smallest over the controls of the share of the stroke the commands span."""
    lo, hi = spec.control_bounds()
    return float(np.min(np.ptp(U, axis=0) / (hi - lo)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="2600001")
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--test", type=int, default=200)
    ap.add_argument("--motion", default="multisine", help="the no-holds commands: multisine, designed, via, "
                    "via-random, several comma-separated")
    ap.add_argument("--design-seed", type=int, default=0, help="the designed excitation's seed (default 0)")
    ap.add_argument("--period-s", type=float, default=PERIOD_S, help="the design's period, s (plan's default)")
    ap.add_argument("--harmonics", type=int, default=HARMONICS, help="the design's harmonics (plan's default)")
    ap.add_argument("--no-slow", action="store_true", help="leave out the slow actuator's session")
    args = ap.parse_args()
    motions = [m.strip() for m in args.motion.split(",")]
    if not motions or any(m not in MOTIONS for m in motions):
        ap.error(f"--motion: each of {', '.join(MOTIONS)}, got {args.motion!r}")
    spec = get_platform("stewart")
    designed = Designed(spec, args.design_seed, args.period_s, args.harmonics) if "designed" in motions else None
    swept = {m: Swept(spec, args.design_seed, m == "via-random") for m in motions if m.startswith("via")}
    head = "seed  holds_mm  " + "  ".join(f"{m}_mm" for m in motions) + "  " + "  ".join(
        f"{m}/holds(goal<=1.5)" for m in motions)
    if not args.no_slow:
        head += "  slow_mm(goal<=0.01)  slow_tau/true(goal 0.9-1.1)"
    print(head + "  [stroke share, min over the controls: holds, " + ", ".join(motions) + "]")
    ratios: dict[str, list[float]] = {m: [] for m in motions}
    for seed in (int(s) for s in args.seeds.split(",")):
        rng = np.random.default_rng([seed, 99])
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            held = simulate_physics(spec, seed=seed, n_poses=args.poses, plan="random", mocap_rate_hz=100.0)
            lo, hi = spec.control_bounds()
            U = spec.neutral_u() + (rng.uniform(size=(4 * args.test, spec.n_u)) - 0.5) * 0.6 * (hi - lo)
            ok, _ = feasible(spec, U, held.td)
            U = U[ok][:args.test]
            s = session_of(held, tmp, "holds")
            cal_h = calibrate(load_poses(s.folder, spec=s.spec, session=s), s.spec)
            e_h = truth_error(cal_h, held, U)
            duration = float(held.marker_t[-1] - held.marker_t[0])
            e_m, share, notes = {}, [stroke_share(spec, held.commands)], []
            for m in motions:
                if m == "designed" or m in swept:
                    assert designed is not None or m in swept
                    Um, used = swept[m].commands(duration / 3) if m in swept else designed.commands(duration / 3)
                    stream = simulate_physics(spec, seed=seed, motion=Um, command_rate_hz=COMMAND_RATE_HZ,
                                              mocap_rate_hz=100.0)
                    vias = (f" ({used['via_points']} {used['choice']} via points in {used['box_share']:.0%} of the box)"
                            if m in swept else "")
                    notes.append(f"{m} {len(Um)} commands{vias}, {used['rate_share']:.2f}/{used['accel_share']:.2f} of "
                                 f"its rate/accel limits, {stream.plan_info['drive_rate_share']:.2f}/"
                                 f"{stream.plan_info['drive_accel_share']:.2f} of the drawn drives'"
                                 + (f", {stream.plan_info['unreachable_with_true_geometry']} unreachable dropped"
                                    if "unreachable_with_true_geometry" in stream.plan_info else ""))
                else:
                    stream = simulate_physics(spec, seed=seed, motion="multisine", duration_s=duration / 3,
                                              mocap_rate_hz=100.0)
                s = session_of(stream, tmp, m)
                cal_m, _ = calibrate_motion(s, s.spec)
                e_m[m] = truth_error(cal_m, stream, U)
                share.append(stroke_share(spec, stream.commands))
            for m in motions:
                ratios[m].append(e_m[m] / e_h)
            line = (f"{seed}  {e_h * 1e3:.4f}  " + "  ".join(f"{e_m[m] * 1e3:.4f}" for m in motions) + "  "
                    + "  ".join(f"{e_m[m] / e_h:.2f}" for m in motions))
            if args.no_slow:
                print(f"{line}  [{', '.join(f'{x:.2f}' for x in share)}]  {'; '.join(notes)}", flush=True)
                continue
            slow = simulate_physics(spec, seed=seed, n_poses=args.poses, plan="random", mocap_rate_hz=100.0,
                                    effects=[("settling_lag", 0.5)])
            s = session_of(slow, tmp, "slow")
            try:
                load_poses(s.folder, spec=s.spec, session=s)
                settled = "settled"
            except PlatkitError:
                settled = "refused"
            cal_s, _ = calibrate_motion(s, s.spec)
            e_s = truth_error(cal_s, slow, U)
            j = int(np.argmax(slow.response.tau_s))
            tau = cal_s.motion["response"]["actuators"][spec.control_names[j]]["tau_s"]["value"]
            print(f"{line}  {e_s * 1e3:.4f} (holds {settled})  {tau / slow.response.tau_s[j]:.3f}  "
                  f"[{', '.join(f'{x:.2f}' for x in share)}]  {'; '.join(notes)}", flush=True)
    for m, r in ratios.items():
        print(f"{m}: no-holds / holds {min(r):.2f} to {max(r):.2f} (median {np.median(r):.2f}); goal 1.5 met on "
              f"{sum(x <= 1.5 for x in r)}/{len(r)} seeds")


if __name__ == "__main__":
    main()
