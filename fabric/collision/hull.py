"""Swept hulls of the tool's cylinders (tip, nozzle, tool body) along linear moves.

The tip and the nozzle (and the tool body when the TCP is on the flange's
axis) are cylinders on the TCP's z axis. Along a linear move every point
``p`` of a rigid body stays within the chord error ``e`` of the straight
chord between its two end positions (:meth:`RobotBodies.chord_error_mm`), and
that chord lies in the convex hull of the body at both ends: the swept volume
lies in ``hull(B_a, B_b)`` grown by ``e``. For a run of pieces, the cylinders
at every piece end, turned onto their mean axis (which moves a point by at
most ``rho * t``, ``rho`` the cylinder's half-diagonal and ``t`` the largest
turn), fit in one cylinder on that axis: as wide as the tool plus the spread
of the centres across the axis, as long as the tool plus their spread along
it. That cover, grown by ``e + rho * t``, holds every position the tool takes
along the run.

A linear move is cut into pieces until the chord error is at most
``CHORD_TARGET_MM`` and a piece at most ``PIECE_MAX_MM`` long; consecutive
pieces of a stretch share a cover where it is at most ``GROUP_RADIUS_MM``
wider than the tool (blocks of 16, else 4, else single pieces). The tools
share the grouping: their centres differ only along the common axis, by a
fixed offset (up to the offset times the turn, which the growth takes). Covers are
measured against the obstacles' boxes (the layer boxes of
:mod:`fabric.collision.trees`, the table's, the plate's) in numpy: a cover on
the z axis is a disk times an interval and a box a rectangle times an
interval, so their distance is exactly ``hypot(gap across, gap along)``;
any other cover counts by the bounding box of the tool at every piece end
(each end's cylinder on its own axis: the hull of two ends lies in the box
around both, so the box, grown by the chord error alone, holds the sweep;
a tilted tool's lowest point is exact, whatever its covers' spread). A
planar layer is flat, so over a layer's box the tool's clearance comes out
exact: the certified clearance of a print is what the nozzle and the tip
really keep. Covers closer than the tolerance hand their pieces to the
refinement (:mod:`fabric.collision.narrow`, then the walk's exact
bisection); :func:`piece_covers` makes the covers of any run of pieces, as
cylinders, for it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.collision.bodies import GJK_EPS_MM, Body, RobotBodies
from fabric.collision.path import Segments
from fabric.robot.frames import frame_from_z_axis

__all__ = ["ToolCylinder", "HullCovers", "hull_covers", "piece_covers", "vertical_covers", "cover_distances",
           "CHORD_TARGET_MM", "PIECE_MAX_MM", "GROUP_RADIUS_MM"]

CHORD_TARGET_MM = 0.02       # chord error allowed per piece
X_REF = np.array([1.0, 0.0, 0.0])   # any x will do for a cylinder's frame
GROUP_RADIUS_MM = 6.0        # consecutive pieces share a cover when they fit this much wider than the tool
PIECE_MAX_MM = 10.0          # longest piece


@dataclass(frozen=True)
class ToolCylinder:
    """A cylinder on the TCP's z axis: radius, half-length and centre offset along TCP z (mm)."""

    body: Body
    radius_mm: float
    half_mm: float
    offset_mm: float


@dataclass
class HullCovers:
    """The covers of one tool over a set of pieces, in path order."""

    centre: np.ndarray           # (G, 3)
    axis: np.ndarray             # (G, 3)
    radius: np.ndarray           # (G,)
    half: np.ndarray             # (G,)
    grow: np.ndarray             # (G,)
    vertical: np.ndarray         # (G,) bool: on the z axis (its distance to a box is exact)
    box_lo: np.ndarray           # (G, 3) the bounding box of the tool at every piece end of the cover
    box_hi: np.ndarray           # (G, 3) (both (0, 3) when every cover is on the z axis)
    box_grow: np.ndarray         # (G,) what that box is grown by (the chord error)
    stretch: np.ndarray          # (G,) the stretch each cover belongs to
    edges: np.ndarray            # (G + 1,) pieces edges[g] .. edges[g + 1] - 1 are under cover g
    segment: np.ndarray          # (P,) per piece: its segment
    s0: np.ndarray               # (P,) and its fractions of the segment's row
    s1: np.ndarray


