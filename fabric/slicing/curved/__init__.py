"""Curved-layer slicing: layers along a field grown from the base and following the top, a tilted nozzle."""
from fabric.slicing.curved.gcode import MULTIAXIS_HEADER, write_multiaxis
from fabric.slicing.curved.metrics import CurvedReport
from fabric.slicing.curved.options import CurvedOptions, ThicknessBounds, thickness_bounds
from fabric.slicing.curved.paths import CurvedPath
from fabric.slicing.curved.slicer import CurvedSlice, slice_curved

__all__ = ["CurvedOptions", "CurvedPath", "CurvedReport", "CurvedSlice", "MULTIAXIS_HEADER", "ThicknessBounds",
           "slice_curved", "thickness_bounds", "write_multiaxis"]
