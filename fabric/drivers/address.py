"""``KIND:HOST`` -> a controller: where the station's robot is, from ``--robot``, the cell file's
``[robot] controller`` or ``FABRIC_ROBOT`` (in that order of precedence).

Kinds: ``franka`` (a Franka Research 3 through franky-control). ``twin`` or nothing: the twin alone.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from fabric.drivers.controller import Controller
from fabric.wire.errors import ConfigError

__all__ = ["RobotAddress", "parse_robot", "robot_address", "open_controller", "KINDS", "ENV_VAR"]

KINDS = ("franka",)
ENV_VAR = "FABRIC_ROBOT"


@dataclass(frozen=True)
class RobotAddress:
    kind: str
    host: str

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}"


def parse_robot(text: str, where: str = "--robot") -> RobotAddress | None:
    """``franka:HOST`` -> its address; ``twin`` or an empty string -> None (no robot). A typed error names
    ``where`` the text came from."""
    text = text.strip()
    if text in ("", "twin", "none"):
        return None
    kind, sep, host = text.partition(":")
    if not sep or not host.strip() or " " in host.strip():
        raise ConfigError(f"{where}: {text!r} is no robot address: write KIND:HOST, e.g. franka:172.16.0.2 "
                          "(or 'twin' for the twin alone)", field=where, value=text)
    if kind not in KINDS:
        raise ConfigError(f"{where}: unknown robot kind {kind!r} in {text!r}; known: {', '.join(KINDS)}",
                          field=where, value=text)
    return RobotAddress(kind, host.strip())


def robot_address(option: str | None, cell_value: str | None) -> RobotAddress | None:
    """The robot the station drives: ``--robot`` first, then the cell file's, then ``FABRIC_ROBOT``."""
    if option is not None:
        return parse_robot(option, "--robot")
    if cell_value:
        return parse_robot(cell_value, "robot.controller")
    return parse_robot(os.environ.get(ENV_VAR, ""), ENV_VAR)


def open_controller(address: RobotAddress) -> Controller:
    """A driver for ``address`` (not connected yet)."""
    if address.kind == "franka":
        from fabric.extras import require
        require("robot")                      # franky-control: the one-line missing-extra error, not a trace
        from fabric.drivers.franka import FrankaController
        return FrankaController(address.host)
    raise ConfigError(f"no driver for robot kind {address.kind!r}", field="robot", value=str(address))
