"""Path tracing (kernels/integrator.cl through clrender.trace): scenes with known answers,
determinism, tiling invariance, and the Cornell boxes against longer renders.

Statistical checks use the standard error measured from the samples themselves; the bound is
stated at each check. Every seed is fixed, so the outcome is reproducible.
"""

import dataclasses
import math

import numpy as np
import pyopencl as cl
import pytest

from clrender.errors import ParameterError
from clrender.sampling import (
    SAMPLERS,
    DeviceSampleSets,
    generate_sample_sets,
    make_sampler,
    rectangle_pixels,
)
from clrender.scene import load_scene
from clrender.trace import PathTracer

FURNACE_ALBEDO = 0.5
# Every sampler, at counts all of them take (16: a square and a power of two).
EVERY_SAMPLER = list(SAMPLERS)


def render(tracer, sampler, n, seed, width, height, pixels=None):
    if pixels is None:
        pixels = rectangle_pixels(width, 0, 0, width, height)
    config = make_sampler(sampler, n)
    sets = generate_sample_sets(tracer.runtime, config, seed, pixels, None, (width, height))
    result = tracer.trace(sets, seed, width, height)
    return result.to_host(), result, sets


def mean_and_se(values):
    values = np.asarray(values, np.float64)
    return values.mean(axis=0), values.std(axis=0) / math.sqrt(len(values))


def pixel_means(radiance, sets):
    """(P, 3) per-pixel mean radiance: with low-discrepancy samplers a pixel's samples are not
    independent, its pixels are (or, for zsobol, negatively correlated), so standard errors are
    taken over pixel means."""
    sums = np.add.reduceat(radiance.astype(np.float64), sets.traced_offsets[:-1], axis=0)
    return sums / np.diff(sets.traced_offsets)[:, None]


@pytest.fixture(scope="module")
def furnace():
    return load_scene("furnace")


@pytest.mark.parametrize("depth", [0, 1, 2, 8])
def test_white_furnace(runtime, furnace, depth):
    """Inside a closed cube of albedo a emitting Le = 1 everywhere, L = sum_{k<=D} a^k.
    Bound: 5 standard errors (depth 0 is exact)."""
    tracer = PathTracer(runtime, furnace, max_depth=depth)
    radiance, result, _ = render(tracer, "independent", 16, 5, 16, 16)
    expected = (1.0 - FURNACE_ALBEDO ** (depth + 1)) / (1.0 - FURNACE_ALBEDO)
    mean, se = mean_and_se(radiance)
    assert result.nonfinite == 0
    if depth == 0:
        np.testing.assert_array_equal(radiance, 1.0)
        assert result.rays == len(radiance)  # one camera ray each
    else:
        assert np.all(np.abs(mean - expected) <= 5 * se), (mean, se, expected)
        assert result.rays > 2 * len(radiance)


def test_glass_is_invisible_in_the_furnace(runtime, furnace, tmp_path):
    """A lossless glass ball inside the furnace changes nothing once paths are long enough
    (depth 64: the truncated tail is below 1e-6 here). Bound: 5 standard errors."""
    text = furnace.path.read_text() + (
        '\n[materials.glass]\ntype = "dielectric"\nior = 1.5\n'
        '\n[[shapes]]\ntype = "sphere"\ncenter = [0.0, 0.0, -0.5]\nradius = 0.4\n'
        'material = "glass"\n'
    )
    path = tmp_path / "furnace-glass.toml"
    path.write_text(text)
    tracer = PathTracer(runtime, load_scene(path), max_depth=64)
    radiance, result, _ = render(tracer, "independent", 16, 6, 16, 16)
    mean, se = mean_and_se(radiance)
    assert np.all(np.abs(mean - 1.0 / (1.0 - FURNACE_ALBEDO)) <= 5 * se), (mean, se)


