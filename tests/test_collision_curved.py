"""The certified sweep of multi-axis programs: curved layers, a tilted nozzle, beads hung along it.

What is certified fast here (tilted tools against chains of beads, a curved layer's boxes cut into runs,
a grid for exact queries) must certify what the plain exact queries certify: every distance it reports
is checked against exact distances sampled along the path, and a hit is where they say the tool touches."""
from __future__ import annotations

import coal
import numpy as np
import pytest

from fabric.collision import trees as trees_module
from fabric.collision.advance import Item
from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import MM, TIP
from fabric.collision.certify import Certifier
from fabric.collision.path import MOVE_KINDS
from fabric.collision.trees import PartTrees
from fabric.robot.cell import CELLS_DIR, Cell

from support.certify_cells import plan_reachable

pytestmark = pytest.mark.timeout(300)

CENTRE = (125.0, 125.0)     # plate frame, mm
LAYER_MM = 0.3


def ridge_gcode(layers: int = 6, curve: float = 0.0577, tilt_deg: float | None = None, upright: int = 1,
                tail: tuple[str, ...] = ()) -> str:
    """``upright`` flat layers (the nozzle vertical), then layers over a ridge along y, ``z = z0 + curve
    (x - xc)^2`` (up to 30 deg at its sides), the nozzle along the surface's normal; or, with ``tilt_deg``, flat
    layers laid with the nozzle tilted that much about y. Each layer is lines along y, 0.5 mm apart and cut
    into 0.5 mm moves, as a curved slicer writes them. Then ``tail``."""
    xc, yc = CENTRE
    e_mm = 0.5 * LAYER_MM / (np.pi * 1.425 ** 2)
    out = ["; multiaxis: nozzle axis in I J K", "G21", "G90", "M83", "M104 S205", "M109 S205"]
    steps = np.arange(-5.0, 5.0 + 1e-9, 0.5)
    for layer in range(layers):
        z0 = LAYER_MM * (layer + 1)
        out += [";LAYER_CHANGE", f";Z:{z0:.3f}", f";HEIGHT:{LAYER_MM:.3f}"]
        for j, dx in enumerate(steps):
            if layer < upright:
                z, axis = z0, np.array([0.0, 0.0, 1.0])
            elif tilt_deg is None:
                z, axis = z0 + curve * dx * dx, np.array([-2.0 * curve * dx, 0.0, 1.0])
            else:
                z, axis = z0, np.array([np.sin(np.radians(tilt_deg)), 0.0, np.cos(np.radians(tilt_deg))])
            axis /= np.linalg.norm(axis)
            ijk = f"I{axis[0]:.4f} J{axis[1]:.4f} K{axis[2]:.4f}"
            ys = steps if j % 2 == 0 else steps[::-1]
            if j == 0:
                out += [f"G0 X{xc + dx:.3f} Y{yc + ys[0]:.3f} Z{z + 2.0:.3f} {ijk} F6000", f"G0 Z{z:.3f} {ijk}",
                        ";TYPE:Solid infill", ";WIDTH:0.500"]
            else:
                out.append(f"G1 X{xc + dx:.3f} Y{yc + ys[0]:.3f} Z{z:.3f} {ijk} E{e_mm * 0.5:.5f} F1200")
            out += [f"G1 X{xc + dx:.3f} Y{yc + y:.3f} Z{z:.3f} {ijk} E{e_mm * 0.5:.5f} F1200" for y in ys[1:]]
        out.append(f"G0 Z{z + 2.0:.3f} {ijk}")
    return "\n".join(out + list(tail)) + "\n"


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140-multiaxis")


def plan(cell: Cell, gcode: str):
    program = plan_reachable(cell, gcode)
    assert program.meta.get("multiaxis")
    return program


