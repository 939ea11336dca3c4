"""One trace, many estimators: every estimator's image from one render equals the one it gets
rendered alone (the per-pixel estimators of a redrawn pixel share its accepted draw), the
per-pixel layers hold the accepted draw's count, redraw number and an unbiased variance, and
the render's time is split into stages."""

import functools
from dataclasses import replace

import numpy as np
import pytest

from clrender.analytic import AnalyticSource
from clrender.errors import ParameterError
from clrender.estimators.registry import estimator_info
from clrender.estimators.variance import PixelMoments, mc_variance, variance_is_unbiased
from clrender.pipeline import REDRAWS_BEFORE_ENLARGE, RenderSettings, render
from clrender.runtime import create_runtime
from clrender.samples import SampleSets
from clrender.sampling import generate_sample_sets, make_sampler

WIDTH, HEIGHT = 24, 16


def source(runtime, scene="analytic:mix"):
    return AnalyticSource.for_scene(scene, runtime.queue, WIDTH, HEIGHT)


def settings(estimator, sampler="sppp", spp=16, eps=None, **options):
    config = (
        make_sampler(sampler, spp, eps=eps) if sampler == "sppp" else make_sampler(sampler, spp)
    )
    return RenderSettings(WIDTH, HEIGHT, config, estimator, seed=3, **options)


@pytest.fixture(scope="module")
def rendered_alone(runtime):
    """image_alone(name, backend): an estimator's image rendered alone with eps = 0.02, rendered
    once for every parametrisation that compares with it."""

    @functools.cache
    def image_alone(name, backend):
        return render(runtime, source(runtime), settings(name, eps=0.02, voronoi_backend=backend))

    return image_alone


@pytest.mark.parametrize(
    "names, backend",
    [
        (["mc", "vor_sn", "fvor", "vor"], "device"),
        (["mc_n", "pvor", "vor_sn"], "device"),
        (["ivor_sn", "mc", "vor_sn", "cvor"], "device"),
        (["mc", "vor_sn", "fvor"], "qhull"),
    ],
)
def test_each_image_equals_its_estimator_rendered_alone(runtime, rendered_alone, names, backend):
    # eps = 0.02 makes most pixels reject their first draw: the redraw path is exercised
    many = render(runtime, source(runtime), settings(names, eps=0.02, voronoi_backend=backend))
    redrawn = many.layers.redraws.reshape(-1) > 0
    assert list(many.images) == names and redrawn.sum() > WIDTH * HEIGHT // 4
    for name in names:
        alone = rendered_alone(name, backend)
        same = (alone.image == many.images[name]).all(axis=-1).reshape(-1)
        if estimator_info(name).cells in ("sppp",) or estimator_info(name).image_level:
            assert same.all(), name  # it redraws the same pixels alone, or never redraws
        else:
            # mc, mc_n, cvor, pvor never reject alone: they keep draw 0 there
            assert same[~redrawn].all(), name
            assert not same[redrawn].all(), name


def test_mc_from_the_device_sums_equals_mc_from_the_host_samples(runtime):
    # With a device-cell estimator beside it, mc reads the plain sums of the Voronoi kernel
    many = render(runtime, source(runtime), settings(["vor_sn", "mc"]))
    alone = render(runtime, source(runtime), settings("mc"))
    redrawn = many.layers.images()["redraws"] > 0
    np.testing.assert_array_equal(many.images["mc"][~redrawn], alone.image[~redrawn])


def test_a_pvor_render_shifts_every_estimators_low_discrepancy_points(runtime):
    many = render(runtime, source(runtime), settings(["mc", "pvor"], sampler="sobol"))
    assert many.settings.sampler.toroidal_shift
    alone = render(runtime, source(runtime), settings("pvor", sampler="sobol"))
    np.testing.assert_array_equal(many.images["pvor"], alone.image)


