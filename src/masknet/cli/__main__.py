"""``python -m masknet.cli`` (and ``torchrun -m masknet.cli``): the ``masknet`` command."""

from masknet.cli import entry

entry()
