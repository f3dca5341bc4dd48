"""The core's layers lean no further than the nozzle can follow them.

The core field is the distance from the plate inside the part (:mod:`.field`):
its layers climb whatever the part does. Up an arch's legs they lean towards
the crown; round a hook's curl they lean past horizontal and on down (130
degrees on the hook of the tests). The nozzle leans no further than the tilt
limit (45 degrees; less where the cell's arm cannot hold more,
:mod:`.cell_tilt`), and an axis ``d`` off its layer's normal dips its tip's rim
``r sin d`` into the layers under it: past about ``LEAN_SLACK_DEG`` (0.2 mm
for the multi-axis cell's 0.35 mm tip, a thin layer) it digs into the layer
two under, which the collision check does not let it touch (the hook's curl:
the tip in a bead of layer 102 while laying layer 104).

So where an element's layers lean more than the tilt limit there plus
``LEAN_SLACK_DEG``, the field is fitted again (least squares, as the distance
itself is: :func:`.heat.fit_potential`) to the directions turned up to that
lean in their vertical plane. Past that lean the part overhangs its layers,
and the slice reports the overhang it leaves; a part whose layers lean less
everywhere keeps its field as it was.
"""
from __future__ import annotations

import numpy as np

from fabric.slicing.curved.axis import TiltLimits, limit_tilt, unit_rows
from fabric.slicing.curved.heat import FemOperators, fit_potential, tet_gradients
from fabric.slicing.curved.tetmesh import TetMesh

__all__ = ["limit_lean", "LEAN_SLACK_DEG", "leaning_over"]

LEAN_SLACK_DEG = 30.0        # layers may lean this much more than the nozzle: its axis that far off their normal
LEAN_PASSES = 3              # fits at most (the least squares leave some elements over: turned again)
LEAN_TOLERANCE_DEG = 2.0     # an element this little over the lean allowed is left as it is


def leaning_over(mesh: TetMesh, ops: FemOperators, field: np.ndarray, tilts: TiltLimits
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per element: its layers' unit normal, the lean they may have, and by how much (deg) they lean more."""
    x = unit_rows(tet_gradients(ops, mesh.tets, field))
    centres = mesh.nodes[mesh.tets].mean(axis=1)
    allowed = tilts.deg(centres, x) + LEAN_SLACK_DEG
    lean = np.degrees(np.arccos(np.clip(x[:, 2], -1.0, 1.0)))
    return x, allowed, lean - allowed


def limit_lean(mesh: TetMesh, ops: FemOperators, field: np.ndarray, sources: np.ndarray, tilts: TiltLimits
               ) -> np.ndarray:
    """``field`` (0 on ``sources``), fitted again where its layers lean further than the nozzle can follow
    (module docstring); the same array when they lean no further anywhere."""
    x, allowed, over = leaning_over(mesh, ops, field, tilts)
    if not np.any(over > LEAN_TOLERANCE_DEG):
        return field
    target = limit_tilt(x, allowed)
    out = field
    for _pass in range(LEAN_PASSES):
        out = fit_potential(mesh, ops, target, sources, out)
        x, allowed, over = leaning_over(mesh, ops, out, tilts)
        if not np.any(over > LEAN_TOLERANCE_DEG):
            break
        turn = over > 0.0                        # turned up further where the fit left them over
        target[turn] = limit_tilt(x[turn], np.maximum(allowed[turn] - over[turn], 0.0))
    return out