def test_nonfinite_radiance_is_counted_and_zeroed(runtime, furnace):
    """Radiance 3e38 overflows float32 as soon as two emissions add up (depth >= 1). Scene
    files cannot hold such a value (the loader refuses numbers over 1e18), so the packed
    emitters are changed directly: the device must still count and zero what overflows."""
    emitters = furnace.emitters.copy()
    emitters["radiance"][:, 0] = 3e38
    hot = dataclasses.replace(furnace, emitters=emitters)
    _, result0, _ = render(PathTracer(runtime, hot, max_depth=0), "independent", 4, 1, 8, 8)
    assert result0.nonfinite == 0
    radiance, result, _ = render(PathTracer(runtime, hot, max_depth=1), "independent", 4, 1, 8, 8)
    assert result.nonfinite > 0
    assert np.all(np.isfinite(radiance))
    assert np.sum(np.all(radiance == 0, axis=1)) >= result.nonfinite


def project(scene, point, width, height):
    """Image position (x right, y down, in pixels) of a world point."""
    basis = scene.camera.basis(width, height)
    d = np.asarray(point, np.float64) - basis["origin"]
    depth = d @ basis["forward"]
    sx = d @ basis["right"] / (basis["right"] @ basis["right"]) / depth
    sy = d @ basis["up"] / (basis["up"] @ basis["up"]) / depth
    return (sx + 1.0) / 2.0 * width, (1.0 - sy) / 2.0 * height


@pytest.mark.parametrize(
    ("name", "depth"), [("cornell-box", 1), ("cornell-box", 8), ("mitsuba-cbox", 1)]
)
def test_pixel_seeing_only_the_light_equals_its_radiance(runtime, name, depth):
    scene = load_scene(name)
    width = height = 64
    light = scene.quads[scene.emitters["index"][0]]
    centre = light["corner"] + 0.5 * (light["edge1"] + light["edge2"])
    x, y = (int(v) for v in project(scene, centre, width, height))
    # The whole pixel must lie inside the light's image
    for cx in (x, x + 1):
        for cy in (y, y + 1):
            corner_hits = [
                project(
                    scene, light["corner"] + a * light["edge1"] + b * light["edge2"], width, height
                )
                for a in (0, 1)
                for b in (0, 1)
            ]
            xs, ys = zip(*corner_hits, strict=True)
            assert min(xs) < cx < max(xs) and min(ys) < cy < max(ys)
    tracer = PathTracer(runtime, scene, max_depth=depth)
    pixel = np.array([y * width + x], np.uint32)
    for sampler in EVERY_SAMPLER:
        radiance, _, _ = render(tracer, sampler, 64, 9, width, height, pixel)
        expected = np.tile(scene.emitters["radiance"][0], (len(radiance), 1))
        np.testing.assert_allclose(radiance, expected, rtol=1e-5, err_msg=sampler)


def explicit_sample_sets(runtime, positions):
    """A one-pixel launch with the given pixel-local sample positions."""
    positions = np.ascontiguousarray(positions, np.float32)
    offsets = np.array([0, len(positions)], np.int64)
    flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    zero = np.zeros(1, np.uint32)
    return DeviceSampleSets(
        make_sampler("independent", len(positions)),
        zero,
        zero,
        offsets,
        cl.Buffer(runtime.context, flags, hostbuf=positions),
        cl.Buffer(runtime.context, flags, hostbuf=offsets.astype(np.uint32)),
        cl.Buffer(runtime.context, flags, hostbuf=zero),
        cl.Buffer(runtime.context, flags, hostbuf=zero),
    )


def test_sample_positions_map_to_the_image(runtime, tmp_path):
    """A 1x1 image whose upper-right quadrant is an emitter: a sample at pixel-local (u, v)
    sits at image position (1/2 + u, 1/2 + v) with v growing downwards."""
    path = tmp_path / "quadrant.toml"
    path.write_text(
        "[camera]\nlook_from = [0.0, 0.0, 0.0]\nlook_at = [0.0, 0.0, -1.0]\nfov = 90.0\n"
        'resolution = [1, 1]\n\n[[shapes]]\ntype = "quad"\ncorner = [0.0, 0.0, -1.0]\n'
        "edge1 = [10.0, 0.0, 0.0]\nedge2 = [0.0, 10.0, 0.0]\nemission = [2.0, 3.0, 4.0]\n"
    )
    tracer = PathTracer(runtime, load_scene(path), max_depth=0)
    positions = [(0.25, -0.25), (-0.25, -0.25), (0.25, 0.25), (-0.25, 0.25), (0.45, -0.01)]
    radiance = tracer.trace(explicit_sample_sets(runtime, positions), 1).to_host()
    lit = [True, False, False, False, True]
    np.testing.assert_array_equal(radiance[lit], [[2.0, 3.0, 4.0]] * 2)
    np.testing.assert_array_equal(radiance[np.logical_not(lit)], 0.0)


