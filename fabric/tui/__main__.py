"""``python -m fabric.tui``: the operator console (same as ``fabric-tui``)."""
import sys

from fabric.tui import main

sys.exit(main())
