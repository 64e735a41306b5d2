"""Moved to :mod:`masknet.registration.terms.validation`; this name works for one more release, with a
``DeprecationWarning``."""

from masknet._moved import moved_module

__getattr__ = moved_module(__name__, "masknet.registration.terms.validation")
