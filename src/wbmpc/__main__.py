"""`python -m wbmpc` runs the `wbmpc` command."""

import sys

from wbmpc.cli import main

sys.exit(main())
