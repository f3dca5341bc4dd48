"""Planning options: how G-code coordinates, speeds and extrusion map onto the robot cell."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fabric.gcode.material import FILAMENT_DIAMETER_RANGE_MM
from fabric.planning.material import ASSUMED_FILAMENT_DIAMETER_MM
from fabric.wire.errors import ValidationError

__all__ = ["PlanOptions"]


def _vec(value: Any, n: int, name: str) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise ValidationError(f"{name} needs {n} finite numbers", field=name, value=np.asarray(value).tolist())
    return tuple(float(v) for v in arr)


@dataclass
class PlanOptions:
    """Validated planning options (units in the names; see each field's comment).

    ``offset_mm`` places the G-code origin in the plate frame (G-code point ``p``
    becomes plate point ``p + offset_mm``). ``tilt_deg`` tilts the nozzle axis
    (vertical, pointing down the plate's -z, at (0, 0)) about the plate x then
    y axis. The free rotation about the nozzle axis is searched over
    ``rot_range_deg`` in ``rot_step_deg`` steps to keep clear of joint limits
    and singularities. Travel moves (no extrusion) of at least
    ``lift_min_travel_mm`` in XY are lifted by ``travel_lift_mm`` along the
    plate z: up, across, down.
    """

    # any sequences of 3, 2 and 2 numbers: tuples of floats once checked (__post_init__)
    offset_mm: tuple[float, ...] = (0.0, 0.0, 0.0)
    tilt_deg: tuple[float, ...] = (0.0, 0.0)
    rot_range_deg: tuple[float, ...] = (-180.0, 180.0)
    rot_step_deg: float = 15.0
    speed_r: float = 1.0                 # feed-rate factor applied to every G-code feed
    max_tcp_speed_mm_s: float = 500.0    # cap on any programmed linear speed
    travel_lift_mm: float = 1.0
    lift_min_travel_mm: float = 2.0
    filament_diameter_mm: float | None = None   # None: as the G-code states (fabric.planning.material)
    approach_height_mm: float | None = None   # None: the cell's
    approach_speed_mm_s: float | None = None  # None: the cell's
    zone_mm: float = 0.5                 # blend zone of print and travel moves
    fw_retract_mm: float = 0.8           # filament length of a firmware retraction (G10 / G11)
    chord_tol_mm: float = 0.01           # arc (G2/G3) chord tolerance
    linear_tol_mm: float = 0.1           # joint interpolation between two rows strays at most this far from a
    #                                      linear move's straight line: longer moves are split (refine.py)
    ik_block_rows: int = 1 << 18         # toolpath rows planned at a time (a chunk: one IK call): bounds memory
    wobj_T: np.ndarray | None = None     # work object (plate frame in the base frame, mm); None: the cell's
    allow_off_plate: bool = False        # targets off the plate or below it: counted, not fatal (envelope.py)
    max_turn_deg: float = 5.0            # multi-axis G-code: a move turning the nozzle more is split (turns.py)

    def __post_init__(self) -> None:
        self.offset_mm = _vec(self.offset_mm, 3, "offset_mm")
        self.tilt_deg = _vec(self.tilt_deg, 2, "tilt_deg")
        self.rot_range_deg = _vec(self.rot_range_deg, 2, "rot_range_deg")
        lo, hi = self.rot_range_deg
        if not (-360.0 <= lo <= hi <= 360.0):
            raise ValidationError("rot_range_deg must be (lo, hi) with -360 <= lo <= hi <= 360",
                                  field="rot_range_deg", value=list(self.rot_range_deg))
        if max(abs(t) for t in self.tilt_deg) >= 90.0:
            raise ValidationError("tilt_deg must stay below 90 deg", field="tilt_deg", value=list(self.tilt_deg))
        checks = (("rot_step_deg", 0.0, 360.0, False), ("speed_r", 0.0, 10.0, False),
                  ("max_tcp_speed_mm_s", 0.0, 10_000.0, False), ("travel_lift_mm", 0.0, 100.0, True),
                  ("lift_min_travel_mm", 0.0, 1e6, True),
                  ("zone_mm", 0.0, 50.0, True), ("fw_retract_mm", 0.0, 50.0, True),
                  ("chord_tol_mm", 0.0, 10.0, False), ("max_turn_deg", 0.1, 90.0, False),
                  ("linear_tol_mm", 0.0, 10.0, False))
        for name, lo_v, hi_v, zero_ok in checks:
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and np.isfinite(v) and (lo_v <= v if zero_ok else lo_v < v) and v <= hi_v
            if not ok:
                raise ValidationError(f"{name} must be in {'[' if zero_ok else '('}{lo_v:g}, {hi_v:g}], got {v!r}",
                                      field=name, value=v)
            setattr(self, name, float(v))
        d = self.filament_diameter_mm
        lo_d, hi_d = FILAMENT_DIAMETER_RANGE_MM
        if d is not None:
            if not (isinstance(d, (int, float)) and not isinstance(d, bool) and lo_d <= d <= hi_d):
                raise ValidationError(f"filament_diameter_mm must be in [{lo_d:g}, {hi_d:g}] or None, got {d!r}",
                                      field="filament_diameter_mm", value=d)
            self.filament_diameter_mm = float(d)
        for name in ("approach_height_mm", "approach_speed_mm_s"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValidationError(f"{name} must be a positive number or None", field=name, value=v)
        if self.wobj_T is not None:
            w = np.asarray(self.wobj_T, dtype=float)
            if w.shape != (4, 4) or not np.isfinite(w).all() or not np.allclose(w[:3, :3] @ w[:3, :3].T, np.eye(3),
                                                                                 atol=1e-6):
                raise ValidationError("wobj_T must be a rigid 4x4 transform", field="wobj_T")
            self.wobj_T = w
        if not isinstance(self.allow_off_plate, bool):
            raise ValidationError("allow_off_plate must be true or false", field="allow_off_plate",
                                  value=repr(self.allow_off_plate))
        if not (isinstance(self.ik_block_rows, int) and self.ik_block_rows >= 1000):
            raise ValidationError("ik_block_rows must be an int >= 1000", field="ik_block_rows")

    @property
    def filament_area_mm2(self) -> float:
        """Filament cross-section (mm^2); the assumed diameter when none is set (the planner sets it)."""
        d = ASSUMED_FILAMENT_DIAMETER_MM if self.filament_diameter_mm is None else self.filament_diameter_mm
        return float(np.pi * d ** 2 / 4.0)

    def nozzle_axis(self) -> np.ndarray:
        """(3,) nozzle axis (TCP z) in the plate frame: -z tilted about x then y."""
        ax, ay = np.radians(self.tilt_deg)
        rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
        ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
        return ry @ rx @ np.array([0.0, 0.0, -1.0])

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if self.wobj_T is not None:
            d["wobj_T"] = self.wobj_T.tolist()
        return d
