"""The one exception type for bad user input, and the one warning type; the CLI prints
each as a single line."""

from __future__ import annotations

import contextlib
import contextvars
import functools
import warnings
from collections.abc import Callable, Iterator
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


# The messages already issued within the outermost call of a @warns_once entry point
# (None outside one): per thread and task, no global warnings state is touched.
_ISSUED: contextvars.ContextVar[set[str] | None] = contextvars.ContextVar(
    "masknet_warnings_issued", default=None
)


# True within :func:`checks_done`: the clouds were checked, and warned about, already.
_CHECKED: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "masknet_clouds_checked", default=False
)


def first_line(text: str) -> str:
    """The first non-blank line of ``text`` (an exception's message), stripped; "" if none."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


def warn(message: str, stacklevel: int = 3) -> None:
    """Issue ``message`` as a :class:`MaskNetWarning`, once per call of a
    :func:`warns_once` entry point (every time outside one); never within
    :func:`checks_done`."""
    if _CHECKED.get():
        return
    issued = _ISSUED.get()
    if issued is not None:
        if message in issued:
            return
        issued.add(message)
    warnings.warn(message, MaskNetWarning, stacklevel=stacklevel)


def warns_once(function: F) -> F:
    """Decorate an entry point of the API whose stages check the clouds again: each
    :class:`MaskNetWarning` message reaches the caller once per call, whatever the
    stages repeat. Other warnings are not touched."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        if _ISSUED.get() is not None:  # an inner entry point: the outer one counts
            return function(*args, **kwargs)
        token = _ISSUED.set(set())
        try:
            return function(*args, **kwargs)
        finally:
            _ISSUED.reset(token)

    return wrapper  # type: ignore[return-value]


def clouds_checked() -> bool:
    """True within :func:`checks_done`: the clouds were checked already."""
    return _CHECKED.get()


@contextlib.contextmanager
def checks_done() -> Iterator[None]:
    """Within: the clouds were checked, so no :class:`MaskNetWarning` is issued and the
    stages skip the cloud checks (:func:`masknet.geometry.clouds.check_pair`). For an entry
    point that has checked its clouds under their own names (``noisy``) and then hands them
    to stages that would check them again under theirs (``template``, ``source``): checked
    once, the warnings given once, rightly named. Per thread and task, as
    :func:`warns_once`."""
    token = _CHECKED.set(True)
    try:
        yield
    finally:
        _CHECKED.reset(token)
