"""The nozzle's reach: axes turned where the nozzle would run into beads laid before.

The axis rules of :mod:`.axis` keep the nozzle near the layer normal. Where two
fronts of layers meet (an arch's crown, even rounded by :mod:`.crease`) the
normal of one side points into the other side's beads a few millimetres up
the nozzle. This rule looks along the nozzle as it will be, a tip of
``nozzle_tip_radius_mm`` for ``nozzle_tip_length_mm`` (which lays the bead and
may touch it), a cone widening to ``nozzle_radius_mm`` over
``nozzle_taper_mm``, covered by the same three steps as the cell's collision
model (:func:`fabric.robot.tool.taper_cover`), then that radius
up to ``nozzle_reach_mm``; and it turns an axis that comes within a bead's
half width (plus ``MARGIN_MM``) of a bead centre of this layer or one laid
before:

1. first towards +z in its own vertical plane (a fraction of its tilt at a
   time, the least that clears);
2. else to the clear direction nearest it of a fixed fan (vertical, and tilts
   all round, each as far as the point's tilt limit allows that way:
   :class:`.axis.TiltLimits`);
3. else it is left as it was and counted: the slice warns of such points, and
   the collision check of the planned program has the last word.

The turned axes are then averaged along the path (as :func:`.axis.smooth_along`
does), never ending less upright than the turn made them. A nozzle turned off
the layer normal by ``d`` dips its tip's rim ``r sin d`` into the layer under
(0.26 mm at most for the multi-axis cell's 0.35 mm tip and 48 degrees), which
the collision check allows the tip and nothing else.

Beads are points here (their centres, half a layer under the tip), near
enough: the collision check measures them as the boxes they are.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fabric.robot.tool import taper_cover
from fabric.slicing.curved.axis import TiltLimits, limit_tilt, smooth_along, unit_rows
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.paths import CurvedPath

__all__ = ["NozzleReach", "nozzle_pieces"]

MARGIN_MM = 0.1                 # kept between the nozzle and a bead's side, over its half width
TAPER_PIECE_MM = 0.25           # the cone's steps are looked along in pieces this long
SHANK_PIECE_MM = 1.0            # and the nozzle's cylinder in pieces this long
SHANK_FINE_MM = 8.0             # ... up to this far from the tip, then
SHANK_COARSE_MM = 2.0           # ... in pieces this long
NEIGHBOURS = 24                 # bead centres measured exactly round each piece
BEAD_STEP_MM = 0.15             # a path's bead centres kept this far apart (the margin covers half of it)
REBUILD_R = 0.25                # the older beads' tree is rebuilt when the newer ones reach this share of it
LOOK_STEP_MM = 0.15             # a path is first looked at with points this far apart (the margin covers half:
                                # 0.5 mm apart, a cone between two points clear met a bead of the arch's crown)
PASSES = 4                      # turn, smooth along the path, look again: at most this many times
TURN_FRACTIONS = (0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.0)
_FAN_TILTS_DEG = (10.0, 20.0, 30.0, 40.0, 45.0)
_FAN_AZIMUTHS_DEG = np.arange(0.0, 360.0, 20.0)


def _fan() -> np.ndarray:
    t, a = np.meshgrid(np.radians(_FAN_TILTS_DEG), np.radians(_FAN_AZIMUTHS_DEG))
    t, a = t.ravel(), a.ravel()
    return np.vstack([[0.0, 0.0, 1.0], np.column_stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])])


FAN = _fan()
FAN_TILT_DEG = np.degrees(np.arccos(np.clip(FAN[:, 2], -1.0, 1.0)))


def _spaced(points_mm: np.ndarray, step_mm: float) -> np.ndarray:
    """Indices of points along a path at least ``step_mm`` apart (by arc length), its first and last always."""
    n = len(points_mm)
    if n <= 2:
        return np.arange(n)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points_mm, axis=0), axis=1))])
    first = np.flatnonzero(np.diff(np.floor(s / step_mm), prepend=-1.0) > 0)
    return np.unique(np.concatenate([first, [n - 1]]))


def nozzle_pieces(opts: CurvedOptions) -> list[tuple[float, float, float]]:
    """The nozzle above its tip as pieces (start, end along the axis from the tip, radius), mm."""
    pieces = []
    s = opts.nozzle_tip_length_mm
    if opts.nozzle_taper_mm > 0.0:
        for r, length, start in taper_cover(opts.nozzle_tip_radius_mm, opts.nozzle_radius_mm, opts.nozzle_taper_mm,
                                            s):
            n = max(1, int(np.ceil(length / TAPER_PIECE_MM)))
            pieces += [(start + length * j / n, start + length * (j + 1) / n, r) for j in range(n)]
        s += opts.nozzle_taper_mm
    while s < opts.nozzle_reach_mm - 1e-9:
        end = min(s + (SHANK_PIECE_MM if s < SHANK_FINE_MM else SHANK_COARSE_MM), opts.nozzle_reach_mm)
        pieces.append((s, end, opts.nozzle_radius_mm))
        s = end
    return pieces


class _FanLooks:
    """Which directions of the fan the tilt limit allows and clear the beads at each point of one path (looked at
    once per point: the fan, the point and the beads laid before do not change between the passes over it)."""

    def __init__(self, n: int) -> None:
        self.known = np.zeros(n, dtype=bool)
        self.clear = np.zeros((n, len(FAN)), dtype=bool)


class NozzleReach:
    """The bead centres laid so far, layer by layer, and the rule of the module docstring."""

    def __init__(self, opts: CurvedOptions) -> None:
        self.opts = opts
        self.pieces = nozzle_pieces(opts) if opts.nozzle_radius_mm > 0.0 else []
        self._laid: list[np.ndarray] = []          # bead centres in the older tree
        self._recent: list[np.ndarray] = []        # ... and laid since it was built
        self._old: cKDTree | None = None
        self.checked = 0          # points looked at
        self.turned = 0           # points whose axis was turned
        self.blocked = 0          # points no axis cleared (left as they were)

    def hold(self, paths: list[CurvedPath], tilts: TiltLimits) -> list[CurvedPath]:
        """Turn the axes of one layer's ``paths`` (each point's tilt within ``tilts``) where they must, then count
        the layer's beads as laid."""
        if not paths or not self.pieces:
            return paths
        # the beads as centres at most BEAD_STEP_MM apart along their paths (a fine path is not a wider bead)
        here = np.vstack([(p.points_mm - p.normals * (p.heights_mm[:, None] / 2.0))[_spaced(p.points_mm, BEAD_STEP_MM)]
                          for p in paths])
        self._recent.append(here)
        trees = self._trees()
        # every path's points LOOK_STEP_MM apart at once first: a path they all clear is left as it is
        # (most are); the others are looked at point by point
        some = [_spaced(p.points_mm, LOOK_STEP_MM) for p in paths]
        points = np.vstack([p.points_mm[i] for p, i in zip(paths, some, strict=True)])
        axes = np.vstack([p.axes[i] for p, i in zip(paths, some, strict=True)])
        reach = np.concatenate([np.full(len(i), 0.5 * p.width_mm + MARGIN_MM) for p, i in
                                zip(paths, some, strict=True)])
        bad = self._blocked(points, axes, trees, reach)
        ends = np.cumsum([len(i) for i in some])
        for path, b, a in zip(paths, ends, np.r_[0, ends[:-1]], strict=True):
            self.checked += len(path.axes)
            if bad[a:b].any():
                self._hold_path(path, tilts, trees)
        return paths

    def _trees(self) -> list[cKDTree]:
        """The beads laid so far as two trees: the older ones, rebuilt only when the newer ones reach a
        quarter of them (a tree of every bead at every layer cost 17 s of a 100k-triangle part's slice), and
        the newer ones."""
        recent = sum(len(r) for r in self._recent)
        if self._old is None or recent > REBUILD_R * self._old.n:
            self._laid.extend(self._recent)
            self._recent = []
            self._old = cKDTree(np.vstack(self._laid))
            return [self._old]
        return [self._old, cKDTree(np.vstack(self._recent))]

    def _hold_path(self, path: CurvedPath, tilts: TiltLimits, trees: list[cKDTree]) -> None:
        reach = 0.5 * path.width_mm + MARGIN_MM
        bad = self._blocked(path.points_mm, path.axes, trees, reach)
        if not bad.any():
            return
        first = int(bad.sum())
        fan = _FanLooks(len(path.axes))          # a point's fan is the same in every pass: looked at once
        for _pass in range(PASSES):
            turned, todo = self._turn(path, bad, tilts, trees, reach, fan)
            smooth = smooth_along(path.points_mm, turned, path.closed, self.opts.path_axis_window_mm)
            keep = bad & ~todo & (smooth[:, 2] < turned[:, 2])       # never less upright than the turn made it
            path.axes = tilts.hold(path.points_mm, unit_rows(np.where(keep[:, None], turned, smooth)))
            bad = self._blocked(path.points_mm, path.axes, trees, reach)
            if not bad.any():
                break
        left = int(bad.sum())
        self.turned += first - left
        self.blocked += left

    def _turn(self, path: CurvedPath, bad: np.ndarray, tilts: TiltLimits, trees: list[cKDTree], reach: float,
              fan: _FanLooks) -> tuple[np.ndarray, np.ndarray]:
        """The axes with the ``bad`` ones turned (steps 1 and 2 of the module docstring), and which are left."""
        turned = path.axes.copy()
        todo = bad.copy()
        tilt_deg = np.degrees(np.arccos(np.clip(turned[:, 2], -1.0, 1.0)))
        for fraction in TURN_FRACTIONS:
            idx = np.flatnonzero(todo)
            if len(idx) == 0:
                break
            cand = limit_tilt(turned[idx], tilt_deg[idx] * (1.0 - fraction))
            ok = ~self._blocked(path.points_mm[idx], cand, trees, reach)
            turned[idx[ok]] = cand[ok]
            todo[idx[ok]] = False
        idx = np.flatnonzero(todo)
        if len(idx):
            # every point not looked at yet against every direction of the fan in one look
            new = idx[~fan.known[idx]]
            if len(new):
                looks, towards = np.repeat(path.points_mm[new], len(FAN), axis=0), np.tile(FAN, (len(new), 1))
                allowed = tilts.deg(looks, towards).reshape(len(new), -1) + 1e-9 >= FAN_TILT_DEG
                fan.clear[new] = allowed & ~self._blocked(looks, towards, trees, reach).reshape(len(new), -1)
                fan.known[new] = True
            clear = fan.clear[idx]
            best = np.full(len(idx), -2.0)
            for j, d in enumerate(FAN):
                ok = clear[:, j]
                score = np.where(ok, path.axes[idx] @ d, -2.0)
                better = score > best
                turned[idx[better]] = d
                best = np.maximum(best, score)
            todo[idx[best > -2.0]] = False
        return turned, todo

    def _blocked(self, points: np.ndarray, axes: np.ndarray, trees: list[cKDTree], reach_mm: float | np.ndarray
                 ) -> np.ndarray:
        """(n,) bool: the nozzle on ``axes`` at ``points`` comes within ``reach_mm`` (one, or one per point) of a
        bead centre. Each piece is looked at only for the rows still clear (a row blocked low on the nozzle,
        as most of a blocked fan's are, costs a piece or two instead of all of them)."""
        bad = np.zeros(len(points), dtype=bool)
        reach = np.broadcast_to(np.asarray(reach_mm, dtype=float), (len(points),))
        widest = float(reach.max(initial=0.0))
        for tree in trees:
            beads = tree.data
            for s0, s1, radius in self.pieces:
                alive = np.flatnonzero(~bad)
                if len(alive) == 0:
                    return bad
                centre = points[alive] + axes[alive] * (0.5 * (s0 + s1))
                bound = float(np.hypot(radius, 0.5 * (s1 - s0))) + widest
                # the nearest bead first (cheap): only where one is within the piece's ball, the nearest few
                nearest, _i = tree.query(centre, k=1, distance_upper_bound=bound)
                close = np.flatnonzero(np.isfinite(nearest))
                if len(close) == 0:
                    continue
                _d, near = tree.query(centre[close], k=NEIGHBOURS, distance_upper_bound=bound)
                found = near < len(beads)
                hit = np.nonzero(found)[0]
                rows = alive[close[hit]]
                rel = beads[near[found]] - points[rows]
                a = axes[rows]
                along = np.einsum("ij,ij->i", rel, a)
                side = np.linalg.norm(rel - along[:, None] * a, axis=1)
                off_end = np.maximum(np.maximum(s0 - along, along - s1), 0.0)
                off_side = np.maximum(side - radius, 0.0)
                bad[rows[off_end * off_end + off_side * off_side < reach[rows] ** 2]] = True
        return bad
