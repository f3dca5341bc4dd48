"""A directory tree showing only folders and the files a print job can start from."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from textual.widgets import DirectoryTree

PRINTABLE_SUFFIXES = (".stl", ".3mf", ".obj", ".gcode", ".gco", ".g", ".nc")


class ModelTree(DirectoryTree):
    def filter_paths(self, paths: Iterable[Path]) -> Iterable[Path]:
        return [p for p in paths if not p.name.startswith(".")
                and (p.is_dir() or p.suffix.lower() in PRINTABLE_SUFFIXES)]
