"""An in-process stand-in for the Zenoh transport, for the fast tier of the tests (httpx's ``MockTransport``).

    with MemoryFabric() as fabric:
        service = SupervisorService(fabric.session(), "cell1")
        service.start()
        client = Client(fabric.session(), "cell1")
        print(client.status())

A :class:`MemoryFabric` is a hub in one process; its sessions (:class:`MemorySession`) implement the part of
``zenoh.Session`` that :class:`fabric.server.service.Service` and :class:`fabric.client.Client` use, with
Zenoh's semantics where the fabric's code depends on them: key expressions matched by ``zenoh.KeyExpr``,
queries answered from worker threads (FIFO channels) or callbacks on a thread of the fabric's own, replies
handed over as the consolidation asked, ``Timeout`` at a get's timeout, liveliness tokens with history, and
``zenoh.ZError`` from a closed session. The seam is the session object itself: the services and the client
take a session and call only what it provides, so nothing in them changes (they are annotated
``zenoh.Session``; the stand-in is one by duck typing, for tests).

What it does not model (the slow tier, over real sessions, does): links, routing through a hub or relay,
access control, congestion, message sizes, and a peer's incomplete liveliness answers.
"""
from fabric.wire.memory.hub import MemoryFabric, MemoryId
from fabric.wire.memory.session import BlockedCallback, MemorySession

__all__ = ["MemoryFabric", "MemorySession", "MemoryId", "BlockedCallback"]
