"""``python -m trainclimate.cli``: the command line."""

import sys

from trainclimate.cli import main

sys.exit(main())
