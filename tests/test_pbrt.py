"""pbrt-v4 import (clrender.pbrt): tokens, transforms, the camera, quads from triangle pairs,
materials, lights, Include, every refusal, and the shipped veach-mis.pbrt."""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import clrender
from clrender import cli, probes
from clrender.imageio import read_exr
from clrender.pbrt import read_pbrt, tokenize
from clrender.scene import SceneError, SceneWarning, load_scene

# The file (../shared/scenes-data/veach-mis.pbrt), kept here so the tests need nothing
# outside the repository.
VEACH_PBRT = Path(__file__).resolve().parent / "data" / "veach-mis.pbrt"
VEACH_TOML = Path(__file__).resolve().parents[1] / "scenes" / "veach-mis.toml"

# A camera, an emitting parallelogram and a diffuse floor: the smallest renderable pbrt scene.
HEADER = """Film "rgb" "integer xresolution" [ 16 ] "integer yresolution" [ 8 ]
LookAt 0 1 5  0 1 0  0 1 0
Camera "perspective" "float fov" [ 40 ]
WorldBegin
"""
LAMP = """AttributeBegin
  AreaLightSource "diffuse" "rgb L" [ 2 3 4 ] "float scale" 0.5
  Material "diffuse" "rgb reflectance" [ 0 0 0 ]
  Shape "bilinearmesh" "point3 P" [ -1 2 -1  1 2 -1  -1 2 1  1 2 1 ]
AttributeEnd
"""
FLOOR = """Material "diffuse" "rgb reflectance" [ 0.25 0.5 0.75 ]
Shape "trianglemesh" "point3 P" [ -3 0 -3  3 0 -3  3 0 3  -3 0 3 ]
    "integer indices" [ 0 2 1  0 3 2 ]
"""
SCENE = HEADER + LAMP + FLOOR


def write(tmp_path, text, name="scene.pbrt"):
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def document(tmp_path, text, name="scene.pbrt"):
    return read_pbrt(write(tmp_path, text, name))[0]


def world_shapes(tmp_path, body):
    return document(tmp_path, HEADER + body)["shapes"]


# --------------------------------------------------------------------------- tokens


def test_01_tokens_strings_brackets_comments_and_lines(tmp_path):
    text = 'Shape "tri\\"mesh" # a comment "not a string"\n  [ 1 -2.5e1 ]\n\n"a b"#x\n'
    tokens = tokenize(tmp_path / "f.pbrt", text)
    assert [(t.text, t.line, t.quoted) for t in tokens] == [
        ("Shape", 1, False),
        ('tri"mesh', 1, True),
        ("[", 2, False),
        ("1", 2, False),
        ("-2.5e1", 2, False),
        ("]", 2, False),
        ("a b", 4, True),
    ]


def test_01b_a_byte_order_mark_and_an_upper_case_suffix(tmp_path):
    # Before: "\ufeffFilm: unknown directive", and scene.PBRT read as TOML
    path = tmp_path / "bom.pbrt"
    path.write_text("\ufeff" + SCENE, encoding="utf-8")
    assert len(load_scene(path).quads) == 2
    upper = write(tmp_path, SCENE, "scene.PBRT")
    assert len(load_scene(upper).quads) == 2
    with pytest.raises(SceneError, match=r"^scene file 'missing\.PBRT' does not exist$"):
        load_scene("missing.PBRT")  # a file's name, not a shipped scene's


def test_02_unterminated_string_names_file_and_line(tmp_path):
    with pytest.raises(SceneError, match=r"scene\.pbrt:5: a string opened"):
        document(tmp_path, HEADER + 'Shape "sphere\n')


# --------------------------------------------------------------------------- transforms


def test_03_transforms_compose_as_numpy_says(tmp_path):
    # Translate, Rotate, Scale, ConcatTransform (column-major) compose by right-multiplication
    concat = np.array(
        [[1.0, 0.5, 0.0, 0.25], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 2.0], [0, 0, 0, 1]]
    )
    body = (
        "Translate 1 2 3\nRotate 30 0 1 1\nScale 2 3 4\n"
        f"ConcatTransform [ {' '.join(str(v) for v in concat.T.ravel())} ]\n"
        'Shape "trianglemesh" "point3 P" [ 1 0 0  0 1 0  0 0 1 ]\n'
    )
    (mesh,) = world_shapes(tmp_path, body)
    rotation = np.eye(4)
    rotation[:3, :3] = Rotation.from_rotvec(
        math.radians(30) * np.array([0, 1, 1]) / math.sqrt(2)
    ).as_matrix()
    translation = np.eye(4)
    translation[:3, 3] = [1, 2, 3]
    matrix = translation @ rotation @ np.diag([2.0, 3.0, 4.0, 1.0]) @ concat
    expected = (matrix @ np.vstack([np.eye(3), np.ones((1, 3))]))[:3].T
    assert mesh["type"] == "mesh" and mesh["indices"] == [[0, 1, 2]]
    np.testing.assert_allclose(mesh["positions"], expected, rtol=0, atol=1e-12)


def test_04_transform_replaces_identity_resets_attributes_restore(tmp_path):
    body = (
        "Translate 5 5 5\nAttributeBegin\n"
        "  Transform [ 1 0 0 0  0 1 0 0  0 0 1 0  0 6.5 -2.8 1 ]\n"
        '  Shape "sphere" "float radius" 2\n'
        "  Identity\n  Scale 3 3 3\n"
        '  Shape "sphere"\n'
        "AttributeEnd\n"
        'Shape "sphere" "float radius" 0.5\n'
    )
    spheres = world_shapes(tmp_path, body)
    assert [(s["center"], s["radius"]) for s in spheres] == [
        ([0.0, 6.5, -2.8], 2.0),
        ([0.0, 0.0, 0.0], 3.0),
        ([5.0, 5.0, 5.0], 0.5),
    ]


