"""Which layers each layer rests on: the layers the nozzle's tip may touch while it lays a layer.

The tip lays a bead on top of older beads and rides on them: it may touch
the layer it lays and what that layer rests on, nothing else. With planar
layers, and with curved layers nested one in the next, a layer rests on the
one printed before it (``L - 1``). Not always: where a curved slicer's top
band lies over the core, the band's first layer rests on the ends of every
core layer that meets the band's bottom (on a wing's sloping flank, a dozen
of them), and a layer that runs on past the end of the layer under rests on
the one under that. Here the layers a layer rests on are found from the beads
themselves: under each bead, one bead height's fraction below its bottom face
along its nozzle axis, at its middle and near both ends, the older bead whose
box holds that point is one it rests on.

A point under a bead lies in a box only if that box reaches up to the bead's
bottom there: a bead of a layer far below is never found, and a layer is
counted only where its beads carry the layer above.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["resting_layers", "PROBE_DEPTH_R", "PROBE_ENDS_R", "NEAREST_BEADS", "CONTAIN_SLACK_MM"]

PROBE_DEPTH_R = 0.3          # probes this many of the bead's heights below its bottom face
PROBE_ENDS_R = 0.8           # at its middle and this far towards each end (of its half-length)
NEAREST_BEADS = 8            # beads looked at for each probe (nearest centres)
CONTAIN_SLACK_MM = 0.02      # a probe this close outside a box is held by it
FLAT_TOL = 1e-6              # beads' nozzle axes this close are one axis
FLAT_TOL_MM = 1e-3           # and a layer's beads this close in height are at one height


def resting_layers(centre: np.ndarray, axes: np.ndarray, half: np.ndarray, layer: np.ndarray,
                   ) -> dict[int, tuple[int, ...]]:
    """Per layer label: the labels its beads rest on other than its own and the one before it (module
    docstring), sorted; only labels with any. Beads in print order: centres (n, 3), axes (n, 3, 3; columns
    along, side, up), half extents (n, 3), labels (n,). Beads all laid with one nozzle axis (planar printing)
    rest on the layer before theirs only: nothing to find."""
    n = len(centre)
    up = axes[:, :, 2]
    if n < 2 or _flat_layers(centre, up, layer):
        return {}
    below = centre - up * (half[:, 2] * (1.0 + 2.0 * PROBE_DEPTH_R))[:, None]
    long = np.flatnonzero(half[:, 0] > half[:, 1])             # longer than wide: its ends are probed too
    reach = (axes[long, :, 0] * (PROBE_ENDS_R * half[long, :1]))
    pts = np.concatenate([below, below[long] - reach, below[long] + reach])
    owner = np.concatenate([np.arange(n), long, long])
    k = min(NEAREST_BEADS, n)
    _, idx = cKDTree(centre).query(pts, k=k, workers=-1)
    idx = idx.reshape(len(pts), k)
    own, other = layer[owner][:, None], layer[idx]
    maybe = (idx < owner[:, None]) & (other != own) & (other != own - 1)     # older, not exempt already
    p, j = np.nonzero(maybe)
    i = idx[p, j]
    local = np.einsum("pj,pji->pi", pts[p] - centre[i], axes[i])               # in each box's frame
    inside = np.all(np.abs(local) <= half[i] + CONTAIN_SLACK_MM, axis=1)
    a, b = layer[owner[p[inside]]].astype(np.int64), layer[i[inside]].astype(np.int64)
    span = int(layer.max()) - int(layer.min()) + 1
    keys = np.unique((a - int(layer.min())) * span + (b - int(layer.min())))
    out: dict[int, list[int]] = {}
    for key in keys.tolist():
        out.setdefault(key // span + int(layer.min()), []).append(key % span + int(layer.min()))
    return {x: tuple(sorted(y)) for x, y in out.items()}


def _flat_layers(centre: np.ndarray, up: np.ndarray, layer: np.ndarray) -> bool:
    """Planar printing: every bead laid with one nozzle axis, and each layer's beads at one height along it.
    A layer then lies on the one before it and on nothing older (what is under it, if anything, is a layer
    thickness or more below)."""
    if not bool(np.all(np.abs(up - up[0]) < FLAT_TOL)):
        return False
    height = centre @ up[0]
    _, label = np.unique(layer, return_inverse=True)
    lo = np.full(int(label.max()) + 1, np.inf)
    hi = np.full(int(label.max()) + 1, -np.inf)
    np.minimum.at(lo, label, height)
    np.maximum.at(hi, label, height)
    return bool(np.all(hi - lo < FLAT_TOL_MM))
