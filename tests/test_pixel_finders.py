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


@pytest.fixture(scope="module")
def shadow(scene):
    return probes.shadow_boundary_pixel(scene, SIZE, SIZE)


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


def test_08_shadow_boundary_pixel_is_on_the_floor_across_the_box_shadow(scene, shadow):
    shape, points = probes.pixel_hits(scene, SIZE, SIZE)
    floor = scene.quad_names.index("floor")
    assert (shape[shadow.y, shadow.x] == floor).all()
    assert scene.materials["type"][scene.quads["material"][floor]] == 0  # diffuse
    # Each light point on its own (sees_points), not light_blockers' batches.
    grid = probes.light_grid(scene)
    fraction = np.array(
        [
            np.mean([probes.sees_points(scene, point, target[None]) for target in grid])
            for point in points[shadow.y, shadow.x]
        ]
    )
    np.testing.assert_allclose(fraction, shadow.detail["light_fraction_at_probes"])
    assert 0.1 < fraction[0] < 0.9  # the centre is in the penumbra
    assert fraction.max() - fraction.min() >= 0.25  # the boundary crosses the pixel
    assert shadow.detail["occluders"]
    assert all(name.startswith("tall box/") for name in shadow.detail["occluders"])


def test_09_shadow_boundary_pixel_is_lit_between_its_neighbours(runtime, scene, shadow):
    """Direct light only (max depth 1): the pixel is darker than its most lit floor neighbour
    and brighter than its most shadowed one, in proportion to the light each sees."""
    neighbours = [(shadow.x + dx, shadow.y + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    pos = np.array([[x + 0.5, y + 0.5] for x, y in [(shadow.x, shadow.y), *neighbours]])
    origins, dirs = probes.camera_rays(scene, SIZE, SIZE, pos)
    t, hit = probes.first_hits(scene, origins, dirs)
    assert (hit == scene.quad_names.index("floor")).all()
    fraction = probes.visible_light_fraction(scene, origins + t[:, None] * dirs)
    lit, shadowed = neighbours[np.argmax(fraction[1:])], neighbours[np.argmin(fraction[1:])]
    tracer = PathTracer(runtime, scene, max_depth=1)

    def direct(x, y):
        runs = probes.trace_pixel_runs(
            runtime, tracer, make_sampler("sobol", 4096), 5, y * SIZE + x, 1, SIZE, SIZE
        )
        return runs.radiance.mean()

    value, lit_value, shadowed_value = (
        direct(x, y) for x, y in [(shadow.x, shadow.y), lit, shadowed]
    )
    # The boundary crosses the pixel's neighbourhood: a step of at least 10 % on each side.
    assert shadowed_value < 0.9 * value and value < 0.9 * lit_value
    # The pixel's direct light against its lit neighbour's: as the light they see (the
    # probes' mean against the lit neighbour's centre; the floor's cosines barely differ).
    seen = np.mean(shadow.detail["light_fraction_at_probes"]) / fraction[1:].max()
    assert value / lit_value == pytest.approx(seen, rel=0.15)


def test_10_glossy_highlight_edge_pixel_is_where_the_highlight_falls_off():
    glossy = load_scene("cornell-box-glossy")
    mask = probes.glossy_pixels(glossy, SIZE, SIZE)
    _, interior = probes.glossy_brightness(glossy, np.zeros((SIZE, SIZE, 3)))
    ys, xs = np.mgrid[0:SIZE, 0:SIZE]
    step_row = int(np.median(ys[mask]))
    # A highlight below step_row, brighter to the right (so its edge is steepest there) and
    # downwards (its peak is away from its edge), on a dim glossy surface.
    image = np.zeros((SIZE, SIZE, 3))
    right = (xs - xs[mask].min()) / (xs[mask].max() - xs[mask].min())
    down = (ys - step_row) / (ys[mask].max() - step_row)
    highlight = mask & (ys >= step_row)
    image[highlight] = (1.0 + 0.5 * right + 0.5 * down)[highlight, None]
    image[mask & (ys < step_row)] = 0.1
    # Above it, apart: a patch above half the peak with steeper edges (not the highlight's),
    # and a lone firefly (removed by the median filter).
    patch_row = step_row - 25
    patch_x = int(np.median(np.flatnonzero(interior[patch_row])))
    image[patch_row - 4 : patch_row + 5, patch_x - 4 : patch_x + 5] = 1.9
    image[patch_row + 12, patch_x] = 100.0
    pick = probes.glossy_highlight_edge_pixel(glossy, image)
    assert interior[pick.y, pick.x] and pick.y == step_row
    # The steepest edge pixel: the rightmost of the interior on the step row, within a pixel.
    assert pick.x >= np.flatnonzero(interior[step_row]).max() - 1
    peak_x, peak_y = pick.detail["highlight_peak_pixel"]
    assert peak_y > step_row + 5 and pick.detail["short_render_radiance"] > 1.0
