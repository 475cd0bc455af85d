"""``python -m hil.cli``: the same as ``elegant-stepping``."""

import sys

from hil.cli import main

sys.exit(main())
