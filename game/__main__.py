"""`python -m game` is the same as the `chainsim` command."""

import sys

from game.cli import main

sys.exit(main())
