"""The tests stand alone: no module under tests/ imports the benchmarks (what both need lives under
tests/, and the benchmarks import it from there), and the library imports neither."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _imported(path: Path) -> set[str]:
    """The top-level names of the modules ``path`` imports (absolute imports, at any depth)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _offenders(root: Path, forbidden: set[str]) -> dict[str, set[str]]:
    out = {}
    for path in sorted(root.rglob("*.py")):
        bad = _imported(path) & forbidden
        if bad:
            out[path.relative_to(REPO).as_posix()] = bad
    return out


def test_the_walk_sees_imports_at_any_depth(tmp_path):
    (tmp_path / "m.py").write_text("import os\ndef f():\n    from benchmarks.x import y\n    import batch_cases\n"
                                   "from . import z\n")
    assert _imported(tmp_path / "m.py") == {"os", "benchmarks", "batch_cases"}


def test_no_test_imports_the_benchmarks():
    assert (REPO / "tests" / "real_data" / "tiago.py").is_file()  # the walk below has something to read
    assert _offenders(REPO / "tests", {"benchmarks"}) == {}


def test_the_library_imports_neither_tests_nor_benchmarks():
    helpers = {p.stem for p in (REPO / "tests").iterdir() if p.suffix == ".py" or (p / "__init__.py").is_file()}
    assert {"real_data", "batch_cases", "proof_protocol"} <= helpers
    for root in (REPO / "platkit", REPO / "plugins"):
        assert _offenders(root, {"benchmarks", "tests"} | helpers - {"conftest"}) == {}
