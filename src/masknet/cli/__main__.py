"""``python -m masknet.cli`` (and ``torchrun -m masknet.cli``): the ``masknet`` command."""

import sys

from masknet.cli import main

sys.exit(main())
