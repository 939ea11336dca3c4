"""Image-level Voronoi cells on the device (clrender.estimators.image_device) against Qhull's
(clrender.estimators.image, itself tested against scipy's global Voronoi diagram and a 60-digit
reference in tests/test_image_estimators.py): the same cells and sums, the certification that
sends a pixel to the host when its neighbourhood does not decide its cells, finite
realisations, and renders with either backend.

Tolerance: the device takes each pixel's nuclei relative to its centre rounded to float32
(|coordinate| <= 1/2 + ring, so within 2^-24 (1/2 + ring) of the exact values, about 3e-7 at
ring 4); a cell's area moves by about its perimeter times that: AREA_ATOL (measured 1.8e-7 at
n = 1, 3e-8 at n = 256).
"""

import math

import numpy as np
import pytest
from test_image_estimators import CLUSTER_IMAGE, cluster_estimate, with_cluster

from clrender.analytic import AnalyticSource
from clrender.estimators import image_device
from clrender.estimators.image import draw_plane_poisson, estimate_image, guard_distance
from clrender.estimators.image_device import device_ring, estimate_run_device
from clrender.estimators.image_plane import PixelRect, grid_from_points
from clrender.pipeline import RenderSettings, render
from clrender.sampling import make_sampler

AREA_ATOL = 1e-6
WIDTH, HEIGHT = 12, 9


def realisation(seed, n, frame, width=WIDTH, height=HEIGHT):
    rng = np.random.default_rng(seed)
    points = draw_plane_poisson(rng, n, (-frame, -frame, width + frame, height + frame))
    return points, rng.random((len(points), 3))


def assert_same_estimates(device, host):
    done = np.isfinite(host.areas)
    assert np.array_equal(np.isfinite(device.areas), done)
    np.testing.assert_allclose(device.areas[done], host.areas[done], rtol=0, atol=AREA_ATOL)
    for name in ("ivor", "ivor_sn"):
        np.testing.assert_allclose(
            device.estimates[name], host.estimates[name], rtol=0, atol=4 * AREA_ATOL
        )


@pytest.mark.parametrize("n", [1, 4, 64])  # rings 4, 2, 1
def test_device_cells_equal_qhull_cells(runtime, n):
    # The default ring certifies every pixel on the device (all cells of these realisations)
    frame = device_ring(guard_distance(n))
    points, values = realisation(n, n, frame)
    host = estimate_image(points, values, WIDTH, HEIGHT, n, frame)
    device = estimate_image(points, values, WIDTH, HEIGHT, n, frame, runtime=runtime)
    assert device.stats.device_pixels == WIDTH * HEIGHT
    assert device.stats.qhull_calls == 0 and host.stats.uncertified_nuclei == 0
    assert_same_estimates(device, host)
    # Not the same bits: the cells really come from the device
    assert not np.array_equal(device.areas, host.areas)


def run_both(runtime, points, values, n, frame, ring=None):
    delta = guard_distance(n)
    extent = (-frame, -frame, WIDTH + frame, HEIGHT + frame)
    grid = grid_from_points(
        PixelRect(0, 0, WIDTH, HEIGHT).grown(math.ceil(frame)),
        points,
        values,
        np.arange(len(points)),
    )
    count = WIDTH * HEIGHT
    device = estimate_run_device(runtime, grid.take, WIDTH, 0, count, n, delta, extent, ring=ring)
    host = estimate_image(points, values, WIDTH, HEIGHT, n, frame)
    return device, host


def test_pixels_the_ring_cannot_certify_go_to_the_host(runtime):
    # n = 1 with a ring of 1 pixel instead of 4: many cells have a vertex disc beyond the
    # known square; their pixels are estimated by Qhull, the others stay on the device, and
    # together they give Qhull's cells (accepting an uncertified cell gives wrong areas here)
    n, frame = 1, 4.0
    points, values = realisation(11, n, frame)
    device, host = run_both(runtime, points, values, n, frame, ring=1)
    assert 0 < device.stats.device_pixels < WIDTH * HEIGHT - 20
    assert device.stats.qhull_calls == WIDTH * HEIGHT - device.stats.device_pixels
    # ids are the indices of the points (grid_from_points' ids); host.areas is per point
    np.testing.assert_allclose(device.areas, host.areas[device.ids], rtol=0, atol=AREA_ATOL)
    for name in ("ivor", "ivor_sn"):
        np.testing.assert_allclose(
            device.estimates[name], host.estimates[name].reshape(-1, 3), rtol=0, atol=4e-6
        )


