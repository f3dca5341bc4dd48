"""``fabric-cli``: every command over the thin client; ``serve``/``up``/``router`` run the fabric itself."""
from __future__ import annotations

import argparse
import importlib
import sys
import threading
from pathlib import Path

from fabric.cli import auth_cmds, cell_cmds, check_cmds, doctor, file_cmds, job_cmds, pipeline_cmds, station_cmds
from fabric.cli.output import fail
from fabric.client import Client
from fabric.client.sessions import CONNECT_WINDOW_S
from fabric.extras import missing_extra, require
from fabric.wire.config import add_cell_argument, add_data_argument, add_session_args, settings_from_args
from fabric.wire.errors import FabricError
from fabric.wire.keys import SERVICES

# Building the parser and running a query import only the client and the schemas (numpy, zenoh, msgpack).
# The heavy modules (services, twin, robot model: scipy, trimesh, pinocchio) are imported inside the
# commands that need them: ``serve`` (the service's module), ``up`` (the launcher), ``cell`` (the cell model).
# Those come with extras (fabric/extras.py); ``main`` turns a missing one into one line, for every command.

__all__ = ["main", "build_parser", "service_parser"]


def _common() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    add_session_args(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    return p


def build_parser() -> argparse.ArgumentParser:
    common = _common()
    parser = argparse.ArgumentParser(prog="fabric-cli", description="Control fabric for robotic additive manufacturing")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("serve", help="run one service in this process",
                       description="Run one service in this process. Its options follow its name: "
                                   "fabric-cli serve station --help lists them.")
    p.add_argument("service", choices=SERVICES)
    p.add_argument("service_args", nargs=argparse.REMAINDER, metavar="...", help="the service's options")
    p.set_defaults(local=_cmd_serve)

    p = sub.add_parser("up", parents=[common], help="start the whole cell on this host (Ctrl-C stops it)")
    p.add_argument("--services", nargs="+", choices=SERVICES, default=list(SERVICES))
    p.add_argument("--no-hub", action="store_true", help="do not host the hub (a router runs elsewhere)")
    p.add_argument("--log-dir", type=Path, default=None, help="write each service's log there")
    p.add_argument("--secure", type=Path, default=None, metavar="DIR",
                   help="hub with TLS, passwords and roles; credentials from 'fabric-cli auth init DIR'")
    add_data_argument(p)
    add_cell_argument(p, "for every service of the cell")
    p.add_argument("--robot", default=None, metavar="KIND:HOST",
                   help="the station drives this robot controller (franka:HOST: a Franka FR3 or franky-sim); "
                        "default: the cell file's robot.controller, else $FABRIC_ROBOT, else the twin alone")
    p.set_defaults(local=_cmd_up)

    p = sub.add_parser("router", parents=[common], help="host the fabric hub (a Zenoh router) in this process")
    p.add_argument("--secure", type=Path, default=None, metavar="DIR",
                   help="TLS, passwords and roles; credentials from 'fabric-cli auth init DIR'")
    p.set_defaults(local=_cmd_router)

    p = sub.add_parser("relay", parents=[common],
                       help="a router linked to the hub that dashboards connect to, so that the hub does not "
                            "fan telemetry out to each of them")
    p.add_argument("--secure", type=Path, default=None, metavar="DIR",
                   help="a relay of a secured fabric (TLS, passwords): its own folder ('fabric-cli auth export DIR "
                        "relay --host HOST -o OUT': it listens and finds the hub where that says), or the whole "
                        "credentials folder; it joins the hub as monitor, and whoever connects to it has a "
                        "monitor's rights")
    p.set_defaults(local=_cmd_relay)

    station_cmds.register(sub, common)
    pipeline_cmds.register(sub, common)
    check_cmds.register(sub, common)
    job_cmds.register(sub, common)
    file_cmds.register(sub, common)
    importlib.import_module("fabric.cli.record_cmds").register(sub, common)     # record, plot, preview
    auth_cmds.register(sub, common)
    doctor.register(sub, common)                      # check and repair the cell's stores

    cell_cmds.register(sub, common)                   # cell show | list | export-urdf
    return parser


def service_parser(name: str) -> argparse.ArgumentParser:
    """The options of service ``name``; imports that service's module, so only ``serve`` builds it."""
    from fabric.services import SERVICE_MODULES
    module = importlib.import_module(SERVICE_MODULES[name])
    p = argparse.ArgumentParser(prog="fabric-cli serve " + name, parents=[_common()],
                                description=f"Run the {name} service in this process.")
    p.add_argument("--log-level", default="INFO")
    add_data_argument(p)
    module.add_arguments(p)
    return p


def _cmd_serve(a: argparse.Namespace) -> int:
    from fabric.services.host import serve, setup_logging
    opts = service_parser(a.service).parse_args(a.service_args)
    opts.service = a.service
    setup_logging(a.service, opts.log_level)
    return serve(a.service, settings_from_args(opts), opts)


def _cmd_up(a: argparse.Namespace) -> int:
    require("services")                 # here, not in each child as it starts (and is restarted)
    from fabric.cli.up import run_up
    extra: dict[str, list[str]] = {}
    if a.cell_config:
        extra = {n: ["--cell-config", a.cell_config] for n in ("station", "slicer", "planner", "collision")}
    if a.robot is not None:
        from fabric.drivers.address import parse_robot
        if parse_robot(a.robot) is not None:            # a typed error here, before anything starts
            require("robot")
        extra.setdefault("station", []).extend(["--robot", a.robot])
    settings = settings_from_args(a)
    if a.secure is None:
        return run_up(settings, tuple(a.services), not a.no_hub, a.log_dir, extra, a.data_dir)
    from fabric.security.credentials import Credentials
    creds = Credentials(a.secure.resolve()).check()
    settings.connect = list(a.connect or creds.hub_endpoints())
    settings.listen = list(a.listen or [])
    return run_up(settings, tuple(a.services), not a.no_hub, a.log_dir, extra, a.data_dir, secure=creds)


def _cmd_router(a: argparse.Namespace) -> int:
    from fabric.cli.up import hub_settings
    from fabric.wire.config import zenoh_config
    st = hub_settings(settings_from_args(a))
    conf = zenoh_config(st)
    if a.secure is not None:
        from fabric.security.credentials import Credentials
        from fabric.security.hub import hub_zenoh_config
        creds = Credentials(a.secure.resolve()).check()
        st.listen = list(a.listen or creds.listen_endpoints())
        conf = hub_zenoh_config(creds, st, st.listen)
    secured = " (TLS, passwords, roles)" if a.secure is not None else ""
    return _run_router(conf, f"fabric hub listening on {', '.join(st.listen)}{secured}")


def _cmd_relay(a: argparse.Namespace) -> int:
    """A router that listens for dashboards and links to the hub: telemetry crosses to it once and is fanned
    out here, so the hub (and the commands it carries) does not do that work for every dashboard. Secured, from
    its own folder ('fabric-cli auth export DIR relay ...': where it listens and the hub come from there unless
    --listen/--connect say otherwise) or from the whole credentials folder."""
    from dataclasses import replace

    from fabric.security.relay import serve_info
    from fabric.wire.config import DEFAULT_HUB, zenoh_config
    from fabric.wire.errors import ConfigError
    st = settings_from_args(a)
    if a.secure is None:
        if not st.listen:
            raise ConfigError("a relay needs --listen ENDPOINT: where dashboards connect to it", field="--listen")
        listen, hub = list(st.listen), list(a.connect or [DEFAULT_HUB])
        conf, secured = zenoh_config(replace(st, mode="router", connect=hub)), ""
    else:
        from fabric.security.relay import relay_setup
        conf, listen, hub = relay_setup(a.secure, a.listen, a.connect)
        secured = " (TLS, passwords; monitor rights)"
    if set(hub) & set(listen):
        raise ConfigError(f"a relay listens elsewhere than the hub it links to ({', '.join(hub)})",
                          field="--listen", value=listen)
    info = {"relay": True, "listen": listen, "hub": hub, "secured": a.secure is not None,
            "rights": "monitor" if a.secure is not None else "all"}
    return _run_router(conf, f"fabric relay listening on {', '.join(listen)}{secured}, linked to the hub at "
                             f"{', '.join(hub)}", on_open=lambda session: serve_info(session, info))


def _run_router(conf, what: str, on_open=None) -> int:
    """Open router session ``conf``, say ``what`` it is, and serve until SIGINT or SIGTERM (``on_open(session)``
    first: what it declares lives as long as the session)."""
    import zenoh

    from fabric.signals import on_signals
    stop = threading.Event()
    on_signals(lambda: stop)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:             # e.g. the port is taken: say so in one line, not a traceback
        from fabric.wire.errors import ConfigError
        reason = str(exc).split(" at /")[0]
        raise ConfigError(f"cannot start the router: {reason}", field="--listen") from None
    with session:
        kept = on_open(session) if on_open is not None else None
        print(f"{what} (Ctrl-C stops it)", flush=True)
        stop.wait()
        del kept
    return 0


def _command_name(a: argparse.Namespace) -> str:
    """``fabric-cli job submit``: the command as typed, for messages."""
    words = [a.command] + [v for k, v in vars(a).items() if k.endswith("_cmd") and isinstance(v, str)]
    if a.command == "serve":
        words.append(a.service)
    return " ".join(["fabric-cli", *words])


def _connect_window_s(a: argparse.Namespace) -> float:
    """How long to wait for the hub: ``status --wait N`` waits for a hub still starting too."""
    wait = getattr(a, "wait", None) if a.command == "status" else None
    return max(CONNECT_WINDOW_S, float(wait)) if isinstance(wait, (int, float)) else CONNECT_WINDOW_S


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    as_json = bool(getattr(a, "json", False))
    try:
        if hasattr(a, "local"):
            return a.local(a)
        with Client.connect(settings_from_args(a, default_mode="client"), _connect_window_s(a)) as client:
            return a.run(client, a)
    except FabricError as err:
        return fail(err.message, as_json, err.code, err.details)
    except ModuleNotFoundError as exc:  # a command of an extra that is not installed: one line, no traceback
        missing = missing_extra(exc, _command_name(a))
        if missing is None:
            raise
        return fail(missing.message, as_json, missing.code, missing.details)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())