def test_05_world_begin_resets_the_transform(tmp_path):
    text = 'Translate 1 2 3\nCamera "perspective"\nWorldBegin\nShape "sphere"\n'
    assert document(tmp_path, text)["shapes"][0]["center"] == [0.0, 0.0, 0.0]


def test_06_sphere_under_a_rotation_and_uniform_scale(tmp_path):
    body = 'Translate 1 0 0\nRotate 90 0 0 1\nScale 2 2 2\nShape "sphere" "float radius" 1.5\n'
    (sphere,) = world_shapes(tmp_path, body)
    np.testing.assert_allclose(sphere["center"], [1, 0, 0], atol=1e-15)
    assert sphere["radius"] == pytest.approx(3.0, rel=1e-12)


# --------------------------------------------------------------------------- camera


def pbrt_raster(world_to_camera, fov, width, height, points):
    """pbrt-v4's perspective projection: camera space, screen window [-a, a] x [-1, 1] (or
    [-1, 1] x [-1/a, 1/a] when taller), raster y down."""
    p = (world_to_camera @ np.c_[points, np.ones(len(points))].T)[:3].T
    t = math.tan(math.radians(fov) / 2)
    screen = p[:, :2] / (p[:, 2:3] * t)
    aspect = width / height
    half = (aspect, 1.0) if aspect > 1 else (1.0, 1.0 / aspect)
    x = (screen[:, 0] + half[0]) / (2 * half[0]) * width
    y = (half[1] - screen[:, 1]) / (2 * half[1]) * height
    return np.stack([x, y], axis=1)


def world_to_camera_by_hand(eye, target, up):
    """Rows: camera x = cross(up, forward), y, z = forward (pbrt's LookAt, written apart)."""
    forward = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    x = np.cross(up, forward)
    x /= np.linalg.norm(x)
    y = np.cross(forward, x)
    rotation = np.eye(4)
    rotation[:3, :3] = np.array([x, y, forward])
    shift = np.eye(4)
    shift[:3, 3] = -np.asarray(eye, float)
    return rotation @ shift


def camera_scene(tmp_path, transform_lines, width, height, fov=35.0, name="scene.pbrt"):
    text = (
        f'Film "rgb" "integer xresolution" {width} "integer yresolution" {height}\n'
        f'{transform_lines}\nCamera "perspective" "float fov" {fov}\nWorldBegin\n{LAMP}{FLOOR}'
    )
    return load_scene(write(tmp_path, text, name))


@pytest.mark.parametrize("width,height", [(40, 20), (20, 40)])
@pytest.mark.parametrize("mirror", [False, True])
def test_07_projection_lands_on_the_pixel_pbrt_draws(tmp_path, width, height, mirror):
    eye, target, up = (3.0, 2.0, 6.0), (0.0, 0.5, 0.0), (0.1, 1.0, 0.0)
    lines = ("Scale -1 1 1\n" if mirror else "") + "LookAt " + " ".join(map(str, eye + target + up))
    scene = camera_scene(tmp_path, lines, width, height)
    matrix = world_to_camera_by_hand(eye, target, up)
    if mirror:
        matrix = np.diag([-1.0, 1, 1, 1]) @ matrix
    assert scene.camera.handedness == ("right" if mirror else "left")
    points = np.random.default_rng(3).uniform(-1.0, 1.5, (50, 3))
    expected = pbrt_raster(matrix, 35.0, width, height, points)
    # within 1e-4 pixel: the camera record the kernel reads is float32
    np.testing.assert_allclose(probes.project(scene, width, height, points), expected, atol=1e-4)
    # and the camera ray through that pixel position passes through the point
    origins, dirs = probes.camera_rays(scene, width, height, expected)
    towards = points - origins
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    np.testing.assert_allclose(dirs, towards, atol=1e-6)


def test_08_lookat_and_the_same_camera_by_transform_agree(tmp_path):
    eye, target, up = (3.0, 2.0, 6.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0)
    by_look_at = camera_scene(tmp_path, "LookAt " + " ".join(map(str, eye + target + up)), 32, 24)
    matrix = world_to_camera_by_hand(eye, target, up)
    column_major = " ".join(repr(float(v)) for v in matrix.T.ravel())
    by_matrix = camera_scene(tmp_path, f"Transform [ {column_major} ]", 32, 24, name="t.pbrt")
    assert by_look_at.camera.handedness == by_matrix.camera.handedness == "left"
    for key in ("look_from", "look_at", "up"):
        np.testing.assert_allclose(
            getattr(by_look_at.camera, key), getattr(by_matrix.camera, key), atol=1e-12
        )
    np.testing.assert_allclose(by_look_at.camera.look_from, eye, atol=1e-12)
    basis = by_look_at.camera.basis(32, 24)
    other = by_matrix.camera.basis(32, 24)
    for key in ("origin", "forward", "right", "up"):
        np.testing.assert_allclose(basis[key], other[key], atol=1e-6)


def printed(matrix: np.ndarray, form: str = "%g") -> str:
    """A pbrt Transform of the matrix, its 16 numbers column-major printed with `form`."""
    return "Transform [ " + " ".join(form % v for v in matrix.T.ravel()) + " ]"


def transform_matrix(line: str) -> np.ndarray:
    """The matrix of a pbrt `Transform [ ... ]` line (column-major numbers)."""
    return np.array(line.split("[")[1].split("]")[0].split(), float).reshape(4, 4).T


def similarity_error(matrix: np.ndarray) -> float:
    linear = matrix[:3, :3]
    s2 = abs(np.linalg.det(linear)) ** (2 / 3)
    return float(np.abs(linear.T @ linear - s2 * np.eye(3)).max() / s2)


