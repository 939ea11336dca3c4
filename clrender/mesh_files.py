"""Triangle meshes from PLY and OBJ files, for the scene's ``mesh`` shape (``file = ...``).

    mesh = read_mesh_file(Path("bunny.ply"))   # MeshData: positions, indices, normals

PLY (ASCII or binary) is read with plyfile: a small, well-kept reader (numpy its only
dependency) that hands over the file's elements and properties as they are, so per-vertex
normals (nx, ny, nz) are used exactly when the file has them. trimesh was tried first: it loads
both formats, but without processing it does not say whether the normals came from the file or
were computed, and it is a much larger package. OBJ is a simple text format: the reader below
takes ``v`` positions, ``vn`` normals and ``f`` faces (``i``, ``i/t``, ``i//n``, ``i/t/n``;
negative indices count back from the end), polygons split into triangle fans, and ignores
everything else (texture coordinates, groups, materials, smoothing); a line ending in a
backslash continues on the next. A vertex whose corners have different normals becomes one
vertex per (position, normal) pair. Faces with normals on some corners and not on others are
refused, and so is a vertex position or normal that is not finite (naming the vertex).

Large files without Python work per line: a binary PLY file whose faces are all triangles is
memory-mapped as arrays (plyfile's known_list_len); an ASCII PLY file of vertices then faces
(one record a line, nothing else) is parsed as two blocks of numbers in NumPy; an OBJ file in
the regular form exporters write (no indented lines, one face form throughout, indices to
elements defined before) is parsed by whole byte columns in NumPy, any other OBJ file line by
line (which also names the line of an error). Any other PLY file is read by plyfile, record by
record. On 1 M random triangles (500 k vertices), `python bench/mesh_file_speed.py`: binary PLY
0.06 s (plyfile face by face 7.2 s), ASCII PLY 1.5 s (plyfile 15.9 s), OBJ 1.9 s (line by line
4.8 s).

Every problem is a `MeshFileError` (a ValueError) with a one-line message naming the path;
scene.py turns it into a SceneError naming the shape.
"""

from __future__ import annotations

import warnings
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
        mesh = read_ply(path) if suffix == ".ply" else read_obj(path, path.read_bytes())
    except OSError as err:
        raise MeshFileError(f"{path}: cannot read: {err.strerror}") from None
    if len(mesh.indices) == 0:
        raise MeshFileError(f"{path}: the file has no triangles")
    return mesh


# Face list properties plyfile may map from a binary file as (faces, 3) arrays at once
TRIANGLE_LISTS = {"face": {"vertex_indices": 3, "vertex_index": 3}}


def read_ply(path: Path) -> MeshData:
    """A PLY file's vertex x, y, z (and nx, ny, nz if all present) and its faces'
    vertex_indices (or vertex_index) lists, polygons split into fans. A binary file whose faces
    are all triangles is memory-mapped as arrays (plyfile's known_list_len, which checks every
    face's length); other files are read face by face by plyfile."""
    from plyfile import PlyData, PlyElementParseError

    with open(path, "rb") as stream:
        ascii_file = stream.read(64).startswith(ASCII_PLY_START)
    if ascii_file:
        blocks = ascii_ply_blocks(path.read_bytes())
        if blocks is not None:
            vertex, corners, sizes = blocks
            return _ply_mesh(path, vertex, ["vertex", "face"], corners, sizes)
    try:
        try:
            ply = PlyData.read(str(path), known_list_len=TRIANGLE_LISTS)
        except PlyElementParseError as err:
            if "unexpected list length" not in str(err):
                raise
            ply = PlyData.read(str(path), mmap=False)
    except OSError:
        raise
    except Exception as err:  # plyfile raises several types for malformed files
        raise MeshFileError(f"{path}: not a readable PLY file: {err}") from None
    names = [element.name for element in ply.elements]
    if "vertex" not in names:
        raise MeshFileError(f"{path}: no 'vertex' element (elements: {', '.join(names)})")
    if "face" not in names:
        raise MeshFileError(f"{path}: the file has no triangles (no 'face' element)")
    face = ply["face"].data
    key = next(
        (k for k in ("vertex_indices", "vertex_index") if k in (face.dtype.names or ())), None
    )
    if key is None:
        raise MeshFileError(f"{path}: faces lack a vertex_indices list")
    lists = face[key]
    if lists.dtype != object:  # memory-mapped triangles: (faces, 3)
        corners = np.asarray(lists, np.int64).reshape(-1)
        sizes = np.full(len(lists), 3, np.int64)
    else:
        sizes = np.fromiter(map(len, lists), np.int64, len(lists))
        corners = np.concatenate(lists).astype(np.int64) if len(lists) else np.zeros(0, np.int64)
    return _ply_mesh(path, ply["vertex"].data, names, corners, sizes)