def sampled(cert: Certifier, names=(TIP, "tool_nozzle"), fractions=(0.0, 0.5), upto: int | None = None,
            ) -> tuple[float, int, str]:
    """After a sweep: the smallest exact distance of the tool's bodies near the part (the plain exact query,
    with exactly the beads laid before each row and the tip's exemption) at fractions of every segment (before
    ``upto``): (distance, segment, body)."""
    segs, adv, bodies = cert.segs, cert.adv, cert.bodies
    items = [Item(n, bodies.by_name[n], None, bodies.by_name[n].rate_mm, n == TIP) for n in names]
    best = (np.inf, -1, "")
    for k in range(len(segs) if upto is None else upto):
        for f in fractions:
            q = segs.q_at(k, segs.s0[k] + (segs.s1[k] - segs.s0[k]) * f)
            for item in items:
                d = adv.exact(item, k, q, 5.0).d
                if d < best[0]:
                    best = (d, k, item.name)
    return best


@pytest.mark.slow                         # 7 s (not the fast tier)
def test_a_tilted_tip_on_its_own_two_layers_is_not_reported_and_the_clearance_holds(cell, cert):
    program = plan(cell, ridge_gcode())
    res = cert.sweep_program(program)
    assert res.collision_free, res.first_hit
    assert cert.trees.split                                    # the curved layers are cut into runs
    d, _k, _body = sampled(cert)
    # a lower bound of every exact distance, and close to the smallest (the tip over the plate on the first
    # layer, less the sag of the joint interpolation): the plain exact queries' own figure
    assert res.clearance_mm <= d + 1e-6
    # within a factor two of it, as the walk's rule promises (measured: 0.210 against 0.299 with the tapered
    # nozzle; the exact queries' reach fed on the clearance so far and gave 0.021)
    assert res.clearance_mm >= 0.5 * d and res.clearance_body.startswith("tool_")
    assert 0.5 * LAYER_MM < res.clearance_mm < LAYER_MM


@pytest.mark.slow                         # 4 s (not the fast tier)
def test_a_travel_through_a_curved_layer_is_reported_with_its_line(cell, cert):
    xc, yc = CENTRE
    gcode = ridge_gcode(tail=("G0 Z12 I0 J0 K1", f"G0 X{xc - 8:.1f} Y{yc:.1f} I0.3 J0 K0.954",
                              "G0 Z1.1 I0.3 J0 K0.954", f"G0 X{xc + 8:.1f} Y{yc:.1f} I0.3 J0 K0.954"))
    line = len(gcode.splitlines())
    program = plan(cell, gcode)
    res = cert.sweep_program(program)
    hit = res.first_hit
    assert not res.collision_free and hit is not None
    assert int(program.gcode_line[hit.row]) == line and MOVE_KINDS[int(res.segs.kind[hit.segment])] == "travel"
    assert hit.body.startswith("tool_") and hit.other == "part" and hit.bead >= 0
    assert cert.beads.layer[hit.bead] >= 1                     # a bead of a curved layer
    # nothing touches before it (the plain exact queries, sampled), and it touches there
    d, k, body = sampled(cert, upto=hit.segment)
    assert d > cert.tol, (d, k, body)
    item = Item(hit.body, cert.bodies.by_name[hit.body], None, cert.bodies.by_name[hit.body].rate_mm, hit.body == TIP)
    assert cert.adv.exact(item, hit.segment, hit.q_rad, 5.0).d <= 2.0 * cert.tol


@pytest.fixture(scope="module")
def blunt_cell(cell) -> Cell:
    """The multi-axis cell with a nozzle as wide at its tip as its shank (2 mm): no taper."""
    text = (CELLS_DIR / "irb140-multiaxis.toml").read_text()
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(("tip_diameter_mm", "taper_length_mm")))
    blunt = Cell.from_toml_text(text, source="blunt")
    assert blunt.robot.tool.tip_mm == 2.0
    return blunt


@pytest.mark.parametrize("tilt_deg, tapered, free", [(10.0, False, True), (-40.0, False, False),
                                                     (-40.0, True, True)])
