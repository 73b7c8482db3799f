"""The wheel: built from a copy of the source (no install), it holds the package, the built-in
plugins, the stand descriptions and the example sessions, and platkit run from it (the wheel
unpacked onto PYTHONPATH) finds its stands and example sessions inside it.

The build uses this environment's setuptools (the `dev` extra asks for the version that
pyproject.toml's build-system requires), so it needs no network.
"""
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import platkit
from platkit.errors import BadDescription, PlatkitError
from platkit.io import shipped
from platkit.io.description import default_description
from platkit.io.session import example_session
from platkit.plugins import BUILTIN_PLUGINS

REPO = Path(__file__).resolve().parents[2]
#: what a wheel is built from (the rest of the repository is not packaged)
SOURCE = ("pyproject.toml", "setup.py", "README.md", "LICENSE", "platkit", "plugins", "descriptions",
          "examples/sessions")
SHIPPED_SUFFIXES = {".yaml", ".urdf", ".csv", ".c3d"}


def _shipped(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")
            if p.is_file() and (p.suffix in SHIPPED_SUFFIXES or p.name == "README.md")}


def _packages(root: Path, prefix: str = "") -> set[str]:
    return {prefix + p.parent.relative_to(root).as_posix() for p in root.rglob("__init__.py")
            if "__pycache__" not in p.parts}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    for name in SOURCE:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "build"))
        else:
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--disable-pip-version-check", "--no-deps",
         "--no-build-isolation", "--no-index", "--wheel-dir", str(tmp / "dist"), str(src)],
        capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    (built,) = (tmp / "dist").glob("platkit-*.whl")
    return built


@pytest.fixture(scope="module")
def names(wheel) -> set[str]:
    with zipfile.ZipFile(wheel) as z:
        return set(z.namelist())


def test_the_wheel_holds_every_description_and_example_session(names):
    descriptions = _shipped(REPO / "descriptions")
    sessions = _shipped(REPO / "examples" / "sessions")
    assert {"stewart.yaml", "psvr.yaml", "rotary.urdf", "urdf_default_arm.urdf"} <= descriptions
    assert {"stewart/session.yaml", "stewart/markers.csv", "psvr/commands.csv", "rotary/session.yaml"} <= sessions
    missing = ({f"platkit_data/descriptions/{n}" for n in descriptions}
               | {f"platkit_data/sessions/{n}" for n in sessions}) - names
    assert missing == set()


def test_the_wheel_holds_every_package_and_builtin_plugin(names):
    packages = _packages(REPO / "platkit", "platkit/") | _packages(REPO / "plugins")
    packages = {p.removesuffix("/.") for p in packages}
    assert {"platkit", "platkit/io", "platkit_stewart", "platkit_effects"} <= packages
    assert {f"{p}/__init__.py" for p in packages} - names == set()
    assert "platkit/py.typed" in names
    assert not [n for n in names if n.startswith(("tests/", "benchmarks/", "docs/")) or "__pycache__" in n]
    # the C sources compiled on first use (platkit.native.compiled_library) are package data
    sources = {str(p.relative_to(REPO)) for p in (REPO / "platkit").rglob("*.c")}
    assert {"platkit/newton_driver.c", "platkit/chains/native_servo.c"} <= sources
    assert sources - names == set()


def test_every_plugin_folder_is_on_the_builtin_list():
    folders = {p.name for p in (REPO / "plugins").iterdir() if (p / "__init__.py").is_file()}
    assert folders == set(BUILTIN_PLUGINS)


def test_the_wheel_metadata(wheel, names):
    with zipfile.ZipFile(wheel) as z:
        info = next(n.split("/")[0] for n in names if n.endswith(".dist-info/METADATA"))
        meta = z.read(f"{info}/METADATA").decode()
        entry_points = z.read(f"{info}/entry_points.txt").decode() if f"{info}/entry_points.txt" in names else ""
        license_text = z.read(f"{info}/licenses/LICENSE").decode()
    assert re.search(rf"^Version: {re.escape(platkit.__version__)}$", meta, re.M)
    assert re.search(r"^License-Expression: MIT$", meta, re.M)
    assert license_text.startswith("MIT License")
    assert re.search(r"^Requires-Dist: lxml", meta, re.M)
    assert "platkit = platkit.cli:main" in entry_points
    # built-ins come from platkit.plugins.BUILTIN_PLUGINS, never through the entry-point group too
    assert "[platkit]" not in entry_points


def test_platkit_run_from_the_unpacked_wheel_finds_its_data_inside_it(wheel, tmp_path):
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    code = ("from platkit.io.description import default_description as d; "
            "from platkit.io.session import example_session as e; import platkit_stewart; "
            "print(platkit_stewart.__file__); print(d('stewart.yaml')); print(e('psvr'))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PLATKIT_")}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env=dict(env, PYTHONPATH=str(site)), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    plugin, description, session = (Path(line) for line in res.stdout.split())
    assert plugin == site / "platkit_stewart" / "__init__.py"
    assert description == site / "platkit_data" / "descriptions" / "stewart.yaml"
    assert session == site / "platkit_data" / "sessions" / "psvr"


def test_this_install_finds_the_shipped_files():
    assert default_description("stewart.yaml").read_text(encoding="utf-8") == \
        (REPO / "descriptions" / "stewart.yaml").read_text(encoding="utf-8")
    assert (example_session("rotary") / "markers.csv").is_file()


def test_the_variables_folders_come_first(tmp_path, monkeypatch):
    (tmp_path / "stewart.yaml").write_text("platform: stewart\n", encoding="utf-8")
    (tmp_path / "psvr").mkdir()
    (tmp_path / "psvr" / "session.yaml").write_text("platform: psvr\n", encoding="utf-8")
    monkeypatch.setenv("PLATKIT_DESCRIPTIONS", str(tmp_path))
    monkeypatch.setenv("PLATKIT_EXAMPLES", str(tmp_path))
    assert default_description("stewart.yaml") == tmp_path / "stewart.yaml"
    assert example_session("psvr") == tmp_path / "psvr"
    # what the folders lack still comes from the installed package
    assert default_description("psvr.yaml").parent != tmp_path
    assert example_session("rotary").parent != tmp_path


def test_missing_shipped_data_is_one_line_saying_what_to_do(monkeypatch):
    monkeypatch.delenv("PLATKIT_DESCRIPTIONS", raising=False)
    monkeypatch.setitem(shipped.PACKAGES, "descriptions", "platkit_data.not_installed")
    with pytest.raises(PlatkitError, match=r"^platkit's shipped descriptions .* not installed: .*\$PLATKIT_DESCRIPTIONS$"):
        default_description("stewart.yaml")


def test_a_description_that_does_not_ship_is_bad_input_naming_where_it_looked(monkeypatch):
    monkeypatch.delenv("PLATKIT_DESCRIPTIONS", raising=False)
    with pytest.raises(BadDescription, match=r"'nothing\.yaml' not found \(looked in .*descriptions\)$"):
        default_description("nothing.yaml")
