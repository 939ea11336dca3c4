"""The mesh file readers' fast paths (clrender/mesh_files.py) against their general readers:
OBJ text parsed by whole byte columns against the line-by-line reader, binary PLY files of
triangles memory-mapped and ASCII PLY files parsed in two blocks against plyfile's
record-by-record reading, on random files of every statement form the readers accept."""

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from clrender.mesh_files import (
    MeshFileError,
    ascii_ply_blocks,
    obj_statements_by_line,
    read_mesh_file,
    read_ply,
    regular_obj_statements,
)


def random_obj(rng, forms=("i", "i/t", "i//n", "i/t/n"), crlf=False) -> str:
    """An OBJ text of random v, vn, vt and f statements (faces of 3-6 corners, positive and
    negative indices to elements defined before the face), comments, blank and ignored lines."""
    form = forms[rng.integers(len(forms))]
    lines, positions, normals = ["# a random mesh", "o thing", ""], 0, 0
    for _ in range(60):
        kind = rng.choice(["v", "v", "vn", "vt", "f", "f", "g", "blank"])
        if kind == "v":
            extra = " 0.5 0.5 0.5" if rng.random() < 0.2 else ""  # vertex colours: ignored
            lines.append("v " + " ".join(f"{x:.6g}" for x in rng.normal(size=3)) + extra)
            positions += 1
        elif kind == "vn":
            lines.append("vn " + " ".join(f"{x:.6g}" for x in rng.normal(size=3)))
            normals += 1
        elif kind == "vt":
            lines.append("vt 0.25 0.75")
        elif kind == "g":
            lines.append("g part  # group")
        elif kind == "blank":
            lines.append("   " if rng.random() < 0.5 else "")
        elif positions >= 1 and (normals >= 1 or "n" not in form):
            corners = []
            for _ in range(rng.integers(3, 7)):
                v = rng.integers(1, positions + 1)
                v = v if rng.random() < 0.7 else v - positions - 1  # negative: from the end
                n = rng.integers(1, normals + 1) if normals else 0
                n = n if rng.random() < 0.7 else n - normals - 1
                corners.append(
                    {"i": f"{v}", "i/t": f"{v}/1", "i//n": f"{v}//{n}", "i/t/n": f"{v}/1/{n}"}[form]
                )
            lines.append("f " + "\t".join(corners) + (" # face" if rng.random() < 0.2 else ""))
    return ("\r\n" if crlf else "\n").join(lines) + "\n"


def same_statements(a, b) -> None:
    np.testing.assert_array_equal(a.positions, b.positions)
    assert (a.normals is None) == (b.normals is None)
    if a.normals is not None:
        np.testing.assert_array_equal(a.normals, b.normals)
    np.testing.assert_array_equal(a.corners, b.corners)
    np.testing.assert_array_equal(a.sizes, b.sizes)


@pytest.mark.parametrize("seed", range(40))
def test_regular_obj_reader_equals_line_reader(seed):
    rng = np.random.default_rng(seed)
    text = random_obj(rng, crlf=seed % 5 == 0)
    fast = regular_obj_statements(text.encode())
    if "   \n" in text or "   \r\n" in text:
        # Lines starting with a blank go to the line reader
        assert fast is None
        text = text.replace("   \r\n", "\r\n").replace("   \n", "\n")
        fast = regular_obj_statements(text.encode())
    assert fast is not None
    same_statements(fast, obj_statements_by_line("random.obj", text))


IRREGULAR = {
    "forward reference": "v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n",
    "index zero": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
    "two forms": "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2/1 3\n",
    "empty normal": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/ 2/1/ 3/1/\n",
    "short vertex": "v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "not a number": "v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "fraction index": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2.5\n",
    "number with a tail": "v 0 0 0\nv 1 0 0\nv 0 1 1.5x\nf 1 2 3\n",
    "two-corner face": "v 0 0 0\nv 1 0 0\nf 1 2\n",
    "indented line": "v 0 0 0\n  v 1 0 0\nv 0 1 0\nf 1 2 3\n",
}


@pytest.mark.parametrize("name", sorted(IRREGULAR))
def test_irregular_obj_files_go_to_the_line_reader(name):
    text = IRREGULAR[name]
    assert regular_obj_statements(text.encode()) is None
    if name == "indented line":  # a valid file: the line reader reads it
        assert len(obj_statements_by_line("x.obj", text).positions) == 3


