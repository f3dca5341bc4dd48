"""``fabric-tui``: the Textual operator console."""
from __future__ import annotations

import argparse
import sys

from fabric.config import add_session_args, settings_from_args

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    from fabric.client import Client
    from fabric.tui.app import FabricConsole
    p = argparse.ArgumentParser(prog="fabric-tui", description="operator console for an am-fabric cell")
    add_session_args(p)
    a = p.parse_args(argv)
    with Client.connect(settings_from_args(a, default_mode="client")) as client:
        FabricConsole(client).run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
