"""The built-in slicer (trimesh + shapely + numpy): ``slice_mesh(placed_mesh, profile, progress)``."""
from fabric.slicing.builtin.slicer import BuiltinOutput, slice_mesh

__all__ = ["BuiltinOutput", "slice_mesh"]
