"""Write the bundled sample models into fabric/data/ (binary STL, each under 200 KB).

Run: .venv/bin/python tools/make_samples.py   (deterministic: same bytes every run)
"""
from __future__ import annotations

import sys
from pathlib import Path

from fabric.slicing.samples import sample_part, to_stl_bytes, twisted_vase

DATA = Path(__file__).resolve().parents[1] / "fabric" / "data"
LIMIT_BYTES = 200_000


def main() -> int:
    """Generate the samples; fail if one is not watertight or too large."""
    models = {
        "sample_part.stl": sample_part(),
        "twisted_vase.stl": twisted_vase(height_mm=30.0, r_in_mm=14.0, r_out_mm=19.0, wall_mm=1.6,
                                         floor_mm=2.0, twist_deg=90.0, points_per_lobe=8, divisions=16),
    }
    DATA.mkdir(parents=True, exist_ok=True)
    for name, mesh in models.items():
        data = to_stl_bytes(mesh)
        if not mesh.is_watertight or len(data) > LIMIT_BYTES:
            print(f"{name}: watertight={mesh.is_watertight}, {len(data)} bytes: refusing", file=sys.stderr)
            return 1
        (DATA / name).write_bytes(data)
        print(f"{name}: {len(mesh.faces)} faces, {mesh.volume:.0f} mm^3, {len(data)} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
