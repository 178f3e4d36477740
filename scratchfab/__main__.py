"""``python -m scratchfab``: the same CLI as the ``scratchfab`` command."""

from __future__ import annotations

import sys

from scratchfab.cli import main

if __name__ == "__main__":
    sys.exit(main())