def test_layers_hold_the_accepted_draws_counts_and_redraw_numbers(runtime):
    config = make_sampler("sppp", 16, eps=0.12)
    result = render(runtime, source(runtime), settings(["mc", "vor_sn"], eps=0.12))
    layers = result.layers
    assert (layers.redraws[layers.redraws <= REDRAWS_BEFORE_ENLARGE + 1] > 0).sum() > 50
    # Regenerate each pixel's accepted draw where it kept the sampler's eps (the driver widens
    # eps after REDRAWS_BEFORE_ENLARGE + 1 redraws): its count is the layer's
    pixels = np.flatnonzero(layers.redraws <= REDRAWS_BEFORE_ENLARGE + 1).astype(np.uint32)
    assert len(pixels) > WIDTH * HEIGHT // 4  # 147 of 384 here
    drawn = generate_sample_sets(
        runtime, config, 3, pixels, layers.redraws[pixels], (WIDTH, HEIGHT)
    )
    np.testing.assert_array_equal(np.diff(drawn.traced_offsets), layers.samples[pixels])
    fixed = render(runtime, source(runtime), settings("mc", sampler="stratified"))
    assert (fixed.layers.samples == 16).all() and (fixed.layers.redraws == 0).all()


def test_image_level_estimators_keep_draw_zero_and_its_layers(runtime):
    result = render(runtime, source(runtime), settings(["ivor", "vor_sn"], eps=0.02))
    assert (result.layers.redraws > 0).any()
    first = result.layers_of("ivor")
    assert first is result.first_draw_layers and not first.redraws.any()
    alone = render(runtime, source(runtime), settings("ivor", eps=0.02))
    np.testing.assert_array_equal(result.images["ivor"], alone.image)
    np.testing.assert_array_equal(first.samples, alone.layers.samples)
    assert result.layers_of("vor_sn") is result.layers


def test_variance_layer_is_the_unbiased_variance_of_mc(runtime):
    # Independent samples of analytic:smooth, 64 seeds: the mean of the layer matches the
    # variance of the mc estimates across seeds within 5 standard errors (per image)
    estimates, layers = [], []
    for seed in range(64):
        config = make_sampler("independent", 8)
        result = render(
            runtime,
            source(runtime, "analytic:smooth"),
            RenderSettings(WIDTH, HEIGHT, config, "mc", seed=seed),
        )
        estimates.append(result.image)
        layers.append(result.layers.variance.reshape(HEIGHT, WIDTH, 3))
    estimates, layers = np.array(estimates, np.float64), np.array(layers, np.float64)
    observed = estimates.var(axis=0, ddof=1).mean()
    predicted = layers.mean()
    # The across-seed variance of a variance estimate from 64 draws: about sqrt(2/63) relative
    assert abs(observed - predicted) < 5 * np.sqrt(2 / 63) * predicted / np.sqrt(WIDTH * HEIGHT / 4)


def test_variance_formulas_against_hand_computed_values():
    sets = SampleSets(
        np.array([[0.1, 0.2], [0.3, -0.1], [0.0, 0.0], [0.2, 0.2], [0.4, 0.4]], np.float32),
        np.array([0, 2, 5]),
        n=2.0,
    )
    values = np.array([[1.0, 2, 3], [3, 2, 1], [0, 0, 0], [1, 1, 1], [2, 2, 2]])
    moments = PixelMoments.of_samples(sets, values)
    fixed = mc_variance(moments, make_sampler("independent", 2))
    np.testing.assert_allclose(fixed[0], [1.0, 0.0, 1.0])  # s^2 / n: s^2 = (2, 0, 2), n = 2
    poisson = mc_variance(moments, make_sampler("sppp", 2))
    np.testing.assert_allclose(poisson[1], [5 / 4] * 3)  # sum f^2 / n^2 = (0 + 1 + 4) / 4
    assert variance_is_unbiased(estimator_info("mc"), make_sampler("sppp", 4))
    assert not variance_is_unbiased(estimator_info("mc"), make_sampler("sobol", 4))
    assert not variance_is_unbiased(estimator_info("vor_sn"), make_sampler("sppp", 4))


