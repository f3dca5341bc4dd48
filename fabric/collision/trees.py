"""The broad phase of a sweep: what has been laid so far, in coal's dynamic AABB trees, as the path goes on.

Three levels, each containing the next, so each gives a distance lower bound
of the one below:

* the part's bounding box so far and the fixed bodies' boxes, as arrays: the
  vectorised first pass of :mod:`fabric.collision.advance` (spheres around
  each body against them);
* ``coarse``: the part's boxes with the table and the plate; ``coarse_tip``
  is the same without the boxes of the tip's exempt layers. A flat layer
  (planar printing) is one box around all of its beads, whose top is the
  beads' top. A curved layer's box is as tall as the layer (a dome's layer
  spans its height) and would touch the tool wherever it goes, so a layer
  whose box stands more than ``RUN_SLACK_R`` bead heights above its tallest
  bead is cut into runs of consecutive beads, each box at most that much
  taller than its tallest bead and ``RUN_SPAN_MM`` across: along the layer,
  the box's top stays near the beads' top. The walks use these trees; the
  swept hulls of the tool are measured against one box per layer, as arrays
  (:meth:`layer_boxes`);
* ``fine``: the beads, by chains (:meth:`BeadSolids.chains`: boxes around
  runs of consecutive beads), and ``fine_tip``: the same without the tip's
  exempt layers, each built the first time a query needs it (a body within a
  few mm of a box: beside a wall, in a gap, a tilted nozzle over a curved
  layer). They follow the path: a query for a row brings in the chains of the
  beads laid before it (and no more, but the rest of a chain), so a tilted
  nozzle over the layer it lays is not held against the beads it has yet to
  lay. Layers only go up along a print, so a layer's chains join ``fine_tip``
  once, when the tip leaves it for the layer above the next; a live move's
  exempt labels may also leave it.

A box goes in with its first bead, and holds the beads its run will get
later in the stretch too: a superset, which can only make a distance smaller
(:mod:`fabric.collision.advance` asks again with exactly the beads laid
before a row when that matters).
"""
from __future__ import annotations

import coal
import numpy as np

from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import MM
from fabric.collision.path import NO_LAYER

__all__ = ["PartTrees", "RUN_SLACK_R", "RUN_SPAN_MM", "FINE_TREE_MAX_CHAINS"]

RUN_SLACK_R = 0.5            # a box may stand this many bead heights taller than its tallest bead
RUN_SPAN_MM = 10.0           # and a run's box spans at most this much along x and along y
FINE_TREE_MAX_CHAINS = 200_000   # above this many chains, exact queries (by bounding boxes) stand in for the trees


