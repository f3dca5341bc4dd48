"""Small C helpers for the hottest loops, built on first use (Klipper's ``chelper`` way).

A helper is one C file of this folder. :func:`library` compiles it with the
system's C compiler (``$CC``, else ``cc``) into a shared object in the user's
cache folder (``$XDG_CACHE_HOME/am-fabric/native``, named by the hash of the
source and the compiler, so an edited source or another compiler builds
anew), writing it under a temporary name and renaming it into place (two
processes building at once both end with a whole file), and loads it with
ctypes. Every helper has a pure-Python path beside it: where there is no
compiler, the build fails, or ``FABRIC_NATIVE=0`` is set, :func:`library`
answers None (the reason is logged once) and the caller takes that path.

``python -m fabric.native`` builds every helper ahead (``tools/setup-env``
runs it), so the first plan does not wait for the compiler.

Every function of a helper is called with its prototype declared (Klipper's
``chelper`` declares each to cffi): :func:`bound` sets ``restype`` and
``argtypes`` from a table, and an array argument is an :func:`array` type (its
dtype, alignment, contiguity and, for an output, writability), so a wrong array
is a ``ctypes.ArgumentError`` in Python, never a crash or silent garbage.
"""
from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import DTypeLike

__all__ = ["library", "bound", "build", "array", "HELPERS", "cache_dir", "Signature"]

log = logging.getLogger(__name__)

HELPERS = ("numtext", "gclex", "armik", "nozzle", "chain", "lookahead")
# no -Werror: a newer compiler's new warning is no reason to take the Python path
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-Wall")
BUILD_TIMEOUT_S = 120.0

_lock = threading.Lock()
_loaded: dict[str, ctypes.CDLL | None] = {}
_bound: dict[str, ctypes.CDLL | None] = {}

Signature = tuple[Any, list[Any]]           # a function's restype and argtypes


def array(dtype: DTypeLike, *, out: bool = False, ndim: int | None = None, strided: bool = False,
          nullable: bool = False) -> type:
    """The ctypes argument type of an array a C function reads (``out``: writes) as ``dtype`` elements.

    A numpy ``ndpointer``: the call raises ``ctypes.ArgumentError`` for an array of another dtype or number
    of dimensions, one not aligned, not C-contiguous (unless ``strided``: the function takes the strides in
    other arguments) or, for an output, read-only. ``nullable``: None passes NULL."""
    flags: Any = ",".join(["ALIGNED"] + ([] if strided else ["C_CONTIGUOUS"]) + (["WRITEABLE"] if out else []))
    ptr = np.ctypeslib.ndpointer(dtype=np.dtype(dtype), ndim=ndim, flags=flags)
    if not nullable:
        return ptr

    def from_param(cls: type, obj: Any) -> Any:
        return None if obj is None else ptr.from_param(obj)

    return type(f"{ptr.__name__}_or_NULL", (ptr,), {"from_param": classmethod(from_param)})


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "am-fabric" / "native"


def _compiler() -> str | None:
    cc = os.environ.get("CC", "cc")
    return shutil.which(cc)


def _target(name: str, cc: str) -> Path:
    source = (Path(__file__).parent / f"{name}.c").read_bytes()
    key = hashlib.sha256(source + b"\0" + cc.encode() + b"\0" + " ".join(CFLAGS).encode()).hexdigest()[:16]
    return cache_dir() / f"{name}-{key}.so"


def build(name: str) -> Path:
    """Compile helper ``name`` (if not built already); returns the shared object's path.

    Raises OSError (no compiler, unwritable cache) or subprocess.CalledProcessError (the compiler failed).
    """
    cc = _compiler()
    if cc is None:
        raise OSError(f"no C compiler ({os.environ.get('CC', 'cc')}) on PATH")
    target = _target(name, cc)
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{name}-", suffix=".so", dir=target.parent)
    os.close(fd)
    try:
        subprocess.run([cc, *CFLAGS, "-o", tmp, str(Path(__file__).parent / f"{name}.c"), "-lm"],
                       check=True, capture_output=True, timeout=BUILD_TIMEOUT_S)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def library(name: str) -> ctypes.CDLL | None:
    """Helper ``name`` loaded (built first if need be), or None: its callers then take their Python path."""
    with _lock:
        if name in _loaded:
            return _loaded[name]
        lib: ctypes.CDLL | None = None
        if os.environ.get("FABRIC_NATIVE", "1") == "0":
            log.info("native helper %s off (FABRIC_NATIVE=0)", name)
        else:
            try:
                lib = ctypes.CDLL(str(build(name)))
            except subprocess.CalledProcessError as e:
                log.warning("native helper %s did not build, using Python: %s", name,
                            e.stderr.decode(errors="replace").strip()[:400])
            except (OSError, subprocess.TimeoutExpired) as e:
                log.warning("native helper %s not available, using Python: %s", name, e)
        _loaded[name] = lib
        return lib


def bound(name: str, signatures: Mapping[str, Signature]) -> ctypes.CDLL | None:
    """Helper ``name`` loaded (:func:`library`) with its functions' ``restype`` and ``argtypes`` set from
    ``signatures`` (function name -> (restype, argtypes)), once; None where there is no helper."""
    with _lock:
        if name in _bound:
            return _bound[name]
    lib = library(name)
    if lib is not None:
        for fn, (restype, argtypes) in signatures.items():
            f = getattr(lib, fn)
            f.restype = restype
            f.argtypes = argtypes
    with _lock:
        _bound.setdefault(name, lib)
        return _bound[name]
