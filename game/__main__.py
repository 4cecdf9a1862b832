"""`python -m game` is the same as the `chainsim` command."""

import sys

from chainsim.game.cli.main import main

sys.exit(main())
