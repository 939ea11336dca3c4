"""The mesh file readers' fast paths (clrender/mesh_files.py) against their general readers:
OBJ text parsed by whole byte columns against the line-by-line reader, and binary PLY files of
triangles memory-mapped against plyfile's face-by-face reading, on random files of every
statement form the readers accept."""

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from clrender.mesh_files import (
    MeshFileError,
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
