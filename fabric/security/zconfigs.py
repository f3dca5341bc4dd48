"""The Zenoh JSON5 configs of a secured fabric: the hub's (router) and one client config per role.

A role's config is self-contained (certificates inline, base64): copy that one file to a dashboard
host and ``zenoh.Config.from_file`` opens a session with it. It names its role in ``metadata`` so the
fabric's client can refuse at once what the hub would drop.
"""
from __future__ import annotations

import base64
import json
import os
from pathlib import Path
from typing import Any

from fabric.wire.config import DEFAULT_LEASE_MS, KEEP_ALIVE_PER_LEASE
from fabric.wire.errors import ConfigError

__all__ = ["client_config", "hub_config", "write_json5", "read_json5", "role_of_config", "ROLE_METADATA"]

ROLE_METADATA = "fabric_role"


def _b64(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def _common(mode: str) -> dict[str, Any]:
    return {"mode": mode, "scouting": {"multicast": {"enabled": False}},
            "transport": {"link": {"tx": {"lease": DEFAULT_LEASE_MS, "keep_alive": KEEP_ALIVE_PER_LEASE}}}}


def client_config(role: str, connect: list[str], user: str, password: str, ca_cert: Path, cert: Path,
                  key: Path) -> dict[str, Any]:
    """A client session of ``role``: TLS with its certificate to the hub, user and password."""
    conf = _common("client")
    conf["metadata"] = {ROLE_METADATA: role}
    conf["connect"] = {"endpoints": connect}
    conf["transport"]["auth"] = {"usrpwd": {"user": user, "password": password}}
    conf["transport"]["link"]["tls"] = {
        "root_ca_certificate_base64": _b64(ca_cert), "enable_mtls": True,
        "connect_private_key_base64": _b64(key), "connect_certificate_base64": _b64(cert),
        "verify_name_on_connect": True,
    }
    return conf


def hub_config(listen: list[str], dictionary: Path, ca_cert: Path, cert: Path, key: Path,
               access_control: dict[str, Any]) -> dict[str, Any]:
    """The hub: a router listening on TLS only, mutual TLS, user/password and access control."""
    conf = _common("router")
    conf["listen"] = {"endpoints": listen}
    conf["transport"]["auth"] = {"usrpwd": {"dictionary_file": str(dictionary)}}
    conf["transport"]["link"]["tls"] = {
        "root_ca_certificate": str(ca_cert), "listen_private_key": str(key), "listen_certificate": str(cert),
        "enable_mtls": True,
    }
    conf["access_control"] = access_control
    return conf


def write_json5(path: Path, conf: dict[str, Any], header: str) -> None:
    """Write ``conf`` as JSON (valid JSON5) after ``//`` comment lines; readable by its owner only."""
    text = "".join(f"// {line}\n" for line in header.splitlines()) + json.dumps(conf, indent=2) + "\n"
    tmp = path.with_suffix(".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)


def read_json5(path: Path) -> dict[str, Any]:
    """Read back a config written by :func:`write_json5` (comment lines, then JSON)."""
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror})", field=str(path)) from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not text (damaged? make it again with 'fabric-cli auth')",
                          field=str(path)) from None
    try:
        conf = json.loads("\n".join(ln for ln in lines if not ln.lstrip().startswith("//")))
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not a config written by 'fabric-cli auth' ({exc}): make it again",
                          field=str(path)) from None
    if not isinstance(conf, dict):
        raise ConfigError(f"{path}: not a config written by 'fabric-cli auth' (not an object): make it again",
                          field=str(path))
    return conf


def role_of_config(path: str | Path | None) -> str | None:
    """The fabric role a Zenoh config file declares in ``metadata`` (None: no file, or no role)."""
    if not path:
        return None
    import zenoh  # here: reading a config is all this module needs from zenoh
    try:
        meta = json.loads(zenoh.Config.from_file(str(path)).get_json("metadata"))
    except (zenoh.ZError, json.JSONDecodeError, ValueError):
        return None
    role = meta.get(ROLE_METADATA) if isinstance(meta, dict) else None
    return role if isinstance(role, str) else None