def test_a_tip_tilted_past_the_layer_under_it_is_reported(cell, blunt_cell, cert, tilt_deg, tapered, free):
    """Flat layers 0.3 mm apart, the nozzle tilted from the fourth on. A blunt one (2 mm across at its tip): at
    10 deg its rim dips 0.17 mm below the tip, clear of the layer two down; at 40 deg, 0.64 mm: into it, which
    is not exempt. The multi-axis cell's tapered nozzle (0.7 mm across at its tip) at 40 deg dips 0.22 mm, and
    its cone stays over the tip: clear."""
    use = cell if tapered else blunt_cell
    cert = cert if tapered else Certifier(blunt_cell)
    program = plan(use, ridge_gcode(layers=5, tilt_deg=tilt_deg, upright=3))
    res = cert.sweep_program(program)
    assert res.collision_free == free, res.first_hit
    if free:
        assert res.clearance_mm <= sampled(cert, names=(TIP,))[0] + 1e-6
        return
    hit = res.first_hit
    assert hit is not None and hit.body == TIP and hit.other == "part"
    assert int(program.layer[hit.row]) == 3 and cert.beads.layer[hit.bead] <= 1   # a layer it may not touch


@pytest.mark.parametrize("tilt_deg", [10.0, -40.0])
def test_a_print_too_big_for_the_beads_trees_gets_the_same_verdict(cell, cert, monkeypatch, tilt_deg):
    """Above ``FINE_TREE_MAX_CHAINS`` chains the sweep takes exact queries where it would ask the beads' trees:
    the same verdict, the same first hit, and a clearance that is still a lower bound of the exact distances.
    (The limit counts the chains a tree holds; it counted beads, so a curved print of 222k beads, 35k
    chains, went exact near the part everywhere: 635 s instead of 9 s with a slender nozzle.)"""
    program = plan(cell, ridge_gcode(layers=5, tilt_deg=tilt_deg, upright=3))
    with_trees = cert.sweep_program(program)
    asked = cert.trees.fine is not None or cert.trees.fine_tip is not None
    assert asked or with_trees.collision_free                  # the tip dug in where the trees were asked
    monkeypatch.setattr(trees_module, "FINE_TREE_MAX_CHAINS", -1)
    plain = Certifier(cell)
    exact = plain.sweep_program(program)
    assert plain.trees.fine is None and plain.trees.fine_tip is None     # no tree: exact queries only
    assert exact.collision_free == with_trees.collision_free
    if with_trees.first_hit is None:
        assert exact.first_hit is None
        assert min(with_trees.clearance_mm, exact.clearance_mm) <= sampled(cert, names=(TIP,))[0] + 1e-6
    else:
        assert exact.first_hit is not None
        assert (exact.first_hit.row, exact.first_hit.body) == (with_trees.first_hit.row, with_trees.first_hit.body)


