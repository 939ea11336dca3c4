"""Every estimator end to end (device samples -> analytic radiance -> host estimator -> film)
against exact pixel integrals.

Statistics: a pixel's error is independent of the others', so over P pixels the mean error
has standard error SE = std(errors) / sqrt(P). Unbiased estimators must keep |mean error| below
4 SE in every channel (fixed seeds: the outcome is deterministic, the bound says how far a
correct implementation could land by chance). Biased ones are held to stated tolerances.
"""

from dataclasses import replace

import numpy as np
import pytest

from clrender.analytic import (
    AnalyticImage,
    AnalyticSource,
    Disc,
    PixelBowl,
    SmoothSines,
    StepEdge,
    analytic_functions,
    analytic_image,
)
from clrender.pipeline import RenderSettings, render
from clrender.sampling import make_sampler

WIDTH, HEIGHT, SPP = 48, 48, 16


def check_image(width: int, height: int) -> AnalyticImage:
    """Smooth (Hoelder 1), disc (discontinuous) and pixel bowl (periodic) channels."""
    functions = analytic_functions(width, height)
    return AnalyticImage("check", (functions["smooth"], functions["disc"], functions["bowl"]))


def render_errors(runtime, image, estimator, sampler, spp=SPP, seed=11):
    """(P, 3) errors of a full-pipeline render against the exact pixel integrals."""
    source = AnalyticSource(image, runtime.queue, WIDTH, HEIGHT)
    settings = RenderSettings(WIDTH, HEIGHT, make_sampler(sampler, spp), estimator, seed)
    result = render(runtime, source, settings)
    assert result.film.complete and result.film.flagged_count == 0
    return (result.film.image() - source.pixel_integrals()).reshape(-1, 3)


def z_scores(errors: np.ndarray) -> np.ndarray:
    return errors.mean(axis=0) / (errors.std(axis=0, ddof=1) / np.sqrt(len(errors)))


def rmse(errors: np.ndarray) -> np.ndarray:
    return np.sqrt((errors**2).mean(axis=0))


# --- the reference integrals themselves ----------------------------------------------------


def midpoint_integral(function, x: int, y: int, m: int = 1000) -> float:
    grid = (np.arange(m) + 0.5) / m
    xs, ys = np.meshgrid(x + grid, y + grid)
    return float(function.value(xs, ys).mean())


@pytest.mark.parametrize("kind", ["edge", "smooth", "disc", "bowl"])
def test_exact_integrals_match_a_fine_midpoint_rule(kind):
    function = analytic_functions(20, 16)[kind]
    exact = function.pixel_integrals(20, 16)
    # Pixels on the edge, on the disc boundary, inside and outside; a midpoint rule with
    # m^2 points errs by about (jump) / m on discontinuous pixels.
    for y, x in [(8, 10), (8, 11), (3, 4), (12, 15), (5, 5), (13, 8), (8, 9), (2, 6)]:
        assert exact[y, x] == pytest.approx(midpoint_integral(function, x, y), abs=2e-3)


def test_edge_and_disc_integrals_sum_to_their_areas():
    edge = StepEdge(x0=10.3, y0=8.0, slope=0.364, inside=1.0, outside=0.0)
    # Left of the line within the 20 x 16 image: a trapezoid with x from 10.3 - 0.364 * 8 to
    # 10.3 + 0.364 * 8 across the rows, mean width 10.3.
    assert edge.pixel_integrals(20, 16).sum() == pytest.approx(10.3 * 16, abs=1e-10)
    disc = Disc(cx=9.21, cy=7.67, r=5.17, inside=1.0, outside=0.0)
    assert disc.pixel_integrals(20, 16).sum() == pytest.approx(np.pi * 5.17**2, abs=1e-10)


def test_smooth_and_bowl_integrals_are_exact():
    smooth = SmoothSines(kx=0.9, ky=1.3)
    y, x = 3, 7
    assert smooth.pixel_integrals(10, 5)[y, x] == pytest.approx(
        midpoint_integral(smooth, x, y, 400), abs=1e-6
    )
    assert PixelBowl().pixel_integrals(3, 2) == pytest.approx(np.full((2, 3), 1 / 6))


# --- the pipeline maps samples to the right pixels ------------------------------------------


