"""Probe pixels found from the scene's geometry (clrender.probes): what each one sees is
checked against the camera, the host ray caster and short renders on the device."""

import numpy as np
import pytest

from clrender import probes
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

SIZE = 256
LIGHT_RADIANCE = 24.0


@pytest.fixture(scope="module")
def scene():
    return load_scene("cornell-box")


def depth0_pixel_mean(runtime, scene, pixel: int, runs: int = 4, n: int = 4096) -> np.ndarray:
    """Mean RGB radiance of a pixel seen with max depth 0 (emission only), R x n samples."""
    tracer = PathTracer(runtime, scene, max_depth=0)
    traced = probes.trace_pixel_runs(
        runtime, tracer, make_sampler("independent", n), 3, pixel, runs, SIZE, SIZE
    )
    return traced.radiance.mean(axis=0)


def test_01_project_inverts_camera_rays(scene):
    pos = np.array([[0.5, 0.5], [100.25, 33.75], [255.5, 200.0]])
    origins, dirs = probes.camera_rays(scene, SIZE, SIZE, pos)
    np.testing.assert_allclose(
        probes.project(scene, SIZE, SIZE, origins + 700.0 * dirs), pos, atol=1e-9
    )


def test_02_polygon_coverage_of_a_pixel():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert probes.polygon_pixel_coverage(square * 3 - 1, 0, 0) == pytest.approx(1.0)
    assert probes.polygon_pixel_coverage(square + [0.5, 0.0], 0, 0) == pytest.approx(0.5)
    assert probes.polygon_pixel_coverage(square + [2.0, 0.0], 0, 0) == 0.0


def test_03_light_edge_pixel_is_partly_covered(runtime, scene):
    edge = probes.light_edge_pixel(scene, SIZE, SIZE)
    coverage = edge.detail["light_coverage"]
    assert 0.3 < coverage < 0.7
    mean = depth0_pixel_mean(runtime, scene, edge.pixel)
    # Emission only: light radiance times the covered fraction, strictly between 0 and 24.
    assert mean.min() > 0.0 and mean.max() < LIGHT_RADIANCE
    np.testing.assert_allclose(mean, LIGHT_RADIANCE * coverage, rtol=0.03)


def test_04_diffuse_wall_pixel_sees_only_the_lit_wall(runtime, scene):
    wall = probes.diffuse_wall_pixel(scene, SIZE, SIZE)
    shape, points = probes.pixel_hits(scene, SIZE, SIZE)
    assert (shape[wall.y, wall.x] == scene.quad_names.index("back wall")).all()
    assert probes.sees_points(scene, points[wall.y, wall.x], probes.light_points(scene)).all()
    assert wall.detail["distance_to_region_edge_px"] >= 5
    np.testing.assert_array_equal(depth0_pixel_mean(runtime, scene, wall.pixel, runs=1, n=64), 0.0)


def test_05_sphere_pixel_sees_the_ball(scene):
    ball = probes.sphere_pixel(scene, SIZE, SIZE)
    shape, _ = probes.pixel_hits(scene, SIZE, SIZE)
    assert (shape[ball.y, ball.x] == len(scene.quads)).all()


def test_06_glossy_highlight_pixel_is_on_the_glossy_box():
    glossy = load_scene("cornell-box-glossy")
    mask = probes.glossy_pixels(glossy, SIZE, SIZE)
    image = np.zeros((SIZE, SIZE, 3))
    ys, xs = np.nonzero(mask)
    image[
        ys[len(ys) // 2] - 3 : ys[len(ys) // 2] + 4, xs[len(xs) // 2] - 3 : xs[len(xs) // 2] + 4
    ] = 1.0  # a bright 7 x 7 patch survives the median filter
    image[ys[0], xs[0]] = 100.0  # a lone firefly does not
    pick = probes.glossy_highlight_pixel(glossy, image)
    assert mask[pick.y, pick.x]
    assert abs(pick.y - ys[len(ys) // 2]) <= 3 and abs(pick.x - xs[len(xs) // 2]) <= 3


def test_07_pixel_runs_are_independent(runtime, scene):
    tracer = PathTracer(runtime, scene, max_depth=1)
    runs = probes.trace_pixel_runs(
        runtime, tracer, make_sampler("sppp", 16), 1, 1000, 3, SIZE, SIZE
    )
    sets = runs.sets
    assert runs.runs == 3 and len(runs.radiance) == sets.offsets[-1]
    first = sets.traced[sets.offsets[0] : sets.offsets[1]]
    second = sets.traced[sets.offsets[1] : sets.offsets[2]]
    assert len(first) == 0 or len(second) == 0 or not np.array_equal(first[:1], second[:1])
