"""``fabric-cli auth``: make the credentials of a secured fabric, export a relay's folder, rotate a password, list
what each role may do."""
from __future__ import annotations

import argparse
from pathlib import Path

from fabric.cli.output import emit

__all__ = ["register"]


def cmd_init(a: argparse.Namespace) -> int:
    from fabric.security.credentials import Credentials
    from fabric.security.roles import ROLES
    creds = Credentials.init(a.dir, hub=a.hub, listen=a.hub_listen, hosts=a.host, force=a.force)
    out = {"dir": str(creds.root), "hub": creds.hub_endpoints(), "listen": creds.listen_endpoints(),
           "hub_config": str(creds.hub_config), "configs": {r: str(creds.config(r)) for r in ROLES}}

    def text(d: dict) -> str:
        lines = [f"credentials in {d['dir']} (CA, certificates, passwords; keep ca-key.pem offline)",
                 f"  hub          {d['hub_config']}  listens on {', '.join(d['listen'])}"]
        lines += [f"  {role:<12} {path}" for role, path in d["configs"].items()]
        lines.append(f"start the cell:  fabric-cli up --secure {d['dir']}")
        lines.append(f"then:            fabric-cli status --config {d['configs']['operator']}")
        return "\n".join(lines)
    emit(out, a.json, text)
    return 0


def cmd_export(a: argparse.Namespace) -> int:
    from fabric.security.credentials import Credentials
    from fabric.security.relay import RelayFolder
    creds = Credentials(Path(a.dir).resolve())
    folder = RelayFolder.export(creds, a.output, a.host[0], a.host[1:], a.listen, a.force)
    out = {"dir": str(folder.root), "host": a.host[0], "files": sorted(p.name for p in folder.root.iterdir()),
           "listen": folder.listen_endpoints(), "hub": folder.hub_endpoints(), "dashboard": str(folder.dashboard)}

    def text(d: dict) -> str:
        return "\n".join([
            f"relay folder for {d['host']} in {d['dir']}: {' '.join(d['files'])}",
            "  the CA certificate, the relay's own certificate, the monitor's credentials; no operator's or "
            "service's password or key",
            f"  the relay listens on {', '.join(d['listen'])} and links to the hub at {', '.join(d['hub'])}",
            f"copy it to {d['host']}, then there:  fabric-cli relay --secure {d['dir']}",
            f"dashboards there:  fabric-cli status --config {d['dashboard']}"])
    emit(out, a.json, text)
    return 0


def cmd_passwd(a: argparse.Namespace) -> int:
    from fabric.security.credentials import Credentials
    creds = Credentials(Path(a.dir).resolve())
    creds.rotate(a.role, a.password)
    relays = " and export every relay's folder again (it holds the monitor's password)" if a.role == "monitor" else ""
    emit({"role": a.role, "config": str(creds.config(a.role)), "passwords": str(creds.passwords)}, a.json,
         lambda d: f"new password for {d['role']} in {d['passwords']} and {d['config']}: restart the hub, then "
                   f"hand out the new config{relays} (the old password is refused from then on)")
    return 0


def cmd_roles(a: argparse.Namespace) -> int:
    from fabric.security.roles import ROLES, permissions
    table = {role: permissions(role) for role in ROLES}

    def text(d: dict) -> str:
        lines = []
        for role, p in d.items():
            lines.append(f"{role}:")
            lines.append(f"  commands  {' '.join(p['commands'])}")
            lines.append(f"  streams   {' '.join(p['streams'])}")
            lines.append(f"  also      {', '.join(p['other'])}")
        return "\n".join(lines)
    emit(table, a.json, text)
    return 0


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    from fabric.security.roles import ROLES
    auth = sub.add_parser("auth", help="credentials of a secured fabric (TLS, passwords, roles)")
    asub = auth.add_subparsers(dest="auth_cmd", required=True)
    p = asub.add_parser("init", help="make a CA, certificates, passwords and one Zenoh config per role in DIR")
    p.add_argument("dir", metavar="DIR")
    p.add_argument("--hub", default="tls/127.0.0.1:7447", metavar="ENDPOINT",
                   help="where clients reach the hub, tls/<host>:<port> (default %(default)s)")
    p.add_argument("--hub-listen", default=None, metavar="ENDPOINT",
                   help="where the hub listens (default: --hub on loopback, else tls/0.0.0.0:<port>)")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="another name or address of the hub for its certificate (repeatable)")
    p.add_argument("--force", action="store_true", help="replace the credentials already in DIR")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_init)
    p = asub.add_parser("export", help="a folder for one relay host: only what the relay needs (no operator's or "
                                       "service's password or key)",
                        description="Write OUT for a relay on HOST: the CA certificate, the relay's own certificate "
                                    "for HOST (signed here with DIR's CA key), the monitor's credentials it joins "
                                    "the hub with, its config (relay.json5) and a dashboard's config connecting to "
                                    "it (monitor.json5). Copy OUT to HOST and run 'fabric-cli relay --secure OUT'.")
    p.add_argument("dir", metavar="DIR", help="the credentials folder ('fabric-cli auth init DIR')")
    p.add_argument("what", choices=("relay",), help="what the folder is for")
    p.add_argument("--host", action="append", required=True, metavar="HOST",
                   help="the relay host's name or address, as dashboards reach it (repeat for more names)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="the folder to write")
    p.add_argument("--listen", default=None, metavar="ENDPOINT",
                   help="where the relay listens (default tls/0.0.0.0:7448)")
    p.add_argument("--force", action="store_true", help="replace what OUT holds")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_export)
    p = asub.add_parser("passwd", help="give a role a new password (dictionary and its config)")
    p.add_argument("dir", metavar="DIR")
    p.add_argument("role", choices=ROLES)
    p.add_argument("--password", default=None, help="the new password (default: a random one)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_passwd)
    p = asub.add_parser("roles", help="what each role may do")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_roles)
