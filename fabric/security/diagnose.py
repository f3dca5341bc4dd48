"""Why a secured hub refused a session, in one line: Zenoh only says it could not connect.

Asked after ``zenoh.open`` failed: a TLS handshake of our own with the config's certificates tells a
hub whose certificate we do not trust, a hub that refuses our certificate (missing, or from another
CA) and a hub that accepts the certificate, so that what it refused was the user name or password.
"""
from __future__ import annotations

import base64
import contextlib
import json
import socket
import ssl
import tempfile
from pathlib import Path
from typing import Any, NamedTuple

import zenoh

from fabric.security.zconfigs import read_json5
from fabric.wire.errors import ConfigError

__all__ = ["explain_refusal", "explain", "Refusal"]

RELAY_ROLE = "monitor"     # the only credentials a relay's own folder admits (fabric.security.relay)

HANDSHAKE_TIMEOUT_S = 2.0
VERDICT_WAIT_S = 0.5       # a hub that refuses our certificate says so right after the handshake


class Refusal(NamedTuple):
    """Who refused a session and why. ``certain``: the TLS handshake itself showed it (a certificate); False
    when the verdict is by elimination (the handshake passed, so it must have been the password), which a
    hub still starting or slow under load can also cause: the caller retries before saying so."""
    who: str
    why: str
    certain: bool = True


def _tls_section(config_path: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The TLS and user/password sections. Zenoh does not give inline (base64) certificates back, so a
    config written by ``auth init`` is read as the JSON it is; any other through Zenoh."""
    try:
        conf = read_json5(Path(config_path))
        transport = conf.get("transport", {})
        return transport.get("link", {}).get("tls", {}), transport.get("auth", {}).get("usrpwd", {})
    except (ConfigError, AttributeError):
        pass
    zconf = zenoh.Config.from_file(config_path)

    def section(path: str) -> dict[str, Any]:
        try:
            value = json.loads(zconf.get_json(path))
        except (zenoh.ZError, ValueError):
            return {}
        return value if isinstance(value, dict) else {}
    return section("transport/link/tls"), section("transport/auth/usrpwd")


def _pem(tls: dict[str, Any], name: str) -> bytes | None:
    """A PEM item of the TLS section, inline (``<name>_base64``) or by path."""
    if tls.get(f"{name}_base64"):
        return base64.b64decode(tls[f"{name}_base64"])
    if tls.get(name):
        return Path(tls[name]).read_bytes()
    return None


def _context(tls: dict[str, Any], tmp: Path) -> tuple[ssl.SSLContext, bool]:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = bool(tls.get("verify_name_on_connect", True))
    ca = _pem(tls, "root_ca_certificate")
    if ca:
        ctx.load_verify_locations(cadata=ca.decode())
    cert, key = _pem(tls, "connect_certificate"), _pem(tls, "connect_private_key")
    if cert and key:
        (tmp / "cert.pem").write_bytes(cert)
        (tmp / "key.pem").write_bytes(key)
        ctx.load_cert_chain(tmp / "cert.pem", tmp / "key.pem")
    return ctx, bool(cert and key)


def _common_name(tls: ssl.SSLSocket) -> str:
    """The common name of the certificate the other end presented: ``hub``, or ``relay`` (its own certificate,
    from 'fabric-cli auth export ... relay')."""
    with contextlib.suppress(ValueError, AttributeError, TypeError):
        subject: Any = (tls.getpeercert() or {}).get("subject", ())
        for rdn in subject:
            for name, value in rdn:
                if name == "commonName":
                    return str(value)
    return ""


def _probe(endpoint: str, ctx: ssl.SSLContext, has_cert: bool, usrpwd: dict[str, Any]) -> Refusal | None:
    """(who answered at ``endpoint``: "the hub" or "the relay", why it refused); None: nothing answered."""
    host, _, port = endpoint.removeprefix("tls/").rpartition(":")
    host = host.strip("[]")
    try:
        raw = socket.create_connection((host, int(port)), timeout=HANDSHAKE_TIMEOUT_S)
    except (OSError, ValueError):
        return None                                   # not reachable: the caller says so
    who = "the hub"
    with raw:
        try:
            tls = ctx.wrap_socket(raw, server_hostname=host)
        except ssl.SSLCertVerificationError as exc:
            return Refusal(who, f"its certificate is not trusted by this config (another fabric's credentials? "
                                f"{exc.verify_message})")
        except (ssl.SSLError, OSError) as exc:
            return Refusal(who, f"TLS with it failed ({exc})", certain=False)
        with tls:
            if _common_name(tls) == "relay":
                who = "the relay"
            tls.settimeout(VERDICT_WAIT_S)
            try:
                tls.recv(1)
            except TimeoutError:
                pass                                  # it accepted our certificate and waits for us
            except (ssl.SSLError, OSError):
                if not has_cert:
                    return Refusal(who, "it requires a client certificate and this config has none")
                return Refusal(who, "it refused this config's certificate (not signed by the fabric's CA)")
    user = usrpwd.get("user")
    if not user:
        return Refusal(who, "it requires a user name and password and this config has none")
    if who == "the relay" and user != RELAY_ROLE:
        return Refusal(who, f"a relay admits dashboards with the {RELAY_ROLE}'s config only (its folder holds no "
                            f"other password), and this config is the {user}'s: run commands against the hub")
    if who == "the relay":
        return Refusal(who, f"it refused the {user}'s password (changed since? after 'fabric-cli auth passwd DIR "
                            f"{user}' export the relay's folder again)", certain=False)
    return Refusal(who, f"it refused the user name or password of {user!r} (wrong, or changed since)",
                   certain=False)


def _without_credentials(endpoints: list[str]) -> str | None:
    """A hub that takes TCP connections but no session without credentials is a secured one."""
    for ep in endpoints:
        proto, _, address = ep.partition("/")
        host, _, port = address.rpartition(":")
        if proto not in ("tcp", "tls") or not port.isdigit():
            continue
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=HANDSHAKE_TIMEOUT_S).close()
        except OSError:
            continue
        return ("it is a secured hub and this session has no credentials: give --config <DIR>/<role>.json5 "
                "(from 'fabric-cli auth init DIR')")
    return None


def explain_refusal(config_path: str | None, endpoints: list[str]) -> str | None:
    """Why the hub (or relay) at one of ``endpoints`` refused a session opened with ``config_path``; None when
    no TLS endpoint answered (nothing is there) or the config has no TLS to check."""
    found = explain(config_path, endpoints)
    return None if found is None else f"{found[0]} refused this session: {found[1]}"


def explain(config_path: str | None, endpoints: list[str]) -> Refusal | None:
    """(who refused: "the hub" or "the relay", why) a session opened with ``config_path`` at one of
    ``endpoints``; None as :func:`explain_refusal`."""
    if not config_path:
        why = _without_credentials(endpoints)
        return None if why is None else Refusal("the hub", why, certain=False)
    if not any(ep.startswith("tls/") for ep in endpoints):
        return None
    tls, usrpwd = _tls_section(config_path)
    with tempfile.TemporaryDirectory(prefix="am-fabric-diag-") as tmp:
        try:
            ctx, has_cert = _context(tls, Path(tmp))
        except (OSError, ssl.SSLError, ValueError) as exc:
            return Refusal("this config", f"its certificates cannot be read ({exc})")
        for ep in endpoints:
            if ep.startswith("tls/"):
                found = _probe(ep, ctx, has_cert, usrpwd)
                if found is not None:
                    return found
    return None
