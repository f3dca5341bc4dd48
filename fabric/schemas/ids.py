"""The forms of the ids a request names, declared once: the schemas' patterns (and so the JSON Schema's) and
the services' checks are made from these."""
from __future__ import annotations

__all__ = ["UPLOAD_ID_PATTERN", "UPLOAD_ID_OR_NONE", "FILE_ID_MIN_CHARS", "FILE_ID_PATTERN", "FILE_ID_OR_NONE"]

UPLOAD_ID_PATTERN = r"[A-Za-z0-9_-]{8,64}"
"""An upload's id, chosen by its sender: 8 to 64 letters, digits, ``_`` or ``-`` (it names a file on disk)."""

UPLOAD_ID_OR_NONE = f"(?:{UPLOAD_ID_PATTERN})?"
"""A request's ``upload_id``: "" (the input is not an upload) or an upload's id."""

FILE_ID_MIN_CHARS = 6
"""A library file is named by its whole id (12 hex digits) or a unique start of it at least this long (a
shorter one would too easily mean two files)."""

FILE_ID_PATTERN = f".{{{FILE_ID_MIN_CHARS},}}"
"""A library file's id, or a start of it of ``FILE_ID_MIN_CHARS`` or more characters."""

FILE_ID_OR_NONE = f"(?:{FILE_ID_PATTERN})?"
"""A request's ``file_id``: "" (no library file) or a library file's id or start."""
