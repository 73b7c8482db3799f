"""``python -m platkit ...``: the same command line as the ``platkit`` script (platkit.cli.main)."""
from __future__ import annotations

import sys

from platkit.cli import main

if __name__ == "__main__":
    sys.exit(main())
