"""``python -m sqmanip.cli`` = ``sqmanip``."""

import sys

from sqmanip.cli import main

sys.exit(main())
