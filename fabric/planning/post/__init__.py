"""Post-processors: a planned :class:`~fabric.motion.program.Program` -> controller code or CSV.

The names below are imported on first use (``post.atomic`` alone stays light for the CLI).
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fabric.planning.post.csv import CSV_COLUMNS, write_csv
    from fabric.planning.post.files import FORMATS, export_program, write_export
    from fabric.planning.post.krl import write_krl
    from fabric.planning.post.rapid import RapidExport, RapidOptions, write_rapid
    from fabric.planning.post.urscript import write_urscript

__all__ = ["write_rapid", "RapidOptions", "RapidExport", "write_krl", "write_urscript", "write_csv",
           "CSV_COLUMNS", "export_program", "write_export", "FORMATS"]

_HOME = {"write_rapid": "rapid", "RapidOptions": "rapid", "RapidExport": "rapid", "write_krl": "krl",
         "write_urscript": "urscript", "write_csv": "csv", "CSV_COLUMNS": "csv", "export_program": "files",
         "write_export": "files", "FORMATS": "files"}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