# Bitterli's teapot (pbrt-v4 export) as written: a camera rotation computed in float32 and
# printed to 6 digits, off orthonormal by 1.7e-5
TEAPOT_CAMERA = (
    "Transform [ 0.00552692 -0.342144 -0.939631 -0 -0 0.939646 -0.342149 -0 -0.999985 "
    "-0.0018952 -0.00517328 -0 -0.0919892 -2.36787 26.2919 1 ]"
)


def test_08b_transforms_printed_to_6_digits_are_rigid_and_shears_are_not(tmp_path):
    # A camera rotation printed with %g (6 significant digits) renders as the exact matrix
    # does, to the rounding of its digits; so does a sphere under it
    exact = np.eye(4)
    exact[:3, :3] = Rotation.random(random_state=5).as_matrix()
    exact[:3, 3] = [0.3, -1.2, 7.5]
    assert similarity_error(transform_matrix(printed(exact))) > 1e-6  # refused before
    by_exact = camera_scene(tmp_path, printed(exact, "%.17g"), 32, 24, name="exact.pbrt")
    by_print = camera_scene(tmp_path, printed(exact), 32, 24, name="printed.pbrt")
    assert by_print.camera.handedness == by_exact.camera.handedness == "left"
    for key in ("look_from", "look_at", "up"):
        np.testing.assert_allclose(
            getattr(by_print.camera, key), getattr(by_exact.camera, key), atol=2e-5
        )
    points = np.random.default_rng(5).uniform(-1.0, 1.5, (50, 3))
    np.testing.assert_allclose(
        probes.project(by_print, 32, 24, points),
        probes.project(by_exact, 32, 24, points),
        atol=1e-3,
    )
    # the camera's frame is orthonormal (the nearest rotation), not the printed columns
    basis = by_print.camera.basis(32, 24)
    assert abs(float(np.dot(basis["forward"], basis["up"]))) < 1e-6
    (sphere,) = world_shapes(tmp_path, printed(exact) + '\nShape "sphere" "float radius" 0.5\n')
    np.testing.assert_allclose(sphere["center"], [0.3, -1.2, 7.5])
    assert sphere["radius"] == pytest.approx(0.5, rel=1e-6)
    # a real exporter's matrix, further off orthonormal (float32 arithmetic), is a rigid camera
    teapot = camera_scene(tmp_path, TEAPOT_CAMERA, 32, 24, name="teapot.pbrt").camera
    matrix = transform_matrix(TEAPOT_CAMERA)
    assert similarity_error(matrix) > 1e-5
    rows = matrix[:3, :3]  # camera x, y, z in world
    np.testing.assert_allclose(teapot.look_from, -rows.T @ matrix[:3, 3], atol=1e-3)
    np.testing.assert_allclose(np.subtract(teapot.look_at, teapot.look_from), rows[2], atol=3e-5)
    # a clear shear and a non-uniform scale are still refused, each in one line
    shear = np.eye(4)
    shear[0, 1] = 0.01
    for transform in (printed(shear), "Scale 1 1.001 1"):
        with pytest.raises(SceneError, match=r"Camera: the camera transform must be rigid"):
            camera_scene(tmp_path, transform, 32, 24, name="shear.pbrt")
        with pytest.raises(SceneError, match=r"Shape: a sphere's transform must be"):
            world_shapes(tmp_path, transform + '\nShape "sphere"\n')


def test_09_fov_is_the_shorter_axis_and_resolution_defaults(tmp_path):
    tall = camera_scene(tmp_path, "LookAt 0 1 5 0 1 0 0 1 0", 20, 40, fov=30.0).camera
    half = math.tan(math.radians(30.0) / 2) * 2
    assert math.tan(math.radians(tall.fov) / 2) == pytest.approx(half, rel=1e-12)
    wide = camera_scene(tmp_path, "LookAt 0 1 5 0 1 0 0 1 0", 40, 20, fov=30.0).camera
    assert wide.fov == 30.0
    text = 'Camera "perspective"\nWorldBegin\n' + LAMP
    camera = document(tmp_path, text)["camera"]
    assert camera["resolution"] == [1280, 720] and camera["fov"] == 90.0
    assert camera["look_from"] == [0.0, 0.0, 0.0] and camera["handedness"] == "left"


# --------------------------------------------------------------------------- meshes


P4 = "[ 0 0 0  1 0 0  1 1 0  0 1 0 ]"


@pytest.mark.parametrize(
    "indices,order",
    [
        ("0 2 1  0 3 2", [0, 3, 2, 1]),
        ("0 1 2  0 2 3", [0, 1, 2, 3]),
        ("1 2 0  3 0 2", [1, 2, 3, 0]),
    ],
)
def test_10_triangle_pairs_become_quads_by_the_rule(tmp_path, indices, order):
    points = [[0.1, 0.2, -0.3], [1.7, 0.2, -0.3], [1.7, 1.3, -0.3], [0.1, 1.3, -0.3]]
    flat = " ".join(repr(v) for p in points for v in p)
    body = f'Shape "trianglemesh" "point3 P" [ {flat} ] "integer indices" [ {indices} ]\n'
    (quad,) = world_shapes(tmp_path, body)
    assert quad["type"] == "quad"
    assert quad["vertices"] == [points[i] for i in order]  # the file's floats, exactly


def test_11_pairs_that_are_not_parallelograms_or_flat_make_a_mesh(tmp_path):
    bent = "[ 0 0 0  1 0 0  1.2 1 0  0 1 0 ]"
    cases = {
        "not a parallelogram": f'"point3 P" {bent} "integer indices" [ 0 1 2 0 2 3 ]',
        "odd count": f'"point3 P" {P4} "integer indices" [ 0 1 2 ]',
        "opposite winding": f'"point3 P" {P4} "integer indices" [ 0 1 2 0 3 2 ]',
        "no shared edge": f'"point3 P" {P4} "integer indices" [ 0 1 2 0 1 3 ]',
        "smooth normals": f'"point3 P" {P4} "integer indices" [ 0 1 2 0 2 3 ] '
        '"normal N" [ 0 0.1 1  0 0 1  0 0 1  0 0 1 ]',
    }
    for what, params in cases.items():
        (mesh,) = world_shapes(tmp_path, f'Shape "trianglemesh" {params}\n')
        assert mesh["type"] == "mesh", what
    (mesh,) = world_shapes(tmp_path, f'Shape "trianglemesh" {cases["smooth normals"]}\n')
    assert mesh["indices"] == [[0, 1, 2], [0, 2, 3]] and len(mesh["normals"]) == 4