def _ply_mesh(path: Path, vertex: np.ndarray, names: list[str], corners, sizes) -> MeshData:
    """The mesh of a PLY file's vertex records (x, y, z, and nx, ny, nz if all present) and its
    faces' corners (sizes[k] of them for face k)."""
    fields = vertex.dtype.names or ()
    if not all(axis in fields for axis in "xyz"):
        raise MeshFileError(f"{path}: vertices lack x, y, z (properties: {', '.join(fields)})")
    positions = np.stack([vertex[axis] for axis in "xyz"], axis=1).astype(np.float64)
    normals = None
    if all(name in fields for name in ("nx", "ny", "nz")):
        normals = np.stack([vertex[name] for name in ("nx", "ny", "nz")], axis=1)
        normals = normals.astype(np.float64)
    check_finite(path, positions, normals)
    return MeshData(positions, _fans(corners, sizes, path), normals)


def check_finite(path: Path, positions: np.ndarray, normals: np.ndarray | None) -> None:
    """MeshFileError naming the first vertex (its 0-based number in the file) whose position
    or normal has a NaN or infinity."""
    for values, what in ((positions, "position"), (normals, "normal")):
        if values is None:
            continue
        bad = ~np.isfinite(values).all(axis=1)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise MeshFileError(
                f"{path}: vertex {row} has a non-finite {what}: {values[row].tolist()}"
            )


ASCII_PLY_START = b"ply\nformat ascii 1.0\n"
# PLY scalar types as NumPy's (plyfile's names and the PLY 1.0 specification's)
PLY_SCALARS = {
    **dict.fromkeys(("char", "int8"), "i1"),
    **dict.fromkeys(("uchar", "uint8"), "u1"),
    **dict.fromkeys(("short", "int16"), "i2"),
    **dict.fromkeys(("ushort", "uint16"), "u2"),
    **dict.fromkeys(("int", "int32"), "i4"),
    **dict.fromkeys(("uint", "uint32"), "u4"),
    **dict.fromkeys(("float", "float32"), "f4"),
    **dict.fromkeys(("double", "float64"), "f8"),
}


