"""Every C helper's functions are called through declared prototypes (``fabric.native.array``): a wrong array is
a Python error before the call, never a crash or silent garbage."""
from __future__ import annotations

import ctypes
import re
from pathlib import Path

import numpy as np
import pytest

from fabric import native
from fabric.gcode import native_lexer
from fabric.motion import lookahead_native
from fabric.planning.post import numtext
from fabric.robot import chain_native, native_track, nozzle_native

BINDINGS = {"nozzle": nozzle_native, "chain": chain_native, "armik": native_track, "lookahead": lookahead_native,
            "gclex": native_lexer, "numtext": numtext}
EXPORTED = re.compile(r"^(?:long|int|void|double) ([a-z_0-9]+)\(", re.M)


def test_every_helper_has_a_binding_and_every_exported_function_a_prototype() -> None:
    assert set(BINDINGS) == set(native.HELPERS)
    for name, module in BINDINGS.items():
        source = (Path(native.__file__).parent / f"{name}.c").read_text()
        exported = set(EXPORTED.findall(source))
        assert exported == set(module.SIGNATURES), f"{name}.c exports {sorted(exported)}"
        for fn, (_restype, argtypes) in module.SIGNATURES.items():
            assert ctypes.c_void_p not in argtypes, f"{name}.{fn} takes a bare pointer"


def _lib(name: str) -> ctypes.CDLL:
    lib = native.bound(name, BINDINGS[name].SIGNATURES)
    if lib is None:
        pytest.skip("no C compiler: numpy's path only")
    return lib


@pytest.mark.parametrize("bad", ["float32", "read-only", "strided", "2-D"])
def test_a_wrong_output_array_is_refused_before_the_call(bad: str) -> None:
    lib = _lib("nozzle")
    n = 4
    z0, xr = np.tile([[0.0], [0.0], [-1.0]], (1, 1)), np.ones((3, n))
    good = np.empty((3, n))
    wrong = {"float32": np.empty((3, n), np.float32),
             "read-only": np.broadcast_to(np.zeros(1), (3, n)),
             "strided": np.empty((3, 2 * n))[:, ::2],
             "2-D": good}[bad]
    if bad == "2-D":                                 # a 2-D array where the quaternions' rotation (1-D) goes
        with pytest.raises(ctypes.ArgumentError):
            lib.nozzle_quats(n, good, np.ones(3), np.ones(3), np.ones(4), np.ones((2, 2)), 1, 1e-9,
                             np.empty((n, 4)))
        return
    with pytest.raises(ctypes.ArgumentError, match="array must have"):
        lib.nozzle_frames(n, z0, 0, xr, good, wrong)
    lib.nozzle_frames(n, z0, 0, xr, good, np.empty((3, n)))        # the same call with right arrays runs


def test_wrong_arrays_through_the_wrappers_are_python_errors() -> None:
    _lib("armik")
    _lib("lookahead")
    _lib("chain")
    with pytest.raises(ValueError, match=r"\(3, N\)"):
        nozzle_native.frames(np.zeros((2, 1)), np.ones((2, 5)))
    with pytest.raises(ValueError, match="do not match"):
        lookahead_native.caps(np.ones(2), np.zeros((4, 6)), np.zeros(6), np.ones(3), np.array([1, 2]), np.ones(6))
    with pytest.raises(ctypes.ArgumentError):                      # an int64 column where joints (float64) go
        lib = native.bound("armik", native_track.SIGNATURES)
        assert lib is not None
        lib.armik_place_multi_turn(3, np.zeros(3, np.int64), 0.0, -1.0, 1.0, 1e-9, np.empty(3))
