"""The scene's `mesh` shape (clrender/scene.py) and mesh files (clrender/mesh_files.py):
inline arrays, PLY and OBJ files written here, and one-line errors for bad input."""

import struct
import warnings

import numpy as np
import pytest
from scene_texts import lit_room

from clrender.scene import SceneError, SceneWarning, load_scene

HEADER = (
    lit_room(8)
    + """
[[shapes]]
type = "mesh"
name = "thing"
material = "white"
"""
)

SQUARE = """positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
indices = [[0, 1, 2], [0, 2, 3]]
"""


def write(tmp_path, body: str, name="scene.toml"):
    path = tmp_path / name
    path.write_text(HEADER + body)
    return path


def test_inline_mesh_packs_triangles_with_their_vertices(tmp_path):
    scene = load_scene(write(tmp_path, SQUARE))
    assert len(scene.triangles) == 2 and scene.mesh_names == ["thing"]
    np.testing.assert_array_equal(scene.triangles["p1"][1], [1, 1, 0])
    np.testing.assert_array_equal(scene.triangles["p2"][1], [0, 1, 0])
    assert np.all(scene.triangles["normals"] == -1)
    assert np.all(scene.triangles["material"] == 0)
    # Bounds include the mesh
    low, high = scene.bounds()
    assert low[0] <= -0.5 and high[1] >= 3.0


def test_inline_normals_are_normalised_per_triangle_corner(tmp_path):
    body = SQUARE + "normals = [[0, 0, 2], [0, 0, 1], [0, 1, 1], [0, 0, 3]]\n"
    scene = load_scene(write(tmp_path, body))
    np.testing.assert_array_equal(scene.triangles["normals"], [0, 1])
    n = scene.triangle_normals["n"]
    np.testing.assert_allclose(n[0], [[0, 0, 1], [0, 0, 1], [0, 0.70710677, 0.70710677]])
    np.testing.assert_allclose(n[1], [[0, 0, 1], [0, 0.70710677, 0.70710677], [0, 0, 1]])


