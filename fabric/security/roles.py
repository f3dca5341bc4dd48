"""The roles of a secured fabric, what each may do, and the hub's access-control rules that enforce it.

Three identities join a secured fabric, each with its own user name, password and certificate
(common name = role name):

- ``operator``: every command of every service, telemetry, artifacts (G-code, programs, meshes);
- ``monitor``: telemetry and the read-only queries in ``MONITOR_COMMANDS``; nothing that changes a cell;
- ``service``: the five services themselves (they serve commands, publish, and call each other).

The hub enforces it (``access_control``, default deny): a request a role may not make is dropped
there, unanswered. Access control only filters what passes through the hub, so on a secured fabric
every process is a Zenoh *client* of the hub (no peer links around it) and the hub listens on TLS
only. The client library checks the same table first (``may_call``) so that a refused command says
so at once instead of waiting for a reply that will never come.
"""
from __future__ import annotations

from typing import Any

from fabric.wire.keys import ENDPOINTS, EVERY_KEY, TOPICS, Keys

__all__ = ["ROLES", "MONITOR_COMMANDS", "may_call", "permissions", "access_control", "relay_access_control"]

ROLES = ("operator", "monitor", "service")

MONITOR_COMMANDS: frozenset[tuple[str, str]] = frozenset({
    ("station", "position"), ("station", "state"), ("station", "time"), ("station", "events"),
    ("supervisor", "status"), ("supervisor", "jobs"), ("supervisor", "job"), ("supervisor", "files"),
    ("supervisor", "file"),
})
"""The read-only queries a monitor may make (plus liveliness: ``status`` and ``cells`` need no service)."""

_ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]


def may_call(role: str, service: str, command: str) -> bool:
    """Whether ``role`` may call endpoint ``service/command``."""
    if role in ("operator", "service"):
        return True
    return role == "monitor" and (service, command) in MONITOR_COMMANDS


def permissions(role: str) -> dict[str, list[str]]:
    """What ``role`` may do, for people: commands, streams it receives, other rights."""
    if role not in ROLES:
        raise KeyError(f"no role {role!r} (roles: {', '.join(ROLES)})")
    commands = [f"{svc}/{cmd}" for (svc, cmd) in ENDPOINTS if may_call(role, svc, cmd)]
    streams = [f"{svc}/{topic}" for (svc, topic) in TOPICS]
    other = {"operator": ["liveliness (status, cells)", "artifacts (G-code, programs, meshes)"],
             "monitor": ["liveliness (status, cells)"],
             "service": ["serve commands and artifacts", "publish telemetry", "hold liveliness tokens",
                         "call the other services"]}[role]
    return {"commands": commands, "streams": streams, "other": other}


def _rule(rule_id: str, flows: list[str], messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": flows, "messages": messages, "key_exprs": key_exprs}


def access_control() -> dict[str, Any]:
    """The hub's ``access_control`` section: default deny; subjects match user name *and* certificate.

    ``ingress`` is what a session sends to the hub, ``egress`` what the hub forwards to it: a monitor may
    declare subscribers anywhere under ``am/``, but the hub forwards it only telemetry, liveliness and
    the replies to its read-only queries; it may send only those queries (no put, no queryable, no token).
    """
    every = Keys.every_cell()
    telemetry = sorted(every.topic(svc, topic) for (svc, topic) in TOPICS)
    alive = [every.alive_all()]
    read_only = sorted(every.cmd(svc, cmd) for (svc, cmd) in MONITOR_COMMANDS)
    commands = [every.cmd_all("*")]
    artifacts = [every.artifact_all("*")]
    rules = [
        _rule("service_all", ["ingress", "egress"], _ALL_MESSAGES, [EVERY_KEY]),
        _rule("watch", ["ingress"], ["declare_subscriber"], [EVERY_KEY]),
        _rule("liveliness", ["ingress"], ["declare_liveliness_subscriber", "liveliness_query"], alive),
        _rule("liveliness_out", ["egress"], ["liveliness_token"], alive),
        _rule("telemetry_out", ["egress"], ["put", "delete"], telemetry),
        _rule("operator_commands", ["ingress", "egress"], ["query", "reply"], commands + artifacts),
        _rule("read_only_queries", ["ingress", "egress"], ["query", "reply"], read_only),
        # where those queries are answered: a relay (a router) routes a dashboard's query by it
        _rule("read_only_routes", ["egress"], ["declare_queryable"], read_only),
    ]
    subjects = [{"id": role, "usernames": [role], "cert_common_names": [role]} for role in ROLES]
    reader = ["watch", "liveliness", "liveliness_out", "telemetry_out"]
    policies = [
        {"rules": ["service_all"], "subjects": ["service"]},
        {"rules": reader + ["operator_commands"], "subjects": ["operator"]},
        {"rules": reader + ["read_only_queries", "read_only_routes"], "subjects": ["monitor"]},
    ]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def relay_access_control() -> dict[str, Any]:
    """A relay's ``access_control`` section: the hub (its certificate's name) may do anything; every role
    connecting to the relay has a monitor's rights. The relay itself joins the hub as ``monitor``, so the
    hub holds it to those rights whatever is configured here."""
    acl = access_control()
    acl["subjects"].append({"id": "hub", "cert_common_names": ["hub"]})
    # what the relay is (am/@relay/<its id>, answered by the relay itself): how a client learns it is on one
    acl["rules"].append(_rule("relay_info", ["ingress", "egress"], ["query", "reply"], ["am/@relay/*"]))
    monitor = next(p["rules"] for p in acl["policies"] if p["subjects"] == ["monitor"])
    acl["policies"] = [{"rules": ["service_all"], "subjects": ["hub"]},
                       {"rules": [*monitor, "relay_info"], "subjects": list(ROLES)}]
    return acl

