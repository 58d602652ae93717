"""``python -m train ...`` is ``colorgrid train ...``."""

import sys

from train.cli import main

sys.exit(main())