def ascii_ply_blocks(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """An ASCII PLY file made of a vertex element of scalar properties, then a face element
    whose one property is its vertex index list, each record on a line of its own: read as two
    blocks of numbers in NumPy (no Python work per line). (vertex records with the declared
    types, the faces' corners, corners per face), or None for any other file (plyfile then
    reads it, and words any error)."""
    end = data.find(b"end_header\n")
    if end < 0 or data[end - 1 : end] != b"\n":
        return None
    header = data[:end].decode("ascii", "replace").split("\n")[2:-1]
    elements: list[tuple[str, int, list[list[str]]]] = []
    for line in header:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
        else:
            return None
    if [name for name, _, _ in elements] != ["vertex", "face"]:
        return None
    (_, vertex_count, vertex_properties), (_, face_count, face_properties) = elements
    if vertex_count == 0 or face_count == 0:
        return None
    if not all(len(p) == 2 and p[0] in PLY_SCALARS for p in vertex_properties):
        return None
    if not (
        len(face_properties) == 1
        and len(face_properties[0]) == 4
        and face_properties[0][0] == "list"
        and face_properties[0][3] in ("vertex_indices", "vertex_index")
    ):
        return None
    text = np.frombuffer(data, np.uint8)[end + len(b"end_header\n") :]
    line_end = np.flatnonzero(text == ord("\n"))
    records = vertex_count + face_count
    if len(line_end) < records or not BLANK_BYTES[text[line_end[records - 1] :]].all():
        return None  # fewer lines, or text after the faces
    vertex_end = line_end[vertex_count - 1] + 1
    blocks = (text[:vertex_end], text[vertex_end : line_end[records - 1] + 1])
    word_counts = []
    for block, lines in zip(blocks, (vertex_count, face_count), strict=True):
        blank = BLANK_BYTES[block]
        starts = np.flatnonzero(~blank & np.r_[True, blank[:-1]])
        line = np.searchsorted(np.flatnonzero(block == ord("\n")), starts)
        word_counts.append(np.bincount(line, minlength=lines))
    if len(word_counts[0]) != vertex_count or len(word_counts[1]) != face_count:
        return None
    if (word_counts[0] != len(vertex_properties)).any():
        return None
    try:
        with warnings.catch_warnings():  # text that is not all numbers (see regular_obj_...)
            warnings.simplefilter("error", DeprecationWarning)
            values = np.fromstring(blocks[0].tobytes() + b" 0", np.float64, sep=" ")[:-1]
            face_words = np.fromstring(blocks[1].tobytes() + b" 0", np.int64, sep=" ")[:-1]
    except (ValueError, DeprecationWarning):
        return None
    if len(values) != vertex_count * len(vertex_properties):
        return None
    if len(face_words) != word_counts[1].sum():
        return None
    first = np.cumsum(word_counts[1]) - word_counts[1]
    sizes = face_words[first]
    if (sizes != word_counts[1] - 1).any():
        return None
    is_corner = np.ones(len(face_words), bool)
    is_corner[first] = False
    dtype = np.dtype([(name, PLY_SCALARS[kind]) for kind, name in vertex_properties])
    vertex = np.empty(vertex_count, dtype)
    columns = values.reshape(vertex_count, len(vertex_properties))
    for k, name in enumerate(dtype.names):
        vertex[name] = columns[:, k]
    return vertex, face_words[is_corner], sizes


def _fans(corners: np.ndarray, sizes: np.ndarray, path: Path) -> np.ndarray:
    """Triangle fans (v0, v[i], v[i + 1]) of polygons of 3 or more vertices, as (T, 3): the
    polygons' corners one after another in `corners`, sizes[k] of them for polygon k."""
    if len(sizes) == 0:
        return np.zeros((0, 3), np.int64)
    if sizes.min() < 3:
        face = int(np.argmin(sizes))
        raise MeshFileError(f"{path}: face {face} has {sizes[face]} vertices (at least 3)")
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    fan_count = sizes - 2
    fan_first = np.repeat(first, fan_count)
    step = np.arange(int(fan_count.sum())) - np.repeat(np.cumsum(fan_count) - fan_count, fan_count)
    return np.stack(
        [corners[fan_first], corners[fan_first + step + 1], corners[fan_first + step + 2]], 1
    )


@dataclass
class ObjStatements:
    """What an OBJ file defines: positions (V, 3), normals (N, 3) or None, each polygon
    corner's (position, normal or -1) as 0-based indices (C, 2), corners per polygon (P,)."""

    positions: np.ndarray
    normals: np.ndarray | None
    corners: np.ndarray
    sizes: np.ndarray


def read_obj(path: Path, data: bytes) -> MeshData:
    """An OBJ file's v, vn and f statements (see the module docstring): read at once by
    regular_obj_statements, or, for a file it does not take, line by line (which names the
    line of any error)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise MeshFileError(f"{path}: not UTF-8 text (offset {err.start})") from None
    statements = regular_obj_statements(data) or obj_statements_by_line(path, text)
    check_finite(path, statements.positions, statements.normals)
    if len(statements.sizes) == 0:
        raise MeshFileError(f"{path}: the file has no triangles (no 'f' statements)")
    pairs = statements.corners
    has_normal = pairs[:, 1] >= 0
    if has_normal.any() and not has_normal.all():
        raise MeshFileError(f"{path}: some face corners have normals (f v//n) and some not")
    positions = statements.positions
    normals = None
    if has_normal.all():
        # One vertex per distinct (position, normal) pair, in order of first use
        key = pairs[:, 0] * (len(statements.normals) + 1) + pairs[:, 1]
        unique, first_use, corner_vertex = np.unique(key, return_index=True, return_inverse=True)
        order = np.argsort(first_use, kind="stable")
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        corner_vertex = rank[corner_vertex.reshape(-1)]
        used = pairs[first_use[order]]
        positions = positions[used[:, 0]]
        normals = statements.normals[used[:, 1]]
    else:
        corner_vertex = pairs[:, 0]
    return MeshData(positions, _fans(corner_vertex, statements.sizes, path), normals)


# Bytes that separate words in OBJ text
BLANK_BYTES = np.zeros(256, bool)
BLANK_BYTES[list(b" \t\r\n\v\f")] = True


def regular_obj_statements(data: bytes) -> ObjStatements | None:
    """The statements of an OBJ file in which every v and vn has 3 or more numbers and every
    face 3 or more corners, all of one form (i, i/t, i//n or i/t/n), each index referring to an
    element defined before its line: parsed by whole columns of bytes in NumPy (no Python work
    per line or number). None for any other file: obj_statements_by_line then reads it, or
    names the line of its error."""
    text = np.frombuffer(data + b"\n  ", np.uint8)
    line_end = np.flatnonzero(text == ord("\n"))
    line_start = np.r_[0, line_end[:-1] + 1]
    blank = BLANK_BYTES[text]
    if b"#" in data:  # a comment runs from # to the end of its line
        hashes = np.flatnonzero(text == ord("#"))
        line = np.searchsorted(line_end, hashes)
        first = hashes[np.r_[True, line[1:] != line[:-1]]]
        inside = np.zeros(len(text) + 1, np.int8)
        inside[first] = 1
        inside[line_end[np.unique(line)]] = -1
        blank |= np.cumsum(inside[:-1], dtype=np.int8) > 0
    # Each line's keyword: its first bytes (a line that starts with a blank other than its end
    # is left to the line reader)
    first_byte = text[line_start]
    empty = (line_start == line_end) | (first_byte == ord("#"))
    empty |= (first_byte == ord("\r")) & (line_end == line_start + 1)
    if BLANK_BYTES[first_byte[~empty]].any():
        return None
    keyword_at, line_end = line_start[~empty], line_end[~empty]
    c0, c1, c2 = text[keyword_at], text[keyword_at + 1], text[keyword_at + 2]
    kinds = {
        "v": (c0 == ord("v")) & BLANK_BYTES[c1],
        "vn": (c0 == ord("v")) & (c1 == ord("n")) & BLANK_BYTES[c2],
        "f": (c0 == ord("f")) & BLANK_BYTES[c1],
    }

    def statement_words(kind: str) -> tuple[np.ndarray, np.ndarray]:
        """The bytes of the kind's lines after their keyword (every other byte blank) and the
        number of words on each of those lines."""
        if not kinds[kind].any():
            return np.full(1, ord(" "), np.uint8), np.zeros(0, np.int64)
        keep = np.zeros(len(text) + 1, np.int8)
        keep[keyword_at[kinds[kind]] + len(kind)] = 1
        keep[line_end[kinds[kind]]] = -1
        body = np.where((np.cumsum(keep[:-1], dtype=np.int8) > 0) & ~blank, text, ord(" "))
        starts = np.flatnonzero((body[1:] != ord(" ")) & (body[:-1] == ord(" "))) + 1
        line = np.searchsorted(line_end[kinds[kind]], starts)
        return body, np.bincount(line, minlength=int(kinds[kind].sum()))

    def numbers(body: np.ndarray, dtype, count: int) -> np.ndarray:
        if count == 0:  # (NumPy parses a blank string as one number)
            return np.zeros(0, dtype)
        # Text that is not all numbers raises: ValueError (NumPy 2), DeprecationWarning before
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            return np.fromstring(body.tobytes(), dtype=dtype, sep=" ")

    try:
        vectors = {}
        for kind in ("v", "vn"):
            body, counts = statement_words(kind)
            values = numbers(body, np.float64, int(counts.sum()))
            if len(counts) and counts.min() < 3 or len(values) != counts.sum():
                return None
            first = np.cumsum(counts) - counts  # v x y z [more]: the first three
            vectors[kind] = values[first[:, None] + np.arange(3)].reshape(-1, 3)
        body, sizes = statement_words("f")
        if len(sizes) and sizes.min() < 3:
            return None
        corner_count = int(sizes.sum())
        slash = body == ord("/")
        slashes = int(slash.sum())
        double = int((slash[1:] & slash[:-1]).sum())
        fields, normal_field = {
            (0, 0): (1, None),
            (corner_count, 0): (2, None),  # i/t
            (2 * corner_count, corner_count): (2, 1),  # i//n
            (2 * corner_count, 0): (3, 2),  # i/t/n
        }.get((slashes, double), (0, None))
        if fields == 0:
            return None
        body[slash] = ord(" ")
        indices = numbers(body, np.int64, corner_count)
    except (ValueError, DeprecationWarning):
        return None
    if len(indices) != fields * corner_count:
        return None
    indices = indices.reshape(corner_count, fields)
    # Indices are 1-based, or negative: counted back from the last element defined before the line
    corner_line = np.repeat(np.flatnonzero(kinds["f"]), sizes)
    resolved = []
    for field, kind in ((0, "v"), (normal_field, "vn")):
        if field is None:
            resolved.append(np.full(corner_count, -1, np.int64))
            continue
        index = indices[:, field]
        defined = np.cumsum(kinds[kind])[corner_line]
        zero_based = np.where(index > 0, index - 1, defined + index)
        if not ((index != 0) & (zero_based >= 0) & (zero_based < defined)).all():
            return None
        resolved.append(zero_based)
    normals = vectors["vn"] if len(vectors["vn"]) else None
    return ObjStatements(vectors["v"], normals, np.stack(resolved, 1), sizes)


def obj_statements_by_line(path: Path, text: str) -> ObjStatements:
    """The statements of an OBJ file read line by line: the reader of any file
    regular_obj_statements does not take, and the one that names the line of an error."""
    positions: list[list[float]] = []
    normals: list[list[float]] = []
    corners: list[tuple[int, int]] = []  # (position, normal or -1) of each polygon corner
    polygon_sizes: list[int] = []
    for number, line in obj_lines(text):
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
    return ObjStatements(
        np.array(positions, np.float64).reshape(-1, 3),
        np.array(normals, np.float64).reshape(-1, 3) if normals else None,
        np.array(corners, np.int64).reshape(-1, 2),
        np.array(polygon_sizes, np.int64),
    )


def obj_lines(text: str):
    """(number of its first line, statement) of each OBJ statement: a line ending in a
    backslash continues on the next (the OBJ specification's line continuation)."""
    pending, first = "", 0
    for number, line in enumerate(text.splitlines(), 1):
        if not pending:
            first = number
        stripped = line.rstrip()
        if stripped.endswith("\\") and "#" not in stripped:
            pending += stripped[:-1] + " "
            continue
        yield first, pending + line
        pending = ""
    if pending:
        yield first, pending


def _obj_index(word: str, count: int) -> int:
    """A 0-based index from an OBJ 1-based (or negative, relative) index."""
    index = int(word)
    if index > 0 and index <= count:
        return index - 1
    if index < 0 and -index <= count:
        return count + index
    raise ValueError(f"index {index} refers to none of the {count} defined so far")
