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
