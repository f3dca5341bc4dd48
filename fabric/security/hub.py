"""Sessions of a secured fabric: the hub's router config and each role's settings, from a credentials folder."""
from __future__ import annotations

import json
from dataclasses import replace

import zenoh

from fabric.security.credentials import Credentials
from fabric.wire.config import SessionSettings, zenoh_config

__all__ = ["hub_zenoh_config", "role_settings"]


def hub_zenoh_config(creds: Credentials, settings: SessionSettings, listen: list[str] | None = None) -> zenoh.Config:
    """The hub (router) of a secured fabric listening on ``listen`` (default: where ``hub.json5`` says).

    The files are taken from ``creds`` wherever the folder now is (``hub.json5`` names them by absolute path
    when it is written; the folder may have moved since)."""
    st = replace(settings, mode="router", config_file=str(creds.hub_config), connect=[],
                 listen=list(listen or creds.listen_endpoints()))
    conf = zenoh_config(st)
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(creds.passwords)))
    for field, path in (("root_ca_certificate", creds.ca_cert), ("listen_private_key", creds.key("hub")),
                        ("listen_certificate", creds.cert("hub"))):
        conf.insert_json5(f"transport/link/tls/{field}", json.dumps(str(path)))
    return conf


def role_settings(creds: Credentials, settings: SessionSettings, role: str) -> SessionSettings:
    """``settings`` as a client of the secured hub with the credentials of ``role`` (no listening port: on a
    secured fabric every link goes through the hub, which enforces the roles)."""
    return replace(settings, mode="client", config_file=str(creds.config(role)), listen=[])