def test_zero_normals_add_nothing_and_leave_the_geometric_normal(tmp_path):
    # pbrt-v4's rule: a zero vertex normal adds nothing to the interpolated normal (stored as
    # zero), where the sum is zero the kernel shades with the geometric normal; an unused
    # vertex's zero normal is no concern at all
    body = SQUARE.replace("]]\nindices", "], [5.0, 5.0, 5.0]]\nindices") + (
        "normals = [[0, 0, 1], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]\n"
    )
    scene = load_scene(write(tmp_path, body))
    n = scene.triangle_normals["n"][scene.triangles["normals"]]
    np.testing.assert_array_equal(n[0], [[0, 0, 1], [0, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(n[1], [[0, 0, 1], [0, 0, 0], [0, 0, 0]])
    assert np.isfinite(scene.triangle_normals["n"]).all()


def write_ply_binary(path, positions, faces, normals=None):
    props = "property float x\nproperty float y\nproperty float z\n"
    if normals is not None:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(positions)}\n{props}"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    data = bytearray(header.encode())
    for i, p in enumerate(positions):
        data += struct.pack("<3f", *p)
        if normals is not None:
            data += struct.pack("<3f", *normals[i])
    for face in faces:
        data += struct.pack(f"<B{len(face)}i", len(face), *face)
    path.write_bytes(bytes(data))


def test_ply_file_with_a_quad_face_and_normals(tmp_path):
    positions = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    normals = [(0, 0, 1)] * 5
    write_ply_binary(tmp_path / "m.ply", positions, [(0, 1, 2, 3), (1, 4, 2)], normals)
    scene = load_scene(write(tmp_path, 'file = "m.ply"\n'))
    assert len(scene.triangles) == 3
    np.testing.assert_array_equal(scene.triangles["p0"], [[0, 0, 0], [0, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(scene.triangles["p2"], [[1, 1, 0], [0, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(scene.triangles["normals"], [0, 1, 2])


def test_ascii_ply_without_normals(tmp_path):
    (tmp_path / "t.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_index\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    scene = load_scene(write(tmp_path, 'file = "t.ply"\n'))
    assert len(scene.triangles) == 1 and scene.triangles["normals"][0] == -1


def test_obj_file_with_per_corner_normals_and_negative_indices(tmp_path):
    (tmp_path / "m.obj").write_text(
        "# a square and a triangle\nmtllib x.mtl\no thing\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nvn 1 0 0\n"
        "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
        "f -4//2 -3//2 -2//2\n"
    )
    scene = load_scene(write(tmp_path, 'file = "m.obj"\n'))
    assert len(scene.triangles) == 3
    # The last triangle's corners carry the second normal: vertices split by normal
    np.testing.assert_array_equal(scene.triangles["p0"][2], [0, 0, 0])
    np.testing.assert_array_equal(scene.triangles["p2"][2], [1, 1, 0])
    np.testing.assert_allclose(scene.triangle_normals["n"][2], [[1, 0, 0]] * 3)
    np.testing.assert_allclose(scene.triangle_normals["n"][0], [[0, 0, 1]] * 3)


def test_obj_file_without_normals(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = load_scene(write(tmp_path, 'file = "m.obj"\n'))
    assert len(scene.triangles) == 1 and len(scene.triangle_normals) == 0


def test_degenerate_triangles_are_skipped_with_a_warning(tmp_path):
    body = SQUARE.replace("[[0, 1, 2], [0, 2, 3]]", "[[0, 1, 2], [0, 0, 3], [0, 1, 1], [0, 2, 3]]")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(write(tmp_path, body))
    messages = [str(w.message) for w in caught if issubclass(w.category, SceneWarning)]
    assert any("skipped 2 degenerate" in m and "triangle 1" in m for m in messages)
    assert len(scene.triangles) == 2
    assert any("degenerate" in note for note in scene.warnings)


BAD_INPUT = [
    (SQUARE.replace("[0, 2, 3]]", "[0, 2, 4]]"), "'indices': triangle 1 has index 4 outside 0..3"),
    (SQUARE.replace("[0, 2, 3]]", "[0, 2, -1]]"), "index -1 outside"),
    (SQUARE.replace("[0, 2, 3]]", "[0, 2]]"), "'indices': expected a list of [a, b, c] rows"),
    (SQUARE.replace("[0, 2, 3]]", "[0, 2, 3.0]]"), "rows of 3 integers"),
    (
        SQUARE.replace("[0, 2, 3]]", "[0, 2, true]]"),
        "rows of 3 integers, got a boolean (true) in row 1",
    ),
    (SQUARE.replace("[0, 2, 3]]", "[0, 2, [3]]]"), "got a list of 1 ([3]) in row 1"),
    (SQUARE.replace("[0.0, 1.0, 0.0]]", '[0.0, 1.0, "x"]]'), "'positions': expected a list"),
    (SQUARE.replace("[0.0, 1.0, 0.0]]", "[0.0, 1.0, nan]]"), "row 3 has a non-finite number"),
    (SQUARE.replace("[0.0, 1.0, 0.0]]", "[0.0, 1.0, 1e30]]"), "too large"),
    (SQUARE.replace("[[0, 1, 2], [0, 2, 3]]", "[[0, 0, 1]]"), "every triangle is degenerate"),
    (SQUARE + "normals = [[0, 0, 1]]\n", "expected one normal per position (4), got 1"),
    ("indices = [[0, 1, 2]]\n", "'positions': missing (required)"),
    (SQUARE + 'file = "m.ply"\n', "give either file or positions/indices/normals"),
    ('file = "missing.ply"\n', "missing.ply: cannot read"),
    ('file = "m.stl"\n', "unknown mesh file type '.stl'"),
    (SQUARE + "emission = [1.0, -1.0, 1.0]\n", "'emission': expected 3 numbers >= 0 (RGB)"),
    (SQUARE + "smooth = true\n", "'smooth': unknown field"),
]


@pytest.mark.parametrize(("body", "expected"), BAD_INPUT)
def test_bad_mesh_input_is_a_one_line_scene_error(tmp_path, body, expected):
    with pytest.raises(SceneError) as info:
        load_scene(write(tmp_path, body))
    message = str(info.value)
    assert expected in message and "\n" not in message
    assert "shapes[1] ('thing')" in message


BAD_FILES = [
    ("bad.ply", b"not a ply file\n", "bad.ply: not a readable PLY file"),
    ("empty.obj", b"v 0 0 0\nv 1 0 0\n", "empty.obj: the file has no triangles"),
    ("far.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4: index 4 refers to none"),
    ("short.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n", "line 3: a face needs at least 3 vertices"),
    ("nan.obj", b"v 0 0 0\nv 0 0 nan\nv 1 0 0\nv 0 1 0\nf 2 3 4\n", "nan.obj: vertex 1 has a non"),
    (
        "nan.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
        b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        b"0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 inf 1\n3 0 1 2\n",
        "nan.ply: vertex 2 has a non-finite normal: [0.0, inf, 1.0]",
    ),
    ("cont.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n x\n", "line 4: invalid literal"),
    ("mixed.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2 3\n", "some face corners"),
    ("latin.obj", b"# caf\xe9\nv 0 0 0\n", "latin.obj: not UTF-8 text"),
    (
        "noface.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n0 0 0\n",
        "noface.ply: the file has no triangles",
    ),
]


@pytest.mark.parametrize(("name", "data", "expected"), BAD_FILES)
def test_bad_mesh_files_are_one_line_scene_errors(tmp_path, name, data, expected):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(SceneError) as info:
        load_scene(write(tmp_path, f'file = "{name}"\n'))
    message = str(info.value)
    assert expected in message and "\n" not in message
    assert "field 'file'" in message