@pytest.fixture(scope="module")
def cornell_tracer(runtime):
    return PathTracer(runtime, load_scene("cornell-box-glossy"), max_depth=8)


def test_same_seed_gives_bit_identical_radiance(cornell_tracer):
    first, _, _ = render(cornell_tracer, "sppp", 16, 21, 16, 16)
    second, _, _ = render(cornell_tracer, "sppp", 16, 21, 16, 16)
    other, _, _ = render(cornell_tracer, "sppp", 16, 22, 16, 16)
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first[: len(other)], other[: len(first)])


@pytest.mark.parametrize("sampler", EVERY_SAMPLER)
def test_tiling_does_not_change_per_sample_radiance(cornell_tracer, sampler):
    """The same pixels launched whole, in 4 tiles, or shuffled give bit-identical radiance."""
    width = height = 16
    seed = 33
    whole, _, whole_sets = render(cornell_tracer, sampler, 16, seed, width, height)
    per_pixel = {
        int(p): whole[whole_sets.traced_offsets[k] : whole_sets.traced_offsets[k + 1]]
        for k, p in enumerate(whole_sets.pixels)
    }
    shuffled = np.random.default_rng(0).permutation(rectangle_pixels(width, 0, 0, width, height))
    tiles = [rectangle_pixels(width, x0, y0, 8, 8) for x0 in (0, 8) for y0 in (0, 8)]
    for group in [*tiles, shuffled[:37], shuffled[37:]]:
        part, _, sets = render(cornell_tracer, sampler, 16, seed, width, height, group)
        for k, p in enumerate(sets.pixels):
            chunk = part[sets.traced_offsets[k] : sets.traced_offsets[k + 1]]
            np.testing.assert_array_equal(chunk, per_pixel[int(p)])


@pytest.mark.parametrize("name", ["cornell-box", "cornell-box-glossy", "mitsuba-cbox"])
def test_cornell_mean_matches_a_longer_render(runtime, name):
    """Image mean at 32 x 32: 16 spp against 256 spp with another seed. Bound: 4.5 combined
    standard errors per channel (samples are independent with the independent sampler)."""
    tracer = PathTracer(runtime, load_scene(name), max_depth=8)
    short, result, _ = render(tracer, "independent", 16, 101, 32, 32)
    long, _, _ = render(tracer, "independent", 256, 202, 32, 32)
    mean_s, se_s = mean_and_se(short)
    mean_l, se_l = mean_and_se(long)
    assert result.nonfinite == 0 and np.all(mean_l > 0.03)
    z = (mean_s - mean_l) / np.hypot(se_s, se_l)
    assert np.all(np.abs(z) < 4.5), (mean_s, mean_l, z)


def test_parameters_are_checked(runtime, furnace):
    with pytest.raises(ParameterError, match="max_depth"):
        PathTracer(runtime, furnace, max_depth=-1)
    tracer = PathTracer(runtime, furnace, max_depth=1)
    sets = generate_sample_sets(runtime, make_sampler("independent", 1), 1, np.array([100]))
    with pytest.raises(ParameterError, match="outside the 8 x 8 image"):
        tracer.trace(sets, 1, 8, 8)
    with pytest.raises(ParameterError, match="outside the 8 x 8 image"):
        generate_sample_sets(runtime, make_sampler("sobol", 1), 1, np.array([100]), None, (8, 8))
    with pytest.raises(ParameterError, match="zsobol sampler needs the image size"):
        generate_sample_sets(runtime, make_sampler("zsobol", 4), 1, np.array([0]))
    zsobol = generate_sample_sets(runtime, make_sampler("zsobol", 4), 1, np.arange(4), None, (8, 8))
    with pytest.raises(ParameterError, match="cannot be traced at 16 x 16"):
        tracer.trace(zsobol, 1, 16, 16)
    with pytest.raises(ParameterError, match="at most 16 samples per pixel"):
        make_sampler("zsobol", 32).path_arguments((16384, 1000))
    assert tracer.image_size(64, None) == (64, 64)


