"""A humanoid that picks up a load: diagnosis fitted with empty hands, then a later session with a
payload in one hand, predicted with `platkit predict --payload` and without.

    .venv/bin/python benchmarks/trees_payload.py [--seeds 24401] [--poses 40 --heldout 20] [--later 20]
        [--mass 2.0] [--bare]

The robot and its truth are benchmarks/trees_humanoid.py's (PAL's Talos upper body from
example-robot-data, elastic torso and shoulder/elbow joints, bending links, origin errors and zero
offsets drawn per seed, three markers on each hand, 0.1 mm mocap noise). The first session (fit
and held-out poses) is recorded with empty hands; `platkit calibrate` then `platkit diagnose` run
on it with no options. The later session (new poses, the same truth, markers and mocap) is
recorded by the elastic simulator with ``--mass`` kg in the left hand (10 cm beyond the wrist
link's origin along its z axis: a held tool or part); its session.yaml says so. Printed per seed
and hand, the later session's mean marker error (mm): the rigid calibration, diagnose's model
without the payload (as if the hand were empty) and with it (`predict --payload`), and the true
elastic model (the noise floor); and the payload's own sag (the truth with and without it).
``--bare``: the calibration sees the URDF without inertias; diagnose then fits compliance on a
prior of loads of unknown size, and `predict --payload` must be refused (it was 4x worse than no
payload before it was).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trees_humanoid import HANDS, RECORDED, draw, later_commands, per_hand, upper_body  # noqa: E402

from platkit.cli import main as cli  # noqa: E402
from platkit.simulate.elastic_tree import simulate_elastic_tree, write_elastic_session  # noqa: E402
from platkit.tree_loads import Payload  # noqa: E402

LINK = HANDS["left"]
COM = (0.0, 0.0, -0.1)


def predicted(cal: Path, commands: np.ndarray, names: list[str], work: Path, payload: list[str]) -> dict:
    csv = work / "commands.csv"
    csv.write_text("\n".join([",".join(RECORDED)] + [",".join(f"{v:.10g}" for v in row) for row in commands]) + "\n")
    out = work / "predicted.csv"
    if cli(["predict", "--calibration", str(cal), "--commands", str(csv), "--out", str(out), *payload]):
        raise SystemExit(f"predict failed on {cal}")
    data = np.genfromtxt(out, delimiter=",", names=True)
    return {n: np.stack([data[f"{n}_x"], data[f"{n}_y"], data[f"{n}_z"]], axis=1) for n in names}


def run(seed: int, n_fit: int, n_held: int, n_later: int, mass: float, bare: bool, root: Path) -> dict:
    nominal = upper_body(root / "talos_upper.urdf")
    model_urdf = upper_body(root / "talos_upper_bare.urdf", bare=True) if bare else nominal
    truth, cmd = draw(seed, nominal, n_fit + n_held)
    later = later_commands(seed, nominal, n_later)
    markers = {f"{h[0].upper()}{k}": link for h, link in HANDS.items() for k in range(1, 4)}
    empty = simulate_elastic_tree(nominal, truth, cmd, RECORDED, markers, seed=seed + 1000, workdir=root)
    # the same seed: the same marker places and mocap; the later poses' noise a stream of its own
    loaded = simulate_elastic_tree(nominal, truth, later, RECORDED, markers, seed=seed + 1000, workdir=root,
                                   payload=Payload(LINK, mass, COM))
    unloaded = simulate_elastic_tree(nominal, truth, later, RECORDED, markers, seed=seed + 1000, workdir=root)
    train = write_elastic_session(empty, model_urdf, root / "train", markers, np.arange(n_fit))
    test = write_elastic_session(empty, model_urdf, root / "test", markers, np.arange(n_fit, n_fit + n_held))
    write_elastic_session(loaded, model_urdf, root / "later", markers)  # what the user would record
    if cli(["calibrate", str(train), "--out", str(root / "cal"), "--quiet", "--no-report"]):
        raise SystemExit("calibrate failed")
    if cli(["diagnose", str(train), "--calibration", str(root / "cal" / "calibration.yaml"), "--heldout", str(test),
            "--out", str(root / "diag"), "--quiet"]):
        raise SystemExit("diagnose failed")
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    names = loaded.marker_names
    told = ["--payload", f"{LINK}:{mass}:{','.join(str(c) for c in COM)}"]
    rigid = per_hand(predicted(root / "cal" / "calibration.yaml", later, names, root, []), loaded.markers, loaded)
    blind = per_hand(predicted(root / "diag" / "calibration.yaml", later, names, root, []), loaded.markers, loaded)
    floor = {h: float(np.mean([np.linalg.norm(1e3 * (loaded.exact[:, m] - loaded.markers[:, m]), axis=1)
                               for m, lk in enumerate(loaded.marker_links) if lk == link])) for h, link in HANDS.items()}
    sag = {h: float(np.mean([np.linalg.norm(1e3 * (loaded.exact[:, m] - unloaded.exact[:, m]), axis=1)
                             for m, lk in enumerate(loaded.marker_links) if lk == link])) for h, link in HANDS.items()}
    if bare:  # the loads are a prior of unknown size: predict refuses a payload in kg beside them
        if cli(["predict", "--calibration", str(root / "diag" / "calibration.yaml"), "--commands",
                str(root / "commands.csv"), "--out", str(root / "refused.csv"), *told]) != 2:
            raise SystemExit("predict --payload on a URDF without inertias was not refused")
        print(f"seed {seed} (no inertias): predict --payload refused, as it must be; diagnosed with empty hands "
              f"{blind['left']:.2f} / {blind['right']:.2f} mm (left / right), the payload's sag "
              f"{sag['left']:.2f} / {sag['right']:.2f}", flush=True)
        return {}
    aware = per_hand(predicted(root / "diag" / "calibration.yaml", later, names, root, told), loaded.markers, loaded)
    found = ", ".join(sorted({f["effect"] for f in d["findings"]})) or "none"
    print(f"seed {seed}{' (no inertias)' if bare else ''}, {mass:g} kg in the left hand; findings: {found}\n"
          f"  later session, mean marker error per hand, mm (left / right):\n"
          f"    the payload's own sag:                  {sag['left']:.2f} / {sag['right']:.2f}\n"
          f"    rigid calibration:                      {rigid['left']:.2f} / {rigid['right']:.2f}\n"
          f"    diagnosed, hands taken as empty:        {blind['left']:.2f} / {blind['right']:.2f}\n"
          f"    diagnosed, predict --payload:           {aware['left']:.2f} / {aware['right']:.2f}\n"
          f"    true elastic model (noise floor):       {floor['left']:.2f} / {floor['right']:.2f}", flush=True)
    return {"rigid": rigid, "blind": blind, "aware": aware, "floor": floor, "sag": sag}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[24401])
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--heldout", type=int, default=20)
    ap.add_argument("--later", type=int, default=20)
    ap.add_argument("--mass", type=float, default=2.0, help="kg in the left hand in the later session")
    ap.add_argument("--bare", action="store_true",
                    help="strip every inertia from the URDF the calibration sees (predict --payload must be refused)")
    args = ap.parse_args()
    results = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory(prefix="platkit-payload-") as tmp:
            results.append(run(seed, args.poses, args.heldout, args.later, args.mass, args.bare, Path(tmp)))
    results = [r for r in results if r]
    for hand in HANDS if results else ():
        cut = [1 - r["aware"][hand] / r["blind"][hand] for r in results]
        print(f"over {len(results)} seeds, the {hand} hand: predict --payload cuts the error of diagnose's model taken "
              f"with empty hands by a median of {100 * np.median(cut):.0f} % (per seed: "
              f"{', '.join(f'{100 * x:.0f}' for x in cut)} %); above the noise floor by a median of "
              f"{np.median([r['aware'][hand] - r['floor'][hand] for r in results]):.2f} mm")


if __name__ == "__main__":
    main()
