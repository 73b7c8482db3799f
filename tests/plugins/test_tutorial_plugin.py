"""docs/plugin-tutorial.md: its code is the example package's code, and that package, built from
the page and installed as an outside package is installed (pip, into a folder of its own), is
found through its entry point and passes the conformance suite.

pip builds the package with build isolation (setuptools from the package index or the local
wheel cache): the test venv need not carry a wheel-building setuptools.
"""
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "plugin-tutorial.md"
EXAMPLE = "examples/platkit-hexapod-rss"
FENCE = re.compile(r"^```(\w+) file=(\S+)\n(.*?)^```$", re.S | re.M)


def doc_files() -> dict[str, str]:
    """Path -> content, from the tutorial's ``file=`` code blocks (pieces of one file, in order,
    are joined by two blank lines)."""
    pieces: dict[str, list[str]] = {}
    for _lang, path, body in FENCE.findall(DOC.read_text(encoding="utf-8")):
        pieces.setdefault(path, []).append(body)
    return {path: "\n\n".join(parts) for path, parts in pieces.items()}


def example_files() -> set[str]:
    root = REPO / EXAMPLE
    return {
        str(p.relative_to(REPO)) for p in root.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and not any(part.endswith(".egg-info") for part in p.parts)
        and "build" not in p.relative_to(root).parts
    }


def test_the_tutorials_code_is_the_example_package():
    files = doc_files()
    assert set(files) == example_files(), "the tutorial must show every file of the example package, and only those"
    for path, text in files.items():
        assert text == (REPO / path).read_text(encoding="utf-8"), f"{path} differs from the tutorial's code blocks"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """Write the package from the tutorial's blocks, pip-install it into a target folder; return
    the environment that puts that folder on the path."""
    tmp = tmp_path_factory.mktemp("tutorial")
    for path, text in doc_files().items():
        dest = tmp / "src-tree" / Path(path).relative_to(EXAMPLE)
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_text(text, encoding="utf-8")
    site = tmp / "site"
    res = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps",
         "--target", str(site), str(tmp / "src-tree")],
        capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert (site / "platkit_hexapod_rss" / "hexapod_rss.yaml").is_file(), "the description must ship as package data"
    env = dict(os.environ, PYTHONPATH=str(site), MPLBACKEND="Agg")
    return tmp, env


def _platkit(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "platkit.cli", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=120)


def test_platkit_plugins_lists_the_installed_stand(installed):
    tmp, env = installed
    res = _platkit(env, "plugins", "--json")
    assert res.returncode == 0, res.stderr
    stands = {s["name"]: s for s in json.loads(res.stdout)["platforms"]}
    assert stands["hexapod-rss"]["package"] == "platkit-hexapod-rss 0.1.0"
    # without the install it is not there: the entry point is what found it
    bare = _platkit(dict(env, PYTHONPATH=""), "plugins", "--json")
    assert "hexapod-rss" not in {s["name"] for s in json.loads(bare.stdout)["platforms"]}


def test_installed_stand_passes_its_tests_and_the_conformance_suite(installed):
    tmp, env = installed
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp / "src-tree" / "tests")],
        capture_output=True, text=True, env=env, cwd=tmp / "src-tree", timeout=300,
    )
    assert res.returncode == 0, res.stdout[-3000:]
    assert "3 passed" in res.stdout


def test_the_tutorials_commands_work_on_the_installed_stand(installed):
    tmp, env = installed
    res = _platkit(env, "fk", "--platform", "hexapod-rss", "--u", "0,0,0,0,0,0", "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["z"] == pytest.approx(175.6656, abs=1e-3)
    res = _platkit(env, "fk", "--platform", "hexapod-rss", "--u", "0.3,-0.2,0.1,0.4,-0.1,0.2", "--json")
    assert res.returncode == 0 and json.loads(res.stdout)["on_branch"] is True
    res = _platkit(env, "describe", "--platform", "hexapod-rss", "--json")
    assert res.returncode == 0 and len(json.loads(res.stdout)["parameters"]) == 44


def test_a_bad_description_is_one_line_naming_file_and_field(installed):
    tmp, env = installed
    good = (tmp / "src-tree" / "src" / "platkit_hexapod_rss" / "hexapod_rss.yaml").read_text()
    bad = tmp / "bad.yaml"
    bad.write_text(good.replace("pivot: [-84.8528, 84.8528, 0.0]", "pivot: [-84.8528, 84.8528]"))
    res = _platkit(env, "describe", "--platform", "hexapod-rss", "--description", str(bad))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(bad) in lines[0] and "servos[3].pivot" in lines[0]
