"""The render pipeline's Voronoi backends: the device kernel and host Qhull give the same
image (to float rounding), each deterministic whatever the tiling."""

import numpy as np
import pytest

from clrender.analytic import AnalyticSource
from clrender.errors import ParameterError
from clrender.pipeline import RenderSettings, render
from clrender.sampling import make_sampler

WIDTH, HEIGHT = 24, 16
# Images from float32 cells and sums (no cl_khr_fp64) against float64 ones (measured 5e-7)
SINGLE_RTOL, SINGLE_ATOL = 1e-5, 1e-6


def render_image(runtime, estimator, backend, eps=None, sampler="sppp", **options):
    source = AnalyticSource.for_scene("analytic:mix", runtime.queue, WIDTH, HEIGHT)
    settings = RenderSettings(
        WIDTH,
        HEIGHT,
        make_sampler(sampler, 32, eps=eps),
        estimator,
        seed=3,
        voronoi_backend=backend,
        **options,
    )
    return render(runtime, source, settings)


@pytest.mark.parametrize("estimator", ["vor", "vor_sn", "fvor"])
def test_device_and_qhull_cells_give_the_same_image(runtime, single_precision, estimator):
    device = render_image(runtime, estimator, "device").film.image()
    qhull = render_image(runtime, estimator, "qhull").film.image()
    # Both tessellations are exact; they differ only by float64 rounding (about 1e-14), or by
    # float32's where the device has no double precision
    rtol, atol = (SINGLE_RTOL, SINGLE_ATOL) if single_precision else (1e-9, 1e-12)
    np.testing.assert_allclose(device, qhull, rtol=rtol, atol=atol)


# A device without cl_khr_fp64 (forced here on every device): float32 cells and sums give
# Qhull's float64 image within SINGLE_RTOL, with the same redraws (the walk and the clipping
# decide boundedness in float32 in every precision)
def test_single_precision_device_cells_give_the_qhull_image(runtime, no_fp64):
    # eps below the paper's 0.38 at n = 32: a few pixels are redrawn (redraws use Qhull)
    device = render_image(runtime, "vor_sn", "device", eps=0.2)
    qhull = render_image(runtime, "vor_sn", "qhull", eps=0.2)
    assert 0 < device.stats.redrawn_pixels < WIDTH * HEIGHT / 4
    assert device.stats.redrawn_pixels == qhull.stats.redrawn_pixels
    image = device.film.image()
    np.testing.assert_allclose(image, qhull.film.image(), rtol=SINGLE_RTOL, atol=SINGLE_ATOL)
    assert not np.array_equal(image, qhull.film.image())  # float32 sums: not the same bits


# pvor's torus cells and cvor's clipped cells: the device rounds each translate or mirror image
# to float32 (up to 6e-8), Qhull does not
@pytest.mark.parametrize("estimator", ["pvor", "cvor"])
@pytest.mark.parametrize("sampler", ["independent", "sobol", "sppp"])
def test_device_and_qhull_copy_cells_give_the_same_image(runtime, estimator, sampler):
    device = render_image(runtime, estimator, "device", sampler=sampler)
    qhull = render_image(runtime, estimator, "qhull", sampler=sampler).film.image()
    assert device.settings.device_cells
    np.testing.assert_allclose(device.film.image(), qhull, rtol=1e-6, atol=1e-7)


def test_forced_rejections_agree_between_backends(runtime):
    # eps far below the paper's: many pixels are rejected and redrawn (redraws use Qhull).
    device = render_image(runtime, "vor_sn", "device", eps=0.02)
    qhull = render_image(runtime, "vor_sn", "qhull", eps=0.02)
    assert device.stats.redrawn_pixels > 0
    assert device.stats.redrawn_pixels == qhull.stats.redrawn_pixels
    np.testing.assert_allclose(device.film.image(), qhull.film.image(), rtol=1e-9, atol=1e-12)


def test_qhull_backend_is_bit_identical_whatever_the_tiling(runtime):
    reference = render_image(runtime, "vor_sn", "qhull").film.image()
    tiled = render_image(runtime, "vor_sn", "qhull", tile_samples=7 * 50, overlap=False)
    assert np.array_equal(tiled.film.image(), reference)


def test_only_sppp_torus_and_clipped_cell_estimators_use_the_device_cells():
    sampler = make_sampler("sppp", 16)
    for estimator, expected in [
        ("vor", True),
        ("vor_sn", True),
        ("fvor", True),
        ("mc", False),
        ("pvor", True),
        ("cvor", True),
        ("ivor", False),
    ]:
        assert RenderSettings(4, 4, sampler, estimator).device_cells is expected, estimator
    assert not RenderSettings(4, 4, sampler, "vor", voronoi_backend="qhull").device_cells


def test_unknown_backend_lists_the_accepted_ones():
    with pytest.raises(ParameterError, match="accepted: device, qhull"):
        RenderSettings(4, 4, make_sampler("sppp", 16), "vor", voronoi_backend="gpu")


@pytest.mark.parametrize(
    "estimator, sampler", [("fvor", "sppp"), ("pvor", "independent"), ("cvor", "sobol")]
)
def test_device_backend_is_bit_identical_whatever_the_tiling(runtime, estimator, sampler):
    reference = render_image(runtime, estimator, "device", sampler=sampler).film.image()
    tiled = render_image(
        runtime, estimator, "device", sampler=sampler, tile_samples=7 * 50, overlap=False
    )
    assert np.array_equal(tiled.film.image(), reference)


def test_pixels_with_undecided_cells_are_settled_on_the_host(runtime, monkeypatch):
    # Cells over 5 vertices overflow the kernel: most pixels' device sums are refused and the
    # host settles them (Qhull cells, host sums): the same image.
    from clrender.estimators import device_cells

    monkeypatch.setattr(device_cells, "MAX_VERTICES", 5)
    device = render_image(runtime, "vor_sn", "device").film.image()
    qhull = render_image(runtime, "vor_sn", "qhull").film.image()
    np.testing.assert_allclose(device, qhull, rtol=1e-9, atol=1e-12)
    for estimator in ("pvor", "cvor"):
        copies_device = render_image(runtime, estimator, "device", sampler="sobol")
        copies_qhull = render_image(runtime, estimator, "qhull", sampler="sobol").film.image()
        np.testing.assert_allclose(copies_device.film.image(), copies_qhull, rtol=1e-6, atol=1e-7)
