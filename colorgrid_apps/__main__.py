"""``python -m colorgrid_apps`` is the ``colorgrid`` command."""

import sys

from colorgrid_apps.cli import main

sys.exit(main())
