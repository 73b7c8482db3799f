"""Real data: `platkit diagnose` of the PAL TIAGo arm seen as one rigid body instead of four markers.

    .venv/bin/python benchmarks/diagnose_bodies_tiago.py [--data DIR]

The four points BL, BR, TR, TL of FIGAROH's Qualisys postures (shared/data/real/tiago) ride on one
rigid body on the hand. Each day is converted as benchmarks/diagnosis_tiago.py converts it
(tests/real_data/tiago.py), then once more into a session of one 6-DOF body H and no marker: the
body's frame is fitted to the four points at every pose (Kabsch, onto the constellation the
training day averages in the frame its own points define: origin at their centroid, x along
BL->BR, z normal to BL->BR and BL->TL), as a mocap system reports a rigid body. Both sessions of
the training day (2021-11-30) are calibrated (`platkit calibrate`, no options and `--free
offset,origin`) and diagnosed with the validation day (2021-11-26) as the held-out recording.

Prints, per case, what diagnosis names from the markers and from the body, and on the validation
day: the norm RMSE of point BL (FIGAROH's figure; from the body: BL placed on the body's frame by
the constellation, predicted through the body's calibration) and the body's origin and rotation
RMS, before and after diagnosis.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data.tiago import MARKERS, TRAINING, VALIDATION, bl_rmse_mm, convert, default_data_dir  # noqa: E402

from platkit.calibrate.estimate import predict_markers, second_session_errors  # noqa: E402
from platkit.calibrate.predict import predict_bodies  # noqa: E402
from platkit.cli import main as cli  # noqa: E402
from platkit.geometry import matrix_from_quat, quat_from_matrix  # noqa: E402
from platkit.io.calibration import read_calibration  # noqa: E402
from platkit.settle import load_poses  # noqa: E402

CASES = (("platkit calibrate, no options", []), ("platkit calibrate --free offset,origin", ["--free", "offset,origin"]))


def _frames(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose (N, 4, 3): the centroid (N, 3) and the frame (N, 3, 3) the points define."""
    o = P.mean(axis=1)
    x = P[:, 1] - P[:, 0]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    z = np.cross(x, P[:, 3] - P[:, 0])
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    return o, np.stack([x, np.cross(z, x), z], axis=2)


def constellation(P: np.ndarray) -> np.ndarray:
    """The four points (4, 3) in the body's frame: each complete pose's points in the frame they
    define, averaged."""
    ok = np.all(np.isfinite(P), axis=(1, 2))
    o, R = _frames(P[ok])
    return np.einsum("nba,nkb->nka", R, P[ok] - o[:, None]).mean(axis=0)