def test_the_tips_bead_tree_holds_every_layer_but_its_two(cell, cert):
    """The tip's chains: a layer's beads come in when the tip leaves it for the layer above the next, and go
    out again when it becomes exempt (a live move's labels); every other layer's are always there."""
    beads = BeadSolids.from_program(plan(cell, ridge_gcode(layers=5)))
    trees = PartTrees(beads, cert.bodies.env)
    probe = {layer: beads.object(int(np.flatnonzero(beads.layer == layer)[len(beads.layer[beads.layer == layer]) // 2]))
             for layer in range(5)}

    def touching(layer: int) -> bool:
        obj = probe[layer]
        cb = coal.DistanceCallBackDefault()
        trees.fine_tip_tree(len(beads)).distance(obj, cb)   # the bead itself is in the tree: distance 0
        return cb.data.result.min_distance / MM < 1e-6

    trees.advance(len(beads), 4)
    assert [touching(layer) for layer in range(5)] == [True, True, True, False, False]
    trees.advance(len(beads), 2)                                # back down: layers 2 and 1 leave, 3 and 4 come in
    assert [touching(layer) for layer in range(5)] == [True, False, False, True, True]
    trees.advance(len(beads), 4)
    assert [touching(layer) for layer in range(5)] == [True, True, True, False, False]


def test_chains_hold_their_beads_and_the_grid_finds_what_a_scan_finds(cell):
    beads = BeadSolids.from_program(plan(cell, ridge_gcode()))
    chains, first = beads.chains()
    assert len(chains) < len(beads) / 3                         # consecutive beads boxed together
    of = np.searchsorted(first, np.arange(len(beads)), "right") - 1
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    corners = beads.centre[:, None] + (signs[None] * beads.half[:, None]) @ np.swapaxes(beads.axes, 1, 2)
    local = np.einsum("nck,nkj->ncj", corners - chains.centre[of][:, None], chains.axes[of])
    assert np.all(np.abs(local) <= chains.half[of][:, None] + 1e-9)   # every corner of every bead
    assert np.all(chains.layer[of] == beads.layer) and np.all(chains.row[of] <= beads.row)
    rng = np.random.default_rng(7)
    for _ in range(200):
        c = beads.centre[rng.integers(len(beads))] + rng.normal(size=3)
        lo, hi = c - rng.random(3) * 2.0, c + rng.random(3) * 2.0
        margin, upto = float(rng.random()), int(rng.integers(1, len(beads) + 1))
        layer = int(beads.layer[upto - 1])
        scan = np.all((beads.lo[:upto] <= hi + margin) & (beads.hi[:upto] >= lo - margin), axis=1)
        scan &= (beads.layer[:upto] != layer) & (beads.layer[:upto] != layer - 1)
        assert np.array_equal(beads.near(lo, hi, margin, upto, (layer, layer - 1)), np.flatnonzero(scan))


def test_a_planar_layer_keeps_one_box_and_a_curved_one_is_cut_into_flat_runs(cell, cert):
    beads = BeadSolids.from_program(plan(cell, ridge_gcode(layers=3)))
    trees = PartTrees(beads, cert.bodies.env)
    trees.advance(len(beads), 2)
    lo, hi = trees._box_lo, trees._box_hi
    layer = trees._layers[trees._box_layer]
    assert np.sum(layer == 0) == 1                              # flat: one box
    runs = np.flatnonzero(layer == 2)
    assert len(runs) > 4                                        # 1.4 mm tall: runs
    height = 2.0 * beads.half[beads.layer == 2, 2].max()
    tallest = float((beads.hi[beads.layer == 2, 2] - beads.lo[beads.layer == 2, 2]).max())
    assert np.all(hi[runs, 2] - lo[runs, 2] <= tallest + 0.5 * height + 1e-9)
    for b in runs.tolist():                                     # each run holds its beads
        start = int(trees._box_first[b])
        assert np.all(beads.lo[start] >= lo[b] - 1e-9) and np.all(beads.hi[start] <= hi[b] + 1e-9)


def test_a_nozzle_vertical_at_its_targets_but_tilted_between_them_is_measured_as_tilted():
    """The Panda's joint interpolation tilts its nozzle mid-move though it is vertical at every target of a
    square print: the batch is judged by its pieces' ends, not its segments', so it is not taken as upright
    (the sample print's check once failed there on arrays an upright batch does not keep), and the covers
    off the z axis are measured by the boxes of the tool at their piece ends."""
    from fabric.collision.hull import cover_distances, hull_covers
    from fabric.collision.path import program_segments
    from fabric.motion.testprog import square_program

    panda = Cell.builtin("panda")
    cert = Certifier(panda)
    program = square_program(panda)
    segs = program_segments(program, panda.robot, panda.home_q_rad)
    idx = np.flatnonzero(~segs.joint)
    ends = np.concatenate([panda.robot.fk(segs.q0[idx]), panda.robot.fk(segs.q1[idx])])
    assert np.all(np.abs(ends[:, 2, 2]) > 1.0 - 1e-12), "vertical at every target"
    _tools, covers = hull_covers(cert.bodies, segs, idx, np.zeros(len(idx), np.int64), cert.tools, cert._tilted_tools)
    assert covers is not None
    tip = covers[0]
    assert not tip.vertical.all() and len(tip.box_lo) == len(tip.axis)
    # a box 5 mm under the lowest point of every cover: measured, and no farther than that
    top = float(np.where(tip.vertical, tip.centre[:, 2] - tip.half, tip.box_lo[:, 2]).min()) - 5.0
    d = cover_distances(tip, slice(0, len(tip.axis)), np.array([[-1e4, -1e4, -1e4]]), np.array([[1e4, 1e4, top]]),
                        touch_mm=0.01)
    assert 4.9 < d.min() <= 5.0
