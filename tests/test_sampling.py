"""Per-pixel sample sets drawn on the device: distributions, layout, determinism, errors.

Statistical tests use fixed seeds, so each outcome is deterministic; thresholds are stated
where they are used (chi-square p-values above 1e-3, means within 4 standard errors).
"""

import math

import numpy as np
import pytest
from scipy import stats

from clrender import rng
from clrender.errors import ParameterError
from clrender.sampling import (
    count_samples,
    generate_sample_sets,
    make_sampler,
    queue_counts,
    rectangle_pixels,
)
from clrender.sppp import auxiliary_count, rejection_bound, sppp_eps

P_MIN = 1e-3  # smallest accepted chi-square / KS p-value (fixed seeds: deterministic outcomes)


def host_sets(runtime, config, seed, pixels, redraws=None, image_size=(1024, 1024)):
    """The sets drawn for pixels of an image (its size matters to zsobol alone)."""
    sets = generate_sample_sets(runtime, config, seed, pixels, redraws, image_size)
    return sets.to_host(runtime.queue)


def poisson_chi_square(counts, mean):
    """Chi-square of observed counts against the Poisson(mean) pmf, tail bins merged so
    every expected count is at least 5."""
    lo, hi = int(stats.poisson.ppf(1e-7, mean)), int(stats.poisson.ppf(1 - 1e-7, mean)) + 1
    edges = np.arange(lo, hi + 1)
    observed = np.array(
        [np.sum(counts < lo)] + [np.sum(counts == k) for k in edges[:-1]] + [np.sum(counts >= hi)]
    )
    probs = np.concatenate(
        [
            [stats.poisson.cdf(lo - 1, mean)],
            stats.poisson.pmf(edges[:-1], mean),
            [stats.poisson.sf(hi - 1, mean)],
        ]
    )
    expected = probs * len(counts)
    observed, expected = merge_small_bins(observed, expected)
    chi2 = np.sum((observed - expected) ** 2 / expected)
    return stats.chi2.sf(chi2, len(observed) - 1)


def merge_small_bins(observed, expected, minimum=5.0):
    merged_obs, merged_exp, acc_obs, acc_exp = [], [], 0.0, 0.0
    for obs, exp in zip(observed, expected, strict=True):
        acc_obs, acc_exp = acc_obs + obs, acc_exp + exp
        if acc_exp >= minimum:
            merged_obs.append(acc_obs)
            merged_exp.append(acc_exp)
            acc_obs, acc_exp = 0.0, 0.0
    merged_obs[-1] += acc_obs
    merged_exp[-1] += acc_exp
    return np.array(merged_obs), np.array(merged_exp)


@pytest.mark.parametrize("n", [1, 9, 10, 16, 256, 4096])
def test_poisson_counts_follow_the_pmf(runtime, n):
    pixels = np.arange(200_000, dtype=np.uint32)
    counts = count_samples(runtime, make_sampler("sppp", n), 11, pixels).astype(np.float64)
    assert poisson_chi_square(counts, n) > P_MIN
    # Mean and variance within 4 standard errors (Var of the sample variance ~ (n + 2 n^2)/M).
    assert abs(counts.mean() - n) < 4 * math.sqrt(n / len(counts))
    assert abs(counts.var() - n) < 4 * math.sqrt((n + 2 * n * n) / len(counts))


def test_poisson_counts_at_a_large_mean(runtime):
    n = 65_536
    counts = count_samples(runtime, make_sampler("sppp", n), 5, np.arange(100_000)).astype(float)
    assert poisson_chi_square(counts, n) > P_MIN
    assert abs(counts.mean() - n) < 4 * math.sqrt(n / len(counts))


@pytest.mark.parametrize(
    "sampler", ["independent", "stratified", "stratified-pixel", "sobol", "zsobol"]
)
def test_fixed_count_samplers_draw_exactly_n(runtime, sampler):
    sets = host_sets(runtime, make_sampler(sampler, 16), 3, np.arange(500))
    assert np.all(sets.counts == 16)
    assert len(sets.aux) == 0