class PartTrees:
    """What the sweep has laid so far (beads ``0 .. count - 1``), at three levels (see the module doc)."""

    def __init__(self, beads: BeadSolids, env: dict[str, coal.CollisionObject]) -> None:
        self.beads = beads
        self.env = env
        self.env_lo = np.array([np.asarray(o.getAABB().min_) / MM for o in env.values()])
        self.env_hi = np.array([np.asarray(o.getAABB().max_) / MM for o in env.values()])
        self.fixed = _tree(env.values())
        self.coarse = _tree(env.values())
        self.coarse_tip = _tree(env.values())
        self.fine: coal.BroadPhaseCollisionManager | None = None
        self.fine_tip: coal.BroadPhaseCollisionManager | None = None
        self.count = 0
        self.part_lo = np.full(3, np.inf)
        self.part_hi = np.full(3, -np.inf)
        # the beads of each layer label, in print order
        self._by_label = np.argsort(beads.layer, kind="stable")
        self._labels, edges = np.unique(beads.layer[self._by_label], return_index=True)
        self._label_edges = np.append(edges, len(beads))
        # one box per layer (in order of each layer's first bead), and the part's boxes: the layer's, or its runs
        first = self._by_label[self._label_edges[:-1]]
        order = np.argsort(first, kind="stable")
        self._layers, self._layer_first = self._labels[order], first[order]
        self._layer_lo = np.zeros((len(order), 3))
        self._layer_hi = np.zeros((len(order), 3))
        box_layer, box_first, box_lo, box_hi = [], [], [], []
        self.split = False                                 # some layer is cut into runs
        for p, i in enumerate(order.tolist()):
            idx = self._by_label[self._label_edges[i]:self._label_edges[i + 1]]
            self._layer_lo[p], self._layer_hi[p] = beads.lo[idx].min(axis=0), beads.hi[idx].max(axis=0)
            starts = _run_starts(beads.lo[idx], beads.hi[idx], 2.0 * beads.half[idx, 2])
            box_layer.append(np.full(len(starts), p))
            box_first.append(idx[starts])
            box_lo.append(np.minimum.reduceat(beads.lo[idx], starts, axis=0))
            box_hi.append(np.maximum.reduceat(beads.hi[idx], starts, axis=0))
            self.split |= len(starts) > 1
        box_order = np.argsort(_cat(box_first, (0,)), kind="stable")      # boxes in order of their first bead
        self._box_layer = _cat(box_layer, (0,)).astype(np.int64)[box_order]
        self._box_first = _cat(box_first, (0,)).astype(np.int64)[box_order]
        self._box_lo = _cat(box_lo, (0, 3)).reshape(-1, 3)[box_order]
        self._box_hi = _cat(box_hi, (0, 3)).reshape(-1, 3)[box_order]
        self._boxes: list[coal.CollisionObject | None] = [None] * len(self._box_first)
        self._layer_boxes = [np.flatnonzero(self._box_layer == p) for p in range(len(self._layers))]
        self._pos = {int(layer): p for p, layer in enumerate(self._layers)}
        self._in = 0                                       # boxes in ``coarse`` (the first ones in box order)
        self._layers_in = 0                                # layers with a bead laid
        self._tip_in = np.zeros(len(self._box_first), bool)   # boxes in ``coarse_tip``
        self._exempt_boxes = np.zeros(0, np.int64)
        self._exempt: tuple[int, ...] = ()                 # the tip's exempt layer labels
        # the fine trees: chains of beads (made when first needed), and what they hold
        self._chains: BeadSolids | None = None
        self._chain_first = np.zeros(0, np.int64)
        self._fine_count = 0                               # chains in ``fine`` (the first ones)
        self._tip_fine_count = 0                           # chains looked at for ``fine_tip``
        self._tip_fine_exempt: tuple[int, ...] = ()
        self._tip_fine_in = np.zeros(0, bool)              # per chain: in ``fine_tip``

    def advance(self, count: int, tip_layer: int) -> None:
        """Hold beads ``0 .. count - 1``; ``coarse_tip`` and ``fine_tip`` leave out the layers the tip may touch
        while it lays ``tip_layer`` (:meth:`BeadSolids.exempt_layers`; none for ``NO_LAYER``)."""
        beads = self.beads
        if count > self.count:
            self.part_lo = np.minimum(self.part_lo, beads.lo[self.count:count].min(axis=0))
            self.part_hi = np.maximum(self.part_hi, beads.hi[self.count:count].max(axis=0))
            self.count = count
        n_in = int(np.searchsorted(self._box_first, count, "left"))
        for i in range(self._in, n_in):
            self.coarse.registerObject(self._box(i))
        self._layers_in = int(np.searchsorted(self._layer_first, count, "left"))
        self._exempt = self.beads.exempt_layers(tip_layer) if tip_layer != NO_LAYER else ()
        exempt = [self._layer_boxes[self._pos[x]] for x in self._exempt if x in self._pos]
        ex = np.concatenate(exempt) if exempt else np.zeros(0, np.int64)
        ex = ex[ex < n_in]
        for i in ex[self._tip_in[ex]].tolist():            # boxes of layers that became exempt leave coarse_tip
            self.coarse_tip.unregisterObject(self._box(i))
        self._tip_in[ex] = False
        back = np.concatenate([self._exempt_boxes, np.arange(self._in, n_in)])   # and the others come (back) in
        back = back[~np.isin(back, ex)]
        for i in back[~self._tip_in[back]].tolist():
            self.coarse_tip.registerObject(self._box(i))
        self._tip_in[back] = True
        self._in, self._exempt_boxes = n_in, ex

    # --- the beads' trees ----------------------------------------------------------------------------

    def fine_tree(self, upto: int) -> coal.BroadPhaseCollisionManager:
        """Beads ``0 .. upto - 1`` at least, by chains, with the table and the plate (built on first use)."""
        if self.fine is None:
            self.fine = _tree(self.env.values())
        n = self._chains_upto(upto)
        chains = self._chains
        assert chains is not None
        if n > self._fine_count:
            for obj in chains.objects(np.arange(self._fine_count, n)):
                self.fine.registerObject(obj)
            self._fine_count = n
        return self.fine

    def fine_tip_tree(self, upto: int) -> coal.BroadPhaseCollisionManager:
        """Beads ``0 .. upto - 1`` at least, but not those of the tip's exempt layers, by chains, with the
        table and the plate (built on first use): what the tip may not touch. The chains of layers that
        stopped being exempt come in, those of layers that became exempt leave, then the new chains."""
        if self.fine_tip is None:
            self.fine_tip = _tree(self.env.values())
        tree, n = self.fine_tip, self._chains_upto(upto)
        if self._tip_fine_exempt == self._exempt and n <= self._tip_fine_count:
            return tree
        chains, has = self._chains, self._tip_fine_in
        assert chains is not None
        old, new, done = set(self._tip_fine_exempt), set(self._exempt), self._tip_fine_count
        for label in sorted(old - new):
            idx = self._label_chains(label)
            idx = idx[(idx < done) & ~has[idx]]
            for obj in chains.objects(idx):
                tree.registerObject(obj)
            has[idx] = True
        for label in sorted(new - old):
            idx = self._label_chains(label)
            idx = idx[has[idx]]
            for obj in chains.objects(idx):
                tree.unregisterObject(obj)
            has[idx] = False
        if n > done:
            idx = np.arange(done, n)
            idx = idx[~np.isin(chains.layer[idx], list(new))]
            for obj in chains.objects(idx):
                tree.registerObject(obj)
            has[idx] = True
        self._tip_fine_exempt, self._tip_fine_count = self._exempt, max(done, n)
        return tree

    def chain_balls(self, upto: int, tip: bool) -> tuple[np.ndarray, np.ndarray]:
        """Balls (centres (m, 3), radii (m,), mm) around the chains holding beads ``0 .. upto - 1`` (for the
        tip, not those of its exempt layers): what :meth:`fine_tree` holds, coarser."""
        n = self._chains_upto(upto)
        chains = self._chains
        assert chains is not None
        keep = np.arange(n)
        if tip and self._exempt:
            keep = keep[~np.isin(chains.layer[:n], self._exempt)]
        return chains.centre[keep], self._chain_radius[keep]

    def fine_too_big(self) -> bool:
        """Whether the beads' trees would hold more than :data:`FINE_TREE_MAX_CHAINS` chains for the beads laid so
        far: a tree that big takes longer to build than exact queries take (the objects counted are the
        chains the tree holds, several beads each, not the beads)."""
        return self._chains_upto(self.count) > FINE_TREE_MAX_CHAINS

    def _chains_upto(self, upto: int) -> int:
        """How many chains hold beads ``0 .. upto - 1`` (the chains are made on first use:
        :meth:`BeadSolids.chains`)."""
        if self._chains is None:
            self._chains, self._chain_first = self.beads.chains()
            self._by_chain_label = np.argsort(self._chains.layer, kind="stable")
            self._chain_labels, edges = np.unique(self._chains.layer[self._by_chain_label], return_index=True)
            self._chain_label_edges = np.append(edges, len(self._chains))
            self._tip_fine_in = np.zeros(len(self._chains), bool)
            self._chain_radius = np.linalg.norm(self._chains.half, axis=1)
        return int(np.searchsorted(self._chain_first, upto, "left"))

    def _label_chains(self, label: int) -> np.ndarray:
        """Indices of the chains of beads labelled ``label``, in print order."""
        i = int(np.searchsorted(self._chain_labels, label))
        if i >= len(self._chain_labels) or self._chain_labels[i] != label:
            return np.zeros(0, np.int64)
        return self._by_chain_label[self._chain_label_edges[i]:self._chain_label_edges[i + 1]]

    # --- the boxes as arrays ----------------------------------------------------------------------

    def layer_boxes(self, tip: bool) -> tuple[np.ndarray, np.ndarray]:
        """The fixed bodies' bounding boxes and one box per layer with a bead laid (without the tip's exempt
        layers when ``tip``), as arrays (lo, hi), mm."""
        keep = np.arange(self._layers_in)
        if tip and self._exempt:
            keep = keep[~np.isin(self._layers[keep], self._exempt)]
        return np.vstack([self.env_lo, self._layer_lo[keep]]), np.vstack([self.env_hi, self._layer_hi[keep]])

    def obstacle_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes (lo, hi), mm, of the fixed bodies and of the part so far."""
        if self.count == 0:
            return self.env_lo, self.env_hi
        return np.vstack([self.env_lo, self.part_lo]), np.vstack([self.env_hi, self.part_hi])

    def _box(self, i: int) -> coal.CollisionObject:
        obj = self._boxes[i]
        if obj is None:
            obj = self._boxes[i] = _box(self._box_lo[i], self._box_hi[i])
        return obj


def _run_starts(lo: np.ndarray, hi: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Where the runs of one layer's beads begin (positions; boxes ``lo``/``hi`` and heights of its beads, in
    print order): one run for a flat layer, whose box is no more than ``RUN_SLACK_R`` bead heights taller than
    its tallest bead; else runs of consecutive beads, each as flat as that and ``RUN_SPAN_MM`` across."""
    tall = hi[:, 2] - lo[:, 2]
    if float(hi[:, 2].max() - lo[:, 2].min()) <= float(tall.max() + RUN_SLACK_R * height.max()):
        return np.zeros(1, np.int64)
    room = (tall + RUN_SLACK_R * height).tolist()              # how tall a run holding each bead may be
    los, his = lo.tolist(), hi.tolist()
    starts = [0]
    box_lo, box_hi, box_room = los[0], his[0], room[0]
    for i in range(1, len(los)):
        grown_lo = [min(a, b) for a, b in zip(box_lo, los[i], strict=True)]
        grown_hi = [max(a, b) for a, b in zip(box_hi, his[i], strict=True)]
        grown_room = max(box_room, room[i])
        if (grown_hi[2] - grown_lo[2] <= grown_room and grown_hi[0] - grown_lo[0] <= RUN_SPAN_MM
                and grown_hi[1] - grown_lo[1] <= RUN_SPAN_MM):
            box_lo, box_hi, box_room = grown_lo, grown_hi, grown_room
        else:                                                   # the bead starts a run of its own
            starts.append(i)
            box_lo, box_hi, box_room = los[i], his[i], room[i]
    return np.asarray(starts, dtype=np.int64)


def _cat(parts: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(shape)


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
