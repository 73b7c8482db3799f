"""How many threads BLAS (OpenBLAS, MKL, BLIS) may use while platkit computes, and the one block
that holds it there (:func:`blas_threads`).

The rule. platkit's matrices are small (thousands of rows by tens to hundreds of columns); BLAS's
worker threads, one per core by default, only wake and spin on them, and on a machine shared with
other work (a laptop, a fleet of several processes per machine) they make each product many times
slower (docs/performance.md). So platkit computes on one BLAS thread unless its user says otherwise:

- ``PLATKIT_BLAS_THREADS=N`` (a whole number >= 1): N threads wherever platkit holds BLAS;
  ``PLATKIT_BLAS_THREADS=0``: platkit holds nothing (BLAS's own count);
- else the count the caller names (1 in every block platkit enters).

OPENBLAS_NUM_THREADS, OMP_NUM_THREADS and the like are not read: they set the process's BLAS when
it loads (a scheduler or a cluster may set them for other programs), and platkit's blocks hold
its own work to one thread whatever they say; outside the blocks their count stands. One
thread also keeps the results from depending on the machine: with another count the rounding of
a rank-revealing QR can hold a different one of two aliased parameters (docs/performance.md).

Each ``platkit`` command line runs its verb inside such a block (platkit.cli), as do the
estimators' own entry points (every Levenberg-Marquardt run, the approach fits of settling, the
diagnosis's screen and design floor), so a library caller gets it too.
"""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from typing import Any

from platkit.errors import BadInput

__all__ = ["ENV", "blas_threads", "blas_thread_count"]

#: the environment variable that sets platkit's BLAS threads
ENV = "PLATKIT_BLAS_THREADS"

# the controller (threadpoolctl's) and the number of imported modules it was made at: it knows the
# libraries loaded then (a search of 0.7 ms), so it is made again only after an import may have
# loaded another (scipy carries its own OpenBLAS beside numpy's)
_controller: list[tuple[int, Any]] = []


def blas_thread_count(asked: int = 1) -> int | None:
    """The BLAS threads a block that asks for ``asked`` gets under the rule (module docstring);
    None: platkit holds nothing. Raises BadInput for a PLATKIT_BLAS_THREADS that is not a whole
    number >= 0."""
    given = os.environ.get(ENV, "").strip()
    if given:
        if not given.isdigit():
            raise BadInput(f"{ENV}: {given!r} is not a whole number of threads >= 1 (0: BLAS's own count)")
        return int(given) or None
    return asked


def _blas_controller() -> Any:
    if not _controller or _controller[-1][0] != len(sys.modules):
        # threadpoolctl imported here, not with the module: `platkit --version` and the verbs
        # without numpy start 10 ms sooner (platkit.cli imports this module on every call)
        from threadpoolctl import ThreadpoolController

        _controller[:] = [(len(sys.modules), ThreadpoolController())]
    return _controller[-1][1]


@contextlib.contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """BLAS limited inside the block to ``n`` threads, or to what the user chose
    (:func:`blas_thread_count`); each library's count restored after."""
    count = blas_thread_count(n)
    if count is None or "numpy" not in sys.modules:  # BLAS comes with numpy (scipy needs it): none loaded
        yield
        return
    with _blas_controller().limit(limits=count, user_api="blas"):
        yield