def test_obj_files_read_the_same_through_either_reader(tmp_path):
    rng = np.random.default_rng(7)
    for form in ("i", "i//n"):
        text = random_obj(rng, forms=(form,))
        path = tmp_path / f"m-{form.replace('/', '_')}.obj"
        path.write_text(text)
        mesh = read_mesh_file(path)
        # The same file with one indented line (which only the line reader takes)
        indented = tmp_path / "indented.obj"
        indented.write_text(text.replace("\nv ", "\n v ", 1))
        assert regular_obj_statements(indented.read_bytes()) is None
        slow = read_mesh_file(indented)
        np.testing.assert_array_equal(mesh.positions, slow.positions)
        np.testing.assert_array_equal(mesh.indices, slow.indices)
        assert (mesh.normals is None) == (slow.normals is None)
        if mesh.normals is not None:
            np.testing.assert_array_equal(mesh.normals, slow.normals)


def test_obj_lines_ending_in_a_backslash_continue(tmp_path):
    # The OBJ specification's line continuation; before: "invalid literal for int()"
    path = tmp_path / "continued.obj"
    path.write_text("v -0.5 1 -0.5\nv 0.5 1 -0.5\nv 0.5 1 \\\n 0.5\nv -0.5 1 0.5\nf 1 2 \\\n 3 4\n")
    mesh = read_mesh_file(path)
    np.testing.assert_array_equal(mesh.positions[2], [0.5, 1, 0.5])
    np.testing.assert_array_equal(mesh.indices, [[0, 1, 2], [0, 2, 3]])


def write_ply(path, positions, faces: list, text=False) -> None:
    vertex = np.zeros(len(positions), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"], vertex["y"], vertex["z"] = np.asarray(positions).T
    face = np.empty(len(faces), [("vertex_indices", object)])
    face["vertex_indices"] = [np.asarray(f, np.int32) for f in faces]
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements, text=text).write(str(path))


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("quads", [False, True])
def test_ply_reader_takes_triangles_at_once_and_polygons_face_by_face(tmp_path, text, quads):
    rng = np.random.default_rng(3)
    positions = rng.normal(size=(50, 3)).astype(np.float32)
    faces = [rng.choice(50, 4 if quads and k % 3 == 0 else 3, replace=False) for k in range(40)]
    path = tmp_path / "m.ply"
    write_ply(path, positions, faces, text)
    mesh = read_ply(path)
    # Independent truth: the fans of plyfile's own face-by-face reading
    expected = np.array(
        [[f[0], f[k], f[k + 1]] for f in faces for k in range(1, len(f) - 1)], np.int64
    )
    np.testing.assert_array_equal(mesh.indices, expected)
    np.testing.assert_array_equal(mesh.positions, positions.astype(np.float64))


def test_truncated_binary_ply_is_a_one_line_error(tmp_path):
    path = tmp_path / "cut.ply"
    write_ply(path, np.eye(3), [[0, 1, 2]] * 10)
    path.write_bytes(path.read_bytes()[:-20])
    with pytest.raises(MeshFileError) as info:
        read_mesh_file(path)
    assert "cut.ply: not a readable PLY file" in str(info.value)
    assert "\n" not in str(info.value)


def random_ascii_ply(rng, normals=False, colours=False, polygons=False, spacing=" ") -> str:
    """An ASCII PLY text of random vertices (x, y, z as float or double; optional normals and
    uchar colours) and faces of 3 (or 3-6) corners, with comments, in the given word spacing."""
    kinds = rng.choice(["float", "double"], 3)
    properties = [(kind, axis) for kind, axis in zip(kinds, "xyz", strict=True)]
    properties += [("float", n) for n in ("nx", "ny", "nz")] if normals else []
    properties += [("uchar", c) for c in ("red", "green", "blue")] if colours else []
    count = int(rng.integers(3, 40))
    faces = [
        rng.choice(count, int(rng.integers(3, 7)) if polygons else 3, replace=False)
        for _ in range(int(rng.integers(1, 50)))
    ]
    lines = ["ply", "format ascii 1.0", "comment random", "obj_info test"]
    lines += [f"element vertex {count}"] + [f"property {k} {n}" for k, n in properties]
    lines += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    for _ in range(count):
        words = [f"{x:.9g}" for x in rng.normal(size=len(properties) - 3 * colours)]
        words += [str(c) for c in rng.integers(0, 256, 3)] if colours else []
        lines.append(spacing.join(words) + (spacing if rng.random() < 0.2 else ""))
    lines += [spacing.join(str(v) for v in [len(f), *f]) for f in faces]
    return "\n".join(lines) + "\n"


