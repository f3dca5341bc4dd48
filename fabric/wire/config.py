"""One helper that turns a config file and ``--mode/--connect/--listen`` flags into a ``zenoh.Config``.

Default (one host): every process is a *peer* that connects to the fabric hub
at ``tcp/127.0.0.1:7447`` with multicast scouting off. ``fabric-cli up`` (or
``fabric-cli router``) hosts that hub as a Zenoh session in router mode, so no
separate router binary is needed. For several hosts, point ``--connect`` at a
router on another machine (see deploy/).
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from fabric.wire.errors import ConfigError

__all__ = ["SessionSettings", "DEFAULT_HUB", "add_data_argument", "default_data_root", "service_data_dir",
           "add_session_args", "add_cell_argument", "settings_from_args", "zenoh_config"]

DEFAULT_HUB = os.environ.get("FABRIC_HUB", "tcp/127.0.0.1:7447")
DATA_ROOT_ENV = "FABRIC_DATA_DIR"
DEFAULT_LEASE_MS = int(os.environ.get("FABRIC_LEASE_MS", "1000"))
KEEP_ALIVE_PER_LEASE = 4
MODES = ("peer", "client", "router")


@dataclass
class SessionSettings:
    """What a process needs to join the fabric."""
    mode: str = "peer"
    connect: list[str] = field(default_factory=lambda: [DEFAULT_HUB])
    listen: list[str] = field(default_factory=list)
    config_file: str | None = None
    multicast: bool = False
    gossip: bool = True
    cell: str = "cell1"
    lease_ms: int = DEFAULT_LEASE_MS      # a link silent this long is closed: a frozen process is gone

    def to_args(self) -> list[str]:
        """The same settings as command-line flags (for launching child processes)."""
        args = ["--mode", self.mode, "--cell", self.cell]
        for ep in self.connect:
            args += ["--connect", ep]
        for ep in self.listen:
            args += ["--listen", ep]
        if self.config_file:
            args += ["--config", self.config_file]
        if self.multicast:
            args += ["--multicast"]
        if self.lease_ms != DEFAULT_LEASE_MS:
            args += ["--lease-ms", str(self.lease_ms)]
        return args


def add_session_args(parser: argparse.ArgumentParser) -> None:
    """The flags every fabric program accepts."""
    g = parser.add_argument_group("fabric session")
    g.add_argument("--config", dest="zconfig", metavar="FILE", help="Zenoh JSON5 config file (flags override it)")
    g.add_argument("--mode", choices=MODES, default=None,
                   help="Zenoh mode (default: peer for services, client for the CLI and console)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"endpoint to connect to (default {DEFAULT_HUB})")
    g.add_argument("--listen", action="append", metavar="ENDPOINT", help="endpoint to listen on")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (off by default)")
    g.add_argument("--cell", default=os.environ.get("FABRIC_CELL", "cell1"),
                   help="cell name: the key prefix am/<cell>/")
    g.add_argument("--lease-ms", type=int, default=DEFAULT_LEASE_MS,
                   help="link lease: a peer silent this long (frozen, cut off) is dropped and its services "
                        "reported gone (default %(default)s, $FABRIC_LEASE_MS)")


def default_data_root() -> Path:
    """Where services keep their durable state: ``$FABRIC_DATA_DIR``, else ``$XDG_DATA_HOME/am-fabric``
    (``~/.local/share/am-fabric``)."""
    if os.environ.get(DATA_ROOT_ENV):
        return Path(os.environ[DATA_ROOT_ENV])
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "am-fabric"


def add_data_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--data-dir`` option: the root of the durable state (one folder per cell and service)."""
    parser.add_argument("--data-dir", default=None, metavar="DIR",
                        help=f"durable state (jobs, events, checkpoints, artifacts); default ${DATA_ROOT_ENV} or "
                             f"{default_data_root()}")