def test_the_timed_parts_account_for_the_wall_time(runtime):
    # Without overlap every part runs on the main thread, one after the other: the stages,
    # the estimators, the layers and the builds leave only bookkeeping untimed
    for names in (["mc"], ["mc", "vor_sn", "fvor"], ["ivor_sn", "cvor"]):
        config = settings(names, sampler="sppp", overlap=False)
        bigger = replace(config, width=96, height=64)
        stats = render(runtime, source_of_size(runtime, 96, 64), bigger).stats
        timed = stats.device_seconds + stats.host_seconds + stats.compile_seconds
        assert stats.device_seconds == pytest.approx(sum(stats.stage_seconds.values()))
        assert timed <= stats.wall_seconds
        assert stats.wall_seconds - timed < 0.1 * stats.wall_seconds + 0.02, (names, stats)
        assert stats.layer_seconds > 0 and stats.stage_seconds["tracing"] > 0


def source_of_size(runtime, width, height):
    return AnalyticSource.for_scene("analytic:mix", runtime.queue, width, height)


@pytest.mark.device
def test_program_builds_are_timed_apart_once_per_process():
    # A runtime of its own: its programs are built in the first render, not in the second; with
    # and without overlap (with it, the image-level estimators' kernels run on a second context,
    # without it on the first: each builds its own)
    fresh = create_runtime()
    for overlap in (True, False):
        names = ["ivor", "vor_sn", "mc"]
        first = render(fresh, source(fresh), settings(names, overlap=overlap))
        second = render(fresh, source(fresh), settings(names, overlap=overlap))
        assert first.stats.compile_seconds > 0.01 and first.stats.main_compile_seconds > 0
        assert second.stats.compile_seconds < 0.001, (overlap, second.stats)
        assert first.stats.run_seconds < first.stats.wall_seconds


def test_replace_keeps_every_estimator_and_a_list_replaces_them_all():
    made = settings(["vor_sn", "fvor"])
    assert [e.name for e in replace(made, seed=9).estimators] == ["vor_sn", "fvor"]
    assert [e.name for e in replace(made, estimator=["fvor", "mc"]).estimators] == ["fvor", "mc"]
    assert [e.name for e in replace(made, estimator="mc").estimators] == ["mc", "fvor"]


@pytest.mark.parametrize(
    "estimators, message",
    [
        (["mc", "mc"], "named twice"),
        ([], "at least one"),
        (["mc", "nope"], "unknown estimator"),
        (["mc", "vor_sn"], "needs the auxiliary nuclei"),
    ],
)
def test_bad_estimator_lists_are_one_line_errors(estimators, message):
    sampler = "sobol" if "vor_sn" in estimators else "sppp"
    with pytest.raises(ParameterError, match=message) as error:
        settings(estimators, sampler=sampler)
    assert "\n" not in str(error.value)


def test_without_double_precision_mc_and_the_layers_come_from_the_host(
    runtime, single_precision, monkeypatch
):
    # The device's plain sums would be float32 there: the samples come back instead
    from clrender import pipeline
    from clrender.runtime import NO_FP64_VARIABLE

    config = settings(["vor_sn", "mc"])
    host_samples = pipeline.TilePipeline(runtime, source(runtime), config).host_samples
    assert host_samples == single_precision
    monkeypatch.setenv(NO_FP64_VARIABLE, "1")  # as a device without cl_khr_fp64
    assert pipeline.TilePipeline(runtime, source(runtime), config).host_samples
    many = render(runtime, source(runtime), config)
    alone = render(runtime, source(runtime), settings("mc"))
    np.testing.assert_array_equal(many.images["mc"], alone.image)
    np.testing.assert_array_equal(many.layers.variance, alone.layers.variance)
