"""The states of the station, of print jobs, of long jobs and of a service's health: enums with the questions
the code asks of them (Moonraker's ``JobEvent`` with ``is_printing``), declared once. Imported as a module
(``from fabric.schemas import states``: ``states.Station``, ``states.PrintJob``, ``states.Job``,
``states.Health``), beside the messages of the same names.

Each enum is a ``str``: on the wire, in the stores and in ``--json`` a state is the string it always was
(``states.Station.PRINTING == "printing"``; ``str()`` and f-strings give the bare value), and a string read back
is turned into its member with ``states.Station(text)``. Code asks ``state.in_print`` instead of comparing
strings in a dozen places; the tuples of values (``STATION_STATES``, ``PRINT_JOB_STATES``, ...) that the schemas'
``choices`` and the protocol document list are made from the enums.
"""
from __future__ import annotations

from enum import Enum

__all__ = ["Station", "PrintJob", "Job", "Health", "STATION_STATES", "IN_PRINT_STATES", "FREE_STATION_STATES",
           "PRINT_JOB_STATES",
           "FINAL_JOB_STATES", "ON_STATION_JOB_STATES", "WAITING_JOB_STATES", "JOB_STATES", "HEALTH_STATES"]


class _State(str, Enum):
    """A state: a ``str`` whose text is its value."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


class Station(_State):
    """The station's (the twin's, or the robot it drives) state, as ``station.State`` carries it."""

    IDLE = "idle"                  # nothing loaded, or loaded and not yet checked ready
    READY = "ready"                # a program loaded, the robot at a known pose
    PRINTING = "printing"
    PAUSED = "paused"              # extruder off, retracted, lifted clear; resume goes on where it stopped
    STOPPED = "stopped"            # a print ended by stop (its deposit kept on record)
    FAULT = "fault"                # tripped: a collision, a cold extrusion, a station error; says why
    MOVING = "moving"              # a manual or home move under way (not printing)
    INTERRUPTED = "interrupted"    # a print lost mid-way (the station restarted or stalled): recover goes on

    @property
    def printing(self) -> bool:
        return self is Station.PRINTING

    @property
    def in_print(self) -> bool:
        """A print is under way: printing or paused (stop first to do anything else)."""
        return self in (Station.PRINTING, Station.PAUSED)

    @property
    def print_on(self) -> bool:
        """A print is on, running or not: printing, paused or interrupted (manual moves are refused)."""
        return self in (Station.PRINTING, Station.PAUSED, Station.INTERRUPTED)

    @property
    def free(self) -> bool:
        """No print is on: a job may be loaded, the robot jogged."""
        return self in (Station.IDLE, Station.READY, Station.STOPPED, Station.FAULT)


class PrintJob(_State):
    """A print job's state (``supervisor.JobRecord.state``): queued -> slicing -> planning -> checking -> loaded ->
    printing <-> paused -> finished | stopped | failed | interrupted."""

    QUEUED = "queued"              # in the queue: waiting to be prepared, or prepared (``prepared`` true) and
                                   # waiting to be loaded (``waiting_for`` says for what)
    SLICING = "slicing"            # its model is being sliced (G-code skips this)
    PLANNING = "planning"          # its G-code is being planned into a robot program
    CHECKING = "checking"          # its program is being checked for collisions
    LOADED = "loaded"              # its program is loaded on the station, not started (submitted without
                                   # ``start``: the operator starts it)
    PRINTING = "printing"          # the station prints it
    PAUSED = "paused"              # its print is paused (``station/resume`` goes on)
    FINISHED = "finished"          # its print ended as planned (final)
    STOPPED = "stopped"            # the operator stopped its print (final; the deposit stays on the plate)
    FAILED = "failed"              # it could not be prepared or loaded, or its print faulted (final; ``error``
                                   # says why)
    INTERRUPTED = "interrupted"    # the station restarted or stalled mid-print (``station/recover`` goes on)

    @property
    def ended(self) -> bool:
        """Final: finished, stopped or failed (an interrupted job can still be recovered)."""
        return self in (PrintJob.FINISHED, PrintJob.STOPPED, PrintJob.FAILED)

    @property
    def waiting(self) -> bool:
        """In the queue, being prepared or waiting to be (reorderable): queued, slicing, planning, checking."""
        return self in (PrintJob.QUEUED, PrintJob.SLICING, PrintJob.PLANNING, PrintJob.CHECKING)

    @property
    def on_station(self) -> bool:
        """Its program is the station's: loaded, printing, paused or interrupted."""
        return self in (PrintJob.LOADED, PrintJob.PRINTING, PrintJob.PAUSED,
                        PrintJob.INTERRUPTED)

    @property
    def printing(self) -> bool:
        """On the robot now: printing or paused."""
        return self in (PrintJob.PRINTING, PrintJob.PAUSED)


class Job(_State):
    """A long job's state (slicing, planning, a collision check): queued -> running -> done | failed."""

    QUEUED = "queued"              # accepted, waiting for the service's worker
    RUNNING = "running"            # under way (``progress_r`` and ``stage`` say how far)
    DONE = "done"                  # finished: ``result_id`` names the result (final)
    FAILED = "failed"              # it could not be done: ``error`` says why (final)

    @property
    def ended(self) -> bool:
        return self in (Job.DONE, Job.FAILED)


class Health(_State):
    """A service's health: ``ok``, or ``degraded`` (it serves, but something failed; its report says what)."""

    OK = "ok"                      # serving, nothing failed
    DEGRADED = "degraded"          # serving, but something failed: the reasons say what


STATION_STATES = tuple(s.value for s in Station)
IN_PRINT_STATES = tuple(s for s in Station if s.in_print)          # printing, paused
FREE_STATION_STATES = tuple(s for s in Station if s.free)          # idle, ready, stopped, fault
PRINT_JOB_STATES = tuple(s.value for s in PrintJob)
FINAL_JOB_STATES = tuple(s.value for s in PrintJob if s.ended)
ON_STATION_JOB_STATES = tuple(s.value for s in PrintJob if s.on_station)
WAITING_JOB_STATES = tuple(s.value for s in PrintJob if s.waiting)
JOB_STATES = tuple(s.value for s in Job)
HEALTH_STATES = tuple(s.value for s in Health)
