"""scenes/veach-mis.toml: the conversion from the pbrt-v4 file (tests/data/veach-mis.pbrt), and
the image oriented as pbrt draws it, with pbrt's projection computed here from the pbrt file's
own camera matrix (independently of the converter and of clrender's camera)."""

import importlib.util
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from clrender.pipeline import RenderSettings, render
from clrender.probes import glossy_reflection_pixel, pixel_hits, sphere_light_edge_pixel
from clrender.radiance import PathTracerSource
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

ROOT = Path(__file__).resolve().parent.parent
PBRT = ROOT / "tests" / "data" / "veach-mis.pbrt"
PLATES = ["Smooth", "Glossy", "Rough", "SuperRough"]  # the file's order
WIDTH, HEIGHT = 160, 90  # pbrt's 1280 x 720 / 8


def converter():
    path = ROOT / "bench" / "veach_mis_scene.py"
    spec = importlib.util.spec_from_file_location("veach_mis_scene", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def pbrt_numbers(text: str, directive: str) -> list[list[float]]:
    """The bracketed number lists following each `directive` of the pbrt text."""
    pattern = re.escape(directive) + r"\s*\[([^\]]*)\]"
    return [[float(v) for v in m.split()] for m in re.findall(pattern, text)]


def pbrt_raster(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """pbrt's raster positions (x right, y down, pixel units) of world points: camera space by
    the file's world-to-camera Transform (column-major), then the perspective projection with
    fov on the shorter axis: raster x grows with camera x / z, raster y with -camera y / z."""
    text = PBRT.read_text()
    world_to_camera = np.array(pbrt_numbers(text, "Transform")[0]).reshape(4, 4).T
    fov = float(re.search(r'"float fov"\s*\[\s*([-0-9.e]+)', text).group(1))
    camera = (world_to_camera @ np.c_[points, np.ones(len(points))].T).T[:, :3]
    scale = 1.0 / math.tan(math.radians(fov) / 2.0)
    aspect = width / height  # screen window [-aspect, aspect] x [-1, 1]
    sx = scale * camera[:, 0] / camera[:, 2]
    sy = scale * camera[:, 1] / camera[:, 2]
    return np.stack([(sx + aspect) / (2 * aspect) * width, (1 - sy) / 2 * height], -1)


def pbrt_lights() -> tuple[np.ndarray, list[float]]:
    """Centres (translations of the lights' Transforms) and radii, in file order."""
    text = PBRT.read_text()
    centres = np.array([m[12:15] for m in pbrt_numbers(text, "Transform")[1:]])
    radii = [float(r) for r in re.findall(r'"float radius"\s*\[\s*([-0-9.e]+)', text)]
    return centres, radii


@pytest.fixture(scope="module")
def scene():
    return load_scene("veach-mis")


def test_shipped_scene_is_the_conversion_of_the_pbrt_file():
    module = converter()
    expected = module.convert(PBRT.read_text(), "tests/data/veach-mis.pbrt")
    assert (ROOT / "scenes" / "veach-mis.toml").read_text() == expected


@pytest.mark.parametrize(
    ("tri1", "tri2", "quad"),
    [
        ([0, 2, 1], [0, 3, 2], [0, 3, 2, 1]),
        ([0, 1, 2], [0, 2, 3], [0, 1, 2, 3]),
        ([4, 6, 5], [4, 7, 6], [4, 7, 6, 5]),
        ([0, 1, 2], [1, 3, 2], [0, 1, 3, 2]),
    ],
)
def test_triangle_pairs_become_quads_by_the_shared_rule(tri1, tri2, quad):
    assert converter().quad_from_triangles(tri1, tri2) == quad


def test_triangles_without_one_shared_edge_are_refused():
    module = converter()
    with pytest.raises(module.ConversionError, match="do not share exactly one edge"):
        module.quad_from_triangles([0, 1, 2], [3, 4, 5])


def test_scene_has_the_pbrt_files_shapes_and_materials(scene):
    # 4 plates of 6 faces, the floor and the back wall; three pure emitting spheres
    assert len(scene.quads) == 26 and len(scene.spheres) == 3
    centres, radii = pbrt_lights()
    np.testing.assert_allclose(scene.spheres["center"], centres, rtol=1e-7)
    np.testing.assert_allclose(scene.spheres["radius"], radii, rtol=1e-7)
    assert list(scene.emitters["shape"]) == [1, 1, 1] and list(scene.emitters["index"]) == [0, 1, 2]
    assert np.all(scene.spheres["material"] == -1)
    # Equal power: L r^2 the same for the three lights, so each is picked with pdf 1/3
    np.testing.assert_allclose(scene.emitters["pick_pdf"], 1 / 3, rtol=1e-5)
    alphas = [scene.materials["alpha"][scene.material_names.index(name)] for name in PLATES]
    np.testing.assert_allclose(alphas, [0.01, 0.05, 0.1, 0.25], rtol=1e-7)
    # The triangles' winding normal of each face (pbrt's first triangle of the floor: 0 1 2)
    floor = scene.quads[scene.quad_names.index("mesh4 Diffuse")]
    np.testing.assert_allclose(floor["normal"], [0, 1, 0], atol=1e-6)


def render_image(runtime, scene, depth, spp=16, size=(WIDTH, HEIGHT)):
    source = PathTracerSource(PathTracer(runtime, scene, max_depth=depth), *size)
    settings = RenderSettings(*size, make_sampler("sobol", spp), "mc", 5)
    return render(runtime, source, settings).film.image().astype(np.float64)


def test_lights_lie_where_pbrt_projects_them_in_the_files_order(runtime, scene):
    """Emitters only (depth 0): three bright spots, each centred within a pixel of where
    pbrt's own projection puts that light's centre, ordered along the image as pbrt's
    projection orders them (radius 1, 0.5, 0.05 in the file: right to left here)."""
    image = render_image(runtime, scene, depth=0).mean(axis=-1)
    centres, radii = pbrt_lights()
    expected = pbrt_raster(centres, WIDTH, HEIGHT)
    labels, count = ndimage.label(image > 0)
    assert count == 3
    spots = np.array(ndimage.center_of_mass(image, labels, range(1, 4)))[:, ::-1] + 0.5
    sizes = np.array(ndimage.sum(image > 0, labels, range(1, 4)))
    matched = [int(np.argmin(np.hypot(*(spots - centre).T))) for centre in expected]
    assert sorted(matched) == [0, 1, 2]
    assert np.hypot(*(spots[matched] - expected).T).max() < 1.0, (spots, expected)
    # pbrt draws the file's lights (radius 1, 0.5, 0.05) right to left; so does the render,
    # with spots that shrink with the radius
    assert np.all(np.diff(expected[:, 0]) < 0) and np.all(np.diff(spots[matched, 0]) < 0)
    assert np.all(np.diff(sizes[matched]) < 0) and radii == [1.0, 0.5, 0.05]


def test_plates_lie_top_to_bottom_and_grow_rougher_in_the_files_order(runtime, scene):
    """Each plate's centre projects (pbrt's projection) lower in the image than the one before
    it in the file; in a direct-light render the small light's reflection on each plate is
    dimmer at its peak (a wider lobe) than on the plate before: the plates grow rougher."""
    text = PBRT.read_text()
    points = pbrt_numbers(text, '"point3 P"')[:3] + pbrt_numbers(text, '"point3 P"')[-1:]
    plate_centres = np.array([np.mean(np.reshape(p, (-1, 3)), axis=0) for p in points])
    rows = pbrt_raster(plate_centres, WIDTH, HEIGHT)[:, 1]
    assert np.all(np.diff(rows) > 0), rows
    image = render_image(runtime, scene, depth=1, spp=64).mean(axis=-1)
    shape, _ = pixel_hits(scene, WIDTH, HEIGHT)
    material = np.where(shape >= 0, scene.quads["material"][np.minimum(shape, 25)], -1)
    small_light_x = pbrt_raster(pbrt_lights()[0], WIDTH, HEIGHT)[2, 0]
    columns = np.abs(np.arange(WIDTH) + 0.5 - small_light_x) < 6
    peaks = []
    for name in PLATES:
        on_plate = (material == scene.material_names.index(name)).all(axis=-1)
        peaks.append(image[on_plate & columns[None, :]].max())
    assert all(a > 1.5 * b for a, b in zip(peaks, peaks[1:], strict=False)), peaks


def test_probe_pixels_lie_on_the_light_edges_and_reflections(scene):
    size = 128
    shape, _ = pixel_hits(scene, size, size)
    for emitter in range(3):
        edge = sphere_light_edge_pixel(scene, size, size, emitter)
        sees = shape[edge.y, edge.x] == len(scene.quads) + emitter
        assert sees.any() and not sees.all()
        assert 0.25 < edge.detail["light_coverage"] < 0.75
    for emitter, plate in [(0, "Smooth"), (1, "Glossy"), (2, "Smooth"), (2, "Glossy")]:
        pixel = glossy_reflection_pixel(scene, size, size, emitter, plate)
        assert pixel.detail["offset_from_mirror_point_px"] < 1.0
        hit = shape[pixel.y, pixel.x]
        assert np.all(scene.quads["material"][hit] == scene.material_names.index(plate))