def test_finite_realisation_border_pixels_go_to_the_host(runtime):
    # A frame of half a pixel at n = 16 (ring 2): the pixels within 2 of the image border see
    # beyond the realisation, where no nucleus was drawn, so the device cannot certify them:
    # the host estimates them (with its uncertified cells counted alike)
    n, frame = 16, 0.5
    assert device_ring(guard_distance(n)) == 2
    points, values = realisation(7, n, frame)
    device, host = run_both(runtime, points, values, n, frame)
    assert device.stats.device_pixels == (WIDTH - 4) * (HEIGHT - 4)
    assert host.stats.uncertified_nuclei > 0
    assert device.stats.uncertified_nuclei == host.stats.uncertified_nuclei
    np.testing.assert_allclose(device.areas, host.areas[device.ids], rtol=0, atol=AREA_ATOL)
    np.testing.assert_allclose(
        device.estimates["ivor"], host.estimates["ivor"].reshape(-1, 3), rtol=0, atol=4e-6
    )


def render_image(runtime, estimator, backend, tile_samples=None):
    source = AnalyticSource.for_scene("analytic:mix", runtime.queue, 24, 16)
    options = {} if tile_samples is None else dict(tile_samples=tile_samples, overlap=False)
    settings = RenderSettings(
        24, 16, make_sampler("sppp", 32), estimator, seed=3, voronoi_backend=backend, **options
    )
    return render(runtime, source, settings).film.image()


@pytest.mark.parametrize("estimator", ["ivor", "ivor_sn"])
def test_device_and_qhull_backends_give_the_same_image(runtime, estimator):
    device = render_image(runtime, estimator, "device")
    qhull = render_image(runtime, estimator, "qhull")
    np.testing.assert_allclose(device, qhull, rtol=1e-6, atol=1e-7)
    assert not np.array_equal(device, qhull)
    # Each pixel's diagram is its own: the same bits whatever the tiling
    assert np.array_equal(render_image(runtime, estimator, "device", tile_samples=7 * 50), device)


@pytest.mark.parametrize("scale", [1e-6, 1e-9])
def test_near_coincident_nuclei_go_to_the_host(runtime, scale):
    # 41 nuclei within `scale` of a spot and a pair 0.6 near_coincident_length apart (the
    # host's exact-reference test case): rounded relative to a pixel's centre, their cells
    # would be off by up to 1.5e-2 (measured at 1e-8, before the device checked the nearest
    # neighbour); their pixels go to the host, which settles them exactly
    points, _ = with_cluster(11, scale)
    values = np.random.default_rng(8).uniform(0.5, 1.5, (len(points), 2))
    host = cluster_estimate(points, values)
    device = cluster_estimate(points, values, runtime=runtime)
    pixels = CLUSTER_IMAGE["width"] * CLUSTER_IMAGE["height"]
    assert 0 < pixels - device.stats.device_pixels <= 4
    assert device.stats.settled_nuclei >= 43
    assert_same_estimates(device, host)


def test_launch_chunks_do_not_change_the_bits(runtime, monkeypatch):
    # Launches of a few pixels each (CHUNK_NUCLEI small) give every pixel the same bits as one
    # launch: each pixel's diagram and grid are its own
    n, frame = 16, 2.0
    points, values = realisation(3, n, frame)
    whole, _ = run_both(runtime, points, values, n, frame)
    monkeypatch.setattr(image_device, "CHUNK_NUCLEI", 500)
    chunked, _ = run_both(runtime, points, values, n, frame)
    assert np.array_equal(chunked.ids, whole.ids) and np.array_equal(chunked.areas, whole.areas)
    assert np.array_equal(chunked.sums.weighted, whole.sums.weighted)
    assert chunked.stats == whole.stats