def hull_covers(bodies: RobotBodies, segs: Segments, idx: np.ndarray, stretch: np.ndarray,
                tools: list[ToolCylinder], tilted_tools: list[ToolCylinder] | None = None,
                ) -> tuple[list[ToolCylinder], list[HullCovers] | None]:
    """Covers of every tool along linear segments ``idx`` (in path order) whose stretches are ``stretch``
    (per segment of ``idx``); no cover spans two stretches. The tools are ``tools``, or ``tilted_tools``
    (the same bodies, cut differently) where the TCP axis is not vertical everywhere along them. Returns the
    tools and their covers (None when there is no linear segment)."""
    if len(idx) == 0:
        return tools, None
    robot = bodies.cell.robot
    tcp0 = robot.fk(segs.q0[idx])
    tcp1 = robot.fk(segs.q1[idx])
    dq = segs.dq_abs[idx]
    # the chord error is a body's (the tilted tools cut the same bodies differently)
    error_of = {tool.body.name: bodies.chord_error_mm(dq, tool.body) for tool in tools}
    length = np.linalg.norm(tcp1[:, :3, 3] - tcp0[:, :3, 3], axis=1)
    n = np.maximum(np.ceil(np.sqrt(np.max(list(error_of.values()), axis=0) / CHORD_TARGET_MM)),
                   np.ceil(length / PIECE_MAX_MM))
    n = np.maximum(n, 1).astype(np.int64)
    # the pieces: segment, fractions of it, TCP at both ends
    seg = np.repeat(np.arange(len(idx)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    k = np.arange(len(seg)) - first
    f0, f1 = k / n[seg], (k + 1) / n[seg]
    split = n[seg] > 1
    Ta, Tb = tcp0[seg], tcp1[seg]
    if split.any():
        dq_full = (segs.q1[idx] - segs.q0[idx])[seg[split]]
        base = segs.q0[idx][seg[split]]
        Ta[split] = robot.fk(base + dq_full * f0[split, None])
        Tb[split] = robot.fk(base + dq_full * f1[split, None])
    # upright where the nozzle is vertical at every piece end (between them the chord error holds the tool):
    # a segment's ends are not enough, a 7-axis arm's joint interpolation tilts it by 0.6 deg mid-move
    upright = bool(np.all(np.abs(Ta[:, 2, 2]) > 1.0 - 1e-12) and np.all(np.abs(Tb[:, 2, 2]) > 1.0 - 1e-12))
    if not upright and tilted_tools is not None:
        tools = tilted_tools
    errors = [error_of[tool.body.name] for tool in tools]
    glob = idx[seg]
    span = segs.s1[glob] - segs.s0[glob]
    s0, s1 = segs.s0[glob] + span * f0, segs.s0[glob] + span * f1
    piece_stretch = stretch[seg]
    # one grouping for every tool: they share the axis, so their centres differ only along it
    ref = tools[0]
    edges, centre, axis, spread, along, turn = _groups(Ta, Tb, ref, piece_stretch)
    # judged once, with the end boxes: in an upright batch every cover is vertical (a mean of axes vertical to
    # 1e-12 may round off it by as much again) and needs no end boxes; in any other, the covers off the z axis
    # are measured by theirs
    vertical = np.ones(len(axis), dtype=bool) if upright else np.abs(axis[:, 2]) > 1.0 - 1e-12
    out = []
    for tool, error in zip(tools, errors, strict=True):
        shift = tool.offset_mm - ref.offset_mm     # moving the covers along; turns move it by |shift| * turn
        worst = np.maximum.reduceat(error[seg] / n[seg] ** 2, edges[:-1])     # chord error ~ travel squared
        rho = float(np.hypot(tool.radius_mm, tool.half_mm))
        grow = worst + (rho + abs(shift)) * turn + GJK_EPS_MM
        box_lo, box_hi = (np.zeros((0, 3)),) * 2 if upright else _end_boxes(Ta, Tb, tool, edges)
        out.append(HullCovers(centre + axis * shift, axis, tool.radius_mm + spread, tool.half_mm + along, grow,
                              vertical, box_lo, box_hi, worst + GJK_EPS_MM, piece_stretch[edges[:-1]], edges,
                              glob, s0, s1))
    return tools, out


def _end_boxes(Ta: np.ndarray, Tb: np.ndarray, tool: ToolCylinder, edges: np.ndarray,
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per group of pieces (``edges``): the bounding box of the tool's cylinder at every piece end, each
    with its own axis (a cylinder of radius ``r`` and half-length ``h`` on a unit axis ``a`` reaches
    ``h |a_k| + r sqrt(1 - a_k^2)`` along coordinate ``k``). The hull of the tool at a piece's two ends lies
    in the box around both, so the group's sweep lies in this box grown by the chord error, whatever the
    axes do: no turn to pay, and a tilted tool's lowest point is exact."""
    lo, hi = [], []
    for T in (Ta, Tb):
        a = T[:, :3, 2]
        c = T[:, :3, 3] + a * tool.offset_mm
        ext = tool.half_mm * np.abs(a) + tool.radius_mm * np.sqrt(np.maximum(1.0 - a ** 2, 0.0))
        lo.append(c - ext)
        hi.append(c + ext)
    return (np.minimum.reduceat(np.minimum(*lo), edges[:-1], axis=0),
            np.maximum.reduceat(np.maximum(*hi), edges[:-1], axis=0))


def piece_covers(bodies: RobotBodies, tool: ToolCylinder, Ta: np.ndarray, Tb: np.ndarray, dq: np.ndarray,
                 per: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Covers of pieces of linear moves, the TCP at ``Ta`` and ``Tb`` (N, 4, 4) at their ends and the joints
    travelling ``dq`` (N, nq) along each, ``per`` consecutive pieces to a cover (see the module docstring):
    (centre (G, 3), rotation (G, 3, 3) whose z is the axis, radius (G,), half-length (G,), grow (G,)), mm.
    A cylinder, as the tool is: measured against the beads where boxes are not enough (a tilted nozzle over
    a curved layer)."""
    n = len(Ta)
    pad = np.minimum(np.arange(-(-n // per) * per), n - 1)          # the last cover's room: its last piece again
    ends = np.stack([Ta[:, :3, 3] + Ta[:, :3, 2] * tool.offset_mm, Tb[:, :3, 3] + Tb[:, :3, 2] * tool.offset_mm], 1)
    axes = np.stack([Ta[:, :3, 2], Tb[:, :3, 2]], axis=1)
    centre, axis, spread, along, turn = _cover(ends[pad].reshape(-1, 2 * per, 3), axes[pad].reshape(-1, 2 * per, 3))
    error = bodies.chord_error_mm(np.abs(dq), tool.body)[pad].reshape(-1, per).max(axis=1)
    grow = error + float(np.hypot(tool.radius_mm, tool.half_mm)) * turn + GJK_EPS_MM
    return centre, frame_from_z_axis(axis, X_REF), tool.radius_mm + spread, tool.half_mm + along, grow


def _groups(Ta: np.ndarray, Tb: np.ndarray, tool: ToolCylinder, stretch: np.ndarray,
            ) -> tuple[np.ndarray, ...]:
    """Runs of consecutive pieces of one stretch under one cover where the centres of ``tool`` at their
    ends fit within ``GROUP_RADIUS_MM`` of a line along their mean axis (aligned blocks of 16, else of 4,
    else single pieces): (group edges (G+1,), and per group: the centre between them, the mean axis, their
    spread across it and half their spread along it, the largest turn of an axis from the mean)."""
    ends = np.concatenate([(Ta[:, :3, 3] + Ta[:, :3, 2] * tool.offset_mm)[:, None],
                           (Tb[:, :3, 3] + Tb[:, :3, 2] * tool.offset_mm)[:, None]], axis=1)   # (n, 2, 3)
    axes = np.concatenate([Ta[:, None, :3, 2], Tb[:, None, :3, 2]], axis=1)
    n = len(ends)
    taken = np.zeros(n, bool)
    starts, sizes, parts = [], [], []
    for size in (16, 4, 1):
        cand = np.arange(0, n - size + 1, size)
        sel = cand[:, None] + np.arange(size)[None, :]
        ok = ~taken[sel].any(axis=1) & (stretch[sel[:, 0]] == stretch[sel[:, -1]])
        cand, sel = cand[ok], sel[ok]
        if len(cand) == 0:
            continue
        cover = _cover(ends[sel].reshape(len(cand), 2 * size, 3), axes[sel].reshape(len(cand), 2 * size, 3))
        keep = cover[2] <= GROUP_RADIUS_MM if size > 1 else np.ones(len(cand), bool)
        starts.append(cand[keep])
        sizes.append(np.full(int(keep.sum()), size))
        parts.append(tuple(c[keep] for c in cover))
        taken[sel[keep].ravel()] = True
    begin, length = np.concatenate(starts), np.concatenate(sizes)
    order = np.argsort(begin)
    edges = np.concatenate([begin[order], [n]])
    assert np.array_equal(edges[1:], (begin + length)[order]), "the groups tile the pieces"
    return (edges, *(np.concatenate([c[f] for c in parts])[order] for f in range(5)))


def _cover(ends: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, ...]:
    """For runs of pieces (see the module docstring): ``ends`` (G, P, 3) the tool's centre at each piece end,
    ``axes`` (G, P, 3) its axis there. Returns (centre, mean axis, spread across it, half the spread along
    it, the largest turn of an axis from the mean)."""
    axis = axes.sum(axis=1)
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    turn = np.arccos(np.clip(np.einsum("gpk,gk->gp", axes, axis), -1.0, 1.0)).max(axis=1)
    along = np.einsum("gpk,gk->gp", ends, axis)
    lo, hi = along.min(axis=1), along.max(axis=1)
    across = ends - along[..., None] * axis[:, None, :]
    mid = (across.min(axis=1) + across.max(axis=1)) / 2.0
    mid -= np.sum(mid * axis, axis=1)[:, None] * axis                  # onto the plane across the axis
    spread = np.linalg.norm(across - mid[:, None, :], axis=2).max(axis=1)
    centre = mid + ((lo + hi) / 2.0)[:, None] * axis
    return centre, axis, spread, (hi - lo) / 2.0, turn


def vertical_covers(c: HullCovers, sel: slice) -> np.ndarray:
    """Per cover of ``sel``: is it on the z axis (its distance to a box is exact: see the module docstring)?"""
    return c.vertical[sel]


def cover_distances(c: HullCovers, sel: slice, lo: np.ndarray, hi: np.ndarray, touch_mm: float) -> np.ndarray:
    """Distance lower bound (mm) of covers ``sel`` to the boxes (lo, hi) (B, 3) (see the module docstring):
    exact for every cover within ``touch_mm`` of a box, and for the nearest cover; for the others, a
    distance at least as large as the smallest. Boxes are taken nearest first (by their distance to the
    bounding box of all the covers), and only while they can still be nearer than what is found."""
    centre, axis, radius = c.centre[sel], c.axis[sel], c.radius[sel]
    out = np.full(len(centre), np.inf)
    if len(lo) == 0 or len(centre) == 0:
        return out
    # a cover on the z axis: the disk times the interval; any other: the box of the tool at its piece ends
    vertical = vertical_covers(c, sel)
    ext = c.half[sel, None] * np.abs(axis) + radius[:, None] * np.sqrt(np.maximum(1.0 - axis ** 2, 0.0))
    clo, chi, grow = centre - ext, centre + ext, c.grow[sel]
    if not vertical.all():
        clo = np.where(vertical[:, None], clo, c.box_lo[sel])
        chi = np.where(vertical[:, None], chi, c.box_hi[sel])
        grow = np.where(vertical, grow, c.box_grow[sel])
    all_lo = (clo - grow[:, None]).min(axis=0)
    all_hi = (chi + grow[:, None]).max(axis=0)
    reach = np.linalg.norm(np.maximum(np.maximum(lo - all_hi, all_lo - hi), 0.0), axis=1)
    for b in np.argsort(reach, kind="stable").tolist():
        if reach[b] > max(float(out.min()), touch_mm):
            break
        gap = np.maximum(np.maximum(lo[b] - chi, clo - hi[b]), 0.0)                                 # (G, 3)
        xy = np.maximum(np.maximum(lo[b, :2] - centre[:, :2], centre[:, :2] - hi[b, :2]), 0.0)
        across = np.maximum(np.linalg.norm(xy, axis=1) - radius, 0.0)
        d = np.where(vertical, np.hypot(across, gap[:, 2]), np.linalg.norm(gap, axis=1)) - grow
        np.minimum(out, d, out=out)
    return out
