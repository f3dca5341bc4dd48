"""``fabric-tui``: the Textual operator console."""
from __future__ import annotations

import argparse
import sys

from fabric.extras import missing_extra
from fabric.wire.config import add_session_args, settings_from_args
from fabric.wire.errors import FabricError

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    from fabric.client import Client
    p = argparse.ArgumentParser(prog="fabric-tui", description="operator console for an am-fabric cell")
    add_session_args(p)
    p.add_argument("--cell-config", default=None, metavar="NAME|FILE",
                   help="a cell model whose joint limits stand in while the cell's station cannot tell its own "
                        "(by default the station tells them)")
    a = p.parse_args(argv)
    try:
        from fabric.tui.app import FabricConsole, default_state_path
    except ModuleNotFoundError as exc:      # the tui extra is not installed: one line, no traceback
        missing = missing_extra(exc, "the console")
        if missing is None:
            raise
        print(f"fabric-tui: error [{missing.code}]: {missing.message}", file=sys.stderr)
        return 2
    try:
        with Client.connect(settings_from_args(a, default_mode="client")) as client:
            FabricConsole(client, cell_config=a.cell_config, state_path=default_state_path()).run()
    except FabricError as err:
        print(f"fabric-tui: error [{err.code}]: {err.message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
