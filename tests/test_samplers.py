"""The samplers of every path dimension (kernels/sampler.h, lowdiscrepancy.h) value by value,
through the test kernel kernels/sampler_test.cl: Sobol against SciPy, the net property of the
scrambled points, stratification and permutations, uniformity and independence of the
dimensions, and SPPP positions independent of their Sobol path dimensions.

Statistical checks use fixed seeds and state their bound (P_MIN for p-values, or a number of
standard errors); structural checks (nets, strata, permutations) are exact.
"""

import math

import numpy as np
import pyopencl as cl
import pytest
from scipy import stats
from scipy.stats import qmc

from clrender import rng
from clrender.sampling import generate_sample_sets, make_sampler

P_MIN = 1e-4
BOUNCE = 7  # dimensions per bounce: emitter choice, point (2), lobe, direction (2), roulette
# Columns of sampler_dimensions' output: position (0, 1), then bounce d at 2 + 7 d + k.
EMITTER_CHOICE, EMITTER_POINT, LOBE, DIRECTION, ROULETTE = 0, 1, 3, 4, 6


def column(depth: int, what: int) -> int:
    return 2 + BOUNCE * depth + what


def read(runtime, kernel_name, size, out_shape, out_dtype, *args):
    out = np.empty(out_shape, out_dtype)
    buffer = runtime.allocate(max(out.nbytes, 4))
    kernel = runtime.kernel("sampler_test.cl", kernel_name)
    kernel(runtime.queue, (size,), None, *args, buffer)
    cl.enqueue_copy(runtime.queue, out, buffer)
    return out


def dimensions(runtime, sampler, n, pixels, seed=7, depths=4, redraws=None, size=(64, 64)):
    """(pixels, n, 2 + 7 depths): every value the sampler gives each sample of each pixel (the
    position centred in W, then the bounces' numbers in (0, 1))."""
    config = make_sampler(sampler, n)
    kind, count, strata, log2_count, bits = config.path_arguments(size)
    pixels = np.asarray(pixels, np.uint32)
    redraws = np.zeros(len(pixels), np.uint32) if redraws is None else np.asarray(redraws)
    items = np.zeros((len(pixels), n, 4), np.uint32)
    items[:, :, 0] = pixels[:, None]
    items[:, :, 1] = np.arange(n)
    items[:, :, 2] = redraws[:, None]
    total = len(pixels) * n
    stride = 2 + BOUNCE * depths
    out = read(
        runtime,
        "sampler_dimensions",
        total,
        (len(pixels), n, stride),
        np.float32,
        np.uint32(total),
        kind,
        np.uint32(seed),
        count,
        strata,
        np.uint32(size[0]),
        log2_count,
        bits,
        np.uint32(depths),
        runtime.upload(items.reshape(-1, 4)),
    )
    return out.astype(np.float64)


def is_net(x, y, m):
    """Each of the 2^m elementary intervals of every shape 2^-a x 2^-(m-a) holds one point."""
    for a in range(m + 1):
        ix = np.floor(x * 2**a).astype(np.int64)
        iy = np.floor(y * 2 ** (m - a)).astype(np.int64)
        if not np.all(np.bincount(ix * 2 ** (m - a) + iy, minlength=2**m) == 1):
            return False
    return True


def one_per_stratum(values, strata):
    return np.array_equal(np.sort(np.floor(values * strata).astype(int)), np.arange(strata))


# --- Sobol and its scrambling ----------------------------------------------------------------


def test_sobol_dimensions_0_and_1_equal_scipys_unscrambled_points(runtime):
    count = 4096
    points = read(runtime, "sobol_points", count, (count, 2), np.uint32, np.uint32(count))
    reference = qmc.Sobol(2, scramble=False).random(count)
    # SciPy walks the sequence in Gray-code order: its point i is Sobol point i ^ (i >> 1)
    gray = np.arange(count) ^ (np.arange(count) >> 1)
    np.testing.assert_array_equal(points[gray] / 2.0**32, reference)


