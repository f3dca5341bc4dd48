"""Slicing: models (STL/OBJ/3MF bytes) to G-code with the built-in slicer or PrusaSlicer / Slic3r.

Public API (what the slicer service calls)::

    load_mesh(data, filename) -> trimesh.Trimesh
    load_profile(name_or_path, overrides=None) -> Profile;  list_profiles() -> list[str]
    slice_model(data, filename, profile, backend="builtin", placement=None,
                plate_size_mm=(250, 250), build_height_mm=250, progress=None) -> SliceResult
    available_backends() -> dict[str, str | None]
"""
from fabric.slicing.backends import SliceResult, available_backends, slice_model
from fabric.slicing.mesh import load_mesh
from fabric.slicing.placement import Placement
from fabric.slicing.profile import Profile, list_profiles, load_profile

__all__ = ["load_mesh", "Profile", "load_profile", "list_profiles", "slice_model", "Placement",
           "SliceResult", "available_backends"]
