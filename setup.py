"""Which import packages the distribution holds, and where each lives in the repository.

Here rather than in pyproject.toml, which can either discover packages or list mapped ones, not
both; the rest of the packaging is in pyproject.toml.

- ``platkit`` and its subpackages: discovered, so a new subpackage needs no line here;
- the built-in plugins, one package per folder ``plugins/platkit_*/``: discovered and mapped;
- the shipped data, mapped from the top of the repository where it stays:
  ``platkit_data.descriptions`` <- ``descriptions/`` (the stands' default descriptions) and
  ``platkit_data.sessions`` <- ``examples/sessions/`` (the example sessions). platkit finds them
  through the installed package with importlib.resources (platkit/io/shipped.py).

One mapping serves both installs: a wheel copies each package's files into site-packages, and an
editable install (``pip install -e .``) maps each package to its folder here, so a checkout and a
wheel find the same files the same way and no code walks up from ``__file__``.
"""
from pathlib import Path

from setuptools import find_packages, setup

PLUGINS = find_packages("plugins", include=["platkit_*"])
DATA = {"platkit_data.descriptions": "descriptions", "platkit_data.sessions": "examples/sessions"}
#: one data package per example session folder (examples/sessions/<stand>/)
SESSIONS = sorted(f"platkit_data.sessions.{d.name}" for d in Path("examples/sessions").iterdir()
                  if (d / "session.yaml").is_file())

setup(
    packages=[*find_packages(include=["platkit", "platkit.*"]), *PLUGINS, *DATA, *SESSIONS],
    package_dir={**{p: "plugins/" + p.replace(".", "/") for p in PLUGINS}, **DATA},
    package_data={
        "platkit": ["py.typed", "*.c"],  # C sources compiled on first use (platkit.native.compiled_library)
        "platkit.chains": ["*.c"],
        "platkit.settle": ["*.c"],
        "platkit_data.descriptions": ["*.yaml", "*.urdf"],
        "platkit_data.sessions": ["README.md"],
        **{s: ["*.yaml", "*.csv", "*.c3d"] for s in SESSIONS},
    },
)