def test_pixel_estimates_land_on_the_right_pixels(runtime):
    # A flip, transpose or half-pixel shift moves the tilted edge and the off-centre disc:
    # edge pixels would then miss by up to 0.45, far beyond stratified noise at 64 spp.
    image = analytic_image("analytic:mix", WIDTH, HEIGHT)
    errors = render_errors(runtime, image, "mc", "stratified", spp=64)
    assert np.abs(errors).max() < 0.1


# --- unbiased estimators -------------------------------------------------------------------


@pytest.mark.parametrize(
    "estimator, sampler",
    [
        ("mc", "independent"),
        ("mc", "stratified"),
        ("mc", "stratified-pixel"),
        ("mc", "sobol"),
        ("mc", "zsobol"),
        ("mc", "sppp"),
        ("mc_n", "sppp-sobol"),
        ("vor", "sppp"),
        ("vor", "sppp-sobol"),
        ("pvor", "independent"),
        ("pvor", "sppp"),
        ("pvor", "stratified"),
        ("pvor", "stratified-pixel"),
        ("pvor", "sobol"),
        ("pvor", "zsobol"),
        ("ivor", "sppp"),
        ("ivor", "sppp-sobol"),
    ],
)
def test_unbiased_estimators_within_4_standard_errors(runtime, estimator, sampler):
    # pvor over stratified and Sobol points is unbiased through the toroidal shift the render
    # settings turn on for it (tested on its own below)
    errors = render_errors(runtime, check_image(WIDTH, HEIGHT), estimator, sampler)
    assert np.all(np.abs(z_scores(errors)) < 4.0), z_scores(errors)


# --- self-normalised and filtered Voronoi: small bias, lower error ----------------------------


@pytest.fixture(scope="module")
def check_errors(runtime):
    image = check_image(WIDTH, HEIGHT)
    return {
        name: render_errors(runtime, image, name, sampler)
        for name, sampler in [
            ("vor_sn", "sppp"),
            ("fvor", "sppp"),
            ("ivor_sn", "sppp"),
            ("mc", "independent"),
            ("mc_n", "sppp"),
        ]
    }


@pytest.mark.parametrize("estimator", ["vor_sn", "fvor", "ivor_sn"])
def test_normalised_voronoi_bias_below_2_percent(check_errors, estimator):
    # Ratio estimators: biased by O(1/n); at n = 16 the bowl shows about 1.2 % (z ~ -4.5).
    mean_integrals = check_image(WIDTH, HEIGHT).pixel_integrals(WIDTH, HEIGHT).mean(axis=(0, 1))
    bias = check_errors[estimator].mean(axis=0)
    assert np.all(np.abs(bias) < 0.02 * mean_integrals), bias


@pytest.mark.parametrize("estimator", ["vor_sn", "fvor", "ivor_sn"])
def test_normalised_voronoi_beats_mc_on_smooth_and_discontinuous_channels(check_errors, estimator):
    # Same spp: below i.i.d. uniform mc (measured ratios 0.7 and 0.75) and well below mc_n
    # on the same SPPP samples, whose Poisson count adds variance.
    voronoi = rmse(check_errors[estimator])[:2]
    assert np.all(voronoi < 0.85 * rmse(check_errors["mc"])[:2])
    assert np.all(voronoi < 0.85 * rmse(check_errors["mc_n"])[:2])


# --- clipped Voronoi: biased where the paper says ------------------------------------------


def test_clipped_voronoi_is_biased_on_a_pixel_periodic_bowl(runtime):
    # Clipped cells of nuclei near W's edges reach the border, where the bowl peaks, yet the
    # nucleus value is taken inside: a systematic underestimate (measured -12 %, z ~ -40),
    # which the periodic estimator on the same samples does not have.
    image = AnalyticImage("bowl", (PixelBowl(),) * 3)
    clipped = render_errors(runtime, image, "cvor", "independent")[:, 0]
    periodic = render_errors(runtime, image, "pvor", "independent")[:, 0]
    assert clipped.mean() < -0.05 / 6 and z_scores(clipped[:, None])[0] < -10
    assert abs(z_scores(periodic[:, None])[0]) < 4


# --- pvor over low-discrepancy points: the toroidal shift ------------------------------------