def test_12_normals_and_mirroring_decide_the_front_side(tmp_path):
    # N opposite the winding turns each triangle (pbrt faces the normal toward N)
    against = f'Shape "trianglemesh" "point3 P" {P4} "integer indices" [ 0 1 2 0 2 3 ] '
    (quad,) = world_shapes(tmp_path, against + '"normal N" [ 0 0 -1 0 0 -1 0 0 -1 0 0 -1 ]\n')
    v = np.array(quad["vertices"])
    assert np.cross(v[1] - v[0], v[3] - v[0])[2] < 0
    (quad,) = world_shapes(tmp_path, "Scale 1 1 -1\n" + against + "\n")
    v = np.array(quad["vertices"])
    # the mirror image of a front side +z is -z: pbrt flips a mirrored triangle's normal
    assert np.cross(v[1] - v[0], v[3] - v[0])[2] < 0
    assert v.tolist() == [[0, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0]]


def test_12b_zero_normals_are_pbrts_no_normal_there(tmp_path):
    # One zero N among flat ones: still a flat quad facing the others; all zero under a
    # mirroring: pbrt-v4 keeps the winding's normal, reversed by the mirroring
    mesh = f'Shape "trianglemesh" "point3 P" {P4} "integer indices" [ 0 1 2 0 2 3 ] '
    (quad,) = world_shapes(tmp_path, mesh + '"normal N" [ 0 0 -1 0 0 0 0 0 -1 0 0 -1 ]\n')
    v = np.array(quad["vertices"])
    assert np.cross(v[1] - v[0], v[3] - v[0])[2] < 0
    zeros = '"normal N" [ 0 0 0 0 0 0 0 0 0 0 0 0 ]\n'
    (quad,) = world_shapes(tmp_path, "Scale 1 1 -1\n" + mesh + zeros)
    v = np.array(quad["vertices"])
    assert np.cross(v[1] - v[0], v[3] - v[0])[2] < 0
    # a fan (no quads) keeps its zero normals as zero, unit ones unit, through a transform
    fan = f'Translate 0 0 1\nShape "trianglemesh" {FAN_P}\n    {FAN_DOWN} '
    (mesh,) = world_shapes(tmp_path, fan + '"normal N" [ 0 -2 0  0 0 0  0 -1 0  0 -1 0  0 -1 0 ]\n')
    np.testing.assert_array_equal(mesh["normals"][:2], [[0, -1, 0], [0, 0, 0]])


def test_13_bilinear_patch_is_a_quad_and_a_curved_one_is_refused(tmp_path):
    (quad,) = world_shapes(
        tmp_path, 'Shape "bilinearmesh" "point3 P" [ 0 0 0 2 0 0 0 1 0 2 1 0 ]\n'
    )
    assert quad["vertices"] == [[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]]
    curved = 'Shape "bilinearmesh" "point3 P" [ 0 0 0 2 0 0 0 1 0 2 1 1 ]\n'
    with pytest.raises(
        SceneError, match=r"scene\.pbrt:5: Shape: patch 0 is not a flat parallelogram"
    ):
        world_shapes(tmp_path, curved)


def test_14_plymesh_is_the_files_triangles_transformed(tmp_path):
    ply = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    write(tmp_path, ply, "meshes/tri.ply")
    (mesh,) = world_shapes(tmp_path, 'Shape "plymesh" "string filename" "meshes/tri.ply"\n')
    assert mesh["name"] == "scene.pbrt:5 plymesh" and mesh["material"] == "pbrt default diffuse"
    np.testing.assert_array_equal(mesh["positions"], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh["indices"], [[0, 1, 2]])
    assert "normals" not in mesh and "file" not in mesh
    (moved,) = world_shapes(
        tmp_path, 'Translate 0 0 2\nShape "plymesh" "string filename" "meshes/tri.ply"\n'
    )
    np.testing.assert_array_equal(moved["positions"], [[0, 0, 2], [1, 0, 2], [0, 1, 2]])
    np.testing.assert_array_equal(moved["indices"], [[0, 1, 2]])


# --------------------------------------------------------------------------- materials and lights


def test_15_materials(tmp_path):
    body = """MakeNamedMaterial "metal" "string type" "conductor" "float roughness" 0.04
    "rgb eta" [ 0.2 0.9 1.1 ] "rgb k" [ 3.9 2.4 2.1 ]
MakeNamedMaterial "raw" "string type" "conductor" "float uroughness" 0.3 "float vroughness" 0.3
    "bool remaproughness" false "rgb eta" [ 1 1 1 ] "rgb k" [ 2 2 2 ]
MakeNamedMaterial "glass" "string type" "dielectric" "float eta" 1.33
MakeNamedMaterial "plain" "string type" "diffuse"
NamedMaterial "glass"
Shape "sphere"
Material "diffuse" "rgb reflectance" [ 0.1 0.2 0.3 ]
Shape "sphere"
"""
    doc = document(tmp_path, HEADER + body)
    materials = doc["materials"]
    assert materials["metal"] == {
        "type": "roughconductor",
        "alpha": pytest.approx(0.2),  # pbrt-v4's RoughnessToAlpha: sqrt(roughness)
        "eta": [0.2, 0.9, 1.1],
        "k": [3.9, 2.4, 2.1],
    }
    assert materials["raw"]["alpha"] == 0.3
    assert materials["glass"] == {"type": "dielectric", "ior": 1.33}
    assert materials["plain"] == {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}  # pbrt's default
    anonymous = "Material at scene.pbrt:13"
    assert materials[anonymous] == {"type": "diffuse", "albedo": [0.1, 0.2, 0.3]}
    assert [s["material"] for s in doc["shapes"]] == ["glass", anonymous]


