"""The wavefront path tracer (kernels/wavefront.cl through clrender.wavefront) against the
megakernel (kernels/integrator.cl), which tests/test_trace.py checks against known answers.

The two run the same operations in the same order on the same random dimensions, so the test
is exact: every sample's radiance bit for bit, the ray count and the non-finite count equal,
on one device (the tolerance is zero). Launches are traced in several chunks (wave_paths
smaller than the launch, the last chunk partial) to cover the chunk bookkeeping.
"""

import dataclasses
import math

import numpy as np
import pyopencl as cl
import pytest

from clrender.errors import ParameterError
from clrender.sampling import DeviceSampleSets, generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.trace import PathTracer
from clrender.wavefront import (
    WavefrontPathTracer,
    branch_efficiency,
    queue_efficiency,
    simd_efficiency,
)

SIZE = 16  # 16 x 16 pixels at 16 spp: about 4096 samples a launch
WAVE = 1500  # three chunks, the last one partial
FURNACE_ALBEDO = 0.5


def draw(runtime, sampler, spp, seed, size=SIZE):
    pixels = rectangle_pixels(size, 0, 0, size, size)
    config = make_sampler(sampler, spp)
    return generate_sample_sets(runtime, config, seed, pixels, None, (size, size))


def assert_same_trace(mega, wave, sets, seed, size=SIZE):
    """Both tracers' radiance bit for bit, rays and non-finite counts; returns the radiance."""
    a = mega.trace(sets, seed, size, size)
    b = wave.trace(sets, seed, size, size)
    radiance_a, radiance_b = a.to_host(), b.to_host()
    differing = np.flatnonzero(np.any(radiance_a != radiance_b, axis=1))
    assert differing.size == 0, (
        differing[:5],
        radiance_a[differing[:5]],
        radiance_b[differing[:5]],
    )
    assert b.rays == a.rays
    assert b.nonfinite == a.nonfinite
    return radiance_a, a


@pytest.fixture(
    scope="module", params=["cornell-box", "mitsuba-cbox", "cornell-box-glossy", "veach-mis"]
)
def tracers(request, runtime):
    scene = load_scene(request.param)
    return PathTracer(runtime, scene), WavefrontPathTracer(runtime, scene, wave_paths=WAVE)


@pytest.mark.parametrize("sampler", ["independent", "sppp", "sobol", "zsobol", "stratified"])
def test_radiance_is_the_megakernels(runtime, tracers, sampler):
    """The shipped Cornell boxes (glass, diffuse and, in the glossy one, a rough conductor) and
    veach-mis (spherical lights, four rough conductors): every sample bit-identical at depth 8
    with NEE."""
    sets = draw(runtime, sampler, 16, 41)
    radiance, result = assert_same_trace(*tracers, sets, 41)
    # Paths bounce (veach-mis is open: its paths escape sooner than the boxes' 5 rays each)
    assert len(radiance) > 4000 and result.rays > 4 * len(radiance)
    assert np.count_nonzero(radiance.sum(axis=1)) > len(radiance) // 2


@pytest.mark.parametrize(
    ("depth", "nee", "roulette"),
    [(0, True, False), (1, True, False), (3, False, False), (8, True, True), (24, False, True)],
)
def test_integrator_options_match(runtime, depth, nee, roulette):
    """Emitters only, direct light only, BSDF sampling only, Russian roulette (its own random
    dimension) and long glass paths: the same samples as the megakernel."""
    scene = load_scene("cornell-box")
    options = {"max_depth": depth, "next_event_estimation": nee, "russian_roulette": roulette}
    mega = PathTracer(runtime, scene, **options)
    wave = WavefrontPathTracer(runtime, scene, wave_paths=WAVE, **options)
    sets = draw(runtime, "sobol", 16, 43)
    radiance, result = assert_same_trace(mega, wave, sets, 43)
    if depth == 0:
        assert result.rays == len(radiance)


def test_nonfinite_radiance_matches(runtime):
    """Radiance 3e38 overflows once two emissions add up: the same samples are counted and
    zeroed (set on the packed emitters: scene files refuse such values)."""
    furnace = load_scene("furnace")
    emitters = furnace.emitters.copy()
    emitters["radiance"][:, 0] = 3e38
    hot = dataclasses.replace(furnace, emitters=emitters)
    mega = PathTracer(runtime, hot, max_depth=2)
    wave = WavefrontPathTracer(runtime, hot, max_depth=2, wave_paths=100)
    sets = draw(runtime, "independent", 4, 7, size=8)
    radiance, result = assert_same_trace(mega, wave, sets, 7, size=8)
    assert result.nonfinite > 0 and np.all(np.isfinite(radiance))


def test_overflowing_throughput_matches(runtime):
    """Albedo 1e30 makes the throughput infinite after two bounces: at the third vertex a
    light sample with no shadow ray, or a blocked one, adds inf * 0 = NaN in the megakernel,
    and must here too (the ceiling beside the one-sided light gets no light sample at all)."""
    scene = load_scene("cornell-box")
    materials = scene.materials.copy()
    materials["albedo"] *= 1e30
    bright = dataclasses.replace(scene, materials=materials)
    mega = PathTracer(runtime, bright, max_depth=3)
    wave = WavefrontPathTracer(runtime, bright, max_depth=3, wave_paths=WAVE)
    sets = draw(runtime, "independent", 16, 9)
    radiance, result = assert_same_trace(mega, wave, sets, 9)
    assert 0 < result.nonfinite < len(radiance)


