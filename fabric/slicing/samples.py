"""Parametric test and demo parts (watertight trimesh meshes, mm, lowest point at Z = 0).

Used by ``tools/make_samples.py`` (the bundled sample STLs), the slicing
tests and the slicing benchmark, so all three slice exactly the same shapes.
Solids are built with manifold3d's booleans and twisted extrusion, which
always produce closed, consistently wound meshes.
"""
from __future__ import annotations

import numpy as np
import trimesh
from manifold3d import CrossSection, Manifold

__all__ = ["box", "cylinder", "twisted_vase", "islands_part", "sample_part", "sphere", "gear", "dome", "towers",
           "bridge_part", "thin_walls", "to_stl_bytes"]


def _mesh(solid: Manifold) -> trimesh.Trimesh:
    m = solid.to_mesh()
    out = trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts), process=True)
    out.apply_translation((0.0, 0.0, -out.bounds[0, 2]))
    return out


def _star(r_in: float, r_out: float, lobes: int, points_per_lobe: int) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * np.pi, lobes * points_per_lobe, endpoint=False)
    r = r_in + (r_out - r_in) * 0.5 * (1.0 + np.cos(lobes * t))
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def box(size_mm: tuple[float, float, float] = (20.0, 20.0, 10.0)) -> trimesh.Trimesh:
    """A plain box."""
    return _mesh(Manifold.cube(size_mm, center=True))


def cylinder(radius_mm: float = 10.0, height_mm: float = 10.0, segments: int = 96) -> trimesh.Trimesh:
    """A round cylinder (faceted with ``segments`` sides)."""
    return _mesh(Manifold.cylinder(height_mm, radius_mm, radius_mm, segments))


def twisted_vase(height_mm: float = 15.0, r_in_mm: float = 9.0, r_out_mm: float = 12.0, wall_mm: float = 1.2,
                 floor_mm: float = 1.5, twist_deg: float = 60.0, lobes: int = 6, points_per_lobe: int = 16,
                 divisions: int = 30) -> trimesh.Trimesh:
    """A hollow star-section vase twisted about Z, open at the top, with a floor."""
    outer = Manifold.extrude(CrossSection([_star(r_in_mm, r_out_mm, lobes, points_per_lobe)]), height_mm,
                             divisions, twist_deg)
    inner = Manifold.extrude(CrossSection([_star(r_in_mm - wall_mm, r_out_mm - wall_mm, lobes, points_per_lobe)]),
                             height_mm, divisions, twist_deg).translate((0.0, 0.0, floor_mm))
    return _mesh(outer - inner)


def islands_part() -> trimesh.Trimesh:
    """Three separate towers (islands) on one plate: a tube, a block with a square hole, a pin."""
    tube = Manifold.cylinder(8.0, 5.0, 5.0, 64).translate((-10.0, 0.0, 0.0)) \
        - Manifold.cylinder(10.0, 2.5, 2.5, 48).translate((-10.0, 0.0, -1.0))
    block = Manifold.cube((8.0, 12.0, 8.0)).translate((2.0, -6.0, 0.0)) \
        - Manifold.cube((4.0, 4.0, 10.0)).translate((4.0, -2.0, -1.0))
    pin = Manifold.cylinder(8.0, 3.0, 3.0, 48).translate((16.0, 0.0, 0.0))
    return _mesh(tube + block + pin)


def sample_part() -> trimesh.Trimesh:
    """The demo part: a 40 x 40 x 20 mm block with a 16 mm through hole and a 4 mm deep pocket ring."""
    block = Manifold.cube((40.0, 40.0, 20.0), center=True)
    hole = Manifold.cylinder(30.0, 8.0, 8.0, 96, center=True)
    pocket = (Manifold.cylinder(4.0, 15.0, 15.0, 96) - Manifold.cylinder(4.0, 11.0, 11.0, 96)).translate((0, 0, 6.0))
    return _mesh(block - hole - pocket)


def sphere(radius_mm: float = 15.0, subdivisions: int = 5) -> trimesh.Trimesh:
    """An icosphere: every layer differs, with gently sloped tops and bottoms."""
    out = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_mm)
    out.apply_translation((0.0, 0.0, radius_mm))
    return out


