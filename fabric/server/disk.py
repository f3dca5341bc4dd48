"""Room on a service's disk: work is refused before it starts when it would not fit, and a full disk met
while working is a typed ``disk_full`` error, never an ``internal`` one."""
from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from fabric.schemas.upload import MIB
from fabric.wire.errors import DiskFull

__all__ = ["RESERVE_ENV", "reserve_bytes", "require_room", "disk_full_of"]

RESERVE_ENV = "FABRIC_DISK_RESERVE_MB"
DEFAULT_RESERVE_MB = 256.0      # what a service leaves free for its databases, logs and the system (MiB)


def reserve_bytes() -> int:
    """The room every service keeps free beyond the work itself ($FABRIC_DISK_RESERVE_MB in MiB, default 256)."""
    raw = os.environ.get(RESERVE_ENV, "")
    try:
        mb = float(raw) if raw else DEFAULT_RESERVE_MB
    except ValueError:
        mb = DEFAULT_RESERVE_MB
    return int(max(mb, 0.0) * MIB)


def require_room(path: str | Path, need_bytes: int, service: str, what: str) -> None:
    """Refuse (DiskFull) work of ``need_bytes`` under ``path`` when it would leave less than the reserve."""
    free = shutil.disk_usage(path).free
    if free - int(need_bytes) < reserve_bytes():
        raise DiskFull(f"{service} has {free / MIB:.0f} MiB free at {path}: not enough for {what} "
                       f"({need_bytes / MIB:.0f} MiB and {reserve_bytes() / MIB:.0f} MiB kept free); free "
                       f"space there, then ask again", service=service, path=str(path), free_mb=free / MIB,
                       need_mb=need_bytes / MIB)


def disk_full_of(exc: BaseException, service: str, path: str | Path) -> DiskFull | None:
    """The typed error for an ``OSError`` that is a full disk (ENOSPC, EDQUOT), else None."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return DiskFull(f"{service} ran out of disk space at {path}: {exc.strerror}; free space there, then ask "
                        f"again", service=service, path=str(path), free_mb=0.0, need_mb=0.0)
    return None