@pytest.mark.parametrize("name", ["mitsuba-cbox", "cornell-box-glossy"])
def test_nee_and_bsdf_sampling_alone_agree(runtime, name):
    """MIS must not bias: paths that find the light by BSDF sampling only give the same image
    mean. Bound: 4.5 combined standard errors per channel."""
    scene = load_scene(name)
    with_nee = PathTracer(runtime, scene, max_depth=3)
    without = PathTracer(runtime, scene, max_depth=3, next_event_estimation=False)
    a, _, _ = render(with_nee, "independent", 16, 301, 32, 32)
    b, _, _ = render(without, "independent", 64, 302, 32, 32)
    (mean_a, se_a), (mean_b, se_b) = mean_and_se(a), mean_and_se(b)
    z = (mean_a - mean_b) / np.hypot(se_a, se_b)
    assert np.all(np.abs(z) < 4.5), (mean_a, mean_b, z)
    # NEE is the better estimator for a small light: lower per-sample deviation
    assert np.all(a.std(axis=0) < b.std(axis=0))


@pytest.mark.parametrize("sampler", EVERY_SAMPLER)
def test_every_sampler_agrees_with_a_longer_independent_render(runtime, cornell_tracer, sampler):
    """Image mean of the authors' Cornell box at 24 x 24: 16 spp of the sampler against 256
    independent spp with another seed (every path dimension is drawn by the sampler: a wrong
    dimension, stratum or scramble biases this). Bound: 4.5 combined standard errors per
    channel, over pixel means."""
    short, result, sets = render(cornell_tracer, sampler, 16, 111, 24, 24)
    long, _, long_sets = render(cornell_tracer, "independent", 256, 212, 24, 24)
    mean_s, se_s = mean_and_se(pixel_means(short, sets))
    mean_l, se_l = mean_and_se(pixel_means(long, long_sets))
    assert result.nonfinite == 0
    z = (mean_s - mean_l) / np.hypot(se_s, se_l)
    assert np.all(np.abs(z) < 4.5), (mean_s, mean_l, z)


@pytest.mark.parametrize("sampler", EVERY_SAMPLER)
def test_white_furnace_with_every_sampler(runtime, furnace, sampler):
    """The furnace at depth 8, with Russian roulette (its own dimension): sum_{k<=8} a^k.
    Bound: 5 standard errors over pixel means."""
    tracer = PathTracer(runtime, furnace, max_depth=8, russian_roulette=True)
    radiance, result, sets = render(tracer, sampler, 16, 5, 16, 16)
    mean, se = mean_and_se(pixel_means(radiance, sets))
    expected = (1.0 - FURNACE_ALBEDO**9) / (1.0 - FURNACE_ALBEDO)
    assert result.nonfinite == 0
    assert np.all(np.abs(mean - expected) <= 5 * se + 1e-6), (mean, se)


def test_russian_roulette_is_unbiased(runtime, furnace):
    """Furnace at depth 8 with Russian roulette: same answer. Bound: 5 standard errors."""
    tracer = PathTracer(runtime, furnace, max_depth=8, russian_roulette=True)
    radiance, result, _ = render(tracer, "independent", 16, 8, 16, 16)
    plain = PathTracer(runtime, furnace, max_depth=8)
    _, plain_result, _ = render(plain, "independent", 16, 8, 16, 16)
    mean, se = mean_and_se(radiance)
    expected = (1.0 - FURNACE_ALBEDO**9) / (1.0 - FURNACE_ALBEDO)
    assert np.all(np.abs(mean - expected) <= 5 * se), (mean, se)
    assert result.rays < plain_result.rays
