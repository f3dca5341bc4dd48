"""The controller protocol: what the station needs from a robot controller to drive it.

A controller follows a :class:`~fabric.drivers.reference.Reference` (joint positions timed on this host's
monotonic clock, filled ahead by the station's clock thread) and records what the robot did: each control
step the driver streams, the commanded and the measured joints (:class:`Tracking`). It never plans: every
motion it follows was planned and certified by the station; it stops the robot when the reference runs
dry (the station stalled or died), when told to, or when the robot faults.

Errors are :class:`fabric.wire.errors.RobotError` with a reason of ``ROBOT_REASONS``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from fabric.drivers.reference import Reference

__all__ = ["Controller", "ControllerInfo", "ControllerStatus", "Tracking"]


@dataclass(frozen=True)
class ControllerInfo:
    """What connecting found: the address, the controller's kind and server version, its joints."""

    address: str               # "franka:127.0.0.1"
    kind: str                  # "franka"
    server_version: int | None
    dof: int
    q_rad: np.ndarray          # the measured joints on connecting


@dataclass
class ControllerStatus:
    """The controller now, as ``status`` and the console show it."""

    address: str
    connected: bool
    following: bool = False           # a reference is being streamed
    mode: str = ""                    # the controller's own mode ("Idle", "Move", "Reflex", ...)
    server_version: int | None = None
    errors: list[str] = field(default_factory=list)   # active errors, by the controller's names
    fault: str = ""                   # why following ended, if it ended by itself (a reflex, the link lost)
    lost: bool = False                # the connection is gone (recover reconnects)
    robot_time_s: float | None = None     # the controller's clock
    q_rad: np.ndarray | None = None       # the measured joints

    @property
    def ok(self) -> bool:
        """Connected, no error and nothing faulted: a print may run."""
        return self.connected and not self.lost and not self.errors and not self.fault


@dataclass
class Tracking:
    """Control steps streamed since the last read: when (host monotonic s), the joints commanded then and the
    joints measured then."""

    t_s: np.ndarray            # (N,)
    q_cmd_rad: np.ndarray      # (N, dof)
    q_meas_rad: np.ndarray     # (N, dof)

    @classmethod
    def empty(cls, dof: int) -> Tracking:
        return cls(np.zeros(0), np.zeros((0, dof)), np.zeros((0, dof)))

    def __len__(self) -> int:
        return len(self.t_s)


class Controller(Protocol):
    """A robot controller the station drives. Every method may raise ``RobotError``; none blocks longer than
    its stated deadline."""

    address: str

    def connect(self) -> ControllerInfo:
        """Open the connection (at most the driver's connect deadline): ``unreachable``, ``busy`` or
        ``version`` otherwise."""
        ...

    def status(self) -> ControllerStatus:
        """The controller now (cheap: read each tick of the station's clock)."""
        ...

    def follow(self, reference: Reference) -> None:
        """Start streaming ``reference`` to the robot from where it stands; returns at once. The robot holds
        the reference's last sample when it runs dry."""
        ...

    def tracking(self) -> Tracking:
        """The control steps streamed since the last call (and forgets them)."""
        ...

    def stop(self) -> None:
        """Stop following: the robot stops where it is (the controller's own stop)."""
        ...

    def recover(self) -> ControllerInfo:
        """Reconnect if the connection was lost, clear the controller's errors where its automatic recovery
        may; ``fault`` if it may not."""
        ...

    def close(self) -> None:
        """Stop and let go of the robot."""
        ...
