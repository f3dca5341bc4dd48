"""The beads a print has deposited, kept as growing numpy arrays, and the as-printed mesh.

A bead is one linear move with the extruder on: from the move's start to its
end (the nozzle path, plate frame), with its width, height and deposited
volume. A bead is recorded when its row completes, whatever happened in
between (a pause mid-row and the resume still give one bead, identical to an
uninterrupted run); a stopped job records the row it was in as a partial bead.

Bead cross-section: Slic3r's model, a rectangle of the layer height with
semicircular sides, area ``(w - h) * h + pi * h^2 / 4``. Height is the
program's ``meta['layer_height_mm']`` when present, else the z spacing of the
layers (the first layer: its height above the plate); width is
``meta['bead_width_mm']`` when present, else solved from the flow per mm with
that area formula. The mesh draws each bead as an octagonal prism: the
``w x h`` box with its corners cut so the octagon's area equals the stadium's
(corner legs ``h * sqrt((1 - pi/4) / 2)``), hanging below the nozzle path.

Multi-axis programs (``meta['multiaxis']``: curved layers, a tilted nozzle).
Each bead keeps the nozzle axis it was laid with (``axis``, plate frame, from
the tip up the nozzle; straight up for planar beads) and hangs from the
nozzle path *along* that axis, its cross-section turned with it. A curved
layer's thickness varies along the layer and the slicer's E carries it, so a
bead's height is solved from its flow per mm with the width of the program
(``meta['bead_width_mm']``, the G-code's ``;WIDTH:``): ``(w - h) h + pi h^2 / 4
= flow`` (a flow more than a round bead of that width holds makes the bead
wider, so a bead's volume is always its flow); without a width, beads are
taken ``BEAD_ASPECT_R`` times as wide as high.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
import trimesh

from fabric.motion.program import MOVEL, Program
from fabric.wire.errors import ValidationError

__all__ = ["Deposition", "VolumeReport", "bead_area_mm2"]

_FIELDS = {"start_mm": (3,), "end_mm": (3,), "width_mm": (), "height_mm": (), "volume_mm3": (),
           "row": (), "layer": (), "axis": (3,)}
OPTIONAL_FIELDS = {"axis"}    # absent from beads saved before multi-axis printing: straight up
_CHAMFER = float(np.sqrt((1.0 - np.pi / 4.0) / 2.0))
_K = 1.0 - np.pi / 4.0        # the stadium's area is w h - _K h^2
BEAD_ASPECT_R = 1.6           # width / height of multi-axis beads when the program states no width
UP = np.array([0.0, 0.0, 1.0])


def bead_area_mm2(width_mm: np.ndarray, height_mm: np.ndarray) -> np.ndarray:
    """Cross-section of a bead (rectangle with semicircular sides)."""
    return (width_mm - height_mm) * height_mm + np.pi * height_mm ** 2 / 4.0


def height_for_flow_mm(width_mm: np.ndarray | float, flow_mm3_mm: np.ndarray) -> np.ndarray:
    """The bead height whose cross-section, at ``width_mm``, is ``flow_mm3_mm`` (the smaller root of
    ``w h - _K h^2 = flow``; at most the height of the largest such bead, ``w / (2 _K)`` capped at the width)."""
    w = np.asarray(width_mm, dtype=float)
    a = np.maximum(np.asarray(flow_mm3_mm, dtype=float), 0.0)
    disc = np.maximum(w * w - 4.0 * _K * a, 0.0)
    return np.minimum((w - np.sqrt(disc)) / (2.0 * _K), w)


def nozzle_axes(quat_wxyz: np.ndarray) -> np.ndarray:
    """Nozzle axes (N, 3), from the tip up the nozzle, of TCP orientations (N, 4): minus each TCP's z axis."""
    w, x, y, z = (quat_wxyz[..., k] for k in range(4))
    return -np.stack([2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)], axis=-1)