def test_15b_a_named_material_may_be_made_after_its_use(tmp_path):
    # pbrt-v4 resolves material names when it builds the scene, not at NamedMaterial
    body = """NamedMaterial "late"
Shape "sphere"
AttributeBegin
  AreaLightSource "diffuse" "rgb L" [ 1 1 1 ]
  NamedMaterial "black"
  Shape "sphere" "float radius" 0.5
AttributeEnd
MakeNamedMaterial "late" "string type" "diffuse" "rgb reflectance" [ 0.1 0.2 0.3 ]
MakeNamedMaterial "black" "string type" "diffuse" "rgb reflectance" [ 0 0 0 ]
Material "diffuse"
Shape "sphere" "float radius" 2
"""
    doc = document(tmp_path, HEADER + body)
    late, lamp, plain = doc["shapes"]
    assert late["material"] == "late" and late["radius"] == 1.0
    assert doc["materials"]["late"] == {"type": "diffuse", "albedo": [0.1, 0.2, 0.3]}
    # a black named material made later still makes its emitter a pure emitter
    assert lamp["emission"] == [1.0, 1.0, 1.0] and "material" not in lamp
    assert plain["material"] == "Material at scene.pbrt:14"


def test_16_area_lights_emit_scaled_and_a_black_material_only_emits(tmp_path):
    body = (
        LAMP
        + FLOOR
        + (
            'AttributeBegin\n  AreaLightSource "diffuse" "rgb L" [ 1 1 1 ]\n'
            '  Shape "sphere" "float radius" 0.25\nAttributeEnd\nShape "sphere"\n'
        )
    )
    lamp, floor, lit_ball, ball = world_shapes(tmp_path, body)
    assert lamp["emission"] == [1.0, 1.5, 2.0] and "material" not in lamp
    assert "emission" not in floor and floor["material"] == "Material at scene.pbrt:10"
    assert lit_ball["emission"] == [1.0, 1.0, 1.0]
    assert lit_ball["material"] == "Material at scene.pbrt:10"  # emits and reflects
    assert "emission" not in ball


def test_17_attribute_sets_default_parameters(tmp_path):
    body = (
        'AttributeBegin\n  Attribute "shape" "float radius" 0.25\n  Shape "sphere"\n'
        '  Shape "sphere" "float radius" 2\nAttributeEnd\nShape "sphere"\n'
    )
    assert [s["radius"] for s in world_shapes(tmp_path, body)] == [0.25, 2.0, 1.0]


def test_18_include_falls_back_to_the_including_files_folder(tmp_path):
    write(tmp_path, 'Include "parts/lamp.pbrt"\n', "scenes/world.pbrt")
    write(tmp_path, LAMP + 'Include "floor.pbrt"\n', "scenes/parts/lamp.pbrt")
    write(tmp_path, FLOOR, "scenes/parts/floor.pbrt")
    path = write(tmp_path, HEADER + 'Include "scenes/world.pbrt"\n', "main.pbrt")
    doc = read_pbrt(path)[0]
    assert [s["type"] for s in doc["shapes"]] == ["quad", "quad"]
    assert doc["shapes"][1]["name"] == "floor.pbrt:2 trianglemesh"
    write(tmp_path, 'Include "../main.pbrt"\n', "scenes/world.pbrt")
    with pytest.raises(
        SceneError, match=r"world\.pbrt:1: Include: '\.\./main\.pbrt' includes itself"
    ):
        read_pbrt(path)


def test_18b_names_in_included_files_are_taken_from_the_top_level_folder(tmp_path):
    # As pbrt-v4-scenes write them (sanmiguel/geometry/sanmiguel-geom.pbrt): an included file's
    # Include and plymesh names relative to the main file's folder, as pbrt-v4 resolves them
    ply = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    write(tmp_path, ply, "geometry/tri.ply")
    write(
        tmp_path,
        'Include "geometry/floor.pbrt"\nShape "plymesh" "string filename" "geometry/tri.ply"\n',
        "geometry/all.pbrt",
    )
    write(tmp_path, FLOOR, "geometry/floor.pbrt")
    path = write(tmp_path, HEADER + 'Include "geometry/all.pbrt"\n', "main.pbrt")
    floor, mesh = read_pbrt(path)[0]["shapes"]
    assert floor["name"] == "floor.pbrt:2 trianglemesh"
    np.testing.assert_array_equal(mesh["positions"], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    # the top-level folder's file comes first when both folders have one
    write(tmp_path, 'Shape "sphere" "float radius" 0.5\n', "geometry/geometry/floor.pbrt")
    assert read_pbrt(path)[0]["shapes"][0]["type"] == "quad"
    # and a name found in neither says where it looked, in one line
    write(tmp_path, 'Include "parts/none.pbrt"\n', "geometry/all.pbrt")
    with pytest.raises(SceneError) as caught:
        read_pbrt(path)
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'geometry' / 'all.pbrt'}:1: Include: no file")
    assert str(tmp_path / "parts" / "none.pbrt") in message
    assert str(tmp_path / "geometry" / "parts" / "none.pbrt") in message


# --------------------------------------------------------------------------- refusals


