"""Opening a client's Zenoh session, and reading what the fabric says back: links, refusals, error replies."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import zenoh

from fabric import schemas as s
from fabric.wire import codec
from fabric.wire.config import SessionSettings, zenoh_config
from fabric.wire.errors import DecodeError, FabricError, PermissionDenied, ServiceUnavailable, error_from_code

__all__ = ["open_session", "wait_connected", "check_role", "error_of", "relay_info", "refused_by_relay", "relay_named",
           "CONNECT_WINDOW_S"]

CONNECT_WINDOW_S = 3.0     # how long opening waits for the hub, and connect() for the first link


def open_session(settings: SessionSettings, window_s: float = CONNECT_WINDOW_S) -> zenoh.Session:
    """Open a session; a client that finds no router retries briefly, then says where it looked.

    A refusal the TLS handshake proves (a certificate) is said at once; one reached by elimination (the
    handshake passed, so the password?) only if the hub still refuses at the end of the window (``window_s``):
    a hub that is starting, or slow under load, fails an open the same way."""
    end = time.monotonic() + window_s
    first = True
    while True:
        try:
            return zenoh.open(zenoh_config(settings))
        except zenoh.ZError as exc:
            last = time.monotonic() >= end
            if (first and settings.config_file) or last:
                _refused(settings, certain_only=not last)
            first = False
            if last:
                raise ServiceUnavailable(f"cannot reach the fabric hub at {', '.join(settings.connect)} "
                                         f"(is 'fabric-cli up' or 'fabric-cli router' running?)",
                                         connect=settings.connect, reason=str(exc)) from None
            time.sleep(0.1)


def _refused(settings: SessionSettings, certain_only: bool) -> None:
    """Raise PermissionDenied with the reason when a secured hub refused these credentials (``certain_only``:
    only when the handshake proves it)."""
    from fabric.security.diagnose import explain
    found = explain(settings.config_file, settings.connect)
    if found is None or (certain_only and not found.certain):
        return
    who, why = found.who, found.why
    if who == "the relay" and why.endswith("run commands against the hub"):
        hub = [ep for ep in _config_connect(settings.config_file) if ep not in settings.connect]
        why += f" ({', '.join(hub)}, where this config connects)" if hub else ""
    raise PermissionDenied(f"{'the fabric hub' if who == 'the hub' else who} at {', '.join(settings.connect)} "
                           f"refused this session: {why}", connect=settings.connect, config=settings.config_file,
                           by=who.removeprefix("the "))


def _config_connect(path: str | None) -> list[str]:
    """The endpoints a config file connects to by itself (an operator's: the hub's)."""
    from fabric.security.zconfigs import read_json5
    from fabric.wire.errors import ConfigError
    try:
        eps = read_json5(Path(path)).get("connect", {}).get("endpoints", []) if path else []
    except (ConfigError, AttributeError):
        return []
    return [ep for ep in eps if isinstance(ep, str)] if isinstance(eps, list) else []


def check_role(role: str, service: str, command: str) -> None:
    """Refuse at once what the hub would drop unanswered for this role."""
    from fabric.security.roles import MONITOR_COMMANDS, may_call
    if not may_call(role, service, command):
        allowed = ", ".join(sorted(f"{svc}/{cmd}" for svc, cmd in MONITOR_COMMANDS)) if role == "monitor" else ""
        raise PermissionDenied(f"the {role} role may not run {service}/{command} (ask an operator)"
                               + (f"; it may run {allowed}" if allowed else ""),
                               role=role, service=service, command=command)


RELAY_INFO_WAIT_S = 0.5    # a relay answers what it is at once (it is the router this session is linked to)


def relay_info(session: zenoh.Session) -> dict[str, Any] | None:
    """What the relay this session is linked to says of itself (``listen``, ``hub``, ``rights``: ``monitor`` on a
    secured relay, ``all`` on an open one); None when it is linked to the hub itself (nothing answers)."""
    import msgpack

    from fabric.security.relay import info_key
    try:
        routers = [str(z) for z in session.info.routers_zid()]
        for zid in routers:
            for reply in session.get(info_key(zid), timeout=RELAY_INFO_WAIT_S):
                if reply.ok is not None:
                    info = msgpack.unpackb(reply.ok.payload.to_bytes())
                    return info if isinstance(info, dict) else None
    except (zenoh.ZError, ValueError, msgpack.UnpackException):
        return None
    return None


def relay_named(info: Any) -> str:
    """``, through the relay at ...`` for messages (nothing when not on a relay)."""
    if not isinstance(info, dict):
        return ""
    return (f", through the relay at {', '.join(info.get('listen') or ['?'])} linked to the hub at "
            f"{', '.join(info.get('hub') or ['?'])}")


def refused_by_relay(info: Any, role: str | None, service: str, command: str) -> None:
    """Raise PermissionDenied when a secured relay holds this session to a monitor's rights and those do not
    include ``service/command`` (the relay drops it, as the hub drops what a role may not do)."""
    from fabric.security.roles import may_call
    if not isinstance(info, dict) or info.get("rights") != "monitor" or may_call("monitor", service, command):
        return
    hub = ", ".join(info.get("hub") or ["?"])
    raise PermissionDenied(f"the relay at {', '.join(info.get('listen') or ['?'])} may not pass {service}/{command}: "
                           f"a relay gives every session a monitor's rights, whatever its config"
                           + (f" (this one is the {role}'s)" if role and role != "monitor" else "")
                           + f"; run commands against the hub at {hub}", role="monitor", service=service,
                           command=command, relay=info.get("listen"), hub=info.get("hub"))


def wait_connected(session: zenoh.Session, deadline_s: float) -> bool:
    """Wait (bounded) until the session has a link to a router or a peer; a fresh session's first
    query could otherwise leave before the link is up and find no one."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if list(session.info.routers_zid()) or list(session.info.peers_zid()):
            return True
        time.sleep(0.01)
    return False


def error_of(payload: bytes, what: str, waited_s: float) -> FabricError:
    """The typed error of an error reply. Zenoh itself answers ``Timeout`` for a queryable that did not
    reply in time (a frozen or overloaded service): that is ``unavailable``, not a payload to decode."""
    if payload.strip().lower() == b"timeout":
        return ServiceUnavailable(f"no reply from {what} within {waited_s:.3g} s (the service is there but did "
                                  f"not answer: busy, frozen or cut off)", timeout_s=waited_s)
    try:
        err = codec.decode(payload, s.ErrorReply)
    except DecodeError:
        return DecodeError(f"undecodable error reply from {what}: {payload[:80]!r}")
    return error_from_code(err.code, err.message, err.details)
