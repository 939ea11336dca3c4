"""Triangle meshes from PLY and OBJ files, for the scene's ``mesh`` shape (``file = ...``).

    mesh = read_mesh_file(Path("bunny.ply"))   # MeshData: positions, indices, normals

PLY (ASCII or binary) is read with plyfile: a small, well-kept reader (numpy its only
dependency) that hands over the file's elements and properties as they are, so per-vertex
normals (nx, ny, nz) are used exactly when the file has them. trimesh was tried first: it loads
both formats, but without processing it does not say whether the normals came from the file or
were computed, and it is a much larger package. OBJ is a simple text format: the reader below
takes ``v`` positions, ``vn`` normals and ``f`` faces (``i``, ``i/t``, ``i//n``, ``i/t/n``;
negative indices count back from the end), polygons split into triangle fans, and ignores
everything else (texture coordinates, groups, materials, smoothing). A vertex whose corners have
different normals becomes one vertex per (position, normal) pair. Faces with normals on some
corners and not on others are refused.

Every problem is a `MeshFileError` (a ValueError) with a one-line message naming the path;
scene.py turns it into a SceneError naming the shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


class MeshFileError(ValueError):
    """A mesh file cannot be read: the message names the file and what is wrong."""


@dataclass
class MeshData:
    """A triangle mesh: positions (V, 3) float64, indices (T, 3) int64 (counter-clockwise
    front side), normals (V, 3) float64 or None."""

    positions: np.ndarray
    indices: np.ndarray
    normals: np.ndarray | None


MESH_SUFFIXES = (".ply", ".obj")


def read_mesh_file(path: Path) -> MeshData:
    """The triangle mesh in a PLY or OBJ file (by its suffix)."""
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshFileError(
            f"{path}: unknown mesh file type {path.suffix!r}; accepted: {', '.join(MESH_SUFFIXES)}"
        )
    try:
        data = path.read_bytes()
    except OSError as err:
        raise MeshFileError(f"{path}: cannot read: {err.strerror}") from None
    mesh = read_ply(path, data) if suffix == ".ply" else read_obj(path, data)
    if len(mesh.indices) == 0:
        raise MeshFileError(f"{path}: the file has no triangles")
    return mesh


def read_ply(path: Path, data: bytes) -> MeshData:
    """A PLY file's vertex x, y, z (and nx, ny, nz if all present) and its faces'
    vertex_indices (or vertex_index) lists, polygons split into fans."""
    import io

    from plyfile import PlyData

    try:
        ply = PlyData.read(io.BytesIO(data))
    except Exception as err:  # plyfile raises several types for malformed files
        raise MeshFileError(f"{path}: not a readable PLY file: {err}") from None
    names = [element.name for element in ply.elements]
    if "vertex" not in names:
        raise MeshFileError(f"{path}: no 'vertex' element (elements: {', '.join(names)})")
    vertex = ply["vertex"].data
    fields = vertex.dtype.names or ()
    if not all(axis in fields for axis in "xyz"):
        raise MeshFileError(f"{path}: vertices lack x, y, z (properties: {', '.join(fields)})")
    positions = np.stack([vertex[axis] for axis in "xyz"], axis=1).astype(np.float64)
    normals = None
    if all(name in fields for name in ("nx", "ny", "nz")):
        normals = np.stack([vertex[name] for name in ("nx", "ny", "nz")], axis=1)
        normals = normals.astype(np.float64)
    if "face" not in names:
        raise MeshFileError(f"{path}: the file has no triangles (no 'face' element)")
    face = ply["face"].data
    key = next(
        (k for k in ("vertex_indices", "vertex_index") if k in (face.dtype.names or ())), None
    )
    if key is None:
        raise MeshFileError(f"{path}: faces lack a vertex_indices list")
    indices = _fans([np.asarray(polygon, np.int64) for polygon in face[key]], path)
    return MeshData(positions, indices, normals)


def _fans(polygons: list[np.ndarray], path: Path) -> np.ndarray:
    """Triangle fans (v0, v[i], v[i + 1]) of polygons of 3 or more vertices, as (T, 3)."""
    if not polygons:
        return np.zeros((0, 3), np.int64)
    sizes = np.array([len(polygon) for polygon in polygons])
    if sizes.min() < 3:
        face = int(np.argmin(sizes))
        raise MeshFileError(f"{path}: face {face} has {sizes[face]} vertices (at least 3)")
    flat = np.concatenate(polygons)
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    fan_count = sizes - 2
    fan_first = np.repeat(first, fan_count)
    step = np.arange(int(fan_count.sum())) - np.repeat(np.cumsum(fan_count) - fan_count, fan_count)
    return np.stack([flat[fan_first], flat[fan_first + step + 1], flat[fan_first + step + 2]], 1)


def read_obj(path: Path, data: bytes) -> MeshData:
    """An OBJ file's v, vn and f statements (see the module docstring)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise MeshFileError(f"{path}: not UTF-8 text (offset {err.start})") from None
    positions: list[list[float]] = []
    normals: list[list[float]] = []
    corners: list[tuple[int, int]] = []  # (position, normal or -1) of each polygon corner
    polygon_sizes: list[int] = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        try:
            if words[0] == "v":
                positions.append([float(w) for w in words[1:4]])
                if len(positions[-1]) != 3:
                    raise ValueError("a vertex needs x y z")
            elif words[0] == "vn":
                normals.append([float(w) for w in words[1:4]])
                if len(normals[-1]) != 3:
                    raise ValueError("a normal needs x y z")
            elif words[0] == "f":
                if len(words) < 4:
                    raise ValueError("a face needs at least 3 vertices")
                for word in words[1:]:
                    parts = word.split("/")
                    v = _obj_index(parts[0], len(positions))
                    n = _obj_index(parts[2], len(normals)) if len(parts) > 2 and parts[2] else -1
                    corners.append((v, n))
                polygon_sizes.append(len(words) - 1)
        except ValueError as err:
            raise MeshFileError(f"{path}: line {number}: {err}: {line.strip()[:60]!r}") from None
    if not polygon_sizes:
        raise MeshFileError(f"{path}: the file has no triangles (no 'f' statements)")
    pairs = np.array(corners, np.int64)
    has_normal = pairs[:, 1] >= 0
    if has_normal.any() and not has_normal.all():
        raise MeshFileError(f"{path}: some face corners have normals (f v//n) and some not")
    position_array = np.array(positions, np.float64).reshape(-1, 3)
    normal_array = None
    if has_normal.all():
        # One vertex per distinct (position, normal) pair, in order of first use
        unique, first_use, corner_vertex = np.unique(
            pairs, axis=0, return_index=True, return_inverse=True
        )
        order = np.argsort(first_use, kind="stable")
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        corner_vertex = rank[corner_vertex.reshape(-1)]
        unique = unique[order]
        position_array = position_array[unique[:, 0]]
        normal_array = np.array(normals, np.float64).reshape(-1, 3)[unique[:, 1]]
    else:
        corner_vertex = pairs[:, 0]
    offsets = np.concatenate([[0], np.cumsum(polygon_sizes)[:-1]])
    polygons = [corner_vertex[o : o + s] for o, s in zip(offsets, polygon_sizes, strict=True)]
    return MeshData(position_array, _fans(polygons, path), normal_array)


def _obj_index(word: str, count: int) -> int:
    """A 0-based index from an OBJ 1-based (or negative, relative) index."""
    index = int(word)
    if index > 0 and index <= count:
        return index - 1
    if index < 0 and -index <= count:
        return count + index
    raise ValueError(f"index {index} refers to none of the {count} defined so far")