def kabsch(ref: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Body poses (N, 7) (x, y, z, qw..qz) placing ``ref`` (4, 3; centred) best onto each pose's
    points P (N, 4, 3) in least squares; NaN where a point is unseen."""
    out = np.full((len(P), 7), np.nan)
    for n, p in enumerate(P):
        if not np.all(np.isfinite(p)):
            continue
        c = p.mean(axis=0)
        U, _, Vt = np.linalg.svd((p - c).T @ ref)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        out[n] = np.concatenate([c, quat_from_matrix(U @ D @ Vt)])
    return out


def as_body_session(markers_session: Path, out: Path, ref: np.ndarray | None = None) -> tuple[Path, np.ndarray]:
    """The session ``markers_session`` with its four points replaced by the body H (poses.csv's
    H_x..H_qz; session.yaml's markers [] and rigid_bodies [H]); the constellation ``ref`` (the
    training day's when None) is returned."""
    rows = list(csv.DictReader((markers_session / "poses.csv").open()))
    P = np.array([[[float(r[f"{m}_{a}"] or "nan") for a in "xyz"] for m in MARKERS] for r in rows])
    ref = constellation(P) if ref is None else ref
    H = kabsch(ref - ref.mean(axis=0), P)
    out.mkdir()
    for f in markers_session.iterdir():
        if f.name not in ("poses.csv", "session.yaml"):
            (out / f.name).write_bytes(f.read_bytes())
    text = (markers_session / "session.yaml").read_text()
    text = text.replace(f"markers: [{', '.join(MARKERS)}]", "markers: []\nrigid_bodies: [H]")
    (out / "session.yaml").write_text(text)
    keep = [c for c in rows[0] if not any(c.startswith(m + "_") for m in MARKERS)]
    with (out / "poses.csv").open("w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(keep + [f"H_{a}" for a in ("x", "y", "z", "qw", "qx", "qy", "qz")])
        for r, h in zip(rows, H):
            w.writerow([r[c] for c in keep] + ["" if not np.isfinite(v) else format(v, ".17g") for v in h])
    return out, ref


def bl_from_body_mm(cal, poses, ref, bl_measured) -> float:
    """Norm RMSE (mm) of BL placed on the body H by the constellation, predicted through ``cal``."""
    _, q, X, _ = predict_markers(cal, poses.controls)
    h = predict_bodies(cal, q, X)[:, 0]
    bl = h[:, :3] + np.einsum("nab,b->na", matrix_from_quat(h[:, 3:]), ref[0] - ref.mean(axis=0))
    d = np.linalg.norm(bl - bl_measured, axis=1)
    return float(np.sqrt(np.nanmean(d ** 2)) * 1e3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="the TIAGo folder (default: shared/data/real/tiago beside the checkout)")
    args = ap.parse_args()
    data = Path(args.data) if args.data else default_data_dir()
    with tempfile.TemporaryDirectory(prefix="platkit-tiago-bodies-") as tmp:
        root = Path(tmp)
        train_m, valid_m = convert(data / TRAINING, root / "train_m"), convert(data / VALIDATION, root / "valid_m")
        train_b, ref = as_body_session(train_m, root / "train_b")
        valid_b, _ = as_body_session(valid_m, root / "valid_b", ref)
        spread = np.linalg.norm(ref - ref.mean(axis=0), axis=1)
        print(f"constellation: points {np.round(spread * 1e3, 1)} mm from the body's origin")
        for k, (label, free) in enumerate(CASES):
            print(f"{label}:")
            for kind, train, valid in (("markers", train_m, valid_m), ("body", train_b, valid_b)):
                out = root / f"case{k}_{kind}"
                if cli(["calibrate", str(train), *free, "--out", str(out / "cal"), "--quiet", "--no-report"]):
                    raise SystemExit(f"{label}, {kind}: calibrate failed")
                if cli(["diagnose", str(train), "--calibration", str(out / "cal" / "calibration.yaml"), "--heldout",
                        str(valid), "--out", str(out / "diag"), "--quiet", "--no-report"]):
                    raise SystemExit(f"{label}, {kind}: diagnose failed")
                d = json.loads((out / "diag" / "diagnosis.json").read_text())
                names = ", ".join(f"{f['effect']} ({f['where'].get('actuator') or f['where']})" for f in d["findings"])
                before = read_calibration(out / "cal" / "calibration.yaml")
                after = read_calibration(out / "diag" / "calibration.yaml")
                poses = load_poses(valid, spec=before.spec)
                h = d.get("heldout_session") or {}
                line = (f"  from the {kind}: {names or 'no finding'}; held-out session RMS "
                        f"{1e3 * h.get('rms_before', float('nan')):.2f} -> {1e3 * h.get('rms_after', float('nan')):.2f}"
                        f" mm (paired p = {h.get('p_improvement', float('nan')):.2g}); validation BL ")
                if kind == "markers":
                    line += f"{bl_rmse_mm(before, poses):.2f} -> {bl_rmse_mm(after, poses):.2f} mm"
                else:
                    pm = load_poses(valid_m, spec=before.spec)
                    bl = pm.markers[:, pm.marker_names.index("BL")]
                    e0, e1 = second_session_errors(before, poses), second_session_errors(after, poses)
                    line += (f"{bl_from_body_mm(before, poses, ref, bl):.2f} -> {bl_from_body_mm(after, poses, ref, bl):.2f}"
                             f" mm; body origin {1e3 * e0['rms_per_body']['H']:.2f} -> {1e3 * e1['rms_per_body']['H']:.2f}"
                             f" mm, rotation {np.degrees(e0['rotation_rms_per_body_rad']['H']):.3f} -> "
                             f"{np.degrees(e1['rotation_rms_per_body_rad']['H']):.3f} deg")
                print(line, flush=True)


if __name__ == "__main__":
    main()
