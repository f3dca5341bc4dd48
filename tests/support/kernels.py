"""numpy's SIMD kernels on this machine, and the ``NPY_DISABLE_CPU_FEATURES`` masks that make numpy take older ones.

numpy picks a kernel per function from the CPU's features at import (its dispatch targets: ``X86_V3``,
``X86_V4``, ``AVX512_ICL``, ``AVX512_SPR`` on x86-64; ``ASIMDHP``, ``ASIMDDP``, ``ASIMDFHM``, ``SVE`` on arm64),
and kernels of different targets round some results differently (the sine, cosine and ``atan2`` of AVX-512 are
not libm's). Turning off the best targets here gives the kernels a CPU without them would run: the tests under
those masks stand for the machines this one is not.
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["dispatch_found", "older_kernel_masks", "ENV"]

ENV = "NPY_DISABLE_CPU_FEATURES"


def dispatch_found() -> list[str]:
    """The dispatch targets numpy found on this CPU (and did not have turned off), oldest first."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    return [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]


def older_kernel_masks() -> dict[str, str]:
    """Masks (name -> ``NPY_DISABLE_CPU_FEATURES`` value) that each take this CPU's kernels back one dispatch
    group, then two: on an AVX-512 machine 'without X86_V4' (AVX2 kernels) and 'without X86_V3' (SSE4.2 ones).
    Targets numpy dispatches to above a group go with it (AVX512_ICL and AVX512_SPR with X86_V4)."""
    if os.environ.get(ENV):
        return {}                              # already masked: the caller is one of these runs
    found = dispatch_found()
    x86 = [t for t in found if t.startswith("X86_V")]
    groups = x86 if x86 else found               # arm64 and others: each target is a group of its own
    masks: dict[str, str] = {}
    for k in range(1, min(2, len(groups)) + 1):
        first = found.index(groups[-k])
        masks[f"without {groups[-k]}"] = " ".join(found[first:])
    return masks


if __name__ == "__main__":
    print("numpy", np.__version__, "dispatch targets found:", " ".join(dispatch_found()) or "none")
    for name, mask in older_kernel_masks().items():
        print(f"{name}: {ENV}='{mask}'")
