"""Rigid bodies in a calibration from motion: body samples served and placements read back, with
the bodies served at the stream's nodes (platkit.calibrate.motion_bodies) against the rule before
(body samples served only where their window is kept as raw samples), in the same run.

For each stand and seed: the physical simulator streams a continuous path (`platkit simulate
--physics --motion path --rigid-bodies 2 --white-noise`, --duration-s at --rate-hz, --noise-mm),
a Stewart stand and a tree (tests/data/trees/two_arm_torso.urdf, both hands tracked, one body on
each); `calibrate_motion` (first-order response) fits it twice: as it is ("nodes") and with the
bodies at the nodes withheld ("raw only": the rule before). Printed per body: samples served of
those in the stream, and the worst error of a marker seen from the body's frame (fitted against
true, what does not depend on the link frame the fit chose; on a tree the markers of the body's
link), in mm and over its tolerance, three sigmas of the body's noise over the root of the samples
served (tests/unit/test_motion_bodies.py's bound: 3 (sqrt(6) sigma_p + sqrt(2) sigma_r r) /
sqrt(N)); under 1 is within.

    .venv/bin/python benchmarks/motion_bodies.py [--seeds 7813,7814] [--stands stewart,tree]
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate import motion
from platkit.calibrate.motion_bodies import body_samples_said
from platkit.calibrate.stream import stream_windows
from platkit.cli import main
from platkit.geometry import matrix_from_rotvec
from platkit.io.session import load_session
from platkit.simulate.physics import BODY_LEVER_M

ROOT = Path(__file__).resolve().parents[1]
STANDS = {"stewart": ["--platform", "stewart"],
          "tree": ["--platform", "urdf", "--description", str(ROOT / "tests" / "data" / "trees" / "two_arm_torso.urdf"),
                   "--moving-link", "right_tcp,left_tcp"]}


def _raw_only(fields: dict, win) -> dict:
    """The bodies at the rows of windows kept raw alone (the rule before)."""
    if not fields:
        return fields
    node = win.n_eff.max(axis=1) > 1.0 if win.n_eff.size else np.zeros(len(win.t), bool)
    bodies, counts = fields["bodies"].copy(), fields["n_body_samples"].copy()
    bodies[node], counts[node] = np.nan, 0.0
    return {**fields, "bodies": bodies, "n_body_samples": counts}


def placement_ratios(cal, truth, session, noise, n_used) -> dict[str, tuple[float, float]]:
    """Per body, the worst marker error seen from the body's frame (mm) and that over its tolerance."""
    sp, sr = noise["position_m"] * 1e3, noise["rotation_rad"]
    out = {}
    for j, body in enumerate(session.body_names):
        true = truth["rigid_bodies"][body]
        o_t, R_t = np.array(true["position"]) * 1e3, matrix_from_rotvec(np.array(true["rotation_vector"]))
        o_f, R_f = cal.body_positions[j] * 1e3, matrix_from_rotvec(cal.body_rotvecs[j])
        worst, worst_mm = 0.0, 0.0
        links = session.moving_link if isinstance(session.moving_link, dict) else None
        for i, m in enumerate(cal.marker_names):
            if m not in truth["markers"] or (links is not None and links.get(m) != links.get(body)):
                continue  # a tree's markers on another link than the body's
            v_t = R_t.T @ (np.array(truth["markers"][m]) * 1e3 - o_t)
            v_f = R_f.T @ (cal.marker_positions[i] * 1e3 - o_f)
            tol = 3.0 * (np.sqrt(6.0) * sp + np.sqrt(2.0) * sr * np.linalg.norm(v_t)) / np.sqrt(n_used[body])
            worst = max(worst, float(np.linalg.norm(v_f - v_t) / tol))
            worst_mm = max(worst_mm, float(np.linalg.norm(v_f - v_t)))
        out[body] = (worst_mm, worst)
    return out


def run(stand: str, seed: int, args, folder: Path) -> None:
    sim = folder / f"{stand}_{seed}"
    assert main(["simulate", *STANDS[stand], "--physics", "--motion", "path", "--duration-s", str(args.duration_s),
                 "--rate-hz", str(args.rate_hz), "--noise-mm", str(args.noise_mm), "--white-noise",
                 "--rigid-bodies", "2", "--seed", str(seed), "--unit", "mm", "--out", str(sim)]) == 0
    session = load_session(sim)
    truth = yaml.safe_load((sim / "truth.yaml").read_text())
    spec = session.spec
    # the simulator's body noise (not declared in session.yaml): the markers' white noise, its rotation over the lever
    noise = {"position_m": args.noise_mm * 1e-3, "rotation_rad": args.noise_mm * 1e-3 / BODY_LEVER_M}
    rows = []
    for label in ("raw only", "nodes"):
        original = motion.bodies_at_samples
        if label == "raw only":
            motion.bodies_at_samples = lambda s, w, f=original: _raw_only(f(s, w), w)  # type: ignore[assignment]
        try:
            cal, _ = motion.calibrate_motion(session, spec, kind="first_order")
        finally:
            motion.bodies_at_samples = original
        said = cal.motion["samples"]["rigid_bodies"]
        if label == "raw only":  # served: those at raw rows
            win = stream_windows(session, start_t=cal.motion["samples"]["start_transient"].get("until_s"),
                                 end_t=cal.motion["samples"]["log_end_s"])
            seen = np.isfinite(session.bodies).all(axis=2)
            raw = np.zeros(len(seen), bool)
            for _, a, n, per in win.blocks:
                if per is None:
                    raw[a:a + n] = True
            raw &= np.isfinite(session.markers).all(axis=2).any(axis=1)
            used = {b: int((seen[:, j] & raw).sum()) for j, b in enumerate(session.body_names)}
        else:
            used = {b: said["per_body"][b]["n_used"] for b in session.body_names}
            assert said == body_samples_said(session, stream_windows(
                session, start_t=cal.motion["samples"]["start_transient"].get("until_s"),
                end_t=cal.motion["samples"]["log_end_s"]))
        ratios = placement_ratios(cal, truth, session, noise, used)
        rows.append((label, used, said["per_body"], ratios))
    for label, used, per, ratios in rows:
        text = ", ".join(f"{b} {used[b]} of {per[b]['n_samples']} served, error {ratios[b][0]:.3f} mm "
                         f"= {ratios[b][1]:.2f} tol" for b in used)
        print(f"{stand} seed {seed} {label:>8}: {text}", flush=True)


def cli() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="7813,7814")
    ap.add_argument("--stands", default="stewart,tree")
    ap.add_argument("--duration-s", type=float, default=20.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--noise-mm", type=float, default=0.2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for stand in args.stands.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                run(stand, seed, args, Path(tmp))


if __name__ == "__main__":
    cli()
