"""The supervisor's file library: the models and G-code files submitted or added, kept to print again.

Every file submitted for a job enters the library (once per content and name); a file can also be added
without printing it. An entry keeps what the file is (name, source, size, content id), the settings of
the last job made from it (so that "print again" needs nothing else) and what that job's plan said
(layers, volume, duration), so that a file is worth choosing before it is sliced again.
"""
from __future__ import annotations

from fabric.schemas.base import f, schema
from fabric.schemas.ids import FILE_ID_MIN_CHARS
from fabric.schemas.pipeline import BACKENDS, JOB_SOURCES, LAYER_MODES
from fabric.schemas.upload import MAX_SUBMIT_BYTES

__all__ = ["FileAdd", "FileList", "FileQuery", "FilesQuery", "LibraryFile", "MAX_FILES_PAGE"]

MAX_FILES_PAGE = 1_000               # the most entries one supervisor/files reply carries


@schema("supervisor.LibraryFile")
class LibraryFile:
    """One file of the library. Times ending in ``_s`` are wall-clock epoch seconds (0 = never)."""
    file_id: str                                 # the entry: from the file's content and its name (12 hex)
    name: str                                    # the file name as submitted or added
    source: str = f(choices=JOB_SOURCES)         # model or gcode
    content_id: str = ""                         # the file's bytes: an artifact id at the supervisor
    size_bytes: int = f(default=0, ge=0)         # the file's size
    added_s: float = 0.0                         # when it entered the library (wall clock, epoch)
    used_s: float = 0.0                          # when a job was last made from it (wall clock, epoch; 0: never)
    jobs: int = f(default=0, ge=0)               # how many jobs were made from it
    last_job_id: str = ""                        # the latest of them ("" none)
    last_state: str = ""                         # how that job stands or ended, as last seen
    profile: str = "taz-pla-medium"              # the last job's slicing profile: what "print again" uses
    backend: str = f(default="builtin", choices=BACKENDS)     # the last job's slicer
    overrides: dict[str, str] = f(factory=dict)  # the last job's profile keys
    layer_mode: str = f(default="planar", choices=LAYER_MODES)    # the last job's layers: planar or curved
    rtf: float = f(default=1.0, ge=0.0, le=1e6)  # the last job's real-time factor
    filament_diameter_mm: float | None = None    # the last job's filament (nil: as the file states)
    layers: int = f(default=0, ge=0)             # the last plan's layers (0: not planned yet)
    extruded_mm3: float = f(default=0.0, ge=0.0)     # the last plan's volume
    estimate_s: float = f(default=0.0, ge=0.0)   # the last plan's duration at real time (simulated seconds)


@schema("supervisor.FilesQuery")
class FilesQuery:
    """A page of the library, most recently used first; ``name_contains`` filters by name (any case)."""
    offset: int = f(default=0, ge=0, le=1_000_000_000)      # skip this many matching entries
    limit: int = f(default=100, ge=0, le=MAX_FILES_PAGE)    # the most entries in the reply
    name_contains: str = f(default="", max_len=255)         # only names containing this (any case; "": all)


@schema("supervisor.FileList")
class FileList:
    """Library entries, most recently used first; ``total`` counts every entry that matched."""
    files: list[LibraryFile] = f(factory=list)      # the page asked
    total: int = 0                                  # entries that matched, in all
    offset: int = 0                                 # where the page begins (0-based)


@schema("supervisor.FileAdd")
class FileAdd:
    """Add a file to the library without printing it (``source`` "": from the file name, as ``JobSubmit``)."""
    data: bytes = f(max_len=MAX_SUBMIT_BYTES)        # the file's bytes (a model: at most what the slicer
                                                     # takes, see Inputs)
    name: str = f(max_len=255)                       # its name (a path's last part is kept)
    source: str = f(default="", choices=("", *JOB_SOURCES))     # model, gcode, or "": from the name


@schema("supervisor.FileQuery")
class FileQuery:
    """One library entry by its ``file_id`` (a unique prefix of at least 6 characters is enough)."""
    file_id: str = f(min_len=FILE_ID_MIN_CHARS, max_len=64)   # the entry's id, or a unique start of it
