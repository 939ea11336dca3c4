"""End to end on the path tracer: the authors' Cornell box at a tiny resolution."""

import numpy as np
import pytest

from clrender import cli
from clrender.imageio import read_exr
from clrender.pipeline import RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

SIZE = 24


@pytest.fixture(scope="module")
def cornell(runtime):
    tracer = PathTracer(runtime, load_scene("cornell-box"), max_depth=8)
    return PathTracerSource(tracer, SIZE, SIZE)


def render_cornell(runtime, source, estimator="vor_sn", sampler="sppp", spp=16, **options):
    settings = RenderSettings(SIZE, SIZE, make_sampler(sampler, spp), estimator, 3, **options)
    return render(runtime, source, settings)


def test_cornell_box_image_has_the_walls_and_light_where_they_belong(runtime, cornell):
    result = render_cornell(runtime, cornell)
    image = result.film.image()
    assert result.film.complete and result.film.flagged_count == 0
    assert np.isfinite(image).all() and image.min() >= 0.0
    assert result.stats.rays > result.stats.traced_samples > 0
    middle = slice(SIZE // 3, 2 * SIZE // 3)
    left, right = image[middle, 1].mean(axis=0), image[middle, -2].mean(axis=0)
    assert left[1] > 2 * left[0]  # green wall (x = 555) on the left
    assert right[0] > 2 * right[1]  # red wall on the right
    # The light (radiance 24) is seen at 0.67-0.74 of the half field of view above the centre:
    # rows 3-4 of 24, centre columns; it is the brightest thing in the image.
    row, column = np.unravel_index(image.sum(axis=2).argmax(), (SIZE, SIZE))
    assert 2 <= row <= 5 and abs(column - SIZE / 2) < 3
    assert image[row, column].min() > 5.0


def test_cornell_estimators_agree_on_the_image_mean(runtime, cornell):
    # vor_sn and ivor_sn on SPPP samples against mc on stratified ones, 9216 paths each: the
    # glass ball's caustic paths make the image mean noisy (mc's seeds 3 and 4 differ by 5 %;
    # measured here: 3.3 % and 1.5 %), so 10 % is the bound; an estimator with a wrong scale
    # or a sample/pixel mix-up lands far outside it.
    means = {
        name: render_cornell(runtime, cornell, name, sampler).film.image().mean()
        for name, sampler in [("vor_sn", "sppp"), ("ivor_sn", "sppp"), ("mc", "stratified")]
    }
    assert means["vor_sn"] == pytest.approx(means["mc"], rel=0.10)
    assert means["ivor_sn"] == pytest.approx(means["mc"], rel=0.10)


@pytest.mark.parametrize("estimator", ["vor_sn", "ivor_sn"])
def test_cornell_render_is_bit_identical_across_tilings_and_overlap(runtime, cornell, estimator):
    reference = render_cornell(runtime, cornell, estimator).film.image()
    for tile_samples, overlap in [(16 * 40, True), (16 * 100, False)]:
        image = render_cornell(
            runtime, cornell, estimator, tile_samples=tile_samples, overlap=overlap
        ).film.image()
        assert np.array_equal(image, reference)


@pytest.mark.device
def test_default_command_renders_the_cornell_box(capsys, tmp_path):
    out = tmp_path / "cb.exr"
    status = cli.main(["render", "--res", "12x8", "--spp", "4", "--max-depth", "3", "-o", str(out)])
    assert status == 0
    stdout = capsys.readouterr().out
    assert "cornell-box: 12x8, 4 spp, sppp + vor_sn" in stdout and "rays" in stdout
    pixels, meta = read_exr(out)
    assert pixels.shape == (8, 12, 3)
    assert (meta["scene"], meta["max_depth"], meta["partial"]) == ("cornell-box", 3, 0)
    assert meta["rays"] > 0 or isinstance(meta["rays"], str)


@pytest.fixture(scope="module")
def mitsuba_cbox_reference(runtime):
    """mitsuba-cbox (diffuse only) at 24 x 24: the source and a 256 spp independent mc image."""
    tracer = PathTracer(runtime, load_scene("mitsuba-cbox"), max_depth=8)
    source = PathTracerSource(tracer, SIZE, SIZE)
    settings = RenderSettings(SIZE, SIZE, make_sampler("independent", 256), "mc", 1001)
    return source, render(runtime, source, settings).film.image()


@pytest.mark.parametrize(
    "estimator, sampler",
    [
        ("vor", "sppp-sobol"),
        ("mc_n", "sppp-sobol"),
        ("mc", "sobol"),
        ("mc", "zsobol"),
        ("mc", "stratified"),
        ("pvor", "sobol"),
        ("pvor", "stratified"),
    ],
)
def test_unbiased_estimators_over_low_discrepancy_paths(
    runtime, mitsuba_cbox_reference, estimator, sampler
):
    """Path dimensions from the sampler, Voronoi weights or counts on top: the image at 16 spp
    minus an independent 256 spp image has mean 0 within 4.5 standard errors per channel
    (pixel differences are independent with zero mean if both are unbiased; zsobol's are
    negatively correlated, which only makes the bound looser)."""
    source, reference = mitsuba_cbox_reference
    settings = RenderSettings(SIZE, SIZE, make_sampler(sampler, 16), estimator, 7)
    difference = (render(runtime, source, settings).film.image() - reference).reshape(-1, 3)
    z = difference.mean(axis=0) / (difference.std(axis=0, ddof=1) / np.sqrt(len(difference)))
    assert np.all(np.abs(z) < 4.5), z