def bead_frames(direction: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per bead: unit ``along`` (the move), ``side`` and ``up`` (the nozzle axis made normal to the move), and
    whether the move runs along the axis itself (``up`` is then any normal, and the bead stands centred).

    ``direction`` (N, 3) end minus start; ``axis`` (N, 3) the nozzle axis. A zero-length move runs along x."""
    length = np.linalg.norm(direction, axis=1)
    along = np.where(length[:, None] > 1e-12, direction / np.where(length > 1e-12, length, 1.0)[:, None],
                     [1.0, 0.0, 0.0])
    side = np.cross(along, axis)
    sn = np.linalg.norm(side, axis=1)
    columnar = sn < 1e-9
    side = np.where(columnar[:, None], np.cross(along, [0.0, 1.0, 0.0]), side)
    side_n = np.linalg.norm(side, axis=1)
    side = np.where(side_n[:, None] > 1e-9, side, np.cross(along, [1.0, 0.0, 0.0]))
    side /= np.linalg.norm(side, axis=1)[:, None]
    up = np.cross(side, along)
    return along, side, up, columnar


@dataclass
class VolumeReport:
    """Deposited volume against the model's volume."""

    extruded_mm3: float
    model_mm3: float
    ratio: float
    bead_count: int
    mesh_mm3: float


class Deposition:
    """Every bead deposited so far (arrays grow by doubling; the public arrays are views)."""

    def __init__(self, program: Program | None = None) -> None:
        self._n = 0
        self._buf: dict[str, np.ndarray] = {}
        self._alloc(256)
        self._layer_h = np.zeros(0)
        self._h_default = 0.2
        self._meta_w: float | None = None
        self._meta_h: float | None = None
        self._multiaxis = False
        if program is not None:
            self._bead_shape(program)

    # Bead dimensions -----------------------------------------------------------

    def _bead_shape(self, program: Program) -> None:
        """Per-layer bead height from the program (meta first, else layer z spacing)."""
        meta = program.meta
        self._meta_w = float(meta["bead_width_mm"]) if "bead_width_mm" in meta else None
        self._meta_h = float(meta["layer_height_mm"]) if "layer_height_mm" in meta else None
        self._multiaxis = bool(meta.get("multiaxis", False))
        if self._multiaxis:                      # heights from the flow (module docstring): no layer spacing
            return
        dep = (program.op == MOVEL) & (program.flow_mm3_mm > 0) & (program.layer >= 0)
        if not dep.any():
            return
        layers, z = program.layer[dep], program.xyz_mm[dep, 2]
        n_layers = int(layers.max()) + 1
        # median nozzle z per layer (robust against the odd ramp), then spacing
        order = np.lexsort((z, layers))
        ls, zs = layers[order], z[order]
        first = np.searchsorted(ls, np.arange(n_layers), side="left")
        last = np.searchsorted(ls, np.arange(n_layers), side="right")
        present = last > first
        zl = np.full(n_layers, np.nan)
        zl[present] = zs[(first[present] + last[present] - 1) // 2]
        zl = _ffill(zl)
        h = np.diff(np.concatenate([[0.0], zl]))
        good = h > 0
        self._h_default = float(np.median(h[good])) if good.any() else 0.2
        self._layer_h = np.where(good, h, self._h_default)

    def dims(self, layer: np.ndarray, flow_mm3_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Width and height (mm) of beads on ``layer`` extruding ``flow_mm3_mm``."""
        layer = np.asarray(layer)
        if self._multiaxis:
            flow = np.broadcast_to(np.asarray(flow_mm3_mm, dtype=float), layer.shape)
            if self._meta_w is not None:
                h = height_for_flow_mm(self._meta_w, flow)
                # a flow more than a round bead of that width holds squeezes it wider: the volume is kept
                return np.maximum(self._meta_w, flow / np.maximum(h, 1e-12) + _K * h), h
            h = np.sqrt(np.maximum(flow, 0.0) / (BEAD_ASPECT_R - _K))
            return BEAD_ASPECT_R * h, h
        if self._meta_h is not None:
            h = np.full(layer.shape, self._meta_h)
        else:
            ok = (layer >= 0) & (layer < len(self._layer_h))
            h = np.where(ok, self._layer_h[np.clip(layer, 0, max(len(self._layer_h) - 1, 0))]
                         if len(self._layer_h) else self._h_default, self._h_default)
        if self._meta_w is not None:
            w = np.full(layer.shape, self._meta_w)
        else:
            w = np.maximum(flow_mm3_mm / h + h * (1.0 - np.pi / 4.0), h)
        return w, h

    # Recording -----------------------------------------------------------------------

    def _alloc(self, cap: int) -> None:
        new = {k: np.zeros((cap, *shape), dtype=np.int64 if k in ("row", "layer") else float)
               for k, shape in _FIELDS.items()}
        for k, arr in self._buf.items():
            new[k][: self._n] = arr[: self._n]
        self._buf = new

    def add(self, row: np.ndarray, layer: np.ndarray, start_mm: np.ndarray, end_mm: np.ndarray,
            volume_mm3: np.ndarray, flow_mm3_mm: np.ndarray, axis: np.ndarray | None = None) -> None:
        """Append beads (vectorised); dimensions follow from the layer and the flow per mm; ``axis`` (k, 3)
        is the nozzle axis each was laid with (default straight up)."""
        row = np.atleast_1d(np.asarray(row, dtype=np.int64))
        k = len(row)
        if k == 0:
            return
        volume_mm3 = np.broadcast_to(np.asarray(volume_mm3, dtype=float), (k,))
        if not np.all(np.isfinite(volume_mm3)) or np.any(volume_mm3 < 0):
            raise ValidationError("bead volume must be finite and >= 0", field="volume_mm3", row=int(row[0]))
        cap = len(self._buf["row"])
        if self._n + k > cap:
            self._alloc(max(2 * cap, self._n + k))
        w, h = self.dims(np.atleast_1d(layer), np.atleast_1d(flow_mm3_mm))
        sl = slice(self._n, self._n + k)
        for name, val in (("row", row), ("layer", layer), ("start_mm", start_mm), ("end_mm", end_mm),
                          ("volume_mm3", volume_mm3), ("width_mm", w), ("height_mm", h),
                          ("axis", UP if axis is None else axis)):
            self._buf[name][sl] = val
        self._n += k

    def __len__(self) -> int:
        return self._n

    def to_arrays(self, first: int = 0) -> dict[str, np.ndarray]:
        """Every bead field of beads ``first ..`` as an array (copies), for a snapshot or a checkpoint."""
        return {k: self._buf[k][first: self._n].copy() for k in _FIELDS}

    @classmethod
    def from_arrays(cls, program: Program | None, arrays: dict[str, np.ndarray]) -> Deposition:
        """The beads saved by :meth:`to_arrays`, for ``program`` (which sets the bead shape of new beads); beads
        saved without their nozzle axes (before multi-axis printing) were laid straight up."""
        n = len(arrays["row"]) if "row" in arrays else 0
        arrays = {**{k: np.tile(UP, (n, 1)) for k in OPTIONAL_FIELDS if k not in arrays}, **arrays}
        if set(arrays) != set(_FIELDS):
            raise ValidationError(f"bead arrays {sorted(arrays)}, expected {sorted(_FIELDS)}", field="beads")
        dep = cls(program)
        dep._alloc(max(256, n))
        for k, shape in _FIELDS.items():
            arr = np.asarray(arrays[k])
            if arr.shape != (n, *shape):
                raise ValidationError(f"bead field {k}: shape {arr.shape}, expected {(n, *shape)}", field="beads")
            dep._buf[k][:n] = arr
        dep._n = n
        return dep

    def __getattr__(self, name: str) -> np.ndarray:
        if name in _FIELDS:
            return self.__dict__["_buf"][name][: self.__dict__["_n"]]
        raise AttributeError(name)

    @property
    def total_volume_mm3(self) -> float:
        return float(np.sum(self.volume_mm3))

    # Mesh -----------------------------------------------------------------------------

    def mesh(self) -> trimesh.Trimesh:
        """The as-printed part: one closed octagonal prism per bead (plate frame, mm)."""
        if self._n == 0:
            raise ValidationError("nothing deposited yet", field="beads")
        a, b = self.start_mm, self.end_mm
        w, h = self.width_mm, self.height_mm
        _, side, up, columnar = bead_frames(b - a, self.axis)
        h_hang = np.where(columnar, 0.0, h)       # a bead laid along its own axis stands centred on the path
        # octagon (counter-clockwise in the side/up plane): the w x h box with chamfered corners
        W, H, C = 0.5 * w[:, None], 0.5 * h[:, None], _CHAMFER * h[:, None]
        px = np.concatenate([W, W, W - C, C - W, -W, -W, C - W, W - C], axis=1)
        py = np.concatenate([C - H, H - C, H, H, H - C, C - H, -H, -H], axis=1)
        centre_a = a - 0.5 * h_hang[:, None] * up
        centre_b = b - 0.5 * h_hang[:, None] * up
        ring = px[..., None] * side[:, None, :] + py[..., None] * up[:, None, :]   # (n, 8, 3)
        verts = np.concatenate([centre_a[:, None] + ring, centre_b[:, None] + ring], axis=1)  # (n, 16, 3)
        faces = _prism_faces()
        n = self._n
        all_faces = (faces[None] + 16 * np.arange(n)[:, None, None]).reshape(-1, 3)
        return trimesh.Trimesh(vertices=verts.reshape(-1, 3), faces=all_faces, process=False)

    def export_mesh(self, fmt: str = "stl") -> bytes:
        """The as-printed mesh as ``stl`` (binary) or ``glb`` bytes."""
        fmt = fmt.lower()
        if fmt not in ("stl", "glb"):
            raise ValidationError(f"mesh format {fmt!r}: use 'stl' or 'glb'", field="fmt")
        data = self.mesh().export(file_type=fmt)
        assert isinstance(data, bytes), "trimesh writes binary STL and GLB as bytes"
        return data

    def export_csv(self) -> bytes:
        """The bead list, one row per bead in deposition order (plate frame; full precision)."""
        head = "x0_mm,y0_mm,z0_mm,x1_mm,y1_mm,z1_mm,volume_mm3\n"
        rows = np.column_stack([self.start_mm, self.end_mm, self.volume_mm3])
        buf = io.StringIO()
        buf.write(head)
        np.savetxt(buf, rows, fmt="%.17g", delimiter=",")
        return buf.getvalue().encode()

    def volume_report(self, model_volume_mm3: float) -> VolumeReport:
        """Extruded volume vs the model's (ratio = extruded / model)."""
        if not np.isfinite(model_volume_mm3) or model_volume_mm3 <= 0:
            raise ValidationError("model volume must be > 0", field="model_volume_mm3")
        mesh_mm3 = float(np.sum(bead_area_mm2(self.width_mm, self.height_mm)
                                * np.linalg.norm(self.end_mm - self.start_mm, axis=1)))
        ext = self.total_volume_mm3
        return VolumeReport(ext, float(model_volume_mm3), ext / model_volume_mm3, self._n, mesh_mm3)


def _prism_faces() -> np.ndarray:
    """Triangles (28, 3) of an octagonal prism: ring 0..7 at the start, 8..15 at the end, outward normals."""
    k = np.arange(8)
    k1 = (k + 1) % 8
    sides = np.concatenate([np.stack([k, k1 + 8, k1], 1), np.stack([k, k + 8, k1 + 8], 1)])
    fan = np.arange(1, 7)
    cap_a = np.stack([np.zeros(6, int), fan, fan + 1], 1)
    cap_b = np.stack([np.full(6, 8), fan + 9, fan + 8], 1)
    return np.concatenate([sides, cap_a, cap_b]).astype(np.int64)


def _ffill(a: np.ndarray) -> np.ndarray:
    """Forward-fill NaNs (leading NaNs take the first value)."""
    idx = np.where(np.isnan(a), 0, np.arange(len(a)))
    np.maximum.accumulate(idx, out=idx)
    out = a[idx]
    if np.isnan(out).any():
        first = out[~np.isnan(out)]
        out = np.where(np.isnan(out), first[0] if len(first) else 0.0, out)
    return out
