"""The broad phase of a sweep: what has been laid so far, in coal's dynamic AABB trees, as the path goes on.

Three levels, each containing the next, so each gives a distance lower bound
of the one below:

* the part's bounding box so far and the fixed bodies' boxes, as arrays: the
  vectorised first pass of :mod:`fabric.collision.advance` (spheres around
  each body against them);
* ``coarse``: one box per layer around all of that layer's beads (a layer is
  flat, so the box's top is the beads' top), with the table and the plate;
  ``coarse_tip`` is the same without the tip's two exempt layers. The swept
  hulls of the tool are measured against these boxes as arrays
  (:meth:`layer_boxes`), the walks in the trees;
* ``fine``: every bead laid so far, one box each, built the first time a
  query needs it (a body within a few mm of a layer box: beside a wall, in a
  gap) and kept up to date from then on.

A layer's box goes in with the layer's first bead, and holds the beads the
layer will get later in the stretch too: a superset, which can only make a
distance smaller (:mod:`fabric.collision.advance` asks again with exactly the
beads laid before a row when that matters).
"""
from __future__ import annotations

import coal
import numpy as np

from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import MM
from fabric.collision.path import NO_LAYER

__all__ = ["PartTrees"]


class PartTrees:
    """What the sweep has laid so far (beads ``0 .. count - 1``), at three levels (see the module doc)."""

    def __init__(self, beads: BeadSolids, env: dict[str, coal.CollisionObject]) -> None:
        self.beads = beads
        self.env = env
        self.env_lo = np.array([np.asarray(o.getAABB().min_) / MM for o in env.values()])
        self.env_hi = np.array([np.asarray(o.getAABB().max_) / MM for o in env.values()])
        self.coarse = _tree(env.values())
        self.coarse_tip = _tree(env.values())
        self.fine: coal.BroadPhaseCollisionManager | None = None
        self.count = 0
        self.part_lo = np.full(3, np.inf)
        self.part_hi = np.full(3, -np.inf)
        # one box per layer, in order of each layer's first bead
        layers, first = np.unique(beads.layer, return_index=True)
        order = np.argsort(first, kind="stable")
        self._layers = layers[order]
        self._layer_first = first[order]
        self._box_lo = np.array([beads.lo[beads.layer == layer].min(axis=0) for layer in self._layers]).reshape(-1, 3)
        self._box_hi = np.array([beads.hi[beads.layer == layer].max(axis=0) for layer in self._layers]).reshape(-1, 3)
        self._boxes = [_box(lo, hi) for lo, hi in zip(self._box_lo, self._box_hi, strict=True)]
        self._pos = {int(layer): i for i, layer in enumerate(self._layers)}
        self._in = 0                                       # layers whose box is in ``coarse``
        self._tip_in: set[int] = set()                     # positions in _layers whose box is in ``coarse_tip``
        self._exempt: set[int] = set()
        self._fine_count = 0

    def advance(self, count: int, tip_layer: int) -> None:
        """Hold beads ``0 .. count - 1``; ``coarse_tip`` leaves out layers ``tip_layer`` and ``tip_layer - 1``
        (none for ``NO_LAYER``)."""
        beads = self.beads
        if count > self.count:
            self.part_lo = np.minimum(self.part_lo, beads.lo[self.count:count].min(axis=0))
            self.part_hi = np.maximum(self.part_hi, beads.hi[self.count:count].max(axis=0))
            self.count = count
        new = []
        while self._in < len(self._layers) and self._layer_first[self._in] < count:
            self.coarse.registerObject(self._boxes[self._in])
            new.append(self._in)
            self._in += 1
        exempt = {self._pos[x] for x in (tip_layer, tip_layer - 1) if tip_layer != NO_LAYER and x in self._pos}
        exempt = {i for i in exempt if i < self._in}
        for i in exempt & self._tip_in:                    # layers that became exempt leave coarse_tip
            self.coarse_tip.unregisterObject(self._boxes[i])
            self._tip_in.discard(i)
        for i in sorted((self._exempt - exempt) | set(new)):   # and the ones no longer exempt come back
            if i not in exempt and i not in self._tip_in:
                self.coarse_tip.registerObject(self._boxes[i])
                self._tip_in.add(i)
        self._exempt = exempt
        if self.fine is not None:
            self._fill_fine()

    def fine_tree(self) -> coal.BroadPhaseCollisionManager:
        """Every bead laid so far, one box each, with the table and the plate (built on first use)."""
        if self.fine is None:
            self.fine = _tree(self.env.values())
        self._fill_fine()
        return self.fine

    def _fill_fine(self) -> None:
        assert self.fine is not None
        if self.count > self._fine_count:
            for obj in self.beads.objects(np.arange(self._fine_count, self.count)):
                self.fine.registerObject(obj)
            self._fine_count = self.count

    def layer_boxes(self, tip: bool) -> tuple[np.ndarray, np.ndarray]:
        """The boxes of ``coarse`` (``coarse_tip`` when ``tip``) as arrays (lo, hi), mm: the fixed bodies'
        bounding boxes and the layer boxes."""
        idx = sorted(self._tip_in) if tip else list(range(self._in))
        return np.vstack([self.env_lo, self._box_lo[idx]]), np.vstack([self.env_hi, self._box_hi[idx]])

    def obstacle_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes (lo, hi), mm, of the fixed bodies and of the part so far."""
        if self.count == 0:
            return self.env_lo, self.env_hi
        return np.vstack([self.env_lo, self.part_lo]), np.vstack([self.env_hi, self.part_hi])


def _tree(objects) -> coal.BroadPhaseCollisionManager:
    tree = coal.DynamicAABBTreeCollisionManager()
    for obj in objects:
        tree.registerObject(obj)
    tree.setup()
    return tree


def _box(lo: np.ndarray, hi: np.ndarray) -> coal.CollisionObject:
    obj = coal.CollisionObject(coal.Box(*((hi - lo) * MM)), np.eye(3), (lo + hi) / 2.0 * MM)
    obj.computeAABB()
    return obj
