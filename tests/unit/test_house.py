"""The house rules of platkit/: no module over 600 lines, no function over 120 lines (lines of the
file, docstrings and comments included; a function's from its ``def`` to its last line). A
ratchet: the exceptions left are listed here by name, no new one may appear, and an exception that
has been split must leave the list."""
from __future__ import annotations

import ast
import functools
from pathlib import Path

MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 120
PACKAGE = Path(__file__).resolve().parents[2] / "platkit"

#: modules over MAX_MODULE_LINES still to split, relative to platkit/
KNOWN_LONG_MODULES: set[str] = set()
#: (module relative to platkit/, qualified function name) over MAX_FUNCTION_LINES still to split
KNOWN_LONG_FUNCTIONS: set[tuple[str, str]] = set()


def _functions(tree: ast.AST, prefix: str = ""):
    """(qualified name, lines) of every function and method, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}{node.name}"
            if not isinstance(node, ast.ClassDef):
                yield name, node.end_lineno - node.lineno + 1
            yield from _functions(node, f"{name}.")
        else:
            yield from _functions(node, prefix)


@functools.cache
def _measure(root: Path = PACKAGE):
    """({module: lines}, {(module, function): lines}) of the modules and functions over the limits."""
    long_modules, long_functions = {}, {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        text = path.read_text(encoding="utf-8")
        n = len(text.splitlines())
        if n > MAX_MODULE_LINES:
            long_modules[rel] = n
        for name, lines in _functions(ast.parse(text, filename=str(path))):
            if lines > MAX_FUNCTION_LINES:
                long_functions[(rel, name)] = lines
    return long_modules, long_functions


def test_the_measure_finds_long_modules_and_nested_functions(tmp_path):
    """The walk measures methods and nested functions (decorators not counted) and modules by
    their lines, so the ratchet below cannot pass on a walk that sees nothing."""
    body = "\n".join(f"            x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.py").write_text(f"class A:\n    @staticmethod\n    def f():\n        def g():\n{body}\n"
                                           "        return g\n" + "\n" * MAX_MODULE_LINES)
    (tmp_path / "short.py").write_text("def h():\n    return 1\n")
    modules, functions = _measure(tmp_path)
    assert modules == {"sub/m.py": MAX_FUNCTION_LINES + 5 + MAX_MODULE_LINES}
    assert functions == {("sub/m.py", "A.f"): MAX_FUNCTION_LINES + 3, ("sub/m.py", "A.f.g"): MAX_FUNCTION_LINES + 1}


def test_no_new_long_module_or_function():
    modules, functions = _measure()
    new_modules = {m: n for m, n in modules.items() if m not in KNOWN_LONG_MODULES}
    new_functions = {f: n for f, n in functions.items() if f not in KNOWN_LONG_FUNCTIONS}
    assert not new_modules, f"modules over {MAX_MODULE_LINES} lines (split them): {new_modules}"
    assert not new_functions, f"functions over {MAX_FUNCTION_LINES} lines (split into named stages): {new_functions}"


def test_the_known_exceptions_are_still_exceptions():
    """A split module or function leaves the list, so the list only shrinks."""
    modules, functions = _measure()
    gone_modules = sorted(KNOWN_LONG_MODULES - set(modules))
    gone_functions = sorted(KNOWN_LONG_FUNCTIONS - set(functions))
    assert not gone_modules, f"now within {MAX_MODULE_LINES} lines or gone: remove from KNOWN_LONG_MODULES: {gone_modules}"
    assert not gone_functions, (f"now within {MAX_FUNCTION_LINES} lines or gone: remove from KNOWN_LONG_FUNCTIONS: "
                                f"{gone_functions}")


def _reexported(path: Path) -> list[str]:
    """The names a module lists in ``__all__`` without defining them (imported only to be handed on)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    defined, listed = set(), []
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name):
                        defined.add(name.id)
                        if name.id == "__all__" and node.value is not None:
                            listed = list(ast.literal_eval(node.value))
    return [n for n in listed if n not in defined]


def test_the_reexport_measure_sees_a_handed_on_name(tmp_path):
    (tmp_path / "m.py").write_text("from os import sep\nX = 1\n\ndef f():\n    pass\n\n__all__ = ['X', 'f', 'sep']\n")
    assert _reexported(tmp_path / "m.py") == ["sep"]


def test_only_a_package_face_hands_names_on():
    """Implementation modules list in ``__all__`` what they define; a subpackage's ``__init__`` is
    its public face and may gather its modules' names."""
    found = {path.relative_to(PACKAGE).as_posix(): names for path in sorted(PACKAGE.rglob("*.py"))
             if path.name != "__init__.py" and (names := _reexported(path))}
    assert not found, f"modules that hand on names they import (import them from where they are defined): {found}"


def test_every_benchmark_is_listed_in_the_docs_index():
    """docs/README.md's table of benchmarks names every script in benchmarks/ (a proof no reader
    can find is not a proof), and names none that is gone."""
    root = PACKAGE.parent
    scripts = {p.name for p in (root / "benchmarks").glob("*.py") if not p.name.startswith("_")}
    index = (root / "docs" / "README.md").read_text(encoding="utf-8")
    listed = {line.split("|")[1].strip() for line in index.splitlines()
              if line.startswith("| ") and line.split("|")[1].strip().endswith(".py")}
    assert scripts - listed == set(), f"benchmarks not in docs/README.md: {sorted(scripts - listed)}"
    assert listed - scripts == set(), f"docs/README.md lists benchmarks that are gone: {sorted(listed - scripts)}"
