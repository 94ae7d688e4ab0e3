"""`python -m odofuse`: the odofuse command line."""

import sys

from odofuse.cli import main

sys.exit(main())
