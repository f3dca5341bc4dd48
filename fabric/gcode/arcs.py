"""G2/G3 arcs (XY plane) expanded into chords within a chord tolerance, vectorised over arcs.

Geometry. The centre is ``start + (I, J)`` (I/J are always relative to the
start point), or, in the R form, on the perpendicular bisector of the chord at
distance ``h = sqrt(R^2 - (c/2)^2)`` (``c`` the chord length): to the left of
the chord for a counter-clockwise (G3) minor arc, to the right for a clockwise
(G2) one, and on the other side when R is negative (the major arc). G2 sweeps
clockwise from the start angle to the end angle, G3 counter-clockwise; start ==
end in the I/J form is a full circle. Z and E change linearly along the arc
(a helix), and if the end radius differs slightly from the start radius (I/J
rounded by the slicer) the radius is interpolated too, so the last chord ends
exactly on the programmed point.

A chord of angle ``t`` on radius ``r`` deviates ``r (1 - cos(t/2))`` from the
arc (the sagitta), so the largest chord angle within tolerance ``tol`` is
``2 acos(1 - tol/r)`` (capped at 90 degrees).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["expand_arcs", "ArcChords", "MAX_ARC_SEGMENTS", "ARC_OK", "ARC_NO_CENTRE", "ARC_ZERO_RADIUS",
           "ARC_RADIUS_MISMATCH", "ARC_R_TOO_SMALL", "ARC_R_FULL_CIRCLE", "ARC_TOO_MANY", "ARC_REASONS"]

MAX_ARC_SEGMENTS = 10_000
ARC_OK, ARC_NO_CENTRE, ARC_ZERO_RADIUS, ARC_RADIUS_MISMATCH = 0, 1, 2, 3
ARC_R_TOO_SMALL, ARC_R_FULL_CIRCLE, ARC_TOO_MANY = 4, 5, 6
ARC_REASONS = {
    ARC_NO_CENTRE: "arc with no centre (needs I/J or R)",
    ARC_ZERO_RADIUS: "arc with zero radius",
    ARC_RADIUS_MISMATCH: "arc end point is not on the arc (start and end radius differ)",
    ARC_R_TOO_SMALL: "arc radius R smaller than half the chord",
    ARC_R_FULL_CIRCLE: "R-form arc with the same start and end point",
    ARC_TOO_MANY: f"arc needs more than {MAX_ARC_SEGMENTS} chords for the chord tolerance",
}
_TWO_PI = 2.0 * np.pi


def _centres(s: np.ndarray, e: np.ndarray, cw: np.ndarray, ij: np.ndarray,
             r: np.ndarray, status: np.ndarray) -> np.ndarray:
    """Arc centres (A, 2); flags bad R-form arcs in ``status``."""
    centre = s + np.nan_to_num(ij)
    rform = np.isnan(ij).all(axis=1) & ~np.isnan(r)
    status[np.isnan(ij).all(axis=1) & np.isnan(r)] = ARC_NO_CENTRE
    if rform.any():
        d = e[rform] - s[rform]
        chord = np.hypot(d[:, 0], d[:, 1])
        rr = r[rform]
        h2 = rr * rr - 0.25 * chord * chord
        sub = status[rform]
        sub[chord < 1e-9] = ARC_R_FULL_CIRCLE
        sub[(h2 < -1e-6 * np.maximum(rr * rr, 1.0)) & (sub == ARC_OK)] = ARC_R_TOO_SMALL
        status[rform] = sub
        h = np.sqrt(np.maximum(h2, 0.0))
        safe = np.maximum(chord, 1e-300)
        left = np.stack([-d[:, 1], d[:, 0]], axis=1) / safe[:, None]
        side = np.where((~cw[rform]) ^ (rr < 0), 1.0, -1.0)
        centre[rform] = s[rform] + 0.5 * d + (side * h)[:, None] * left
    return centre


class ArcChords(NamedTuple):
    """Arcs expanded into chords: the points of arc ``k`` are its ``n_points[k]`` chord end points in order."""

    n_points: np.ndarray       # (A,) int64, 0 for a bad arc
    points: np.ndarray         # (P, 3) mm
    e_mm: np.ndarray           # (P,) filament of each chord
    status: np.ndarray         # (A,) uint8 ARC_* (ARC_OK or why the arc is bad)


def expand_arcs(start: np.ndarray, end: np.ndarray, cw: np.ndarray, ij: np.ndarray,
                r: np.ndarray, e_mm: np.ndarray, chord_tol_mm: float) -> ArcChords:
    """Expand ``A`` arcs into chords.

    ``start``/``end`` (A, 3) mm, ``cw`` (A,) True for G2, ``ij`` (A, 2) NaN when
    absent, ``r`` (A,) NaN when absent, ``e_mm`` (A,) filament over the whole
    arc. Returns ``(count (A,), points (P, 3), e_mm (P,), status (A,))`` where the
    points of arc ``k`` are the ``count[k]`` chord end points in order; arcs with
    a non-zero ``status`` (see ``ARC_REASONS``) have count 0.
    """
    a = len(start)
    status = np.zeros(a, np.uint8)
    s, e = start[:, :2], end[:, :2]
    c = _centres(s, e, cw, ij, r, status)
    v0, v1 = s - c, e - c
    r0, r1 = np.hypot(v0[:, 0], v0[:, 1]), np.hypot(v1[:, 0], v1[:, 1])
    status[(r0 < 1e-9) & (status == ARC_OK)] = ARC_ZERO_RADIUS
    mismatch = np.abs(r0 - r1) > np.maximum(0.05, 1e-3 * r0)
    status[mismatch & (status == ARC_OK)] = ARC_RADIUS_MISMATCH
    a0 = np.arctan2(v0[:, 1], v0[:, 0])
    a1 = np.arctan2(v1[:, 1], v1[:, 0])
    ccw_sweep = np.mod(a1 - a0, _TWO_PI)
    cw_sweep = np.mod(a0 - a1, _TWO_PI)
    full = np.hypot(e[:, 0] - s[:, 0], e[:, 1] - s[:, 1]) < 1e-9
    ccw_sweep = np.where(full, _TWO_PI, ccw_sweep)
    cw_sweep = np.where(full, _TWO_PI, cw_sweep)
    sweep = np.where(cw, -cw_sweep, ccw_sweep)
    rmax = np.maximum(r0, r1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosv = np.clip(1.0 - chord_tol_mm / np.maximum(rmax, 1e-300), -1.0, 1.0)
    step = np.minimum(2.0 * np.arccos(cosv), 0.5 * np.pi)
    need = np.ceil(np.abs(sweep) / np.maximum(step, 1e-300))
    status[~(need <= MAX_ARC_SEGMENTS) & (status == ARC_OK)] = ARC_TOO_MANY
    count = np.where(status == ARC_OK, np.maximum(need, 1.0), 0.0).astype(np.int64)
    total = int(count.sum())
    idx = np.repeat(np.arange(a), count)
    first = np.cumsum(count) - count
    k = np.arange(total) - first[idx] + 1
    t = k / count[idx]
    ang = a0[idx] + sweep[idx] * t
    rad = r0[idx] + (r1[idx] - r0[idx]) * t
    pts = np.empty((total, 3))
    pts[:, 0] = c[idx, 0] + rad * np.cos(ang)
    pts[:, 1] = c[idx, 1] + rad * np.sin(ang)
    pts[:, 2] = start[idx, 2] + (end[idx, 2] - start[idx, 2]) * t
    last = first + count - 1
    ok = count > 0
    pts[last[ok]] = end[ok]                      # land exactly on the programmed point
    pe = (e_mm / np.maximum(count, 1))[idx]
    return ArcChords(count, pts, pe, status)
