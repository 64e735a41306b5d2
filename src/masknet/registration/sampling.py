"""Moved: :func:`fit_to_network` is in :mod:`masknet.geometry.sampling`, beside the
farthest-point sampling it uses."""

from masknet._moved import moved_names

__getattr__ = moved_names(__name__, {"fit_to_network": "masknet.geometry.sampling"})
