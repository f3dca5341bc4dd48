"""A minimal 3MF reader (core spec: meshes, components, build items, units) on the stdlib.

3MF is a zip holding ``3D/3dmodel.model``, an XML document of ``<object>``s
that are either a ``<mesh>`` (vertices + triangles) or ``<components>``
(references to other objects with a 3x4 affine ``transform``). The ``<build>``
lists the items to print, each with its own transform. The result is every
build item's triangles flattened into one vertex/face array, in millimetres.
"""
from __future__ import annotations

import io
import xml.etree.ElementTree as ET
import zipfile

import numpy as np

from fabric.wire.errors import MeshError

__all__ = ["read_3mf"]

_UNITS_MM = {"micron": 1e-3, "millimeter": 1.0, "centimeter": 10.0, "inch": 25.4,
             "foot": 304.8, "meter": 1000.0}


def _tag(element: ET.Element) -> str:
    return element.tag.rsplit("}", 1)[-1]


def _transform(text: str | None) -> np.ndarray:
    """3MF's 12 numbers (column-major 3x4, row vectors) as a 4x4 matrix for column vectors."""
    m = np.eye(4)
    if text:
        values = np.array(text.split(), dtype=np.float64)
        if values.size != 12:
            raise ValueError(f"transform needs 12 numbers, got {values.size}")
        m[:3, :4] = values.reshape(4, 3).T
    return m


def read_3mf(data: bytes, filename: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) mm and faces (m, 3) of all build items of a 3MF file."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            names = [n for n in archive.namelist() if n.lower().endswith(".model")]
            if not names:
                raise MeshError(f"{filename}: 3MF archive has no .model part", file=filename, reason="format")
            main = next((n for n in names if n.lower() == "3d/3dmodel.model"), names[0])
            root = ET.fromstring(archive.read(main))
    except (zipfile.BadZipFile, EOFError) as exc:
        raise MeshError(f"{filename}: not a 3MF (zip) file or truncated: {exc}", file=filename,
                        reason="truncated") from None
    except ET.ParseError as exc:
        raise MeshError(f"{filename}: 3MF model XML is malformed: {exc}", file=filename,
                        reason="format") from None
    scale = _UNITS_MM.get(root.get("unit", "millimeter"), 1.0)
    try:
        objects = {oid: obj for obj in root.iter() if _tag(obj) == "object" and (oid := obj.get("id")) is not None}
        build = [item for item in root.iter() if _tag(item) == "item"]
        if not build:  # no build section: print every object once
            build = [ET.Element("item", objectid=oid) for oid in objects]
        vertices: list[np.ndarray] = []
        faces: list[np.ndarray] = []
        count = 0

        def emit(oid: str | None, matrix: np.ndarray, depth: int) -> None:
            nonlocal count
            if depth > 16 or oid not in objects:
                raise ValueError(f"object {oid!r} is missing or nested too deeply")
            for child in objects[oid]:
                kind = _tag(child)
                if kind == "mesh":
                    v, f = _mesh_arrays(child)
                    v = v @ matrix[:3, :3].T + matrix[:3, 3]
                    vertices.append(v)
                    faces.append(f + count)
                    count += len(v)
                elif kind == "components":
                    for comp in child:
                        emit(comp.get("objectid"), matrix @ _transform(comp.get("transform")), depth + 1)

        for item in build:
            emit(item.get("objectid"), _transform(item.get("transform")), 0)
    except (ValueError, IndexError, TypeError) as exc:
        raise MeshError(f"{filename}: invalid 3MF content: {exc}", file=filename, reason="format") from None
    if not faces or sum(len(f) for f in faces) == 0:
        raise MeshError(f"{filename}: 3MF has no triangles", file=filename, reason="empty")
    return np.vstack(vertices) * scale, np.vstack(faces)


def _mesh_arrays(mesh: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    """The vertex and triangle arrays of one ``<mesh>`` element."""
    v = np.array([(float(e.get("x")), float(e.get("y")), float(e.get("z")))  # type: ignore[arg-type]
                  for part in mesh if _tag(part) == "vertices" for e in part], dtype=np.float64)
    f = np.array([(int(e.get("v1")), int(e.get("v2")), int(e.get("v3")))  # type: ignore[arg-type]
                  for part in mesh if _tag(part) == "triangles" for e in part], dtype=np.int64)
    v = v.reshape(-1, 3)
    f = f.reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("triangle refers to a vertex that does not exist")
    return v, f
