"""The planner's one-OpenBLAS-thread setting: applied where OpenBLAS is loaded, products unchanged."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from fabric.planning import blas

_PROBE = """
import numpy as np
from fabric.planning.blas import single_blas_thread
rng = np.random.default_rng(5)
a, b = rng.normal(size=(4096, 6)), rng.normal(size=6)
B, x = rng.normal(size=(3, 3)), rng.normal(size=(3, 5000))
before = (a @ b).tobytes() + (B[:, 1] @ x).tobytes()
print(single_blas_thread())
after = (a @ b).tobytes() + (B[:, 1] @ x).tobytes()
print(before == after)
"""


def test_single_thread_set_and_products_unchanged():
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=60, check=True)
    done, same = out.stdout.split()
    assert same == "True"
    assert done == str(bool(blas._loaded_openblas()))


def test_without_openblas_nothing_is_done(monkeypatch):
    monkeypatch.setattr(blas, "_loaded_openblas", lambda: [])
    assert blas.single_blas_thread() is False
    assert np.ones(3) @ np.ones(3) == 3.0
