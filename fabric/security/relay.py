"""A relay of a secured fabric: a router for dashboards, joined to the hub with the monitor's credentials.

It listens like the hub (TLS with the hub's certificate, mutual TLS, the password dictionary) and
enforces :func:`~fabric.security.roles.relay_access_control`: whoever connects to it has a monitor's
rights. It joins the hub as ``monitor``, so the hub, which holds the access control of the fabric,
forwards nothing from it that a monitor may not send.
"""
from __future__ import annotations

import json

import zenoh

from fabric.security.credentials import Credentials
from fabric.security.hub import hub_zenoh_config
from fabric.security.roles import relay_access_control
from fabric.security.zconfigs import read_json5
from fabric.wire.config import SessionSettings

__all__ = ["relay_zenoh_config"]

RELAY_ROLE = "monitor"


def relay_zenoh_config(creds: Credentials, listen: list[str], hub: list[str]) -> zenoh.Config:
    """The relay's router config: listening on ``listen`` for dashboards, linked to the hub at ``hub``."""
    conf = hub_zenoh_config(creds, SessionSettings(), listen)
    conf.insert_json5("connect/endpoints", json.dumps(hub))
    conf.insert_json5("access_control", json.dumps(relay_access_control()))
    joined_as = read_json5(creds.config(RELAY_ROLE))["transport"]
    for field, value in joined_as["auth"]["usrpwd"].items():                  # user, password
        conf.insert_json5(f"transport/auth/usrpwd/{field}", json.dumps(value))
    for field in ("connect_private_key_base64", "connect_certificate_base64", "verify_name_on_connect"):
        conf.insert_json5(f"transport/link/tls/{field}", json.dumps(joined_as["link"]["tls"][field]))
    return conf
