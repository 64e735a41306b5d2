"""Names that moved to another module stay importable from the old one for one version, with
a ``DeprecationWarning`` naming the new place."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any

__all__ = ["moved_module", "moved_names"]


def moved_names(module: str, moved: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module`` (its ``__name__``): each name of ``moved`` is
    looked up in the module it maps to, with a DeprecationWarning; any other name is an
    AttributeError, as without it.

    Example (at the end of the old module)::

        __getattr__ = moved_names(__name__, {"pose_fit": "masknet.registration.judge.fit"})
    """

    def __getattr__(name: str) -> Any:
        if name not in moved:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(
            f"{module}.{name} has moved to {moved[name]}.{name}; import it from there "
            "(the old place goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(moved[name]), name)

    return __getattr__


def moved_module(module: str, new: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` for a whole module that moved: every name is looked up in
    ``new`` (a dotted module path), with a DeprecationWarning naming the new place.

    Example (the whole of the old module)::

        __getattr__ = moved_module(__name__, "masknet.registration.judge.fit")
    """

    def __getattr__(name: str) -> Any:
        if name.startswith("__"):  # the import machinery's probes: not a moved name
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(
            f"{module} has moved to {new}; import {name} from there "
            "(the old place goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(new), name)

    return __getattr__
