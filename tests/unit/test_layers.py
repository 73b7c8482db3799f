"""The house rules that a linter cannot see: no private name imported across packages, no
platkit import hidden inside a function below the CLI (the layers themselves are checked by
import-linter, .importlinter, in CI)."""
from __future__ import annotations

import ast
from pathlib import Path

import platkit

ROOT = Path(platkit.__file__).parent
#: the CLI's verbs import their work when they run, so that start-up stays fast (issue 13)
LAZY_OK = ("commands/", "cli.py")


def _modules():
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        yield rel, ast.parse(path.read_text(), filename=str(path))


def _package(rel: str) -> str:
    return rel.split("/")[0].removesuffix(".py")


def _imported_package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_no_private_name_crosses_a_package():
    crossings = []
    for rel, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("platkit."):
                if _imported_package(node.module) == _package(rel):
                    continue
                crossings += [f"{rel}: {node.module}.{a.name}" for a in node.names
                              if a.name.startswith("_") and not a.name.startswith("__")]
    assert crossings == []


def _outermost_functions(node: ast.AST):
    """The functions and methods under ``node`` that no other function holds."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield child
        else:
            yield from _outermost_functions(child)


def test_no_platkit_import_inside_a_function_below_the_cli():
    hidden = []
    for rel, tree in _modules():
        if rel.startswith(LAZY_OK):
            continue
        for fn in _outermost_functions(tree):  # nested functions are walked inside theirs, each node once
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("platkit"):
                    hidden.append(f"{rel}:{node.lineno} {node.module}")
                elif isinstance(node, ast.Import) and any(a.name.startswith("platkit") for a in node.names):
                    hidden.append(f"{rel}:{node.lineno}")
    assert hidden == []
