"""The twin's fixed settings: acceleration, pause/stop moves, probing noise and the filament."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from fabric.motion.timing import DEFAULT_ACCEL_MM_S2, DEFAULT_RETRACT_SPEED_MM_S
from fabric.wire.errors import ValidationError

__all__ = ["TwinConfig"]

_POSITIVE = ("accel_mm_s2", "resume_speed_mm_s", "retract_speed_mm_s", "home_vel_r", "filament_diameter_mm")
_NON_NEGATIVE = ("retract_mm", "lift_mm", "probe_noise_mm")


@dataclass(frozen=True)
class TwinConfig:
    """Settings read once when the twin is built; they never change during a job.

    ``accel_mm_s2``: the TCP acceleration limit of linear moves. ``retract_mm``
    and ``lift_mm``: the filament retraction and the straight lift along the
    plate normal when a print pauses or stops. ``resume_speed_mm_s``: the speed
    of those lifts and of the way back down. ``home_vel_r``: the fraction of
    the joint velocity limits used by go-home (capped at 1). ``probe_noise_mm``
    and ``rng_seed``: the simulated touch probe of calibration.
    """

    accel_mm_s2: float = DEFAULT_ACCEL_MM_S2
    retract_mm: float = 1.0
    lift_mm: float = 5.0
    resume_speed_mm_s: float = 50.0
    retract_speed_mm_s: float = DEFAULT_RETRACT_SPEED_MM_S
    home_vel_r: float = 0.5
    probe_noise_mm: float = 0.01
    rng_seed: int = 0
    filament_diameter_mm: float = 1.75

    def __post_init__(self) -> None:
        for name in _POSITIVE:
            val = getattr(self, name)
            if not math.isfinite(val) or val <= 0:
                raise ValidationError(f"{name} must be > 0, got {val}", field=name)
        for name in _NON_NEGATIVE:
            val = getattr(self, name)
            if not math.isfinite(val) or val < 0:
                raise ValidationError(f"{name} must be >= 0, got {val}", field=name)
        object.__setattr__(self, "home_vel_r", min(float(self.home_vel_r), 1.0))

    @property
    def filament_area_mm2(self) -> float:
        """Cross-section of the filament: extruded volume per mm of filament pushed."""
        return math.pi * self.filament_diameter_mm ** 2 / 4.0

    def filament_area_for_mm2(self, program: Any) -> float:
        """Cross-section of the loaded program's filament (its ``filament_diameter_mm``), else of this config's."""
        d = program.meta.get("filament_diameter_mm") if program is not None else None
        return self.filament_area_mm2 if d is None else math.pi * float(d) ** 2 / 4.0

    def to_dict(self) -> dict[str, Any]:
        """Plain values, for a snapshot."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TwinConfig:
        """The inverse of :meth:`to_dict` (unknown keys are an error)."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValidationError(f"unknown twin settings {sorted(unknown)}", field="config")
        return cls(**data)
