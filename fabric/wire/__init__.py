"""The wire: key expressions and the endpoint table, the msgpack codec, typed errors, QoS, session config.

What every participant of the fabric needs, a plain monitor included; imports nothing heavy
(zenoh, msgpack and numpy only). The messages themselves are in :mod:`fabric.schemas`.
:mod:`fabric.wire.memory` stands in for the transport in one process (the fast tier of the tests).
"""
