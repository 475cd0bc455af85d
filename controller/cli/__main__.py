"""``python -m controller.cli``: the same as ``elegant-stepping-leg``."""

import sys

from controller.cli import main

sys.exit(main())