REFUSALS = [
    ('Texture "t" "spectrum" "imagemap"', 5, "Texture: not supported; supported: Camera"),
    ('LightSource "infinite"', 5, "LightSource: not supported"),
    ("ReverseOrientation", 5, "ReverseOrientation: not supported"),
    ('ObjectBegin "x"', 5, "ObjectBegin: not supported"),
    ('MakeNamedMedium "fog" "string type" "homogeneous"', 5, "MakeNamedMedium: not supported"),
    ("Frobnicate 1", 5, "Frobnicate: unknown directive"),
    ('Material "coateddiffuse"', 5, "Material: material 'coateddiffuse' not supported"),
    (
        'Material "diffuse" "texture reflectance" "t"',
        5,
        'Material "texture reflectance": not supported: give "rgb reflectance"',
    ),
    (
        'Material "diffuse" "float sigma" 2',
        5,
        'Material "float sigma": not supported; supported: "string type", "rgb reflectance"',
    ),
    (
        'Material "conductor" "float uroughness" 0.1 "float vroughness" 0.2\n'
        '  "rgb eta" [1 1 1] "rgb k" [1 1 1]',
        5,
        'Material "float vroughness": anisotropic roughness',
    ),
    (
        'Material "conductor" "rgb eta" [1 1 1] "rgb k" [1 1 1]',
        5,
        "Material: a smooth conductor not supported",
    ),
    (
        'Material "conductor" "spectrum eta" "metal-Au-eta" "rgb k" [1 1 1]',
        5,
        'Material "spectrum eta": not supported: give "rgb eta"',
    ),
    ('Material "conductor" "float roughness" 0.1', 5, 'Material: conductor needs "rgb eta"'),
    (
        'Material "dielectric" "float roughness" 0.1',
        5,
        'Material "float roughness": a rough dielectric',
    ),
    (
        'AreaLightSource "diffuse" "blackbody L" 5000',
        5,
        'AreaLightSource "blackbody L": not supported: give "rgb L"',
    ),
    (
        'AreaLightSource "diffuse" "rgb L" [1 1 1] "bool twosided" true',
        5,
        'AreaLightSource "bool twosided": two-sided',
    ),
    ('AreaLightSource "goniometric"', 5, "AreaLightSource: area light 'goniometric' not supported"),
    ('Shape "disk"', 5, "Shape: shape 'disk' not supported"),
    (
        'Shape "sphere" "float zmax" 0.5',
        5,
        'Shape "float zmax": not supported; supported: "float radius"',
    ),
    (
        'Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0]\n  "float alpha" 0.5',
        6,
        'Shape "float alpha": not supported',
    ),
    ('Scale 1 2 1 Shape "sphere"', 5, "Shape: a sphere's transform must be"),
    (
        'Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0] "integer indices" [0 1 3]',
        5,
        'Shape "integer indices": an index outside 0..2',
    ),
    (
        'NamedMaterial "gold"\nShape "sphere"\nMakeNamedMaterial "gilt" "string type" "diffuse"',
        5,
        "NamedMaterial: no MakeNamedMaterial 'gold' in the scene; defined: 'gilt'",
    ),
    ('Attribute "texture" "float scale" 2', 5, "Attribute: target 'texture' not supported"),
    ('Camera "perspective"', 5, "Camera: must come before WorldBegin"),
    ("AttributeEnd", 5, "AttributeEnd: no AttributeBegin to end"),
    ("AttributeBegin", 5, "AttributeBegin: no AttributeEnd closes it"),
    ('Include "missing.pbrt"', 5, "Include: no file"),
    ("Translate 1 2 x", 5, "Translate: expected a number, got 'x'"),
    ("Translate 1 2", 5, "Translate: the file ends where 3 numbers should follow"),
    (
        'Shape "sphere" "float radius" [ 1 2 ]',
        5,
        'Shape "float radius": expected 1 value(s), got 2',
    ),
    (
        'Shape "sphere" "floot radius" 1',
        5,
        "Shape \"floot radius\": unknown parameter type 'floot'",
    ),
]


@pytest.mark.parametrize("line,number,message", REFUSALS)
def test_19_refusals_are_one_line_with_file_line_and_directive(tmp_path, line, number, message):
    with pytest.raises(SceneError) as caught:
        load_scene(write(tmp_path, HEADER + line + "\n"))
    text = str(caught.value)
    assert "\n" not in text
    assert text.startswith(f"{tmp_path / 'scene.pbrt'}:{number}: "), text
    assert message in text, text


@pytest.mark.parametrize(
    "text,message",
    [
        ('Camera "orthographic"\nWorldBegin\n', "scene.pbrt:1: Camera: camera 'orthographic'"),
        (
            'Camera "perspective" "float lensradius" 0.1\n',
            'scene.pbrt:1: Camera "float lensradius"',
        ),
        ('Film "gbuffer"\n', "scene.pbrt:1: Film: film 'gbuffer' not supported"),
        ('Film "rgb" "float iso" 100\n', 'scene.pbrt:1: Film "float iso": not supported'),
        (
            'Scale 1 2 1\nCamera "perspective"\n',
            "scene.pbrt:2: Camera: the camera transform must be",
        ),
        ('Camera "perspective"\n', "no WorldBegin"),
        (
            'WorldBegin\nShape "sphere"\nWorldBegin\n',
            "scene.pbrt:3: WorldBegin: a second WorldBegin",
        ),
        ('Shape "sphere"\n', "scene.pbrt:1: Shape: must come after WorldBegin"),
        ("LookAt 0 0 0 0 0 0 0 1 0\n", "scene.pbrt:1: LookAt: eye and look-at point coincide"),
    ],
)
def test_20_refusals_outside_the_world_block(tmp_path, text, message):
    with pytest.raises(SceneError, match=None) as caught:
        read_pbrt(write(tmp_path, text))
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_21_ignored_directives_warn_once_each(tmp_path):
    text = (
        'Integrator "path" "integer maxdepth" 5\nSampler "sobol"\nSampler "halton"\n'
        'PixelFilter "box"\nColorSpace "srgb"\nOption "bool disablepixeljitter" true\n'
        'Accelerator "bvh"\nFilm "rgb" "string filename" "x.exr"\n' + SCENE
    )
    with pytest.warns(SceneWarning) as caught:
        scene = load_scene(write(tmp_path, text))
    notes = scene.warnings
    assert len(notes) == 7 and [str(w.message) for w in caught] == notes
    for directive, line in [
        ("Integrator", 1),
        ("Sampler", 2),
        ("PixelFilter", 4),
        ("ColorSpace", 5),
        ("Option", 6),
        ("Accelerator", 7),
        ('Film "string filename"', 8),
    ]:
        assert sum(f":{line}: {directive} ignored" in note for note in notes) == 1
    # Each reason names no option clrender lacks (there is no pixel filter option)
    assert any("box filter" in note for note in notes if "PixelFilter" in note)
    assert not any("--" in note for note in notes if "PixelFilter" in note)


