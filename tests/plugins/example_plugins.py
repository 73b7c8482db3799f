"""Installing an example plugin of examples/ the way a user does (pip, with build isolation, into
a folder of its own) and running platkit against it in a subprocess that sees that folder."""
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def install_example(tmp_path_factory, folder: str, package: str, description: str) -> tuple[Path, dict]:
    """pip-install ``examples/<folder>`` into a fresh folder; checks that ``<package>/<description>``
    ships as package data. Returns (the temporary folder, the environment that sees the install)."""
    tmp = tmp_path_factory.mktemp(folder)
    site = tmp / "site"
    res = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps",
         "--target", str(site), str(REPO / "examples" / folder)],
        capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert (site / package / description).is_file(), "the description must ship as package data"
    return tmp, dict(os.environ, PYTHONPATH=str(site), MPLBACKEND="Agg")


def run_platkit(env: dict, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m platkit.cli ARGS`` in ``env``, its output captured as text."""
    return subprocess.run([sys.executable, "-m", "platkit.cli", *args], capture_output=True, text=True, env=env,
                          timeout=timeout)
