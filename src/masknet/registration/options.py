"""Moved to :mod:`masknet.registration.terms.options`; this name works for one more release, with a
``DeprecationWarning``."""

from masknet._moved import moved_module

__getattr__ = moved_module(__name__, "masknet.registration.terms.options")
