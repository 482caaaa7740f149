"""`python -m dream.cli`: the `dream` program."""

import sys

from dream.cli.app import main

sys.exit(main())
