"""Typed errors shared by every service, the client and the CLI.

Exception tree (the ``code`` travels in error replies; the client raises the
class that matches it)::

    FabricError                      code "internal"
    ├── BadRequest                   "bad_request"     malformed or invalid input
    │   ├── DecodeError              "decode"          payload is not a valid message
    │   ├── ValidationError          "validation"      a field has a wrong type/range
    │   ├── GcodeError               "gcode"           names file and line
    │   ├── MeshError                "mesh"            broken or unusable model
    │   ├── ProfileError             "profile"         unknown key or bad value
    │   ├── ConfigError              "config"          cell / service configuration
    │   └── PlacementError           "placement"       part does not fit plate/volume
    ├── UnreachableError             "unreachable"     IK failed: names the G-code line
    ├── ColdExtrusionError           "cold_extrusion"  the program extrudes below the material's minimum
    ├── CollisionError               "collision"       a move would collide
    ├── StateError                   "state"           command not valid in this state
    ├── NotFound                     "not_found"       unknown job / artifact / robot
    ├── SlicerError                  "slicer"          an external slicer failed
    ├── ServiceUnavailable           "unavailable"     no service answered in time
    ├── PermissionDenied             "forbidden"       the caller's role may not do this
    ├── StoreError                   "store"           a database file is damaged, or newer than this release
    ├── DiskFull                     "disk_full"       a service's disk has no room for the work
    ├── RobotError                   "robot"           the robot controller is not there, busy, speaks another
    │                                                  version, or stopped in error
    └── InternalError                "internal"        unexpected failure (bug)

Every error carries ``details``: a dict of plain values that a caller can act
on. Each detail has one type wherever the error is raised; the ones a caller
may rely on, by class (others may be present)::

    DecodeError        reason: str (one of fabric.wire.codec.DECODE_REASONS), expected: str (the message
                       type asked for); reason "type": got: str (the _t received); reason "version":
                       got (the _v received), supported: int
    ValidationError    field: str (dotted path; "" for the whole message), schema: str (the message type)
    GcodeError         line: int (1-based), text: str
    MeshError          file: str, reason: str ("empty", "format", "truncated", "open", ...)
    ConfigError        field: str (``section.key``), value
    UnreachableError   reason: str (one of UNREACHABLE_REASONS), gcode_line: int (-1: not from G-code),
                       and where known row: int, joint: int (0-based), xyz_mm: list[float], probe: int
    ColdExtrusionError reason: str (one of COLD_EXTRUSION_REASONS), gcode_line, row: int, nozzle_c: float
                       (the set point), min_c: float, set_line: int, waited_c: float | None, wait_line: int
    CollisionError     the fields of ``collision.Hit``: body_a, body_b: str, t_s: float,
                       row, gcode_line, layer: int, move_r: float
    StateError         state: str, command: str
    NotFound           what was looked for (job_id, artifact_id, backend, ...): str
    ServiceUnavailable key: str, timeout_s: float, or missing: list[str]
    PermissionDenied   role: str, service: str, command: str
    StoreError         file: str, reason: str ("damaged", "newer", "migration", "open"), for "damaged"
                       problem: str (what SQLite or its quick_check found), and for
                       "newer" and "migration" table: str, version: int
    DiskFull           service: str, path: str, free_mb: float, need_mb: float (MiB)
    RobotError         robot: str (the address, ``franka:HOST``), reason: str (one of ROBOT_REASONS); for
                       "version" server_version: int | None, library_version: int | None
"""
from __future__ import annotations

from typing import Any

__all__ = [
    "FabricError", "BadRequest", "DecodeError", "ValidationError", "GcodeError",
    "MeshError", "ProfileError", "ConfigError", "PlacementError", "UnreachableError",
    "CollisionError", "StateError", "NotFound", "SlicerError", "ServiceUnavailable",
    "PermissionDenied", "StoreError", "InternalError", "error_from_code", "UNREACHABLE_REASONS",
    "ColdExtrusionError", "COLD_EXTRUSION_REASONS", "ERROR_CLASSES", "RobotError", "ROBOT_REASONS", "DiskFull",
]

UNREACHABLE_REASONS = ("out of reach", "joint limit", "singular", "joint jump", "off the plate", "below the plate")
"""Why a target is unreachable (``UnreachableError.details['reason']``): no solution at all, a
solution only beyond a joint's limits, at a singularity, or a configuration change between two
consecutive targets (``fabric.robot.kinematics.ik_reason`` maps the IK status codes to these); or
outside the work envelope: beyond the plate's edges, or under its surface (``fabric.planning.envelope``)."""

COLD_EXTRUSION_REASONS = ("set below the minimum", "not heated")
"""Why a program would extrude cold (``ColdExtrusionError.details['reason']``): the nozzle's set point is
below the material's minimum extrusion temperature, or it is not but nothing waits (M109) for the nozzle
to get there (``fabric.motion.cold``)."""

