"""Opening a client's Zenoh session, and reading what the fabric says back: links, refusals, error replies."""
from __future__ import annotations

import time

import zenoh

from fabric import schemas as s
from fabric.wire import codec
from fabric.wire.config import SessionSettings, zenoh_config
from fabric.wire.errors import DecodeError, FabricError, PermissionDenied, ServiceUnavailable, error_from_code

__all__ = ["open_session", "wait_connected", "check_role", "error_of", "CONNECT_WINDOW_S"]

CONNECT_WINDOW_S = 3.0     # how long opening waits for the hub, and connect() for the first link


def open_session(settings: SessionSettings) -> zenoh.Session:
    """Open a session; a client that finds no router retries briefly, then says where it looked."""
    end = time.monotonic() + CONNECT_WINDOW_S
    first = True
    while True:
        try:
            return zenoh.open(zenoh_config(settings))
        except zenoh.ZError as exc:
            last = time.monotonic() >= end
            if (first and settings.config_file) or last:     # a secured hub that refused us: say why
                _refused(settings)
            first = False
            if last:
                raise ServiceUnavailable(f"cannot reach the fabric hub at {', '.join(settings.connect)} "
                                         f"(is 'fabric-cli up' or 'fabric-cli router' running?)",
                                         connect=settings.connect, reason=str(exc)) from None
            time.sleep(0.1)


def _refused(settings: SessionSettings) -> None:
    """Raise PermissionDenied with the reason when a secured hub refused these credentials."""
    from fabric.security.diagnose import explain_refusal
    why = explain_refusal(settings.config_file, settings.connect)
    if why is not None:
        raise PermissionDenied(f"the fabric hub at {', '.join(settings.connect)} refused this session: {why}",
                               connect=settings.connect, config=settings.config_file)


def check_role(role: str, service: str, command: str) -> None:
    """Refuse at once what the hub would drop unanswered for this role."""
    from fabric.security.roles import MONITOR_COMMANDS, may_call
    if not may_call(role, service, command):
        allowed = ", ".join(sorted(f"{svc}/{cmd}" for svc, cmd in MONITOR_COMMANDS)) if role == "monitor" else ""
        raise PermissionDenied(f"the {role} role may not run {service}/{command} (ask an operator)"
                               + (f"; it may run {allowed}" if allowed else ""),
                               role=role, service=service, command=command)


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
