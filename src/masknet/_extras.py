"""The optional packages, imported on first use: registration needs none of them.

Each belongs to an extra of the ``masknet`` package (``pyproject.toml``):

* ``data``: h5py (ModelNet40's HDF5 shards) and trimesh (``.off`` meshes; ``.ply``
  files when Open3D does not import);
* ``viz``: matplotlib (the PNG pictures);
* ``train``: tqdm (the progress bars of training, evaluation and the experiments).

A missing one raises :class:`~masknet.errors.MaskNetError` with one line that says
which extra installs it, e.g. ``drawing pictures needs matplotlib: pip install
'masknet[viz]'``.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Iterable, Iterator
from types import ModuleType
from typing import Any

from masknet.errors import MaskNetError

__all__ = ["PICTURES", "need", "progress_bar", "pyplot", "require"]

# (module, extra, purpose) of the pictures, for :func:`need` and :func:`require`
PICTURES = ("matplotlib", "viz", "drawing pictures")


def _missing(package: str, extra: str, purpose: str) -> MaskNetError:
    return MaskNetError(f"{purpose} needs {package}: pip install 'masknet[{extra}]'")


def need(module: str, extra: str, purpose: str) -> ModuleType:
    """Import and return ``module``, or raise a MaskNetError when its package is not
    installed: ``<purpose> needs <package>: pip install 'masknet[<extra>]'``.

    ``purpose`` starts the message, e.g. ``"drawing pictures"``. Other import failures
    (a package that is there but broken) propagate unchanged.
    """
    package = module.split(".")[0]
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name not in (module, package):
            raise
        raise _missing(package, extra, purpose) from exc


def require(module: str, extra: str, purpose: str) -> None:
    """Raise :func:`need`'s MaskNetError when ``module`` is not installed, without
    importing it: a refusal before a long computation whose output needs it."""
    if importlib.util.find_spec(module.split(".")[0]) is None:
        raise _missing(module.split(".")[0], extra, purpose)


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the headless Agg backend."""
    matplotlib = need(*PICTURES)
    matplotlib.use("Agg")
    return importlib.import_module("matplotlib.pyplot")


class _Quiet:
    """What :func:`progress_bar` returns when disabled: the iterable, and no-op
    ``set_postfix``/``close``, without importing tqdm."""

    def __init__(self, iterable: Iterable) -> None:
        self._iterable = iterable

    def __iter__(self) -> Iterator:
        return iter(self._iterable)

    def set_postfix(self, *args: Any, **kwargs: Any) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(iterable: Iterable, *, disable: bool = False, **kwargs: Any) -> Any:
    """``tqdm.auto.tqdm(iterable, **kwargs)``; when ``disable``, the iterable alone and
    tqdm is not needed."""
    if disable:
        return _Quiet(iterable)
    return need("tqdm.auto", "train", "showing progress bars").tqdm(iterable, **kwargs)