ROBOT_REASONS = ("unreachable", "busy", "version", "fault", "lost", "refused")
"""Why the robot controller could not be used (``RobotError.details['reason']``): nothing answers at its
address; it answers but another client holds it; it speaks a server version the library does not; it
stopped in error (a reflex, a limit); the connection was lost while it was driven; it refused a command."""


class FabricError(Exception):
    """Base of all fabric errors: a stable ``code``, a message and ``details``."""

    code = "internal"

    def __init__(self, message: str, **details: Any) -> None:
        super().__init__(message)
        self.message = message
        self.details: dict[str, Any] = details

    def __str__(self) -> str:
        return self.message

    def to_wire(self) -> dict[str, Any]:
        """The error as a plain dict: what ``reply_err`` carries."""
        return {"code": self.code, "message": self.message, "details": _plain(self.details)}


class BadRequest(FabricError):
    code = "bad_request"


class DecodeError(BadRequest):
    code = "decode"


class ValidationError(BadRequest):
    """A field is missing, of the wrong type or out of range; ``details['field']`` names it."""

    code = "validation"


class GcodeError(BadRequest):
    """G-code that cannot be interpreted; ``details`` has ``line`` (1-based) and ``text``."""

    code = "gcode"

    def __init__(self, message: str, line: int | None = None, **details: Any) -> None:
        where = f"line {line}: " if line is not None else ""
        super().__init__(f"{where}{message}", line=line, **details)


class MeshError(BadRequest):
    code = "mesh"


class ProfileError(BadRequest):
    code = "profile"


class ConfigError(BadRequest):
    code = "config"


class PlacementError(BadRequest):
    code = "placement"


class UnreachableError(FabricError):
    """A target the robot cannot reach; ``details`` has ``reason`` (one of ``UNREACHABLE_REASONS``)
    and ``gcode_line`` (-1 when the target does not come from G-code)."""

    code = "unreachable"

    def __init__(self, message: str, *, reason: str, gcode_line: int = -1, **details: Any) -> None:
        if reason not in UNREACHABLE_REASONS:
            raise TypeError(f"UnreachableError reason must be one of {UNREACHABLE_REASONS}, got {reason!r}")
        super().__init__(message, reason=reason, gcode_line=int(gcode_line), **details)


class ColdExtrusionError(FabricError):
    """A program that would extrude below its material's minimum extrusion temperature; ``details`` has
    ``reason`` (one of ``COLD_EXTRUSION_REASONS``), ``gcode_line`` and the temperatures."""

    code = "cold_extrusion"


class CollisionError(FabricError):
    code = "collision"


class StateError(FabricError):
    """A command that is not valid now; ``details`` has ``state`` and ``command``."""

    code = "state"


class NotFound(FabricError):
    code = "not_found"


class SlicerError(FabricError):
    code = "slicer"


class ServiceUnavailable(FabricError):
    code = "unavailable"


class PermissionDenied(FabricError):
    """The caller's role (its credentials) may not do this; the hub would drop the request unanswered."""

    code = "forbidden"


class StoreError(FabricError):
    """A service's database cannot be used: the file is damaged (or not SQLite), a table in it was
    written by a newer release, or migrating it failed. ``details['file']`` names the file; the message
    says what to do."""

    code = "store"


class DiskFull(FabricError):
    """A service's disk has no room for the work asked (checked before it is accepted), or ran out of room
    doing it (``ENOSPC``): nothing was half-written that counts; free space, then ask again."""

    code = "disk_full"


class RobotError(FabricError):
    """The robot controller the station drives is not there, is held by another client, speaks another
    version, stopped in error or lost its connection (``details['reason']``, one of ROBOT_REASONS).
    The message is one line that says what to do."""

    code = "robot"


class InternalError(FabricError):
    code = "internal"


ERROR_CLASSES: dict[str, type[FabricError]] = {}
"""Every error code -> the class a client raises for it, in the tree's order (``internal``: InternalError)."""


def _register(cls: type[FabricError]) -> None:
    ERROR_CLASSES[cls.code] = cls
    for sub in cls.__subclasses__():
        _register(sub)


_register(FabricError)
ERROR_CLASSES["internal"] = InternalError


def error_from_code(code: str, message: str, details: dict[str, Any] | None = None) -> FabricError:
    """Rebuild the typed exception for an error reply (unknown codes become InternalError)."""
    cls = ERROR_CLASSES.get(code, InternalError)
    err = cls.__new__(cls)
    FabricError.__init__(err, message, **(details or {}))
    return err


def _plain(value: Any) -> Any:
    """Coerce details to msgpack-friendly plain values (numpy scalars, tuples, paths)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        return value
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        try:
            return value.item()
        except (ValueError, TypeError):
            pass
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)
