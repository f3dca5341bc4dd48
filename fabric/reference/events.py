"""Every kind of the station's events: when it comes and what its ``data`` carries.

The kinds are the twin's (``fabric.sim.types.EVENT_KINDS``); a test fails when a
kind has no entry here, and the contract test validates real events' ``data``
against these entries (no undocumented key, every key of its documented type).
Events of a print job (``fabric.services.station_messages.JOB_EVENTS``) also
carry ``job_id`` and ``elapsed_s`` when the program was loaded for a job.
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["EventKind", "EVENTS", "JOB_DATA", "TOTALS", "RESUME_AT"]


@dataclass(frozen=True)
class EventKind:
    """When an event of this kind comes, and its ``data``: key -> (JSON type, description)."""
    when: str
    data: dict[str, tuple[str, str]] = field(default_factory=dict)
    optional: tuple[str, ...] = ()          # keys of ``data`` that are not always there


JOB_DATA: dict[str, tuple[str, str]] = {
    "job_id": ("string", "the print job loaded (only when the program was loaded for a job)."),
    "elapsed_s": ("number", "simulated seconds since the print started."),
}
TOTALS: dict[str, tuple[str, str]] = {
    "elapsed_s": ("number", "simulated seconds since the print started."),
    "extruded_mm3": ("number", "volume the print deposited (over all its runs)."),
    "filament_mm": ("number", "filament it pushed, retractions counted."),
    "beads": ("integer", "beads on the plate's record."),
}
RESUME_AT: dict[str, tuple[str, str]] = {
    "resume_row": ("integer", "the program row the print goes on from."),
    "resume_s_mm": ("number", "how far along that row, along the path."),
    "xyz_mm": ("array", "where the nozzle left the part: plate frame x, y, z."),
}

EVENTS: dict[str, EventKind] = {
    "started": EventKind(
        "A print started: from the beginning (``from_row`` 0), or at a layer of the part on the plate.",
        {"rows": ("integer", "rows of the program."),
         "estimate_s": ("number", "its expected duration from there, simulated seconds."),
         "from_row": ("integer", "the row it starts at (0: the beginning)."),
         "from_layer": ("integer", "the layer it starts at (0-based; 0 from the beginning).")}),
    "layer": EventKind(
        "The print began a layer (the event's ``layer``).",
        {"z_mm": ("number", "the layer's height: plate frame z of its first extruding move.")}),
    "paused": EventKind(
        "A pause is complete: the extruder is off, the filament retracted and the nozzle lifted clear. Also what "
        "the cold-extrusion interlock ends with.",
        {"reason": ("string", "why: the operator, or the interlock's reason."), **RESUME_AT},
        optional=tuple(RESUME_AT)),
    "resumed": EventKind("The robot is back at the paused spot: printing again."),
    "stopped": EventKind("A stopped print has ended: the robot moved clear, heaters off, the deposit kept.",
                         dict(TOTALS)),
    "finished": EventKind("The print ran to the end of its program: how a finished print shows (then the state is "
                          "``idle`` with reason ``finished``).", dict(TOTALS)),
    "fault": EventKind(
        "The station stopped dead: a failure while moving, an error of the station's own, or an unrestorable "
        "last run. Heaters off; the deposit kept.",
        {"reason": ("string", "what failed.")}),
    "temp_reached": EventKind(
        "A wait for a heater (M109, M190) is over.",
        {"heater": ("string", "``nozzle`` or ``bed``."),
         "temp_c": ("number", "its temperature then."),
         "target_c": ("number", "its set point.")}),
    "home": EventKind("The move home has ended."),
    "interrupted": EventKind(
        "The station restarted (or stalled for seconds) during a print: the print stopped where the station lost "
        "it; ``recover`` goes on from there.",
        {"reason": ("string", "what happened."), **RESUME_AT, **TOTALS}),
    "recovered": EventKind("A recovery's move back is over: printing again (at the interrupted spot, or at a "
                           "layer)."),
    "stall": EventKind(
        "The station's clock was held: its process was frozen or starved (simulated time does not jump).",
        {"stalled_s": ("number", "how late the tick came, wall-clock seconds."),
         "state": ("string", "the station's state then.")}),
    "at_layer": EventKind("A restart at a layer reached the layer's first point: printing from there."),
    "override": EventKind(
        "An override was set (``station/overrides``): the values given.",
        {"speed_r": ("number", "speed factor."), "flow_r": ("number", "flow factor."),
         "nozzle_c": ("number", "nozzle set point."), "bed_c": ("number", "bed set point.")},
        optional=("speed_r", "flow_r", "nozzle_c", "bed_c")),
    "calibrated": EventKind(
        "The plate was probed and the work object fitted (``station/calibrate``).",
        {"residual_rms_mm": ("number", "how well the touches agree with the fitted frame."),
         "correction_xyz_mm": ("array", "the fitted frame's offset from the nominal one.")}),
    "interlock": EventKind(
        "The cold-extrusion interlock stopped the print before a move that would extrude below the material's "
        "minimum temperature; a ``paused`` event follows.",
        {"reason": ("string", "why it tripped."),
         "nozzle_c": ("number", "the nozzle's temperature then."),
         "min_c": ("number", "the material's minimum extrusion temperature."),
         "row": ("integer", "the program row that would extrude cold.")}),
    "plate_cleared": EventKind(
        "The operator said the plate is clear (``station/clear_plate``, or ``supervisor/job_next``): the part, "
        "if the station had one, is off; said of a plate the station saw clear too (a print stopped before its "
        "first bead), then with no job and no volume.",
        {"job_id": ("string", "the job whose part it was (\"\" when printed by hand, or no part)."),
         "plate_mm3": ("number", "the part's volume (0: no part).")}),
    "jogged": EventKind(
        "A jog (``station/jog``: a straight move by hand, collision-checked) has ended.",
        {"xyz_mm": ("array", "where the nozzle tip is now: plate frame x, y, z.")}),
    "extruded": EventKind(
        "Filament was pushed or pulled by hand (``station/extrude``), the robot still; not a bead of the part.",
        {"filament_mm": ("number", "the filament length moved (negative: pulled back).")}),
}