# --------------------------------------------------------------------------- whole scenes


TOML_TWIN = """
[camera]
look_from = [0.0, 1.0, 5.0]
look_at = [0.0, 1.0, 4.0]
up = [0.0, 1.0, 0.0]
fov = 40.0
resolution = [16, 8]
handedness = "left"

[materials.floor]
type = "diffuse"
albedo = [0.25, 0.5, 0.75]

[[shapes]]
type = "quad"
vertices = [[-1.0, 2.0, -1.0], [1.0, 2.0, -1.0], [1.0, 2.0, 1.0], [-1.0, 2.0, 1.0]]
emission = [1.0, 1.5, 2.0]

[[shapes]]
type = "quad"
vertices = [[-3.0, 0.0, -3.0], [-3.0, 0.0, 3.0], [3.0, 0.0, 3.0], [3.0, 0.0, -3.0]]
material = "floor"
"""


def test_22_a_pbrt_scene_loads_as_its_hand_written_toml_twin(tmp_path):
    pbrt = load_scene(write(tmp_path, SCENE))
    twin = load_scene(write(tmp_path, TOML_TWIN, "twin.toml"))
    assert pbrt.camera == twin.camera
    for key in ("corner", "edge1", "edge2", "normal", "emitter"):
        np.testing.assert_array_equal(pbrt.quads[key], twin.quads[key])
    np.testing.assert_array_equal(pbrt.emitters, twin.emitters)
    np.testing.assert_array_equal(pbrt.materials, twin.materials)


@pytest.mark.device
def test_23_render_command_reads_pbrt(tmp_path, capsys):
    path = write(tmp_path, SCENE)
    out = tmp_path / "out.exr"
    status = cli.main(
        ["render", str(path), "--res", "scene", "--spp", "4", "--seed", "3", "-o", str(out)]
    )
    assert status == 0, capsys.readouterr().err
    pixels, meta = read_exr(out)
    assert pixels.shape == (8, 16, 3) and meta["scene"] == "scene"
    assert pixels.max() > 0 and np.isfinite(pixels).all()
    twin = clrender.render(str(write(tmp_path, TOML_TWIN, "twin.toml")), spp=4, seed=3)
    np.testing.assert_array_equal(pixels, twin.image)


def test_24_shipped_veach_mis_parses_into_its_parts():
    doc, notes = read_pbrt(VEACH_PBRT)
    shapes = doc["shapes"]
    quads = [s for s in shapes if s["type"] == "quad"]
    spheres = [s for s in shapes if s["type"] == "sphere"]
    assert (len(quads), len(spheres), len(shapes)) == (4 * 6 + 2, 3, 29)
    assert list(doc["materials"]) == ["Diffuse", "Smooth", "Glossy", "Rough", "Null", "SuperRough"]
    assert [doc["materials"][n]["alpha"] for n in ("Smooth", "Glossy", "Rough", "SuperRough")] == [
        0.01,
        0.05,
        0.1,
        0.25,
    ]
    assert [(s["center"], s["radius"], s["emission"][0]) for s in spheres] == [
        ([0.0, 6.5, -2.8], 1.0, 7.599088),
        ([0.0, 6.5, 0.0], 0.5, 30.396353),
        ([0.0, 6.5, 2.7], 0.05, 3039.6353),
    ]
    assert all("material" not in s for s in spheres)  # the "Null" material: pure emitters
    assert quads[0]["vertices"] == [
        [-0.637866, 4.65614, -4.0],
        [0.973649, 3.30966, -4.0],
        [0.973649, 3.30966, 4.0],
        [-0.637866, 4.65614, 4.0],
    ]
    camera = doc["camera"]
    assert camera["handedness"] == "right"  # the file's camera transform mirrors
    assert camera["resolution"] == [1280, 720] and camera["fov"] == 20.114292
    np.testing.assert_allclose(camera["look_from"], [28.2792, 3.5, 0.0], atol=2e-6)
    np.testing.assert_allclose(
        np.subtract(camera["look_at"], camera["look_from"]), [-1, 0, 0], atol=1e-7
    )
    assert len(notes) == 4


def spheres_can_emit() -> bool:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            load_scene(VEACH_PBRT)
    except SceneError as err:
        if "cannot be an emitter" in str(err):
            return False
        raise
    return True


@pytest.mark.device
@pytest.mark.skipif(not spheres_can_emit(), reason="spheres cannot emit yet (sphere-lights)")
def test_25_veach_mis_pbrt_renders_as_its_toml_conversion():
    settings = {"spp": 4, "seed": 11, "resolution": (64, 36)}
    with pytest.warns(SceneWarning, match="ignored"):
        pbrt_scene = load_scene(VEACH_PBRT)
    from_pbrt = clrender.render(pbrt_scene, **settings)
    from_toml = clrender.render(load_scene(VEACH_TOML), **settings)
    assert from_pbrt.image.max() > 0
    np.testing.assert_array_equal(from_pbrt.image, from_toml.image)


