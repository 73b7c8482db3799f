"""Where the reference robots of example-robot-data live (a dev dependency of the tests and the
benchmarks, not of the library): ``from reference_robots import example_robot_urdf`` (tests/ is on
the tests' path; a benchmark puts it there)."""
from __future__ import annotations

import os
import site
import sys
from pathlib import Path

from platkit.errors import BadInput


def example_robot_data_dir() -> Path:
    """The ``robots`` folder of example-robot-data: $EXAMPLE_ROBOT_DATA, else the cmeel prefix
    in site-packages (where ``pip install example-robot-data`` puts it)."""
    env = os.environ.get("EXAMPLE_ROBOT_DATA")
    candidates = [Path(env)] if env else []
    roots = list(site.getsitepackages()) + [site.getusersitepackages()] + list(sys.path)
    for root in roots:
        candidates.append(Path(root) / "cmeel.prefix" / "share" / "example-robot-data" / "robots")
    for c in candidates:
        if c.is_dir():
            return c
    raise BadInput("example-robot-data is not installed (pip install example-robot-data, or set EXAMPLE_ROBOT_DATA)")


def example_robot_urdf(relative: str) -> Path:
    """Path of a URDF inside example-robot-data's robots folder, e.g.
    'ur_description/urdf/ur5_robot.urdf'."""
    path = example_robot_data_dir() / relative
    if not path.is_file():
        raise BadInput(f"example-robot-data has no {relative}")
    return path
