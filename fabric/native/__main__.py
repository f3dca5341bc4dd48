"""``python -m fabric.native``: build every C helper ahead of first use; says where each went or why not."""
from __future__ import annotations

import subprocess
import sys

from fabric.native import HELPERS, build


def main() -> int:
    for name in HELPERS:
        try:
            print(f"native helper {name}: {build(name)}")
        except subprocess.CalledProcessError as e:
            print(f"native helper {name} did not build (the Python path stands in):\n"
                  f"{e.stderr.decode(errors='replace')}", file=sys.stderr)
        except (OSError, subprocess.TimeoutExpired) as e:
            print(f"native helper {name} not built (the Python path stands in): {e}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
