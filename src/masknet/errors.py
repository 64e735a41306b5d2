"""The one exception type for bad user input, and the one warning type; the CLI prints
each as a single line."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import TypeVar

F = TypeVar("F", bound=Callable)


class MaskNetError(Exception):
    """Bad input or a missing resource, with a message meant for the user.

    The message names the file (when there is one) and the problem, e.g.
    ``scan.ply: 12 rows contain NaN or inf``.
    """


class MaskNetWarning(UserWarning):
    """Input that works but gives an unreliable result (very few points, a point far out
    that sets the cloud's scale). The API issues it through :mod:`warnings`; the CLI
    prints it as ``masknet: warning: <message>``."""


def warns_once(function: F) -> F:
    """Decorate an entry point of the API whose stages check the clouds again: each
    :class:`MaskNetWarning` message reaches the caller once, whatever the stages repeat;
    other warnings pass through unchanged."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        caught: list = []
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                return function(*args, **kwargs)
        finally:  # out of the recording context: pass each on once
            shown: set[str] = set()
            for w in caught:
                text = str(w.message)
                if issubclass(w.category, MaskNetWarning) and text in shown:
                    continue
                shown.add(text)
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)

    return wrapper  # type: ignore[return-value]