def test_26_meshes_load_as_the_scenes_triangles(tmp_path):
    # A triangle fan (not parallelograms) and a plymesh under a transform: the loaded scene
    # holds their triangles in world space, front sides as pbrt winds them.
    ply = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    write(tmp_path, ply, "tri.ply")
    body = (
        'Shape "trianglemesh" "point3 P" [ 0 1 0  1 1 0  1 2 0  0 2 1 ]\n'
        '    "integer indices" [ 0 1 2  0 2 3 ]\n'
        'Translate 0 0 2\nShape "plymesh" "string filename" "tri.ply"\n'
    )
    scene = load_scene(write(tmp_path, SCENE + body))
    assert len(scene.triangles) == 3
    corners = np.stack([scene.triangles[k] for k in ("p0", "p1", "p2")], axis=1)
    expected = [
        [[0, 1, 0], [1, 1, 0], [1, 2, 0]],
        [[0, 1, 0], [1, 2, 0], [0, 2, 1]],
        [[0, 0, 2], [1, 0, 2], [0, 1, 2]],
    ]
    np.testing.assert_array_equal(corners, np.array(expected, np.float32))


# An emitting triangle fan at y = 1.5 above FLOOR: P = centre, +x, +z, -x, -z; indices as
# written wind every triangle so that pbrt's normal, Cross(p0 - p2, p1 - p2), points down (-y)
FAN_P = '"point3 P" [ 0 1.5 0  1 1.5 0  0 1.5 1  -1 1.5 0  0 1.5 -1 ]'
FAN_DOWN = '"integer indices" [ 0 1 2  0 2 3  0 3 4 ]'
FAN_UP = '"integer indices" [ 0 2 1  0 3 2  0 4 3 ]'
NORMALS_DOWN = '"normal N" [ 0 -1 0  0 -1 0  0 -1 0  0 -1 0  0 -1 0 ]'


@pytest.mark.device
@pytest.mark.parametrize(
    ("case", "transform", "indices", "normals", "lit"),
    [
        ("wound down", "", FAN_DOWN, "", True),
        ("wound up", "", FAN_UP, "", False),
        ("wound up, normals down", "", FAN_UP, NORMALS_DOWN, True),
        ("wound down, mirrored", "Scale 1 1 -1\n", FAN_DOWN, "", True),
        ("wound up, mirrored", "Scale 1 1 -1\n", FAN_UP, "", False),
    ],
)
def test_27_mesh_emitters_light_the_side_pbrt_emits_to(
    tmp_path, case, transform, indices, normals, lit
):
    # pbrt-v4: a diffuse area light emits on its surface normal's side only; a triangle's
    # normal is its winding's, flipped by a transform that swaps handedness, and turned toward
    # the vertex normals N when the mesh has them. The floor below is lit by the fan (the only
    # emitter; black, so nothing else lights the floor) exactly when it emits down.
    fan = (
        f'AttributeBegin\n  {transform}  AreaLightSource "diffuse" "rgb L" [ 4 4 4 ]\n'
        '  Material "diffuse" "rgb reflectance" [ 0 0 0 ]\n'
        f'  Shape "trianglemesh" {FAN_P}\n    {indices} {normals}\nAttributeEnd\n'
    )
    scene = load_scene(write(tmp_path, HEADER + FLOOR + fan))
    assert len(scene.triangles) == 3, case
    floor = clrender.render(scene, spp=16, seed=3).image[4:].mean()
    if lit:
        assert floor > 0.01, case
    else:
        assert floor == 0.0, case


def lamp_ply(y: float) -> str:
    """An ASCII PLY square at height y, wound counter-clockwise seen from above (winding's
    front +y) with vertex normals N pointing down (-y): pbrt-v4 emits down, toward N."""
    return (
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        f"-1 {y} -1 0 -1 0\n-1 {y} 1 0 -1 0\n1 {y} 1 0 -1 0\n1 {y} -1 0 -1 0\n4 0 1 2 3\n"
    )


def ply_lamp_scene(tmp_path, transform: str, y: float):
    write(tmp_path, lamp_ply(y), f"lamp{y:g}.ply")
    lamp = (
        'AttributeBegin\n  AreaLightSource "diffuse" "rgb L" [ 4 4 4 ]\n'
        f'  Material "diffuse" "rgb reflectance" [ 0 0 0 ]\n  {transform}\n'
        f'  Shape "plymesh" "string filename" "lamp{y:g}.ply"\nAttributeEnd\n'
    )
    return load_scene(write(tmp_path, HEADER + FLOOR + lamp, f"lamp{y:g}.pbrt"))


def test_28_a_plymesh_faces_its_normals_with_or_without_a_transform(tmp_path):
    # The same emitting square, once from a file at y = 1.5 with no transform, once from a file
    # at y = 0.5 moved up by 1: both face the file's normals (down), as pbrt-v4 turns them
    placed = ply_lamp_scene(tmp_path, "", 1.5)
    moved = ply_lamp_scene(tmp_path, "Translate 0 1 0", 0.5)
    for scene in (placed, moved):
        p0, p1, p2 = (scene.triangles[k].astype(np.float64) for k in ("p0", "p1", "p2"))
        assert (np.cross(p1 - p0, p2 - p0)[:, 1] < 0).all()
    for key in ("p0", "p1", "p2"):
        np.testing.assert_array_equal(placed.triangles[key], moved.triangles[key])


@pytest.mark.device
def test_29_a_plymesh_without_a_transform_lights_what_pbrt_lights(tmp_path):
    placed = clrender.render(ply_lamp_scene(tmp_path, "", 1.5), spp=8, seed=3).image
    moved = clrender.render(ply_lamp_scene(tmp_path, "Translate 0 1 0", 0.5), spp=8, seed=3).image
    assert placed[4:].mean() > 0.01
    np.testing.assert_array_equal(placed, moved)
