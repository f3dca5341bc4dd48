"""The thin client library: one method per endpoint, subscriptions, transfers and job waits.

Importable with the base install alone (no service, robot or console code)::

    from fabric.client import Client
"""
from fabric.client.client import AliveSubscription, Client, Subscription, input_size, wait_connected

__all__ = ["Client", "Subscription", "AliveSubscription", "wait_connected", "input_size"]
