"""Files that ship with platkit: the stands' default descriptions and the example sessions.

In the repository they stay at the top level (descriptions/, examples/sessions/); the packaging
(setup.py, pyproject.toml) maps them into the import packages ``platkit_data.descriptions`` and
``platkit_data.sessions``. They are found here through the installed package with
importlib.resources, alike from a wheel, where they are copied into site-packages, and from an
editable install, where setuptools' finder maps each package to its folder of the checkout.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

from platkit.errors import PlatkitError

#: shipped folder -> the import package that holds it
PACKAGES = {"descriptions": "platkit_data.descriptions", "sessions": "platkit_data.sessions"}
#: shipped folder -> the variable whose folders are searched before it (platkit.io.description,
#: platkit.io.session)
ENV = {"descriptions": "PLATKIT_DESCRIPTIONS", "sessions": "PLATKIT_EXAMPLES"}


def shipped_dir(kind: str) -> Path:
    """The folder of shipped ``kind`` files ('descriptions' or 'sessions') in the installed platkit.

    Raises PlatkitError (one line) when the data package is not installed (a checkout used
    without ``pip install``) or not unpacked on disk (descriptions may refer to files beside them).
    """
    package = PACKAGES[kind]
    try:
        # a package installed as a folder (a wheel unpacked, an editable install): its spec says
        # where, without importing importlib.resources (zipfile, tempfile: a few milliseconds of
        # every verb's start-up)
        spec = importlib.util.find_spec(package)
    except ModuleNotFoundError:
        spec = None
    if spec is not None and spec.origin and spec.has_location and spec.submodule_search_locations:
        here = Path(spec.origin).parent
        if here.is_dir():
            return here
    from importlib import resources  # anything else: as importlib.resources finds it

    try:
        folder = resources.files(package)
    except ModuleNotFoundError:
        raise PlatkitError(
            f"platkit's shipped {kind} (package {package}) are not installed: install platkit "
            f"(pip install -e . in a checkout), or name their folder in ${ENV[kind]}"
        ) from None
    if not isinstance(folder, Path):
        raise PlatkitError(f"platkit's shipped {kind} ({package}) are not files on disk ({folder}): install platkit unpacked")
    return folder
