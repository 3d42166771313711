"""``python -m czmpc``: the console script ``czmpc`` (for a service unit or a container
where the script's directory is not on PATH)."""

import sys

from czmpc.cli import main

sys.exit(main())