def test_uniform_positions_equal_the_numpy_reference(runtime):
    pixels = np.array([0, 7, 1000, 65535], np.uint32)
    sets = host_sets(runtime, make_sampler("independent", 64), 99, pixels, np.array([0, 1, 2, 3]))
    pixel_of = np.repeat(pixels, 64)
    redraw_of = np.repeat([0, 1, 2, 3], 64)
    sample = np.tile(np.arange(64), 4)
    np.testing.assert_array_equal(sets.traced, rng.centered2(99, pixel_of, sample, 0, redraw_of))


def test_stratified_pixel_positions_match_the_numpy_reference_one_per_stratum(runtime):
    m = 8
    sets = host_sets(runtime, make_sampler("stratified-pixel", m * m), 4, np.arange(50))
    u = rng.uniform4(4, np.repeat(np.arange(50), m * m), np.tile(np.arange(m * m), 50), 0)
    s = np.tile(np.arange(m * m), 50)
    cell = np.column_stack([s % m, s // m]).astype(np.float32)
    reference = (cell + u[:, :2]) / np.float32(m) - np.float32(0.5)
    np.testing.assert_allclose(sets.traced, reference, atol=1e-6)
    strata = np.floor((sets.traced.astype(np.float64) + 0.5) * m).astype(int)
    np.testing.assert_array_equal(strata[:, 0] + m * strata[:, 1], s)


@pytest.mark.parametrize(
    "sampler, n",
    [
        ("independent", 64),
        ("sppp", 64),
        ("stratified", 64),
        ("stratified-pixel", 64),
        ("sobol", 64),
        ("zsobol", 64),
    ],
)
def test_positions_are_uniform_in_the_pixel(runtime, sampler, n):
    sets = host_sets(runtime, make_sampler(sampler, n), 21, np.arange(2048))
    xy = sets.traced.astype(np.float64)
    assert np.all(np.abs(xy) < 0.5), "traced samples lie strictly inside W"
    grid = 10  # 10 x 10 cells: not aligned with the 8 x 8 strata
    cells = np.floor((xy + 0.5) * grid).astype(int)
    observed = np.bincount(cells[:, 0] + grid * cells[:, 1], minlength=grid * grid)
    assert stats.chisquare(observed).pvalue > P_MIN
    for axis in range(2):
        assert stats.kstest(xy[:, axis] + 0.5, "uniform").pvalue > P_MIN


def strip_region(points, eps):
    """Index of the strip region holding each point: 4 corners (eps x eps, ids 0-3), then each
    of the 4 edges cut into 4 pieces of 1/4 x eps (ids 4-19); with the region areas."""
    x, y = points[:, 0], points[:, 1]
    out_x, out_y = np.abs(x) >= 0.5, np.abs(y) >= 0.5
    corner = out_x & out_y
    ids = np.full(len(points), -1)
    ids[corner] = (x[corner] > 0) + 2 * (y[corner] > 0)
    horizontal = out_y & ~out_x  # top and bottom edges, cut along x
    piece_x = np.minimum(np.floor((x + 0.5) * 4), 3).astype(int)
    ids[horizontal] = 4 + 4 * (y[horizontal] > 0) + piece_x[horizontal]
    vertical = out_x & ~out_y
    piece_y = np.minimum(np.floor((y + 0.5) * 4), 3).astype(int)
    ids[vertical] = 12 + 4 * (x[vertical] > 0) + piece_y[vertical]
    areas = np.concatenate([np.full(4, eps * eps), np.full(16, eps / 4)])
    return ids, areas


@pytest.mark.parametrize("n", [16, 256])
def test_auxiliary_nuclei_are_uniform_by_area_over_the_strip(runtime, n):
    config = make_sampler("sppp", n)
    sets = host_sets(runtime, config, 8, np.arange(4096))
    aux = sets.aux.astype(np.float64)
    assert len(aux) == config.n_aux * 4096
    reach = 0.5 + config.eps + 1e-6
    assert np.all(np.max(np.abs(aux), axis=1) >= 0.5), "auxiliary nuclei never fall inside W"
    assert np.all(np.abs(aux) <= reach), "auxiliary nuclei stay inside W'"
    ids, areas = strip_region(aux, config.eps)
    observed = np.bincount(ids, minlength=20)
    expected = areas / areas.sum() * len(aux)
    assert stats.chisquare(observed, expected).pvalue > P_MIN
    # The corners get the same density as the edges (the authors' renderer doubles it).
    corner_density = observed[:4].sum() / expected[:4].sum()
    assert abs(corner_density - 1.0) < 4 / math.sqrt(expected[:4].sum())


RNG_AUX_BASE = 0x40000000  # kernels/rng.h: auxiliary nucleus j draws from sample index base + j


def strip_positions(eps: float, u: np.ndarray) -> np.ndarray:
    """NumPy float32 reference of the strip positions (kernels/sampling.cl) from uniforms u."""
    f = np.float32
    eps = f(eps)
    long_side = f(1) + f(2) * eps
    area_tb = long_side * eps
    pick = u[:, 0] * (f(2) * area_tb + f(2) * eps)
    top_or_bottom = pick < f(2) * area_tb
    negative = np.where(top_or_bottom, pick < area_tb, pick < f(2) * area_tb + eps)
    outward = np.where(negative, f(-1), f(1)) * (f(0.5) + u[:, 2] * eps)
    x = np.where(top_or_bottom, f(-0.5) - eps + u[:, 1] * long_side, outward)
    y = np.where(top_or_bottom, outward, f(-0.5) + u[:, 1])
    return np.stack([x, y], axis=1)


# The auxiliary nuclei (drawn 8 per work-item, on 8-wide vectors) are the strip positions of
# Philox's uniforms for their own sample indices (clrender.rng, the NumPy reference), pixel by
# pixel and redraw by redraw; n_aux = 50 and 89 leave a partial group of 8 at each pixel's end.
# Within 2^-23: the device may fuse a multiply-add that NumPy rounds twice.
@pytest.mark.parametrize("n", [16, 64])
def test_auxiliary_nuclei_equal_the_numpy_reference(runtime, n):
    config = make_sampler("sppp", n)
    assert config.n_aux % 8 != 0
    pixels = np.array([0, 5, 77, 4095, 123456], dtype=np.uint32)
    redraws = np.array([0, 3, 0, 1, 2], dtype=np.uint32)
    sets = host_sets(runtime, config, 21, pixels, redraws)
    j = np.tile(np.arange(config.n_aux), len(pixels))
    u = rng.uniform4(
        21,
        np.repeat(pixels, config.n_aux),
        RNG_AUX_BASE + j,
        0,
        np.repeat(redraws, config.n_aux),
    ).astype(np.float32)
    expected = strip_positions(config.eps, u)
    np.testing.assert_allclose(sets.aux, expected, rtol=0, atol=2.0**-23)
    assert (sets.aux == expected).mean() > 0.5


@pytest.mark.parametrize(
    "n, expected",
    [(64, 0.2747), (256, 0.1439), (1024, 0.07506), (4096, 0.03901), (10_000, 0.02556)],
)
def test_eps_values(n, expected):
    eps = sppp_eps(n)
    assert eps == pytest.approx(expected, rel=1e-3)
    assert rejection_bound(n, eps) == pytest.approx(1e-3, rel=1e-9)
    assert math.pi * n * eps * eps > 1.0, "the decreasing branch of the bound"
    assert auxiliary_count(n, eps) == math.floor(n * (4 * eps + 4 * eps * eps))


def test_eps_follows_alpha():
    assert sppp_eps(256, 1e-6) > sppp_eps(256, 1e-3) > sppp_eps(256, 0.5)


def test_eps_root_matches_brent_on_the_decreasing_branch():
    """sppp_eps solves u - ln u = ln(4 n / alpha) by Newton's method; SciPy's brentq on the
    same bracket is the reference."""
    from scipy.optimize import brentq

    for n in (0.5, 1, 3, 16, 256, 4096, 10_000, 1e6):
        for alpha in (1e-9, 1e-3, 0.1, 0.9):
            target = math.log(4 * n / alpha)
            if target <= 1:
                assert sppp_eps(n, alpha) == 0.0
                continue
            u = brentq(lambda u, t=target: u - math.log(u) - t, 1, target + math.log(target) + 2)
            assert sppp_eps(n, alpha) == pytest.approx(math.sqrt(u / (math.pi * n)), rel=1e-13)


@pytest.mark.parametrize(
    "sampler, n",
    [
        ("independent", 9),
        ("stratified", 9),
        ("stratified-pixel", 9),
        ("sobol", 9),
        ("zsobol", 8),
        ("sppp", 9),
        ("sppp", 300),
        ("sppp-sobol", 9),
    ],
)
def test_sample_sets_do_not_depend_on_the_tiling(runtime, sampler, n):
    width, height = 13, 10
    config = make_sampler(sampler, n)
    size = (width, height)
    whole = host_sets(runtime, config, 5, rectangle_pixels(width, 0, 0, width, height), None, size)
    by_pixel = split_by_pixel(whole, rectangle_pixels(width, 0, 0, width, height))
    for tile_w, tile_h in [(4, 3), (1, 1), (13, 1), (6, 10)]:
        for y0 in range(0, height, tile_h):
            for x0 in range(0, width, tile_w):
                tw, th = min(tile_w, width - x0), min(tile_h, height - y0)
                pixels = rectangle_pixels(width, x0, y0, tw, th)
                tile = split_by_pixel(host_sets(runtime, config, 5, pixels, None, size), pixels)
                for pixel, (traced, aux) in tile.items():
                    np.testing.assert_array_equal(traced, by_pixel[pixel][0])
                    np.testing.assert_array_equal(aux, by_pixel[pixel][1])


def split_by_pixel(sets, pixels):
    return {
        int(p): (
            sets.traced[sets.offsets[i] : sets.offsets[i + 1]],
            sets.aux[sets.aux_offsets[i] : sets.aux_offsets[i + 1]],
        )
        for i, p in enumerate(pixels)
    }


def test_a_redraw_changes_only_the_redrawn_pixel(runtime):
    config = make_sampler("sppp", 64)
    pixels = np.arange(4, dtype=np.uint32)
    first = split_by_pixel(host_sets(runtime, config, 1, pixels), pixels)
    again = split_by_pixel(host_sets(runtime, config, 1, pixels, np.array([0, 1, 0, 0])), pixels)
    for p in (0, 2, 3):
        np.testing.assert_array_equal(first[p][0], again[p][0])
    assert len(first[1][0]) != len(again[1][0]) or not np.array_equal(first[1][0], again[1][0])


def test_different_seeds_give_different_sets(runtime):
    config = make_sampler("independent", 16)
    a = host_sets(runtime, config, 1, np.arange(4))
    b = host_sets(runtime, config, 2, np.arange(4))
    assert not np.array_equal(a.traced, b.traced)


@pytest.mark.parametrize(
    "kwargs, names",
    [
        (dict(name="halton", n=16), ["sampler", "independent, stratified, stratified-pixel"]),
        (dict(name="uniform", n=16), ["now called 'independent'"]),
        (dict(name="zsobol", n=12), ["power of two", "8 or 16"]),
        (dict(name="stratified-pixel", n=10), ["perfect square", "9 or 16"]),
        (dict(name="independent", n=0), ["spp (samples per pixel)", "positive"]),
        (dict(name="sppp", n=-4), ["spp (samples per pixel)"]),
        (dict(name="independent", n=2.5), ["spp (samples per pixel)", "integer"]),
        (dict(name="stratified", n=10), ["perfect square", "9 or 16"]),
        (dict(name="sppp", n=64, alpha=0.0), ["alpha", "(0, 1)"]),
        (dict(name="sppp", n=64, alpha=1.5), ["alpha", "(0, 1)"]),
        (dict(name="sppp", n=64, eps=-1.0), ["eps"]),
    ],
)
def test_bad_sampler_parameters_name_the_parameter(kwargs, names):
    with pytest.raises(ParameterError) as err:
        make_sampler(**kwargs)
    for name in names:
        assert name in str(err.value)


@pytest.mark.parametrize("seed", [-1, 2**32, 1.5, "7"])
def test_bad_seed_is_rejected(runtime, seed):
    with pytest.raises(ParameterError, match="seed"):
        generate_sample_sets(runtime, make_sampler("independent", 4), seed, np.arange(2))


def test_an_empty_pixel_list_gives_empty_sets(runtime):
    sets = host_sets(runtime, make_sampler("sppp", 16), 1, np.array([], np.uint32))
    assert sets.traced.shape == (0, 2) and sets.aux.shape == (0, 2)


RNG_PIXEL_STREAM, SHIFT_DIMENSION = 0xFFFFFFFF, 0x7FFFFFFF  # kernels/rng.h, sampler.h
BELOW_HALF = np.float32(0.5 - 2.0**-25)  # the largest float32 below 1/2


def traced_reference(config, seed, pixels, redraws, counts):
    """NumPy twin of fill_traced (clrender.rng's Philox, float32 arithmetic in the kernel's
    order): sample s of a pixel from dimension 0 of its own counter (s, 0, redraw, 0) under key
    (seed, pixel); a stratum in order or uniform in W; then the pixel's toroidal shift."""
    pixel_of, redraw_of = np.repeat(pixels, counts), np.repeat(redraws, counts)
    s = np.concatenate([np.arange(c) for c in counts]).astype(np.int64)
    if config.name == "stratified-pixel":
        m = config.strata
        u = rng.uniform4(seed, pixel_of, s, 0, redraw_of)[:, :2]
        cell = np.column_stack([s % m, s // m]).astype(np.float32)
        positions = np.clip((cell + u) / np.float32(m) - np.float32(0.5), -BELOW_HALF, BELOW_HALF)
    else:
        positions = rng.centered2(seed, pixel_of, s, 0, redraw_of)
    if config.toroidal_shift:
        shift = rng.uniform4(seed, pixel_of, RNG_PIXEL_STREAM, SHIFT_DIMENSION, redraw_of)
        positions = positions + shift[:, :2]
        positions = np.where(positions >= np.float32(0.5), positions - np.float32(1), positions)
        positions = np.maximum(positions, -BELOW_HALF)
    return positions.astype(np.float32)


@pytest.mark.parametrize(
    "sampler, counts",
    [
        ("independent", [1, 2, 7, 8, 9, 15, 17, 64, 255, 1000]),
        # (m = 41: the first m whose s div m a division that is not correctly rounded misses)
        ("stratified-pixel", [1, 4, 9, 49, 64, 81, 961, 1681]),
        ("sppp", [1, 3, 8, 13, 64, 257, 1000]),
    ],
)
@pytest.mark.parametrize("toroidal_shift", [False, True])
def test_traced_positions_equal_the_numpy_reference(runtime, sampler, counts, toroidal_shift):
    """fill_traced draws 8 samples of a pixel per work-item: every sample, each lane of a
    group, partial last groups and (SPPP) pixels of 0, 1 or many samples must be exactly the
    reference's, under several seeds and redraw numbers."""
    rs = np.random.default_rng(8)
    pixels = rs.choice(1 << 20, 23, replace=False).astype(np.uint32)
    redraws = rs.integers(0, 5, len(pixels)).astype(np.uint32)
    for n in counts:
        config = make_sampler(sampler, n, toroidal_shift=toroidal_shift)
        for seed in (0, 77, 2**32 - 1):
            sets = host_sets(runtime, config, seed, pixels, redraws)
            if not config.is_sppp:
                assert np.all(sets.counts == n)
            expected = traced_reference(config, seed, pixels, redraws, sets.counts)
            np.testing.assert_array_equal(sets.traced, expected, err_msg=f"n={n} seed={seed}")


@pytest.mark.parametrize(
    "sampler, n",
    [("independent", 13), ("stratified-pixel", 9), ("sppp", 13), ("stratified", 9), ("sobol", 13)],
)
def test_traced_positions_stay_inside_their_pixels_range(runtime, sampler, n):
    """A pixel's last group of 8 (16 for a path sampler's positions) holds fewer samples: its
    work-item must store those alone.
    Each pixel is filled on its own into a buffer followed by guard words (no auxiliary nuclei
    after it to overwrite a stray store): the guard stays intact, the samples are the
    reference's."""
    from dataclasses import replace

    import pyopencl as cl

    from clrender.sampling import _launch_fill

    config = replace(make_sampler(sampler, n), n_aux=0)
    guard = np.full(16, np.float32(-7.25), np.float32)
    for pixel in np.array([5, 901, 4000], np.uint32):
        pixels, redraws = np.array([pixel], np.uint32), np.zeros(1, np.uint32)
        expected = host_sets(runtime, config, 3, pixels, redraws).traced
        count = len(expected)
        assert count % 8, "a partial last group is the point of the test"
        offsets = np.array([0, count], np.uint32)
        out = np.concatenate([np.zeros(2 * count, np.float32), guard])
        positions = runtime.upload(out)
        _launch_fill(
            runtime,
            config,
            3,
            runtime.upload(pixels),
            runtime.upload(redraws),
            offsets,
            runtime.upload(offsets),
            positions,
            config.path_arguments((1024, 1024)),
            1024,
        )
        cl.enqueue_copy(runtime.queue, out, positions)
        np.testing.assert_array_equal(out[2 * count :], guard, err_msg=f"pixel {pixel}")
        np.testing.assert_array_equal(out[: 2 * count].reshape(-1, 2), expected)


# The fixed-count samplers draw their sets without the count pass (every pixel has n samples:
# no count kernel, no read-back of counts); SPPP still counts on the device. Same sets either
# way: the count kernel's n for a fixed-count sampler is what the host now writes.
@pytest.mark.parametrize(
    "sampler, counted",
    [("independent", False), ("stratified-pixel", False), ("sobol", False), ("sppp", True)],
)
def test_only_sppp_launches_the_count_pass(runtime, monkeypatch, sampler, counted):
    launched = []
    launch = runtime.launch_1d

    def recording(kernel, count, *args, **kwargs):
        launched.append(kernel.function_name)
        return launch(kernel, count, *args, **kwargs)

    monkeypatch.setattr(runtime, "launch_1d", recording)
    config = make_sampler(sampler, 16)
    pixels = np.arange(40, 60, dtype=np.uint32)
    sets = host_sets(runtime, config, 2, pixels)
    assert ("count_samples" in launched) == counted
    np.testing.assert_array_equal(sets.counts, count_samples(runtime, config, 2, pixels))


def test_counts_queued_ahead_give_the_same_sets(runtime):
    """SPPP's count pass queued ahead (queue_counts, on the side queue) stands in for the one
    the launch would run: the same sets to the bit; counts of another launch (pixels, redraws,
    seed or n) are refused, and a fixed-count sampler has no count pass to queue. The counts do
    not depend on eps (a redraw's widened eps keeps them)."""
    config = make_sampler("sppp", 9)
    pixels = np.arange(300, 420, dtype=np.uint32)
    redraws = (pixels % 3).astype(np.uint32)
    reference = host_sets(runtime, config, 4, pixels, redraws)
    ahead = queue_counts(runtime, config, 4, pixels, redraws)
    sets = generate_sample_sets(runtime, config, 4, pixels, redraws, (1024, 1024), ahead)
    drawn = sets.to_host(runtime.queue)
    np.testing.assert_array_equal(drawn.offsets, reference.offsets)
    np.testing.assert_array_equal(drawn.traced, reference.traced)
    np.testing.assert_array_equal(drawn.aux, reference.aux)
    wider = make_sampler("sppp", 9, eps=0.3)
    ahead = queue_counts(runtime, config, 4, pixels, redraws)
    sets = generate_sample_sets(runtime, wider, 4, pixels, redraws, (1024, 1024), ahead)
    np.testing.assert_array_equal(sets.traced_offsets, reference.offsets)
    others = [
        (config, 4, pixels + 1, redraws),
        (config, 4, pixels, redraws + 1),
        (config, 5, pixels, redraws),
        (make_sampler("sppp", 10), 4, pixels, redraws),
    ]
    for other, seed, other_pixels, other_redraws in others:
        ahead = queue_counts(runtime, config, 4, pixels, redraws)
        with pytest.raises(ParameterError, match="counts queued ahead"):
            generate_sample_sets(runtime, other, seed, other_pixels, other_redraws, None, ahead)
    # The caller's arrays reused in place after the counts were queued: they are another launch
    reused = pixels.copy()
    ahead = queue_counts(runtime, config, 4, reused, redraws)
    reused += 64
    with pytest.raises(ParameterError, match="counts queued ahead"):
        generate_sample_sets(runtime, config, 4, reused, redraws, None, ahead)
    with pytest.raises(ParameterError, match="only SPPP samplers count"):
        queue_counts(runtime, make_sampler("independent", 9), 4, pixels)