def test_owen_scrambling_is_a_nested_bijection_uniform_over_seeds(runtime):
    # Nested: points sharing their first k binary digits still share k digits afterwards; a
    # permutation of the 2^12 values of 12-digit fractions.
    values = (np.arange(4096, dtype=np.uint32) << np.uint32(20)).astype(np.uint32)
    scrambled = read(
        runtime,
        "owen_scramble",
        4096,
        4096,
        np.uint32,
        np.uint32(4096),
        np.uint32(12345),
        runtime.upload(values),
    )
    assert len(np.unique(scrambled >> np.uint32(20))) == 4096
    for digits in (1, 3, 7):
        prefix = values >> np.uint32(32 - digits)
        scrambled_prefix = scrambled >> np.uint32(32 - digits)
        for p in np.unique(prefix):
            assert len(np.unique(scrambled_prefix[prefix == p])) == 1
    # One value under many seeds: uniform over [0, 1)
    seeds = np.arange(20_000, dtype=np.uint32) * np.uint32(2654435761)
    under_seeds = np.array(
        [
            read(
                runtime,
                "owen_scramble",
                1,
                1,
                np.uint32,
                np.uint32(1),
                s,
                runtime.upload(values[5:6]),
            )[0]
            for s in seeds[:400]
        ]
    )
    assert stats.kstest(under_seeds / 2.0**32, "uniform").pvalue > P_MIN


@pytest.mark.parametrize("sampler", ["sobol", "zsobol"])
@pytest.mark.parametrize("m", [3, 4, 5, 6, 8])
def test_scrambled_points_are_nets_in_every_dimension_pair(runtime, sampler, m):
    """(0, m, 2)-nets: the pixel pair, the emitter point and BSDF direction of bounces 0 and
    3, and the 1D dimensions one point per 1 / 2^m stratum."""
    values = dimensions(runtime, sampler, 2**m, [0, 5, 1234], seed=3, size=(64, 64))
    for pixel in values:
        pairs = [(pixel[:, 0] + 0.5, pixel[:, 1] + 0.5)]
        for depth in (0, 3):
            for first in (EMITTER_POINT, DIRECTION):
                c = column(depth, first)
                pairs.append((pixel[:, c], pixel[:, c + 1]))
        for x, y in pairs:
            assert is_net(x, y, m)
        for depth in (0, 3):
            for what in (EMITTER_CHOICE, LOBE, ROULETTE):
                assert one_per_stratum(pixel[:, column(depth, what)], 2**m)


def test_zsobol_spreads_a_net_over_each_block_of_2_by_2_pixels(runtime):
    """The four pixels of an aligned 2 x 2 block hold one larger net together (their samples
    are one aligned block of the image-wide sequence), in every dimension pair; four pixels of
    padded sobol do not."""
    block = [0, 1, 64, 65]  # (0, 0), (1, 0), (0, 1), (1, 1) in a 64-wide image
    values = dimensions(runtime, "zsobol", 16, block, size=(64, 64)).reshape(64, -1)
    assert is_net(values[:, 0] + 0.5, values[:, 1] + 0.5, 6)
    c = column(2, DIRECTION)
    assert is_net(values[:, c], values[:, c + 1], 6)
    padded = dimensions(runtime, "sobol", 16, block, size=(64, 64)).reshape(64, -1)
    assert not is_net(padded[:, 0] + 0.5, padded[:, 1] + 0.5, 6)