def test_chunking_does_not_change_radiance(runtime):
    """One chunk, or chunks of 777 paths: bit-identical."""
    scene = load_scene("mitsuba-cbox")
    sets = draw(runtime, "sppp", 16, 45)
    whole = WavefrontPathTracer(runtime, scene).trace(sets, 45, SIZE, SIZE)
    parts = WavefrontPathTracer(runtime, scene, wave_paths=777).trace(sets, 45, SIZE, SIZE)
    np.testing.assert_array_equal(whole.to_host(), parts.to_host())
    assert whole.rays == parts.rays


def test_white_furnace(runtime):
    """An independent truth: inside a closed cube of albedo a emitting 1, L = sum_{k<=8} a^k.
    Bound: 5 standard errors."""
    tracer = WavefrontPathTracer(runtime, load_scene("furnace"), max_depth=8, wave_paths=WAVE)
    radiance = tracer.trace(draw(runtime, "independent", 16, 5), 5, SIZE, SIZE).to_host()
    expected = (1.0 - FURNACE_ALBEDO**9) / (1.0 - FURNACE_ALBEDO)
    mean = radiance.mean(axis=0)
    se = radiance.std(axis=0) / math.sqrt(len(radiance))
    assert np.all(np.abs(mean - expected) <= 5 * se), (mean, se)


def test_recorded_queues_account_for_every_ray(runtime):
    """trace_recording gives the same radiance, and its queues hold every ray: camera and
    bounce rays per path (at most max_depth + 1) plus shadow rays sum to the ray count."""
    scene = load_scene("cornell-box")
    tracer = WavefrontPathTracer(runtime, scene, max_depth=5, wave_paths=WAVE)
    sets = draw(runtime, "independent", 16, 47)
    plain = tracer.trace(sets, 47, SIZE, SIZE)
    result, record = tracer.trace_recording(sets, 47, SIZE, SIZE)
    np.testing.assert_array_equal(plain.to_host(), result.to_host())
    lengths = record.path_lengths()
    shadow = record.shadow_mask()
    assert lengths.min() >= 1 and lengths.max() <= 6
    assert lengths.sum() + shadow.sum() == result.rays
    # Each depth's queue lists distinct paths, and only paths still alive there
    for depth, ids in enumerate(record.rays):
        assert len(np.unique(ids)) == len(ids)
        assert np.all(lengths[ids] > depth)
    for depth, ids in enumerate(record.shadow_rays):
        assert np.all(lengths[ids] > depth)


def test_lockstep_efficiency_by_hand():
    """The SIMD figures on cases worked out by hand."""
    # Groups of 2: (1, 2) and (3, 4): 10 busy lane-iterations of 2 * (2 + 4)
    assert simd_efficiency(np.array([1, 2, 3, 4]), 2) == pytest.approx(10 / 12)
    # A partial last group counts its idle lanes: (5, 5, 5) and (5, pad, pad)
    assert simd_efficiency(np.array([5, 5, 5, 5]), 3) == pytest.approx(20 / 30)
    assert simd_efficiency(np.array([7, 7, 7, 7]), 4) == 1.0
    # Branch taken by lanes 0 and 3 at iteration 0 (groups of 2 run it twice), and by lane 1
    # at iteration 1 (once): 3 taken of 3 runs x 2 lanes
    mask = np.array([[1, 0], [0, 1], [0, 0], [1, 0]], bool)
    assert branch_efficiency(mask, 2) == pytest.approx(3 / 6)
    assert queue_efficiency([5, 8, 0], 4) == pytest.approx(13 / 16)
    with pytest.raises(ParameterError, match="SIMD width"):
        simd_efficiency(np.array([1]), 0)


def test_parameters_are_checked(runtime):
    scene = load_scene("furnace")
    for bad in (0, -1, True, 1.5, 1 << 27):
        with pytest.raises(ParameterError, match="wave_paths"):
            WavefrontPathTracer(runtime, scene, wave_paths=bad)
    with pytest.raises(ParameterError, match="max_depth"):
        WavefrontPathTracer(runtime, scene, max_depth=-1)
    tracer = WavefrontPathTracer(runtime, scene, max_depth=1)
    sets = generate_sample_sets(runtime, make_sampler("independent", 1), 1, np.array([100]))
    with pytest.raises(ParameterError, match="outside the 8 x 8 image"):
        tracer.trace(sets, 1, 8, 8)
    zsobol = generate_sample_sets(runtime, make_sampler("zsobol", 4), 1, np.arange(4), None, (8, 8))
    with pytest.raises(ParameterError, match="cannot be traced at 16 x 16"):
        tracer.trace(zsobol, 1, 16, 16)
    with pytest.raises(ParameterError, match="seed"):
        tracer.trace(zsobol, -1, 8, 8)


def test_empty_launch(runtime):
    """A launch without traced samples traces nothing, as the megakernel."""
    zero = np.zeros(1, np.uint32)
    offsets = np.zeros(2, np.int64)
    flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    sets = DeviceSampleSets(
        make_sampler("independent", 1),
        zero,
        zero,
        offsets,
        cl.Buffer(runtime.context, flags, hostbuf=np.zeros(2, np.float32)),
        cl.Buffer(runtime.context, flags, hostbuf=offsets.astype(np.uint32)),
        cl.Buffer(runtime.context, flags, hostbuf=zero),
        cl.Buffer(runtime.context, flags, hostbuf=zero),
    )
    result = WavefrontPathTracer(runtime, load_scene("furnace")).trace(sets, 1, 8, 8)
    assert result.to_host().shape == (0, 3) and result.rays == 0 and result.nonfinite == 0
