"""``python -m neckstrength``: the same command line as the installed ``neckstrength`` script."""

import sys

from neckstrength.cli import main

sys.exit(main())
