"""One OpenBLAS thread for the planner: its BLAS calls are tiny, and OpenBLAS's idle workers spin on a core.

The planner's matrix products are small ((3,) by (3, N), (N, 6) by (6,)).
OpenBLAS splits them over its worker threads anyway, and a worker that has
finished spins, busy, before it sleeps: after every such call a second core
burns for a while. On a two-core host that is the core the G-code parser, the
export formatter or another process needs (measured: a million-move plan took
some 10-20 % more CPU with the default threads). Results do not change: each
output of these products is one dot product, summed the same way by any thread.

The thread count is set through OpenBLAS's own call in the library NumPy has
loaded (found in ``/proc/self/maps``), so it holds whatever was imported first;
where there is no such library (another BLAS, another OS) nothing is done.
"""
from __future__ import annotations

import ctypes
import logging
import re
from pathlib import Path

__all__ = ["single_blas_thread"]

log = logging.getLogger(__name__)

_SETTERS = ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads64_", "openblas_set_num_threads")
_LIBRARY = re.compile(r"(/\S*openblas\S*\.so\S*)")


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS libraries mapped into this process (none off Linux)."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    return sorted(set(_LIBRARY.findall(maps.read_text())))


def single_blas_thread() -> bool:
    """Make every OpenBLAS loaded in this process use one thread; True if one was set."""
    done = False
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError as exc:                  # mapped but not loadable by name: leave it as it is
            log.debug("cannot open %s: %s", path, exc)
            continue
        for name in _SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter.argtypes = [ctypes.c_int]
                setter.restype = None
                setter(1)
                done = True
                break
    return done
