"""Scene files: the shipped scenes, their exact geometry, and the error messages."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from scene_texts import MINIMAL_SCENE

from clrender.errors import ClrenderError
from clrender.scene import SceneError, SceneWarning, list_scenes, load_scene
from clrender.scene_device import (
    CAMERA_DTYPE,
    EMITTER_DTYPE,
    MATERIAL_DTYPE,
    QUAD_DTYPE,
    SPHERE_DTYPE,
    quad_block_dtype,
)

DATA = Path(__file__).parent / "data"

MINIMAL = MINIMAL_SCENE


def write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_scenes_load():
    names = list_scenes()
    assert {"cornell-box", "cornell-box-glossy", "mitsuba-cbox", "furnace"} <= set(names)
    for name in names:
        scene = load_scene(name)
        assert len(scene.emitters) >= 1 and scene.warnings == []
        assert np.all(scene.quads["material"] < len(scene.materials))
        np.testing.assert_allclose(scene.emitters["pick_pdf"].sum(), 1.0, rtol=1e-6)


def test_load_by_path_and_by_name_agree():
    by_name = load_scene("cornell-box")
    by_path = load_scene(by_name.path)
    assert by_path.path == by_name.path
    np.testing.assert_array_equal(by_path.quads, by_name.quads)


def test_struct_layouts_match_the_kernel(runtime):
    sizes = np.zeros(6, np.uint32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=sizes.nbytes)
    runtime.kernel("scene_types_test.cl", "struct_sizes")(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, sizes, buf)
    dtypes = [
        QUAD_DTYPE,
        SPHERE_DTYPE,
        MATERIAL_DTYPE,
        EMITTER_DTYPE,
        CAMERA_DTYPE,
        quad_block_dtype(),
    ]
    assert list(sizes) == [d.itemsize for d in dtypes]


def test_authors_cornell_box_geometry():
    """NOTES.md section 3: 5 walls, the light, 6 faces of the rotated box, the glass ball."""
    scene = load_scene("cornell-box")
    assert len(scene.quads) == 12 and len(scene.spheres) == 1
    light = scene.quads[scene.emitters["index"][0]]
    np.testing.assert_allclose(light["normal"], [0, -1, 0], atol=1e-7)
    np.testing.assert_allclose(scene.emitters["radiance"][0], 24.0)
    np.testing.assert_allclose(scene.emitters["area"][0], 130 * 105)
    assert light["material"] == -1  # the light only emits
    # Box (0,0,0)-(165,330,165) rotated 15 degrees about y, then moved by (265, 0, 295)
    box = scene.quads[6:]
    corners = np.array(
        [
            q["corner"] + a * q["edge1"] + b * q["edge2"]
            for q in box
            for a in (0, 1)
            for b in (0, 1)
        ],
        np.float64,
    )
    c, s = math.cos(math.radians(15)), math.sin(math.radians(15))
    expected = np.array(
        [
            [c * x + s * z + 265, y, -s * x + c * z + 295]
            for x in (0, 165)
            for y in (0, 330)
            for z in (0, 165)
        ]
    )
    distances = np.linalg.norm(corners[:, None, :] - expected[None, :, :], axis=2)
    assert distances.min(axis=1).max() < 1e-3  # every face corner is a box corner
    assert distances.min(axis=0).max() < 1e-3  # every box corner is used
    ball = scene.spheres[0]
    np.testing.assert_allclose(ball["center"], [190, 90, 190])
    assert ball["radius"] == 90
    assert scene.materials[ball["material"]]["type"] == 1  # dielectric
    np.testing.assert_allclose(scene.materials[ball["material"]]["eta"], 1.5)


def test_green_wall_is_on_the_left_of_the_image():
    scene = load_scene("cornell-box")
    basis = scene.camera.basis(256, 256)
    green = scene.quad_names.index("green wall")
    centre = scene.quads[green]["corner"] + 0.5 * (
        scene.quads[green]["edge1"] + scene.quads[green]["edge2"]
    )
    assert np.dot(centre - basis["origin"], basis["right"]) < 0


def test_left_handed_camera_mirrors_the_image_horizontally(tmp_path):
    # pbrt's camera: the ray through image point (sx, sy) is the right-handed camera's ray
    # through (-sx, sy); origin, forward and up are unchanged.
    scene = load_scene("cornell-box")
    right_handed = scene.camera.basis(256, 128)
    path = write(tmp_path, MINIMAL.replace("fov = 40.0", 'fov = 40.0\nhandedness = "left"'))
    left_camera = load_scene(path).camera
    assert left_camera.handedness == "left"
    mirrored = dataclasses.replace(scene.camera, handedness="left").basis(256, 128)
    for key in ("origin", "forward", "up"):
        np.testing.assert_array_equal(mirrored[key], right_handed[key])
    np.testing.assert_array_equal(mirrored["right"], -right_handed["right"])


def test_mitsuba_geometry_is_exactly_the_json():
    """Every triangle of Mitsuba's Cornell box is half of one of our quads, same winding."""
    source = json.loads((DATA / "mitsuba-cbox.json").read_text())
    scene = load_scene("mitsuba-cbox")
    quad_vertices = [
        np.array(
            [
                q["corner"],
                q["corner"] + q["edge1"],
                q["corner"] + q["edge1"] + q["edge2"],
                q["corner"] + q["edge2"],
            ]
        )
        for q in scene.quads
    ]
    triangles = [
        np.array(shape["vertices"])[tri] for shape in source["shapes"] for tri in shape["triangles"]
    ]
    assert len(triangles) == 2 * len(scene.quads)
    for k, tri in enumerate(triangles):
        quad = quad_vertices[k // 2]
        expected = quad[[0, 1, 2]] if k % 2 == 0 else quad[[0, 2, 3]]
        np.testing.assert_allclose(tri, expected, atol=2e-7)
    light = scene.emitters[0]
    np.testing.assert_allclose(light["radiance"], source["light_radiance"], rtol=1e-6)
    materials = {name: scene.materials[i] for i, name in enumerate(scene.material_names)}
    for name, albedo in source["materials"].items():
        np.testing.assert_allclose(materials[name]["albedo"], albedo, rtol=1e-6)
        assert materials[name]["two_sided"] == 0
    assert scene.material_names[scene.quads[light["index"]]["material"]] == "white"
    camera = scene.camera
    assert camera.look_from == tuple(source["camera"]["origin"])
    assert camera.fov == source["camera"]["fov_deg"]


def test_minimal_scene_and_quad_vertices_form(tmp_path):
    scene = load_scene(write(tmp_path, MINIMAL))
    assert scene.quad_names == ["lamp"] and scene.sphere_names == ["ball"]
    text = MINIMAL.replace(
        "corner = [-1.0, -1.0, 0.0]\nedge1 = [2.0, 0.0, 0.0]\nedge2 = [0.0, 2.0, 0.0]",
        "vertices = [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]",
    )
    np.testing.assert_array_equal(load_scene(write(tmp_path, text, "v.toml")).quads, scene.quads)


def test_scene_without_emitter_warns(tmp_path):
    text = MINIMAL.replace("emission = [1.0, 1.0, 1.0]", 'material = "white"')
    with pytest.warns(SceneWarning, match="no emitter"):
        scene = load_scene(write(tmp_path, text))
    assert scene.warnings and len(scene.emitters) == 0


ERROR_CASES = [
    # (replace this, with this, message fragments)
    ('type = "sphere"', 'type = "sphear"', ["shapes[1] ('ball')", "'type'", "'sphere'"]),
    ('type = "diffuse"', 'type = "difuse"', ["[materials.white]", "'type'", "'diffuse'"]),
    ("radius = 1.0", "radius = -1.0", ["shapes[1] ('ball')", "'radius'", "> 0"]),
    ("radius = 1.0", "radius = nan", ["shapes[1] ('ball')", "'radius'", "finite"]),
    ("radius = 1.0", "radius = 1.0\nradious = 2.0", ["'radious'", "did you mean 'radius'"]),
    ("radius = 1.0", 'radius = "big"', ["'radius'", "expected a number", "string"]),
    ("radius = 1.0\n", "", ["shapes[1] ('ball')", "'radius'", "missing"]),
    ('material = "white"', 'material = "whte"', ["'material'", "did you mean 'white'"]),
    ("edge2 = [0.0, 2.0, 0.0]", "edge2 = [4.0, 0.0, 0.0]", ["shapes[0] ('lamp')", "degenerate"]),
    ("edge2 = [0.0, 2.0, 0.0]", "edge2 = [0.0, 2.0]", ["'edge2'", "3 finite numbers"]),
    ("edge2 = [0.0, 2.0, 0.0]", "edge2 = [0.0, inf, 0.0]", ["'edge2'", "non-finite"]),
    ("albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 1.5, 0.5]", ["'albedo'", "[0, 1]"]),
    ("fov = 40.0", "fov = 200.0", ["[camera]", "'fov'", "(0, 180)"]),
    ("fov = 40.0", "fovy = 40.0", ["[camera]", "'fovy'", "did you mean 'fov'"]),
    ("resolution = [8, 8]", "resolution = [8, 0]", ["[camera]", "'resolution'"]),
    ("fov = 40.0", 'fov = 40.0\nhandedness = "lefty"', ["'handedness'", "'left'", "'lefty'"]),
    ("emission = [1.0, 1.0, 1.0]", "emission = [1.0, -1.0, 1.0]", ["'lamp'", "'emission'"]),
]


@pytest.mark.parametrize(("old", "new", "fragments"), ERROR_CASES)
def test_errors_name_file_object_and_field(tmp_path, old, new, fragments):
    assert old in MINIMAL
    path = write(tmp_path, MINIMAL.replace(old, new, 1))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message


def test_box_errors(tmp_path):
    box = '\n[[shapes]]\ntype = "box"\nmin = [0.0, 0.0, 0.0]\nmax = [1.0, 0.0, 1.0]\n'
    with pytest.raises(SceneError, match=r"shapes\[2\].*'max'.*positive size"):
        load_scene(write(tmp_path, MINIMAL + box.replace("]\n", ']\nmaterial = "white"\n', 1)))
    with pytest.raises(SceneError, match=r"shapes\[2\].*'material'.*missing"):
        load_scene(write(tmp_path, MINIMAL + box))


def test_toml_syntax_error_names_file_and_line(tmp_path):
    path = write(tmp_path, MINIMAL.replace("fov = 40.0", "fov = = 40.0"))
    with pytest.raises(SceneError, match=r"scene\.toml.*TOML syntax error.*line 5"):
        load_scene(path)


def test_unknown_scene_name_suggests():
    with pytest.raises(SceneError, match="did you mean 'cornell-box'") as info:
        load_scene("cornel-box")
    assert isinstance(info.value, ClrenderError)


def test_camera_inside_a_sphere_or_box_warns_and_only_then(tmp_path):
    # The check: look_from strictly inside a sphere, or inside a box in its own frame.
    box = (
        '\n[[shapes]]\nname = "crate"\ntype = "box"\nmin = [-1.0, -1.0, -1.0]\n'
        "max = [1.0, 1.0, 1.0]\nrotate_y = 45.0\ntranslate = [0.0, 0.0, 5.0]\n"
        'material = "white"\n'
    )
    with pytest.warns(SceneWarning, match=r"look_from \[0.0, 0.0, 5.0\] is inside shapes\[2\]"):
        scene = load_scene(write(tmp_path, MINIMAL + box))
    assert len(scene.warnings) == 1 and "(a box)" in scene.warnings[0]
    # (1, 0, 6) lies in the rotated box's bounding box but outside the box itself.
    outside = MINIMAL.replace("look_from = [0.0, 0.0, 5.0]", "look_from = [1.0, 0.0, 6.0]")
    assert load_scene(write(tmp_path, outside + box, "outside.toml")).warnings == []
    # On the sphere's surface is not inside (but on it: tests/test_scene_checks.py); a little
    # further in is.
    surface = MINIMAL.replace("radius = 1.0", "radius = 7.0")
    with pytest.warns(SceneWarning, match="lies on shapes"):
        notes = load_scene(write(tmp_path, surface, "surface.toml")).warnings
    assert len(notes) == 1 and "is inside" not in notes[0]
    inside = MINIMAL.replace("radius = 1.0", "radius = 7.001")
    with pytest.warns(SceneWarning, match=r"inside shapes\[1\] \('ball'\) \(a sphere\)"):
        load_scene(write(tmp_path, inside, "inside.toml"))
    # A room of quads is no solid: the furnace's camera sits inside six quads on purpose.
    assert load_scene("furnace").warnings == []
