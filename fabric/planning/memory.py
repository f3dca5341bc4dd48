"""The C allocator of a planning process: freed memory kept while a plan runs, one arena, given back when idle.

A plan allocates and frees blocks of arrays over and over (a chunk of rows, an
IK block, an export block). By default glibc maps every large array afresh
(``mmap``) and unmaps it when freed, so each block touches new pages again: on
the VMs this runs on a first touch costs 0.5-2 s per GB. Raising the mmap
threshold and the trim threshold makes large arrays come from the heap and stay
there once freed, so the blocks of a plan, and of an export streamed in pieces,
reuse pages already touched (:func:`keep_freed_memory`). A plan holds a chunk of
rows at a time (``fabric.planning.planner``), so that is a few hundred MB
whatever the G-code's size.

Arenas: glibc gives threads arenas of their own (up to 8 per core), each keeping
what it freed; the lexer, the export formatters and the artifact writer are new
threads each plan, and memory freed in one arena is not reused by another, so a
planner kept 40-110 MB more after every plan. With one arena every thread reuses
the same free memory (its threads do large, few allocations: no contention to
speak of), and everything it keeps can be given back.

Between plans: once the planner is idle (no plan, no export being read) what
it holds free goes back to the OS (:func:`give_back_freed_memory`, glibc's
``malloc_trim``); otherwise the process would keep the highest working set any
plan ever had, which depends on how its threads happened to overlap (measured,
four identical plans: 359, 369, 404, 404 MB idle; given back: 185, 185, 184,
183 MB, at no more page faults per plan: 21,000-31,000 either way).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging

__all__ = ["keep_freed_memory", "give_back_freed_memory"]

log = logging.getLogger("fabric.planning.memory")

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -2, -3, -8    # mallopt parameters (malloc.h)
MMAP_THRESHOLD_BYTES = 1 << 30      # allocations below this come from the heap
TRIM_THRESHOLD_BYTES = 2**31 - 1    # free memory at the top of the heap kept up to this
TOP_PAD_BYTES = 64 << 20            # the heap grows by at least this much at a time
ARENA_MAX = 1                       # malloc arenas: one, shared by every thread (see the module doc)

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


def give_back_freed_memory() -> bool:
    """Hand the memory the allocator holds free back to the OS (glibc's ``malloc_trim(0)``: the top of the heap
    and the free pages inside every arena); False where it is not glibc."""
    try:
        return bool(ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim(0))
    except (OSError, AttributeError, TypeError):
        return False
