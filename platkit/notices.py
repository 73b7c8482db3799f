"""Warnings a user must see: a result kept with a caveat (a reading past a limit, observations
rejected, a fit that did not converge, data left out).

Code anywhere says one with :func:`warn`. A verb runs inside :func:`collecting`: each warning is
printed at once on stderr as ``platkit: warning: <text>`` (once, however often it is said) and
kept, so that the verb's report (report.json, report.html) lists every one of them: what
:func:`said` returns. Outside :func:`collecting` (the library used from Python) a warning is an
ordinary Python warning of the category :class:`PlatkitWarning`.

:func:`units_checked` marks a block where the user has answered the plausibility checks of units
(``--units-checked``): they keep the data with a note instead of refusing it.
"""
from __future__ import annotations

import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar


class PlatkitWarning(UserWarning):
    """A result kept with a caveat; the text is one line naming the file, row, field or option."""


#: the warnings of each :func:`collecting` block being run, innermost last
_collected: list[list[str]] = []


def warn(text: str) -> None:
    """Say ``text`` as a :class:`PlatkitWarning` (see the module's docstring)."""
    warnings.warn(text, PlatkitWarning, stacklevel=2)


def said() -> list[str]:
    """The warnings said so far in the innermost :func:`collecting` block, in order ([] outside one)."""
    return list(_collected[-1]) if _collected else []


@contextmanager
def collecting(stream=None, echo: bool = True) -> Iterator[list[str]]:
    """Collect every PlatkitWarning said inside the block, each once, in order, into the list
    yielded; ``echo``: print each on ``stream`` (default stderr) as it is said. Other warnings
    are shown as Python shows them."""
    kept: list[str] = []
    _collected.append(kept)
    with warnings.catch_warnings():
        warnings.simplefilter("always", PlatkitWarning)
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, PlatkitWarning):
                shown(message, category, filename, lineno, file, line)
                return
            text = str(message)
            if text in kept:
                return
            kept.append(text)
            if echo:
                print(f"platkit: warning: {text}", file=stream if stream is not None else sys.stderr, flush=True)

        warnings.showwarning = show
        try:
            yield kept
        finally:
            _collected.pop()


#: whether the user answered the plausibility checks of units (``--units-checked``)
_UNITS_CHECKED: ContextVar[bool] = ContextVar("platkit_units_checked", default=False)


@contextmanager
def units_checked(on: bool = True) -> Iterator[None]:
    """Inside the block the plausibility checks of units (platkit.io.session_checks.implausible)
    keep the data as written, with a note, instead of refusing: the user has checked the units
    (``--units-checked``)."""
    token = _UNITS_CHECKED.set(on)
    try:
        yield
    finally:
        _UNITS_CHECKED.reset(token)


def units_are_checked() -> bool:
    """Whether the code runs inside :func:`units_checked`."""
    return _UNITS_CHECKED.get()
