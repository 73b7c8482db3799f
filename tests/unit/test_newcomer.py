"""A newcomer without ../shared: the README's test command stops at once with one line that says
which folder is missing and where it comes from, instead of failures and errors one by one;
tests that do not read it still run; with the folder there, the tests that read it run."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFTEST = Path(__file__).resolve().parents[1] / "conftest.py"

#: the shared folder's name, never written in quotes here: this file reads no shared data, and the
#: conftest tells the modules that do by the quoted name
NAME = 'shared'
READS_SHARED = '''from pathlib import Path

DATA = Path(__file__).resolve().parents[3] / "SHARED" / "data" / "real"


def test_reads_it():
    assert DATA.is_dir()
'''.replace("SHARED", NAME)
PLAIN = "def test_plain():\n    assert 1 + 1 == 2\n"


def _checkout(tmp_path) -> Path:
    root = tmp_path / "checkout"
    (root / "tests" / "golden").mkdir(parents=True)
    (root / "tests" / "unit").mkdir()
    shutil.copy(CONFTEST, root / "tests" / "conftest.py")
    (root / "tests" / "golden" / "test_real.py").write_text(READS_SHARED)
    (root / "tests" / "unit" / "test_plain.py").write_text(PLAIN)
    return root


def _pytest(root: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args], cwd=root,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("split", [(), ("-n", "2", "--dist", "loadfile")], ids=["one process", "xdist"])
def test_without_shared_one_line_says_what_is_missing(tmp_path, split):
    root = _checkout(tmp_path)
    run = _pytest(root, *split)  # the README's command splits the run over processes: said once, before any starts
    assert run.returncode == 4, run.stdout + run.stderr
    out = run.stdout + run.stderr
    said = [line for line in out.splitlines() if "missing" in line]
    assert len(said) == 1
    assert f"the real data these tests read are missing: {tmp_path / NAME / 'data' / 'real'}" in said[0]
    assert "1 test files need it (golden/test_real.py)" in said[0] and "ln -s /path/to/shared" in said[0]
    assert "passed" not in out and "skipped" not in out and "failed" not in out


def test_tests_that_do_not_read_it_still_run(tmp_path):
    root = _checkout(tmp_path)
    run = _pytest(root, "tests/unit")
    assert run.returncode == 0 and "1 passed" in run.stdout


def test_with_shared_beside_the_checkout_the_golden_tests_run(tmp_path):
    root = _checkout(tmp_path)
    (tmp_path / NAME / "data" / "real").mkdir(parents=True)
    run = _pytest(root)
    assert run.returncode == 0 and "2 passed" in run.stdout, run.stdout + run.stderr
