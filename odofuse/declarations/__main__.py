"""``python -m odofuse.declarations --write-docs [--check]``: regenerate the docs tables."""

from odofuse.declarations import main

raise SystemExit(main())
