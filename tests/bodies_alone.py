"""A simulated session as its rigid bodies alone: what a motion-capture system that reports bodies
only would have written (shared by the tests of bodies without markers)."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import yaml

from platkit.cli import main


def strip_markers(sim: Path, out: Path) -> Path:
    """The session ``sim`` as a session of its rigid bodies alone in ``out``: markers.csv the time
    and the bodies' columns, session.yaml no markers (on a tree, the bodies' links alone in
    ``moving_link``); the commands and the description as they are. Returns ``out``."""
    shutil.copytree(sim, out)
    y = yaml.safe_load((sim / "session.yaml").read_text())
    y["markers"] = []
    if isinstance(y.get("moving_link"), dict):
        y["moving_link"] = {k: v for k, v in y["moving_link"].items() if k in y["rigid_bodies"]}
    (out / "session.yaml").write_text(yaml.safe_dump(y, sort_keys=False))
    rows = list(csv.reader((sim / "markers.csv").open()))
    keep = [i for i, h in enumerate(rows[0]) if h == "t" or h.split("_")[0] in y["rigid_bodies"]]
    with (out / "markers.csv").open("w", newline="") as f:
        csv.writer(f).writerows([[r[i] for i in keep] for r in rows])
    return out


#: the streamed session the tests of bodies alone share: a Stewart of the physical simulator on a
#: 10 s path at 40 Hz, two rigid bodies beside the markers, white noise of 0.2 mm
STEWART_STREAM = ["--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "10", "--rate-hz", "40",
                  "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", "4111"]


def stewart_bodies_stream(root: Path) -> tuple[Path, Path]:
    """:data:`STEWART_STREAM` simulated into ``root / 'sim'`` and its bodies alone in ``root /
    'bodies'``: (sim, bodies)."""
    sim = root / "sim"
    assert main(["simulate", *STEWART_STREAM, "--out", str(sim)]) == 0
    return sim, strip_markers(sim, root / "bodies")


def cut_in_time(src: Path, dst: Path, t_cut: float, later: bool = False) -> Path:
    """``src`` (a session folder) copied to ``dst`` with the commands and motion-capture samples
    before ``t_cut`` (``later`` False) or from it on (``later`` True); the other files as they are.
    Returns ``dst``."""
    dst.mkdir()
    for f in src.iterdir():
        if f.name not in ("markers.csv", "commands.csv"):
            (dst / f.name).write_bytes(f.read_bytes())
    for name in ("markers.csv", "commands.csv"):
        rows = list(csv.reader((src / name).open()))
        with (dst / name).open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(rows[0])
            w.writerows(r for r in rows[1:] if (float(r[0]) >= t_cut) == later)
    return dst


def slipped_stewart_body(root: Path) -> Path:
    """A Stewart session of one rigid body alone (40 random settled poses, seed 3) whose body is
    moved on its link from the 21st command on (2-3 mm, about 1 degree: platkit.simulate.body_slip),
    calibrated into ``root / 'cal'`` and diagnosed into ``root / 'diag'``. Returns the session folder."""
    import numpy as np

    from platkit.simulate.body_slip import slip_body

    sim = root / "sim"
    assert main(["simulate", "--platform", "stewart", "--out", str(sim), "--seed", "3", "--poses", "40",
                 "--plan", "random", "--rigid-bodies", "1"]) == 0
    bodies = strip_markers(sim, root / "b")
    t_slip = float(list(csv.reader((bodies / "commands.csv").open()))[21][0])
    slip_body(bodies, "T1", t_slip, [0.002, -0.002, 0.001], np.radians([0.6, 0.5, -0.6]))
    assert main(["calibrate", str(bodies), "--out", str(root / "cal"), "--quiet", "--no-report"]) == 0
    assert main(["diagnose", str(bodies), "--calibration", str(root / "cal" / "calibration.yaml"),
                 "--out", str(root / "diag"), "--quiet", "--no-report"]) == 0
    return bodies
