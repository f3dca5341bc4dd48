"""Export files written all or nothing: temporary files beside their targets, renamed together at the end."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

__all__ = ["AtomicFiles"]


class AtomicFiles:
    """Open any number of target files; on a clean exit every one is renamed into place, on an error none is.

        with AtomicFiles() as files:
            client.export_to(pid, "csv", files.open("part.csv"))
            client.export_to(pid, "rapid", files.open("part.mod"))

    Each file is written to a hidden temporary file in its target's directory
    (so the rename is atomic on one filesystem). If anything raises inside the
    block, the temporary files are removed and the targets are left as they were.
    """

    def __init__(self) -> None:
        self._open: list[tuple[BinaryIO, Path, Path]] = []

    def open(self, target: str | os.PathLike[str]) -> BinaryIO:
        path = Path(target)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
        os.fchmod(fd, 0o666 & ~_umask())           # the mode a plain open() would give, not mkstemp's 0600
        fh = os.fdopen(fd, "wb")
        self._open.append((fh, Path(tmp), path))
        return fh

    def __enter__(self) -> AtomicFiles:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for fh, _tmp, _path in self._open:
            fh.close()
        if exc_type is not None:
            self.discard()
            return
        try:
            for _fh, tmp, path in self._open:
                os.replace(tmp, path)
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary files not yet renamed."""
        for _fh, tmp, _path in self._open:
            tmp.unlink(missing_ok=True)
        self._open = []


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