def test_morton_codes_and_digit_permutations(runtime):
    xy = np.array([(0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (5, 3), (65535, 0)], np.uint32)
    hashes = np.arange(24, dtype=np.uint64) * (2**32) // 24 + 1
    pairs = np.stack([np.repeat(hashes, 4), np.tile(np.arange(4), 24)], 1).astype(np.uint32)
    count = len(pairs)
    xy_all = np.resize(xy, (count, 2)).astype(np.uint32)
    out = read(
        runtime,
        "morton_and_digits",
        count,
        (count, 2),
        np.uint32,
        np.uint32(count),
        runtime.upload(xy_all),
        runtime.upload(pairs),
    )

    def morton(x, y):
        return sum(((x >> b) & 1) << (2 * b) | ((y >> b) & 1) << (2 * b + 1) for b in range(16))

    assert [int(v) for v in out[: len(xy), 0]] == [morton(int(x), int(y)) for x, y in xy]
    images = out[:, 1].reshape(24, 4)
    assert {tuple(row) for row in images} == set(__import__("itertools").permutations(range(4)))


# --- stratification ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 7, 16, 17, 100, 1024, 1000])
def test_permutation_elements_are_permutations(runtime, n):
    for key, rotation in [(1, 0), (0xDEADBEEF, 12345), (77, 3)]:
        out = read(
            runtime,
            "permutation_elements",
            n,
            n,
            np.uint32,
            np.uint32(n),
            np.uint32(key),
            np.uint32(rotation),
        )
        assert np.array_equal(np.sort(out), np.arange(n))


def test_stratified_sampler_covers_every_stratum_of_every_dimension(runtime):
    n, m = 64, 8
    values = dimensions(runtime, "stratified", n, [0, 9, 300], depths=3)
    for pixel in values:
        cells = [(pixel[:, 0] + 0.5, pixel[:, 1] + 0.5)]
        cells += [
            (pixel[:, column(d, w)], pixel[:, column(d, w) + 1])
            for d in range(3)
            for w in (EMITTER_POINT, DIRECTION)
        ]
        for x, y in cells:
            grid = np.floor(x * m).astype(int) * m + np.floor(y * m).astype(int)
            assert np.array_equal(np.sort(grid), np.arange(n))
        for d in range(3):
            for what in (EMITTER_CHOICE, LOBE, ROULETTE):
                assert one_per_stratum(pixel[:, column(d, what)], n)


def test_stratified_strata_of_two_dimensions_are_independently_permuted(runtime):
    """Sample s's stratum in one dimension says nothing of its stratum in another: over many
    pixels, the joint counts of (stratum of the lobe, stratum of the roulette) of one sample
    are uniform (chi-square), and so are (pixel row, direction row)."""
    n = 16
    values = dimensions(runtime, "stratified", n, np.arange(4000), depths=1)
    sample = values[:, 5]
    lobe = np.floor(sample[:, column(0, LOBE)] * 4).astype(int)
    roulette = np.floor(sample[:, column(0, ROULETTE)] * 4).astype(int)
    assert stats.chisquare(np.bincount(lobe * 4 + roulette, minlength=16)).pvalue > P_MIN
    row = np.floor((sample[:, 1] + 0.5) * 4).astype(int)
    direction_row = np.floor(sample[:, column(0, DIRECTION) + 1] * 4).astype(int)
    joint = np.bincount(row * 4 + direction_row, minlength=16)
    assert stats.chisquare(joint).pvalue > P_MIN


# --- every sampler: uniform, independent dimensions --------------------------------------------


@pytest.mark.parametrize("sampler", ["independent", "stratified", "sobol", "zsobol"])
def test_every_dimension_is_uniform_and_pairs_are_uncorrelated(runtime, sampler):
    """Sample 3 of 4096 pixels: each dimension uniform (Kolmogorov-Smirnov), and no two
    dimensions correlated (|Pearson r| < 4.5 / sqrt(P), a 4.5-sigma bound for every pair)."""
    values = dimensions(runtime, sampler, 16, np.arange(4096), depths=2)[:, 3]
    values[:, :2] += 0.5
    for c in range(values.shape[1]):
        assert stats.kstest(values[:, c], "uniform").pvalue > P_MIN, c
    r = np.corrcoef(values.T)
    off_diagonal = r[~np.eye(len(r), dtype=bool)]
    assert np.abs(off_diagonal).max() < 4.5 / math.sqrt(len(values))


def test_redraws_and_seeds_give_independent_sobol_sets(runtime):
    a = dimensions(runtime, "sobol", 16, [3], redraws=[0])
    b = dimensions(runtime, "sobol", 16, [3], redraws=[1])
    c = dimensions(runtime, "sobol", 16, [3], seed=8)
    assert not np.array_equal(a, b) and not np.array_equal(a, c)
    z = dimensions(runtime, "zsobol", 16, [3, 4], redraws=[0, 1])
    z0 = dimensions(runtime, "zsobol", 16, [3, 4], redraws=[0, 0])
    assert np.array_equal(z[0], z0[0]) and not np.array_equal(z[1], z0[1])


# --- SPPP positions with Sobol path dimensions ----------------------------------------------


def test_sppp_sobol_path_dimensions_are_independent_of_positions(runtime):
    """sppp-sobol: a traced sample's path dimensions come from the padded sobol sequence at its
    index, its position from the SPPP draw. Over 6000 pixels, the first traced sample's
    position and its path numbers are independent: joint 4 x 4 histograms of (position x,
    direction u) and (position y, emitter point v) are uniform (chi-square), and the path
    numbers of all traced samples are uniform whatever N is."""
    pixels = np.arange(6000, dtype=np.uint32)
    config = make_sampler("sppp-sobol", 16)
    sets = generate_sample_sets(runtime, config, 7, pixels, None, (100, 60)).to_host(runtime.queue)
    counts = sets.counts
    assert counts.min() > 0
    first = sets.traced[sets.offsets[:-1]].astype(np.float64) + 0.5
    paths = dimensions(runtime, "sobol", 1, pixels, seed=7, depths=1, size=(100, 60))[:, 0]
    # sampler_dimensions at sample 0 is exactly the path the tracer draws for sample 0
    for position_axis, path_column in [
        (0, column(0, DIRECTION)),
        (1, column(0, EMITTER_POINT) + 1),
    ]:
        a = np.floor(first[:, position_axis] * 4).astype(int)
        b = np.floor(paths[:, path_column] * 4).astype(int)
        assert stats.chisquare(np.bincount(a * 4 + b, minlength=16)).pvalue > P_MIN
    # A pixel's traced samples 0 .. N-1 are its first N sobol points, whatever N
    many = dimensions(runtime, "sobol", 32, pixels[:500], seed=7, depths=1, size=(100, 60))
    taken = np.concatenate([many[k, : min(counts[k], 32)] for k in range(500)])
    for c in (column(0, DIRECTION), column(0, LOBE)):
        assert stats.kstest(taken[:, c], "uniform").pvalue > P_MIN


# --- the path samplers' pixel positions, drawn on lanes ---------------------------------------


@pytest.mark.parametrize(
    "sampler, counts",
    [
        ("stratified", [1, 4, 9, 16, 25, 64, 81, 289]),
        ("sobol", [1, 3, 15, 16, 17, 33, 64, 100]),
        ("zsobol", [1, 2, 8, 16, 32, 64]),
    ],
)
@pytest.mark.parametrize("toroidal_shift", [False, True])
def test_path_sampler_positions_equal_the_scalar_sampler(runtime, sampler, counts, toroidal_shift):
    """fill_traced_from_sampler draws 16 samples of a pixel per work-item, one a vector lane
    (kernels/sampler_lanes.h): every sample's position, partial last groups included, must be
    the scalar Sampler_Position's (sampler_test.cl, one sample a work-item) to the bit, under
    several seeds and redraw numbers, then shifted on the torus as the NumPy reference."""
    rs = np.random.default_rng(13)
    size = (100, 60)
    pixels = rs.choice(size[0] * size[1], 19, replace=False).astype(np.uint32)
    redraws = rs.integers(0, 5, len(pixels)).astype(np.uint32)
    for n in counts:
        config = make_sampler(sampler, n, toroidal_shift=toroidal_shift)
        for seed in (0, 77, 2**32 - 1):
            sets = generate_sample_sets(runtime, config, seed, pixels, redraws, size)
            traced = sets.to_host(runtime.queue).traced
            scalar = dimensions(runtime, sampler, n, pixels, seed, 0, redraws, size)
            expected = scalar[:, :, :2].astype(np.float32).reshape(-1, 2)
            if toroidal_shift:
                shift = rng.uniform4(
                    seed, np.repeat(pixels, n), 0xFFFFFFFF, 0x7FFFFFFF, np.repeat(redraws, n)
                )[:, :2]
                expected = expected + shift
                expected = np.where(expected >= np.float32(0.5), expected - np.float32(1), expected)
                expected = np.maximum(expected, np.float32(-0.5 + 2.0**-25))
            np.testing.assert_array_equal(traced, expected, err_msg=f"n={n} seed={seed}")