def test_pvor_settings_shift_low_discrepancy_points_and_only_those():
    shifted = RenderSettings(8, 8, make_sampler("sobol", 16), "pvor")
    assert shifted.sampler.toroidal_shift
    assert not replace(shifted, estimator="mc").sampler.toroidal_shift  # follows the estimator
    for sampler, estimator in [("sobol", "mc"), ("independent", "pvor"), ("sppp", "pvor")]:
        settings = RenderSettings(8, 8, make_sampler(sampler, 16), estimator)
        assert not settings.sampler.toroidal_shift, (sampler, estimator)


def test_pvor_over_an_unshifted_grid_is_biased_and_the_shift_removes_it(runtime):
    """Owen-scrambled Sobol points are not a stationary process: without the shift their
    torus cell areas correlate with where they lie in the pixel, and pvor on the pixel bowl
    (periodic, peaked at the border) is biased (measured z = -26 at 16 spp; stratified and
    zsobol show it too, at -3 and -78). With the shift (the settings' default for pvor) it is
    within 4 SE (measured -1.1). Bound for the biased case: 10 SE, so the control can fail."""
    image = AnalyticImage("bowl", (PixelBowl(),) * 3)
    source = AnalyticSource(image, runtime.queue, WIDTH, HEIGHT)
    exact = source.pixel_integrals().reshape(-1, 3)[:, 0]
    errors = {}
    for shift in (False, True):
        config = make_sampler("sobol", 16)
        settings = RenderSettings(WIDTH, HEIGHT, config, "pvor", 11)
        if not shift:  # the settings turn the shift on for pvor: take it back off
            object.__setattr__(settings, "sampler", replace(settings.sampler, toroidal_shift=False))
        image_out = render(runtime, source, settings).film.image().reshape(-1, 3)[:, 0]
        errors[shift] = (image_out - exact)[:, None]
    assert abs(z_scores(errors[True])[0]) < 4
    assert abs(z_scores(errors[False])[0]) > 10


# --- convergence rates -----------------------------------------------------------------------

SLOPE_SPP = (16, 64, 256)


def mse_slope(runtime, image, sampler, channel, seeds=(1, 2)):
    """Slope of log MSE against log spp over SLOPE_SPP, MSE over 32 x 32 pixels and seeds."""
    source = AnalyticSource(image, runtime.queue, 32, 32)
    exact = source.pixel_integrals()[..., channel]
    mse = []
    for spp in SLOPE_SPP:
        squared = [
            (
                render(
                    runtime, source, RenderSettings(32, 32, make_sampler(sampler, spp), "mc", s)
                ).film.image()[..., channel]
                - exact
            )
            ** 2
            for s in seeds
        ]
        mse.append(np.mean(squared))
    return float(np.polyfit(np.log(SLOPE_SPP), np.log(mse), 1)[0])


@pytest.fixture(scope="module")
def slope_image():
    functions = analytic_functions(32, 32)
    return AnalyticImage("slopes", (functions["smooth"], functions["edge"], functions["disc"]))


# Measured at 32 x 32, 16-1024 spp, 3 seeds (smooth, edge): independent -0.99, -1.05;
# stratified -2.00, -1.52; sobol -2.81, -1.51; zsobol -2.81, -1.48. Theory: -1 for i.i.d.
# samples; -1.5 for stratified or net points on an edge; -2 for jittered strata and -3 for
# Owen-scrambled nets on a smooth integrand.
@pytest.mark.parametrize(
    "sampler, smooth_range, edge_range",
    [
        ("independent", (-1.2, -0.8), (-1.2, -0.8)),
        ("stratified", (-2.3, -1.7), (-1.8, -1.25)),
        ("sobol", (-3.3, -2.3), (-1.8, -1.25)),
        ("zsobol", (-3.3, -2.3), (-1.8, -1.25)),
    ],
)
def test_error_slopes_on_smooth_and_edge_images(
    runtime, slope_image, sampler, smooth_range, edge_range
):
    smooth = mse_slope(runtime, slope_image, sampler, 0)
    edge = mse_slope(runtime, slope_image, sampler, 1)
    assert smooth_range[0] < smooth < smooth_range[1], smooth
    assert edge_range[0] < edge < edge_range[1], edge
