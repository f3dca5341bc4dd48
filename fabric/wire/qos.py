"""Quality of service of commands: an operator's command goes ahead of telemetry, unbatched.

Telemetry (pose, extrusion, temperatures: hundreds of messages per second to
every monitor) travels at Zenoh's default data priority, batched. A command
and its reply travel at interactive priority and express (sent at once, never
held back to fill a batch), so under load a ``position`` or a ``stop`` does not
queue behind the pose stream in the hub. Bulk endpoints (models, G-code,
exports: megabytes) keep the data priority, so they never hold up commands.

A command's reply is handed to the caller the moment it arrives. Zenoh's
default consolidation (latest per key) holds every reply until the query's
final message has come back through each hop; a command has one answering
service and one reply, so there is nothing to consolidate, and waiting for the
final would only add its trip back through each hop.
"""
from __future__ import annotations

from typing import Any

import zenoh

from fabric.wire.keys import Endpoint

__all__ = ["command_qos", "reply_qos", "BULK_QOS", "INTERACTIVE_QOS"]

INTERACTIVE_QOS: dict[str, Any] = {"priority": zenoh.Priority.INTERACTIVE_HIGH, "express": True,
                                   "consolidation": zenoh.ConsolidationMode.NONE}
BULK_QOS: dict[str, Any] = {}


def command_qos(ep: Endpoint) -> dict[str, Any]:
    """Keyword arguments of ``Session.get`` for endpoint ``ep``."""
    return BULK_QOS if ep.bulk else INTERACTIVE_QOS


def reply_qos(ep: Endpoint) -> dict[str, Any]:
    """Keyword arguments of ``Query.reply`` for endpoint ``ep`` (a reply travels at its query's priority)."""
    return {} if ep.bulk else {"express": True}
