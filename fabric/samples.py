"""The parts bundled with am-fabric (``fabric/data``): where they are and what they are, without the heavy stack."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Sample", "SAMPLES_DIR", "samples"]

SAMPLES_DIR = Path(__file__).parent / "data"
DESCRIPTIONS = {"sample_part.stl": "the demo part (fabric-cli job submit it, or tools/demo)",
                "twisted_vase.stl": "a taller twisted vase: many layers, curved walls"}
_STL_HEADER_BYTES, _STL_TRIANGLE = 84, np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])


@dataclass(frozen=True)
class Sample:
    """A bundled part: its file, triangles and size (mm, x y z), and what it is for."""

    path: Path
    triangles: int
    size_mm: tuple[float, float, float]
    description: str

    @property
    def name(self) -> str:
        return self.path.name


def samples() -> list[Sample]:
    """Every bundled part, by name (binary STL read with NumPy: a base install lists them too)."""
    out = []
    for path in sorted(SAMPLES_DIR.glob("*.stl")):
        data = path.read_bytes()
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        tri = np.frombuffer(data, _STL_TRIANGLE, count, _STL_HEADER_BYTES)
        pts = tri["v"].reshape(-1, 3)
        size = pts.max(axis=0) - pts.min(axis=0) if len(pts) else np.zeros(3)
        out.append(Sample(path, count, (float(size[0]), float(size[1]), float(size[2])),
                          DESCRIPTIONS.get(path.name, "")))
    return out
