"""Writing a stand's workspace (:func:`platkit.workspace.workspace_figures`): workspace.json, the
CSV tables and the plots, into a folder written whole or not at all."""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from platkit.io import jsonout
from platkit.io.atomic import atomic_output_dir
from platkit.kinematics import PlatformModel
from platkit.model import controls_from_si, length_scale
from platkit.workspace import AXES, fixed_orientation_section, workspace_figures


def _scale_lengths(obj, s: float, keys=("min", "max", "range", "larger_than_corners_min", "larger_than_corners_max")):
    if isinstance(obj, dict):
        return {k: (v / s if k in keys and isinstance(v, float) else _scale_lengths(v, s, keys)) for k, v in obj.items()}
    return obj


def write_workspace(model: PlatformModel, out: str | Path, unit: str = "mm", td=None, plots: bool = True) -> dict:
    """Compute the workspace figures and write, atomically, into ``out``:
    workspace.json (figures, lengths in ``unit``, angles in rad), corners.csv (controls and poses
    of every corner), envelope.csv (one row per axis and envelope), coordinates.csv (one row per
    pose coordinate: its neutral value and range, in ``unit`` or rad) and workspace.png /
    sections.png."""

    s = length_scale(unit)
    figures, corners, fixed, free = workspace_figures(model, td)
    spec = model.spec
    shown = _scale_lengths({k: v for k, v in figures.items() if k != "coordinates"}, s)
    shown["coordinates"] = {}
    for c in spec.coordinates:
        if c.name not in figures["coordinates"]:
            continue
        entry = figures["coordinates"][c.name]
        k = s if c.unit == "m" else 1.0
        shown["coordinates"][c.name] = {
            "unit": unit if c.unit == "m" else c.unit,
            **{key: entry[key] / k for key in ("neutral", "min", "max", "range")},
            "poses": {sense: {"p": [v / s if cc.unit == "m" else v for v, cc in zip(pose["p"], spec.coordinates)],
                              "u": controls_from_si(spec, np.array(pose["u"]), unit).tolist(),
                              "active_controls": pose["active_controls"]}
                      for sense, pose in entry["poses"].items()}}
    shown["neutral_position"] = [v / s for v in figures["neutral_position"]]
    shown["conditioning"]["characteristic_length"] = figures["conditioning"]["characteristic_length"] / s
    neutral = shown["conditioning"]["neutral"]
    neutral["distance_to_singularity"] = figures["conditioning"]["neutral"]["distance_to_singularity"] / s
    for env in shown["true_envelope"].values():
        for pose in env["poses"].values():
            pose["u"] = controls_from_si(spec, np.array(pose["u"]), unit).tolist()
            pose["p"] = [v / s if c.unit == "m" else v for v, c in zip(pose["p"], spec.coordinates)]
    shown["unit"] = unit

    with atomic_output_dir(out) as tmp:
        (tmp / "workspace.json").write_text(jsonout.dumps(shown, indent=2) + "\n")
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        U_shown = controls_from_si(spec, corners.U, unit)
        w.writerow(spec.control_names + ["x", "y", "z", "qw", "qx", "qy", "qz", "converged"])
        for uu, XX, qq, ok in zip(U_shown, corners.X / s, corners.q, corners.converged):
            w.writerow([f"{v:.6f}" for v in uu] + [f"{v:.6f}" for v in XX] + [f"{v:.9f}" for v in qq] + [int(ok)])
        (tmp / "corners.csv").write_text(buf.getvalue())
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["envelope", "axis", "min", "max", "range"])
        c = shown["corners"]["relative_to_neutral"]
        for a in AXES:
            w.writerow(["corners", a, f"{c[a]['min']:.4f}", f"{c[a]['max']:.4f}", f"{c[a]['range']:.4f}"])
        for name, env in shown["true_envelope"].items():
            for a in AXES:
                w.writerow([name, a, f"{env[a]['min']:.4f}", f"{env[a]['max']:.4f}", f"{env[a]['range']:.4f}"])
        (tmp / "envelope.csv").write_text(buf.getvalue())
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["coordinate", "unit", "neutral", "min", "max", "range"])
        for name, entry in shown["coordinates"].items():
            w.writerow([name, entry["unit"]] + [f"{entry[key]:.6f}" for key in ("neutral", "min", "max", "range")])
        (tmp / "coordinates.csv").write_text(buf.getvalue())
        if plots:
            _plot(model, corners, fixed, free, unit, tmp, td)
    return shown


def _plot(model, corners, fixed, free, unit, folder: Path, td) -> None:
    # bare matplotlib Figures: no pyplot state, the user's backend untouched; matplotlib only when drawing
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    s = length_scale(unit)
    X0 = corners.neutral_X
    Xc = (corners.X[corners.converged] - X0) / s
    fig = Figure(figsize=(15, 5))
    axes = fig.subplots(1, 3)
    for ax, (i, j) in zip(axes, ((0, 1), (0, 2), (1, 2))):
        ax.scatter(Xc[:, i], Xc[:, j], s=14, label=f"{len(Xc)} control-box corners")
        for env, style in ((fixed, "--"), (free, ":")):
            lo, hi = (env.lower - X0) / s, (env.upper - X0) / s
            ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fill=False, ls=style,
                                   label=f"true envelope, {env.orientation} orientation"))
        lo, hi = Xc.min(axis=0), Xc.max(axis=0)
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fill=False, color="C0", label="corner envelope"))
        ax.set_xlabel(f"{AXES[i]} - neutral [{unit}]")
        ax.set_ylabel(f"{AXES[j]} - neutral [{unit}]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower left")
    fig.suptitle(f"{model.spec.name}: origin of the moving frame at the corners of the control box")
    fig.tight_layout()
    fig.savefig(folder / "workspace.png", dpi=110)

    lo, hi = fixed.lower, fixed.upper
    pad = 0.1 * np.maximum(hi - lo, 1e-3)
    sections = [("xy", X0[2]), ("xz", X0[1]), ("yz", X0[0])]
    results = []
    for plane, level in sections:
        ia, ib = "xyz".index(plane[0]), "xyz".index(plane[1])
        res = fixed_orientation_section(model, plane, level, ((lo[ia] - pad[ia], hi[ia] + pad[ia]),
                                                              (lo[ib] - pad[ib], hi[ib] + pad[ib])), td=td)
        if res is None:
            return
        results.append((plane, level, res))
    fig = Figure(figsize=(15, 5))
    axes = fig.subplots(1, 3)
    for ax, (plane, level, (A, B, ok)) in zip(axes, results):
        ax.contourf(A / s, B / s, ok.astype(float), levels=[0.5, 1.5], colors=["C2"], alpha=0.5)
        ax.contour(A / s, B / s, ok.astype(float), levels=[0.5], colors=["C2"])
        ax.set_xlabel(f"{plane[0]} [{unit}]")
        ax.set_ylabel(f"{plane[1]} [{unit}]")
        third = "xyz".replace(plane[0], "").replace(plane[1], "")
        ax.set_title(f"reachable at neutral orientation, {third} = {level / s:.0f} {unit}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(folder / "sections.png", dpi=110)
