"""The thin client library: one method per endpoint, subscriptions, transfers and job waits.

Importable with the base install alone (it imports ``fabric.wire`` and ``fabric.schemas``, no service, robot or
console code)::

    from fabric.client import Client

``client`` (the :class:`Client`), ``sessions`` (opening a session, reading error replies), ``subscriptions``;
the helpers ``job_waits``, ``transfers`` and ``follow`` are written against the small :class:`Caller`
protocol (``protocols``: ``call`` and ``subscribe``), so none of them imports the Client back.
"""
from fabric.client.client import AliveSubscription, Client, Subscription, input_size, wait_connected
from fabric.client.protocols import Caller, Stream

__all__ = ["Client", "Subscription", "AliveSubscription", "wait_connected", "input_size", "Caller", "Stream"]
