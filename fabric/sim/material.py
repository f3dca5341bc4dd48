"""The material on the plate when a run begins, and where a bead of the run would be laid into it.

A print that goes on with a part on the plate (a restart at a layer, a
recovery) must lay its beads beside and on top of that part, never through it.
The collision sweep cannot see every such case: printing layer 2 of a finished
part again, the nozzle's tip runs exactly over the top face of the beads it
would double, touching nothing. This test looks at the beads themselves: a
new bead goes *into* material when its centreline runs within ``OVERLAP_R``
of the smaller of its width and height from an existing bead's centreline for
at least ``ALONG_WIDTHS`` bead widths. Beads a layer above (one height apart), beside one
another in a layer (a width apart, less the slicer's overlap), meeting end to
end or crossing at an angle stay out of it: that is the normal squash of a
print, not a print into its own part.

Both the collision service (certifying the rest of a program before it runs,
``fabric.services.collision``) and the twin (its last guard while it prints,
``fabric.sim.runner``) ask the same question of the same class.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fabric.motion.program import MOVEL, Program

__all__ = ["PlateMaterial", "Overlap", "NewBeads", "DepositGuard", "program_beads", "OVERLAP_R", "ALONG_WIDTHS"]

OVERLAP_R = 0.5               # a centreline this share of the smaller of width and height from another's: inside
ALONG_WIDTHS = 2.0            # ... for this many of its widths: into the material (a crossing at 45 deg: 0.85)
_MIN_SPACING_MM = 0.02        # centreline samples no closer than this (a tiny bead is one or two samples)


@dataclass(frozen=True)
class Overlap:
    """The first new bead that goes into the material: its index among the new beads, the existing bead's
    index, and how long a stretch of it runs inside (mm)."""

    new: int
    existing: int
    length_mm: float


@dataclass(frozen=True)
class NewBeads:
    """Beads a run would lay (plate frame, mm), in the order it lays them, with their program rows."""

    start_mm: np.ndarray       # (n, 3)
    end_mm: np.ndarray         # (n, 3)
    width_mm: np.ndarray       # (n,)
    height_mm: np.ndarray      # (n,)
    row: np.ndarray            # (n,)


def program_beads(program: Program, first_row: int = 0, dims: object | None = None) -> NewBeads:
    """The beads ``program`` lays from row ``first_row`` on (an extruding linear move after another row);
    ``dims``: a ``Deposition`` of the program for their widths and heights (default: made here)."""
    from fabric.sim.deposition import Deposition
    rows = np.flatnonzero((program.op == MOVEL) & (program.flow_mm3_mm > 0))
    rows = rows[rows > max(first_row - 1, 0)]
    dep = dims if dims is not None else Deposition(program)
    w, h = dep.dims(program.layer[rows], program.flow_mm3_mm[rows])       # type: ignore[attr-defined]
    return NewBeads(program.xyz_mm[rows - 1], program.xyz_mm[rows], np.asarray(w, float), np.asarray(h, float),
                    rows)


class PlateMaterial:
    """The beads on the plate (plate frame): their centrelines, sampled, in a k-d tree."""

    def __init__(self, start_mm: np.ndarray, end_mm: np.ndarray, width_mm: np.ndarray, height_mm: np.ndarray,
                 layer: np.ndarray | None = None) -> None:
        self.start = np.asarray(start_mm, dtype=float).reshape(-1, 3)
        self.end = np.asarray(end_mm, dtype=float).reshape(-1, 3)
        self.width = np.asarray(width_mm, dtype=float).reshape(-1)
        self.height = np.asarray(height_mm, dtype=float).reshape(-1)
        self.layer = np.full(len(self.start), -1, np.int64) if layer is None else np.asarray(layer, np.int64)
        reach = OVERLAP_R * np.minimum(self.width, self.height)
        self.spacing = max(float(np.min(reach)) if len(reach) else 1.0, _MIN_SPACING_MM)
        points, self._owner = _samples(self.start, self.end, self.spacing)
        self._tree = cKDTree(points) if len(points) else None

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> PlateMaterial:
        """The beads as the twin records them (``Deposition.to_arrays``)."""
        return cls(arrays["start_mm"], arrays["end_mm"], arrays["width_mm"], arrays["height_mm"], arrays["layer"])

    def __len__(self) -> int:
        return len(self.start)

    def first_overlap(self, new: NewBeads) -> Overlap | None:
        """The first of ``new`` (in order) whose centreline runs inside an existing bead for ``ALONG_WIDTHS`` of
        its widths (module docstring), or None."""
        found = self.overlapping(new)
        return found[0] if found else None

    def overlapping(self, new: NewBeads) -> list[Overlap]:
        """Every one of ``new`` that goes into the material (module docstring), in order."""
        if self._tree is None or not len(new.row):
            return []
        reach_new = OVERLAP_R * np.minimum(new.width_mm, new.height_mm)
        step = max(self.spacing, _MIN_SPACING_MM)
        points, owner = _samples(new.start_mm, new.end_mm, step)
        limit = float(np.max(reach_new)) + self.spacing            # no sample of a bead inside is farther
        dist, near = self._tree.query(points, k=1, distance_upper_bound=limit)
        idx = np.flatnonzero(np.isfinite(dist))
        if not len(idx):
            return []
        other = self._owner[near[idx]]
        d = _segment_distance(points[idx], self.start[other], self.end[other])
        inside = d < np.minimum(reach_new[owner[idx]], OVERLAP_R * np.minimum(self.width[other], self.height[other]))
        idx, other = idx[inside], other[inside]
        beads = owner[idx]
        length = np.bincount(beads, minlength=len(new.row)) * step      # the stretch inside, per new bead
        over = np.flatnonzero(length >= ALONG_WIDTHS * new.width_mm)
        if not len(over):
            return []
        # for each, the existing bead most of its inside stretch runs along (not one it grazes at a corner)
        pairs, counts = np.unique(beads * np.int64(len(self.start)) + other, return_counts=True)
        order = np.lexsort((-counts, pairs // len(self.start)))
        firsts = pairs[order][np.unique(pairs[order] // len(self.start), return_index=True)[1]]
        along = {int(p // len(self.start)): int(p % len(self.start)) for p in firsts.tolist()}
        return [Overlap(int(k), along[int(k)], float(length[k])) for k in over.tolist()]


class DepositGuard:
    """The twin's last guard for one run: the program rows whose beads would go into the material on the plate
    when the run began (``rows``, ascending), and for each the existing bead's layer and how far it goes in."""

    def __init__(self, rows: np.ndarray, existing_layer: np.ndarray, length_mm: np.ndarray) -> None:
        self.rows = np.asarray(rows, dtype=np.int64)
        self.existing_layer = np.asarray(existing_layer, dtype=np.int64)
        self.length_mm = np.asarray(length_mm, dtype=float)

    @classmethod
    def of(cls, program: Program, first_row: int, material: PlateMaterial, dims: object | None = None
           ) -> DepositGuard | None:
        """The guard of a run of ``program`` from ``first_row`` on ``material``; None when no row goes in."""
        if not len(material):
            return None
        new = program_beads(program, first_row, dims)
        found = material.overlapping(new)
        if not found:
            return None
        return cls(new.row[[o.new for o in found]], material.layer[[o.existing for o in found]],
                   np.array([o.length_mm for o in found]))

    def first_in(self, lo_row: int, hi_row: int) -> int | None:
        """The first guarded row in ``[lo_row, hi_row)`` (its index in ``rows``), or None."""
        k = int(np.searchsorted(self.rows, lo_row))
        return k if k < len(self.rows) and self.rows[k] < hi_row else None


def _samples(start: np.ndarray, end: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each segment, ``spacing`` apart at most, both ends included; and each point's segment."""
    length = np.linalg.norm(end - start, axis=1)
    count = np.maximum(np.ceil(length / spacing).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(len(start)), count)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]) if len(count) else np.zeros(0, np.int64)
    t = (np.arange(len(owner)) - first[owner]) / (count[owner] - 1)
    points = start[owner] + (end - start)[owner] * t[:, None]
    return points, owner


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from each point to its segment ``a``-``b``."""
    ab = b - a
    den = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + ab * t[:, None]), axis=1)
