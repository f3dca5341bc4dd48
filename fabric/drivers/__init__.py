"""Robot controllers the station drives: the controller protocol and its drivers.

The station keeps the twin: it plans, certifies and times every motion, and the twin's timeline is the
commanded path. With a controller attached (``fabric-cli up --robot franka:HOST``), the station streams that
timeline to the robot as a joint reference and reads the measured joints back: the twin becomes the robot's
shadow. A driver implements :class:`fabric.drivers.controller.Controller` (connect, status, follow a
reference, stop, recover, close); :mod:`fabric.drivers.address` turns ``KIND:HOST`` into one.

* :mod:`fabric.drivers.controller`: the protocol, the facts a controller reports, the tracking samples
* :mod:`fabric.drivers.reference`: the timed joint reference the station fills and a driver follows
* :mod:`fabric.drivers.address`: ``franka:HOST`` -> a controller
* :mod:`fabric.drivers.franka`: Franka Research 3 through franky-control (the libfranka network protocol)

docs/robots.md says what a driver for ABB EGM or UR RTDE would implement.
"""