def service_data_dir(root: str | Path | None, cell: str, service: str) -> Path:
    """The folder of ``service`` of ``cell`` under the data root (``root`` None: the default root)."""
    base = Path(root) if root is not None else default_data_root()
    return base / cell / service


def add_cell_argument(parser: argparse.ArgumentParser, what: str = "",
                      default: str = "default: the built-in IRB 140 cell") -> None:
    """The ``--cell-config`` option (read with ``Cell.load_or_builtin``); ``what`` says what the cell is used for,
    ``default`` what is used without the option."""
    parser.add_argument("--cell-config", default=None, metavar="NAME|FILE",
                        help="a built-in cell by name ('fabric-cli cell list') or a cell file"
                             + (f" ({what})" if what else "") + f"; {default}")


def settings_from_args(ns: argparse.Namespace, default_mode: str = "peer") -> SessionSettings:
    """Settings from the flags; ``default_mode`` applies when ``--mode`` is not given.

    Services default to ``peer``. Short-lived tools (the CLI, the console) default to
    ``client``: a client routes everything through the hub, which already knows every
    service, so its first query sees the whole cell; a fresh peer may briefly see only
    the part of the cell whose declarations reached it first.
    """
    st = SessionSettings(cell=ns.cell)
    in_file = _file_settings(ns.zconfig) if ns.zconfig else {}
    st.mode = ns.mode or in_file.get("mode") or default_mode
    if ns.connect or in_file.get("connect"):
        st.connect = list(ns.connect or in_file["connect"])
    if ns.listen or in_file.get("listen"):
        st.listen = list(ns.listen or in_file["listen"])
    st.config_file = ns.zconfig
    st.multicast = bool(ns.multicast)
    st.lease_ms = int(getattr(ns, "lease_ms", DEFAULT_LEASE_MS))
    return st


def _file_settings(path: str) -> dict:
    """What a config file says about mode and endpoints (a flag not given keeps the file's value)."""
    try:
        conf = zenoh.Config.from_file(path)
    except zenoh.ZError as exc:
        raise ConfigError(f"cannot read the Zenoh config {path}: {exc}", field="--config", value=path) from None
    found = {}
    for name, key in (("mode", "mode"), ("connect", "connect/endpoints"), ("listen", "listen/endpoints")):
        try:
            value = json.loads(conf.get_json(key))
        except (zenoh.ZError, ValueError):
            continue
        if (name == "mode" and value in MODES) or (name != "mode" and isinstance(value, list) and value):
            found[name] = value
    return found


def zenoh_config(st: SessionSettings) -> zenoh.Config:
    """Build the ``zenoh.Config`` (file first, then flags on top)."""
    conf = zenoh.Config.from_file(st.config_file) if st.config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(st.mode))
    if st.mode == "client":
        # A client (fabric-cli, the console, a monitor) sends without a shared-memory pool of its own. Zenoh's
        # transport optimisation gives every sending process a 16 MB pool that each receiving process maps and
        # never unmaps: a planner took 32 MB more with every `fabric-cli plan` that uploaded to it. Clients
        # come and go, so they send over the socket (a 4 MB upload piece costs ~2 ms); they still read replies
        # from a service's pool, and services (long-lived, a few) keep theirs.
        conf.insert_json5("transport/shared_memory/transport_optimization/enabled", "false")
    conf.insert_json5("scouting/multicast/enabled", json.dumps(st.multicast))
    conf.insert_json5("scouting/gossip/enabled", json.dumps(st.gossip))
    if not st.config_file or st.lease_ms != DEFAULT_LEASE_MS:
        conf.insert_json5("transport/link/tx/lease", json.dumps(st.lease_ms))
        conf.insert_json5("transport/link/tx/keep_alive", json.dumps(KEEP_ALIVE_PER_LEASE))
    connect = [ep for ep in st.connect if ep not in st.listen]
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if st.listen:
        conf.insert_json5("listen/endpoints", json.dumps(st.listen))
    elif st.mode == "peer":
        # a peer that listens nowhere cannot be reached directly: ephemeral loopback port
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    return conf
