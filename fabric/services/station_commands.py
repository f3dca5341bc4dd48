"""The one way a station command changes the twin: :class:`CommandRunner` (Klipper's reactor as the only way in).

A command is a *change* or a *checked change*. A change is one step of the
station's writer: the command's ``act`` runs there, and the runner then takes
the checkpoint (the journal, the ``position`` snapshot, the change counter); a
refused command raises before anything is changed, and nothing is written. A
checked change is a motion the collision service certifies first, in four
parts that no command can skip or reorder:

1. **plan**, a step: read the twin, refuse what the state forbids, and say
   what the command will make the robot do (:class:`Move` for a joint move,
   :class:`RestOfProgram` for the print a restart or a recovery runs on the
   part), with a stamp of the twin as it is (the change counter, its state,
   the robot's joints);
2. **certify**, in the handler's thread, outside the writer: every move, and
   all of the print that follows, against the beads on the plate
   (``StationService.certify``);
3. **act**, a step: only if the stamp is unchanged (compare-and-set; else
   :class:`~fabric.server.writer.Stale`, nothing done), make the change;
4. **checkpoint and acknowledge**: the runner's, after ``act`` returns.

Commands outside the station module register themselves on the station
through its public surface (:class:`StationSurface`: ``register_command``,
Klipper's, and the runner) and use these same mechanisms.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from fabric import schemas as s
from fabric.server.writer import Owned, Stale, Writer
from fabric.sim.twin import Twin

__all__ = ["Move", "RestOfProgram", "Check", "Planned", "CommandRunner", "StationSurface", "STEP_TIMEOUT_S"]

STEP_TIMEOUT_S = 4.0          # a command's step not begun by then is dropped (under the 5 s a caller waits)
P = TypeVar("P")
R = TypeVar("R")


@dataclass(frozen=True)
class Move:
    """A joint move the station is about to make, to be certified before it is made.

    ``descent`` (joints, layer): a straight way down after the move (a restart onto the first point of
    a layer, or a jog's straight piece), certified with it; on the way down the nozzle tip may touch that
    layer's beads and the layer under's (-1: none)."""

    q_from_rad: np.ndarray
    q_to_rad: np.ndarray
    what: str                        # "the move home", for the refusal: "the move home would collide: ..."
    kind: str                        # the collision service's kind: home, recover, restart, jog
    vel_r: float                     # the move's share of the joints' top speeds
    descent: tuple[np.ndarray, int] | None = None
    accepted: str = ""               # what would be taken instead, for a refusal ("go on at layer 26")


@dataclass(frozen=True)
class RestOfProgram:
    """The loaded program from ``from_row`` to its return home, started from ``q_start_rad``: what a restart at a
    layer or a recovery prints on the part already on the plate, certified whole before it runs (its moves
    against the part and the beads it lays, none of its beads into the part). ``what`` names it in a refusal,
    ``accepted`` says what would be taken instead ("go on at layer 26")."""

    program_id: str
    from_row: int
    q_start_rad: np.ndarray
    what: str
    accepted: str = ""


Check = Move | RestOfProgram


@dataclass
class Planned(Generic[P]):
    """What a checked command's plan found: the moves to certify, what ``act`` needs, and ``what`` to name
    in a stale refusal ("the station changed while the move home was being checked")."""

    moves: list[Check]
    data: P
    what: str = "the move"
    stamp: tuple = field(default=(), repr=False)      # set by the runner


class CommandRunner:
    """Runs the station's commands as steps of its ``writer`` (see the module docstring).

    ``stamp()`` (on the writer) is what a checked command's act compares with its plan's; ``checkpoint()``
    (on the writer) saves the twin after a change; ``certify(move)`` (outside it) raises CollisionError on
    a hit. ``state()`` (on the writer) names the station's state for a stale refusal."""

    generation: Owned[int] = Owned()          # counts the changes (a checked command's stamp compares it)

    def __init__(self, writer: Writer, stamp: Callable[[], tuple], checkpoint: Callable[[], None],
                 certify: Callable[[Check], None], state: Callable[[], str]) -> None:
        self.writer = writer
        self._stamp_of, self._checkpoint, self._certify, self._state = stamp, checkpoint, certify, state
        self.generation = 0
        self.motion_gate: Callable[[str], None] | None = None
        """Called (on the writer) first in every checked command's plan: a station driving a robot refuses
        a motion there while the robot is not ready."""

    def read(self, fn: Callable[[], R]) -> R:
        """``fn`` as a step that changes nothing (a consistent read of the twin); no checkpoint."""
        return self.writer.call(fn, timeout_s=STEP_TIMEOUT_S)

    def change(self, act: Callable[[], R]) -> R:
        """``act`` as one step, then the checkpoint; an ``act`` that raises has changed nothing, and no
        checkpoint is taken."""
        def step() -> R:
            reply = act()
            self._committed()
            return reply
        return self.writer.call(step, timeout_s=STEP_TIMEOUT_S)

    def checked(self, command: str, plan: Callable[[], Planned[P]], act: Callable[[Planned[P]], R]) -> R:
        """A motion certified before it is made: plan (a step), certify every move (here, outside the
        writer), act only if nothing changed meanwhile (a step), checkpoint. A plan with no moves acts in
        its own step."""
        def planning() -> tuple[Planned[P], R | None]:
            if self.motion_gate is not None:
                self.motion_gate(command)
            planned = plan()
            if not planned.moves:                    # nothing to certify: act at once, in this step
                reply = act(planned)
                self._committed()
                return planned, reply
            planned.stamp = self._stamp()
            return planned, None
        planned, done = self.writer.call(planning, timeout_s=STEP_TIMEOUT_S)
        if not planned.moves:
            return done                                   # type: ignore[return-value]
        for move in planned.moves:
            self._certify(move)

        def acting() -> R:
            if self._stamp() != planned.stamp:
                state = self._state()
                raise Stale(f"the station changed while {planned.what} was being checked (it is now {state}); "
                            f"nothing was done: ask again", state=state, command=command)
            reply = act(planned)
            self._committed()
            return reply
        return self.writer.call(acting, timeout_s=STEP_TIMEOUT_S)

    def _stamp(self) -> tuple:
        return (self.generation, *self._stamp_of())

    def _committed(self) -> None:
        self.generation += 1
        self._checkpoint()


class StationSurface(Protocol):
    """What a station command of another module may use of the station (``StationService`` is one): it never
    reaches into the station's private names, and the station keeps no forwarding methods for it."""

    commands: CommandRunner

    @property
    def twin(self) -> Twin:
        """The twin, in a step of :attr:`commands` only (owned by the writer)."""
        ...

    def register_command(self, command: str, handler: Callable[[Any], Any]) -> None:
        """Serve the station endpoint ``command`` with ``handler``."""
        ...

    def move(self, q_from_rad: np.ndarray, q_to_rad: np.ndarray, what: str, kind: str,
             descent: tuple[np.ndarray, int] | None = None, accepted: str = "") -> Move:
        """A joint move at the twin's home speed, for a checked command's plan (in a step)."""
        ...

    def ack(self, message: str) -> s.Ack:
        """A command's acknowledgement with the station's state (in a step)."""
        ...
