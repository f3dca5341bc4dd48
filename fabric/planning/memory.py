"""Keep freed memory in the process for the next plan instead of handing it back to the OS (glibc only).

A million-move plan allocates some 500 MB of arrays. By default glibc maps
every large array afresh (``mmap``) and unmaps it when freed, so the next plan
touches new pages again: on the VMs this runs on a first touch costs
0.5-2 s per GB (measured: 40,000 page faults, 0.1-0.3 s of system time for
every plan after the first, more for the first). Raising the mmap threshold
and the trim threshold makes large arrays come from the heap and stay there
once freed, so a planner that plans again, or streams an export in pieces,
reuses pages it already touched. The price: the process keeps its peak
resident size (one plan's worth) instead of shrinking between plans; since a
plan holds a chunk of rows at a time (``fabric.planning.planner``), that is a
few hundred MB whatever the G-code's size.

Arenas: glibc gives threads arenas of their own (up to 8 per core), each
keeping what it freed; the lexer, the export formatters and the artifact writer
are new threads each plan, and memory freed in one arena is not reused by
another, so a planner kept ~60 MB more after every plan. Two arenas (the main
one and one the worker threads share) make every plan reuse the same free
memory: measured, the idle size after four plans in a row stays flat.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging

__all__ = ["keep_freed_memory"]

log = logging.getLogger("fabric.planning.memory")

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -2, -3, -8    # mallopt parameters (malloc.h)
MMAP_THRESHOLD_BYTES = 1 << 30      # allocations below this come from the heap
TRIM_THRESHOLD_BYTES = 2**31 - 1    # free memory at the top of the heap kept up to this
TOP_PAD_BYTES = 64 << 20            # the heap grows by at least this much at a time
ARENA_MAX = 2                       # malloc arenas: the main thread's and one for every other thread

_done = False


def keep_freed_memory() -> bool:
    """Tune the C allocator as the module docstring says (once per process); False where it is not glibc."""
    global _done
    if _done:
        return True
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        log.info("no glibc mallopt here: freed memory goes back to the OS as usual")
        return False
    ok = all(mallopt(param, value) == 1 for param, value in ((_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES),
                                                               (_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES),
                                                               (_M_TOP_PAD, TOP_PAD_BYTES),
                                                               (_M_ARENA_MAX, ARENA_MAX)))
    _done = ok
    return ok