def gear(teeth: int = 24, root_r_mm: float = 17.0, tip_r_mm: float = 20.0, bore_r_mm: float = 5.0,
         height_mm: float = 8.0) -> trimesh.Trimesh:
    """A spur gear: trapezoidal teeth (wide root, narrow tip) round a bored hub.

    The tooth flanks make a concave corner at every root, where an aligned
    or hidden seam can go; the many short infill pieces between the teeth and
    the bore are what drive a naive slicer's retractions up.
    """
    pitch = 2.0 * np.pi / teeth
    pts = []
    for k in range(teeth):
        a = k * pitch
        for da, r in ((-0.30, root_r_mm), (-0.16, tip_r_mm), (0.16, tip_r_mm), (0.30, root_r_mm)):
            pts.append((r * np.cos(a + da * pitch), r * np.sin(a + da * pitch)))
        for t in np.linspace(0.30, 0.70, 5)[1:-1]:            # the root arc between two teeth
            pts.append((root_r_mm * np.cos(a + t * pitch), root_r_mm * np.sin(a + t * pitch)))
    body = Manifold.extrude(CrossSection([np.asarray(pts)]), height_mm)
    return _mesh(body - Manifold.cylinder(height_mm + 2.0, bore_r_mm, bore_r_mm, 64).translate((0, 0, -1.0)))


def dome(radius_mm: float = 20.0, wall_mm: float = 2.4, floor_mm: float = 1.2, segments: int = 96) -> trimesh.Trimesh:
    """A hollow hemispherical dome closed by a floor: every layer a ring, the cavity's top bridged over air."""
    outer = Manifold.sphere(radius_mm, segments)
    inner = Manifold.sphere(radius_mm - wall_mm, segments)
    shell = (outer - inner.translate((0.0, 0.0, floor_mm))).trim_by_plane((0.0, 0.0, 1.0), 0.0)
    return _mesh(shell)


def towers(count: int = 6, radius_mm: float = 3.0, height_mm: float = 15.0, spacing_mm: float = 12.0,
           base_mm: float = 1.5) -> trimesh.Trimesh:
    """Round, square and hollow towers in two rows on a thin common base: many islands per layer."""
    cols = (count + 1) // 2
    base = Manifold.cube(((cols - 1) * spacing_mm + 4 * radius_mm, spacing_mm + 4 * radius_mm, base_mm),
                         center=True).translate((0.0, 0.0, base_mm / 2.0))
    solid = base
    for i in range(count):
        x = (i % cols - (cols - 1) / 2.0) * spacing_mm
        y = (i // cols - 0.5) * spacing_mm
        kind = i % 3
        if kind == 0:
            t = Manifold.cylinder(height_mm, radius_mm, radius_mm, 64)
        elif kind == 1:
            t = Manifold.cube((2 * radius_mm, 2 * radius_mm, height_mm), center=True).translate((0, 0, height_mm / 2))
        else:
            bore = Manifold.cylinder(height_mm + 2.0, radius_mm - 1.6, radius_mm - 1.6, 48)
            t = Manifold.cylinder(height_mm, radius_mm, radius_mm, 64) - bore.translate((0, 0, 1.0 + base_mm))
        solid = solid + t.translate((x, y, 0.0))
    return _mesh(solid)


def bridge_part(span_mm: float = 20.0, pillar_mm: float = 8.0, depth_mm: float = 12.0, height_mm: float = 8.0,
                deck_mm: float = 2.0) -> trimesh.Trimesh:
    """Two pillars joined by a deck: the deck's underside spans ``span_mm`` of air along X."""
    width = span_mm + 2 * pillar_mm
    left = Manifold.cube((pillar_mm, depth_mm, height_mm)).translate((-width / 2, -depth_mm / 2, 0.0))
    right = Manifold.cube((pillar_mm, depth_mm, height_mm)).translate((width / 2 - pillar_mm, -depth_mm / 2, 0.0))
    deck = Manifold.cube((width, depth_mm, deck_mm)).translate((-width / 2, -depth_mm / 2, height_mm))
    return _mesh(left + right + deck)


def thin_walls(thicknesses_mm: tuple[float, ...] = (0.6, 0.8, 1.0, 1.2, 1.5), length_mm: float = 24.0,
               height_mm: float = 10.0, gap_mm: float = 4.0, base_mm: float = 1.2) -> trimesh.Trimesh:
    """Parallel fins of several thicknesses on a base, each too thin for two full perimeters per side."""
    total = sum(thicknesses_mm) + gap_mm * (len(thicknesses_mm) - 1)
    solid = Manifold.cube((total + 4.0, length_mm + 4.0, base_mm)).translate((-total / 2 - 2.0, -length_mm / 2 - 2.0,
                                                                              0.0))
    x = -total / 2.0
    for t in thicknesses_mm:
        solid = solid + Manifold.cube((t, length_mm, height_mm)).translate((x, -length_mm / 2, 0.0))
        x += t + gap_mm
    return _mesh(solid)


def to_stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary STL of a mesh (what the slicer service receives)."""
    data = mesh.export(file_type="stl")
    assert isinstance(data, bytes), "trimesh writes binary STL as bytes"
    return data