def assert_blocks_equal_plyfile(path):
    """The fast path's vertex records, corners and sizes equal plyfile's own reading."""
    blocks = ascii_ply_blocks(path.read_bytes())
    assert blocks is not None
    vertex, corners, sizes = blocks
    ply = PlyData.read(str(path), mmap=False)
    expected = ply["vertex"].data
    assert vertex.dtype == expected.dtype
    for name in expected.dtype.names:
        np.testing.assert_array_equal(vertex[name], expected[name])
    lists = ply["face"].data["vertex_indices"]
    np.testing.assert_array_equal(sizes, [len(f) for f in lists])
    np.testing.assert_array_equal(corners, np.concatenate(lists))


@pytest.mark.parametrize("seed", range(24))
def test_ascii_ply_blocks_equal_plyfile(tmp_path, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path / "m.ply"
    path.write_text(
        random_ascii_ply(
            rng,
            normals=seed % 2 == 1,
            colours=seed % 3 == 1,
            polygons=seed % 4 >= 2,
            spacing=[" ", "  ", "\t", " \t "][seed % 4],
        )
    )
    assert_blocks_equal_plyfile(path)
    mesh = read_ply(path)  # the whole way, against plyfile's reading of the same file
    ply = PlyData.read(str(path), mmap=False)
    vertex = ply["vertex"].data
    np.testing.assert_array_equal(mesh.positions, np.stack([vertex[a] for a in "xyz"], 1))
    assert (mesh.normals is not None) == (seed % 2 == 1)
    expected = [
        [f[0], f[k], f[k + 1]]
        for f in ply["face"].data["vertex_indices"]
        for k in range(1, len(f) - 1)
    ]
    np.testing.assert_array_equal(mesh.indices, expected)


# A regular file, and changes that make the block parser leave it to plyfile (which reads it,
# or refuses it in one line)
REGULAR_ASCII_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n0.5 0.25 1\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n"
)
IRREGULAR_ASCII_PLY = {
    "an edge element": ("end_header", "element edge 0\nend_header"),
    "a face property": ("vertex_indices\n", "vertex_indices\nproperty uchar flags\n"),
    "faces before vertices": (
        "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n0.5 0.25 1\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n",
        "element face 2\nproperty list uchar int vertex_indices\nelement vertex 4\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
        "3 0 1 2\n3 0 2 3\n0 0 0\n0.5 0.25 1\n1 1 0\n0 1 0\n",
    ),
    "a vertex line short of a number": ("\n0.5 0.25 1\n", "\n0.5 0.25\n"),
    "two vertices on one line": ("\n0.5 0.25 1\n", "\n0.5 0.25 1 "),
    "a face's count not its corners": ("\n3 0 1 2\n", "\n4 0 1 2\n"),
    "text after the faces": ("3 0 2 3\n", "3 0 2 3\njunk\n"),
    "a word that is no number": ("\n0.5 0.25 1\n", "\n0.5 x 1\n"),
    "no final newline": ("3 0 2 3\n", "3 0 2 3"),
    "a list property on vertices": (
        "property float z",
        "property float z\nproperty list uchar int extra",
    ),
}


def test_the_regular_ascii_ply_takes_the_block_parser(tmp_path):
    path = tmp_path / "m.ply"
    path.write_text(REGULAR_ASCII_PLY)
    assert_blocks_equal_plyfile(path)


@pytest.mark.parametrize("case", list(IRREGULAR_ASCII_PLY))
def test_irregular_ascii_ply_is_left_to_plyfile(tmp_path, case):
    old, new = IRREGULAR_ASCII_PLY[case]
    assert REGULAR_ASCII_PLY.count(old) == 1, case
    path = tmp_path / "m.ply"
    path.write_text(REGULAR_ASCII_PLY.replace(old, new))
    assert ascii_ply_blocks(path.read_bytes()) is None
    try:
        ply = PlyData.read(str(path), mmap=False)
        vertex = ply["vertex"].data
    except Exception:
        with pytest.raises(MeshFileError, match="m.ply: ") as info:
            read_ply(path)
        assert "\n" not in str(info.value)
        return
    mesh = read_ply(path)  # plyfile's reading, as before the block parser
    np.testing.assert_array_equal(mesh.positions, np.stack([vertex[a] for a in "xyz"], 1))
