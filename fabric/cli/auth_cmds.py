"""``fabric-cli auth``: make the credentials of a secured fabric, rotate a password, list what each role may do."""
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


def cmd_passwd(a: argparse.Namespace) -> int:
    from fabric.security.credentials import Credentials
    creds = Credentials(Path(a.dir).resolve())
    creds.rotate(a.role, a.password)
    emit({"role": a.role, "config": str(creds.config(a.role)), "passwords": str(creds.passwords)}, a.json,
         lambda d: f"new password for {d['role']} in {d['passwords']} and {d['config']}: restart the hub, then "
                   f"hand out the new config (the old password is refused from then on)")
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
    p = asub.add_parser("passwd", help="give a role a new password (dictionary and its config)")
    p.add_argument("dir", metavar="DIR")
    p.add_argument("role", choices=ROLES)
    p.add_argument("--password", default=None, help="the new password (default: a random one)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_passwd)
    p = asub.add_parser("roles", help="what each role may do")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(local=cmd_roles)
