"""``python -m czmpc.cli``: the console script without the installed entry point."""

import sys

from czmpc.cli import main

sys.exit(main())
