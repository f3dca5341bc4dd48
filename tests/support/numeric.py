"""Comparing floating point computed two ways (C and numpy, one CPU's kernels and another's) within stated ULPs.

Bit-equality between two implementations holds only where they pick the same kernels: numpy's AVX-512 sine,
cosine and dot products round differently from libm's (4e-16 apart on unit quaternions). A comparison here
counts the difference in units in the last place of the quantity's *scale* (a unit vector: 1; joints: pi; a
position in mm: the largest coordinate), so an element near zero is not held to the spacing of zero.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ulps_apart", "assert_ulps"]


def ulps_apart(actual: np.ndarray, desired: np.ndarray, scale: float | None = None) -> float:
    """The largest ``|actual - desired|`` in units of ``spacing(scale)`` (``scale``: the largest ``|desired|``
    when None). Non-finite elements must match exactly (inf where inf, nan where nan); they count 0."""
    a = np.asarray(actual, dtype=float)
    d = np.asarray(desired, dtype=float)
    if a.shape != d.shape:
        raise AssertionError(f"shapes differ: {a.shape} and {d.shape}")
    finite = np.isfinite(d)
    np.testing.assert_array_equal(np.isfinite(a), finite)
    np.testing.assert_array_equal(a[~finite], d[~finite])
    if not finite.any():
        return 0.0
    ref = float(np.max(np.abs(d[finite]))) if scale is None else float(scale)
    unit = float(np.spacing(max(ref, np.finfo(float).tiny)))
    return float(np.max(np.abs(a[finite] - d[finite]))) / unit


def assert_ulps(actual: np.ndarray, desired: np.ndarray, max_ulps: float, scale: float | None = None,
                what: str = "") -> None:
    """``actual`` within ``max_ulps`` units in the last place (of ``scale``, see :func:`ulps_apart`) of
    ``desired``, element by element."""
    apart = ulps_apart(actual, desired, scale)
    if apart > max_ulps:
        raise AssertionError(f"{what or 'arrays'}: {apart:.1f} ULPs apart, more than {max_ulps:g}")
