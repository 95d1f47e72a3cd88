"""``python -m slmlab``: the command line (see :mod:`slmlab.cli`)."""

import sys

from .cli import main

sys.exit(main())
