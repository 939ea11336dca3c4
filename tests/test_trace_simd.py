"""The SIMD-across-paths kernel (kernels/trace_simd.cl through PathTracer(trace_kernel="simd"))
against the megakernel (kernels/integrator.cl), which tests/test_trace.py checks against known
answers.

Its vector code mirrors the megakernel's operations and its per-lane fallbacks call the
megakernel's own functions, so the test is exact: every sample's radiance bit for bit, the ray
count and the non-finite count equal, on one device (the tolerance is zero). Launches hold a
number of samples that is not a multiple of the kernel's width (lanes past the end).
"""

import dataclasses

import numpy as np
import pytest
from scene_texts import lit_room, mesh_text, random_shapes_text

from clrender.errors import ParameterError
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene, scenes_dir
from clrender.scene_device import BRUTE_FORCE_LIMIT
from clrender.trace import PathTracer

SIZE = 15  # 15 x 15 pixels at 4 spp: 900 samples, not a multiple of 16 or 8
SPP = 4  # a square (stratified)


def draw(runtime, sampler, seed, size=SIZE, spp=SPP):
    pixels = rectangle_pixels(size, 0, 0, size, size)
    config = make_sampler(sampler, spp)
    return generate_sample_sets(runtime, config, seed, pixels, None, (size, size))


def assert_same_trace(runtime, scene, sets, seed, size=SIZE, simd_defines=None, **options):
    """Both kernels' radiance bit for bit, rays and non-finite counts; returns the megakernel's
    radiance and result."""
    # The megakernel named: "auto" (the default) takes simd on CPU devices
    mega = PathTracer(runtime, scene, trace_kernel="megakernel", **options)
    assert mega.trace_kernel == "megakernel"
    simd = PathTracer(runtime, scene, trace_kernel="simd", simd_defines=simd_defines, **options)
    a = mega.trace(sets, seed, size, size)
    b = simd.trace(sets, seed, size, size)
    radiance_a, radiance_b = a.to_host(), b.to_host()
    differing = np.flatnonzero(np.any(radiance_a != radiance_b, axis=1))
    assert differing.size == 0, (
        f"{differing.size} of {len(radiance_a)} samples differ",
        differing[:5],
        radiance_a[differing[:5]],
        radiance_b[differing[:5]],
    )
    assert b.rays == a.rays
    assert b.nonfinite == a.nonfinite
    return radiance_a, a


@pytest.mark.parametrize(
    "scene_name", ["mitsuba-cbox", "cornell-box", "cornell-box-glossy", "veach-mis", "furnace"]
)
@pytest.mark.parametrize("sampler", ["independent", "sppp", "stratified", "sobol", "zsobol"])
def test_shipped_scenes_trace_the_megakernels_samples(runtime, scene_name, sampler):
    """Quads, a sphere, glass and rough conductors (per-lane vertices), sphere emitters, several
    quad emitters; every path sampler (sppp: a Poisson number of samples a pixel)."""
    sets = draw(runtime, sampler, 11)
    radiance, result = assert_same_trace(runtime, load_scene(scene_name), sets, 11)
    assert len(radiance) > 600 and result.rays > 2 * len(radiance)
    assert np.count_nonzero(radiance.sum(axis=1)) > len(radiance) // 4


@pytest.mark.parametrize(
    ("scene_name", "depth", "nee", "roulette"),
    [
        ("cornell-box", 0, True, False),
        ("cornell-box", 1, True, False),
        ("cornell-box", 2, False, False),
        ("cornell-box", 8, True, True),
        ("cornell-box-glossy", 5, False, True),
        ("mitsuba-cbox", 8, True, True),
        ("veach-mis", 8, False, True),
        ("cornell-box", 24, False, True),
    ],
)
def test_integrator_options_match(runtime, scene_name, depth, nee, roulette):
    """Emitters only, direct light only, BSDF sampling only, Russian roulette, long glass
    paths: the same samples as the megakernel."""
    sets = draw(runtime, "independent", 13)
    options = {"max_depth": depth, "next_event_estimation": nee, "russian_roulette": roulette}
    radiance, result = assert_same_trace(runtime, load_scene(scene_name), sets, 13, **options)
    if depth == 0:
        assert result.rays == len(radiance)


@pytest.mark.parametrize(
    "defines",
    [{"SIMD_WIDTH": 8}, {"SIMD_PORTABLE": True}, {"SIMD_WIDTH": 8, "SIMD_PORTABLE": True}],
    ids=["width8", "portable", "portable-width8"],
)
@pytest.mark.parametrize("scene_name", ["mitsuba-cbox", "cornell-box-glossy"])
@pytest.mark.parametrize("sampler", ["independent", "zsobol"])
def test_build_variants_match(runtime, scene_name, defines, sampler):
    """Width 8, and the portable code (no x86 builtins) a compiler without AVX would get."""
    sets = draw(runtime, sampler, 17)
    assert_same_trace(runtime, load_scene(scene_name), sets, 17, simd_defines=defines)


@pytest.mark.parametrize(
    ("sampler", "spp", "side", "depth"),
    [
        ("zsobol", 8, SIZE, 8),  # 2 x 4 + 3 = 11 index bits: the last binary digit
        ("zsobol", 4, 2**15, 8),  # 32 bits: the top digit has no digits above it
        ("zsobol", 2, 2**15, 8),  # 31 bits: the top digit and the last binary digit
        ("sobol", 4, SIZE, 24),  # dimensions up to 2 + 7 x 24
        ("zsobol", 4, SIZE, 24),
        ("sobol", 1, SIZE, 8),  # one sample a pixel: every index 0
        ("stratified", 9, SIZE, 8),  # 9 strata in a range of 16: permutations walk cycles
        ("stratified", 25, SIZE, 24),
        ("stratified", 1, SIZE, 8),  # one stratum: division by 1
    ],
)
def test_low_discrepancy_layouts_match(runtime, sampler, spp, side, depth):
    """The stratified, sobol and zsobol samplers on lanes: zsobol's index layouts (odd bit
    counts, 32 bits), stratum counts that are not powers of two, long paths (high dimensions),
    a block of pixels in the middle of a large image."""
    x0 = (side - SIZE) // 2
    pixels = rectangle_pixels(side, x0, x0, SIZE, SIZE)
    sets = generate_sample_sets(runtime, make_sampler(sampler, spp), 23, pixels, None, (side, side))
    options = {"max_depth": depth, "russian_roulette": depth > 8}
    radiance, _ = assert_same_trace(runtime, load_scene("cornell-box"), sets, 23, side, **options)
    assert np.count_nonzero(radiance.sum(axis=1)) > len(radiance) // 4


def write_scene(tmp_path, text, name):
    path = tmp_path / name
    path.write_text(text)
    return load_scene(path)


@pytest.fixture(scope="module")
def mesh_scenes(tmp_path_factory):
    """Triangles by brute force (with vertex normals), a BVH over triangles, spheres and quads,
    and the Cornell box lit by an emitting mesh (triangle emitters: NEE lane by lane)."""
    folder = tmp_path_factory.mktemp("simd-meshes")
    rng = np.random.default_rng(5)
    room = lit_room(SIZE)
    few = room + random_shapes_text(rng, 2, 1, 6, 0.6, (0.2, 0.4), 0.5, normals=True)
    many = room + random_shapes_text(rng, 4, 3, 300, 0.5, (0.1, 0.3), 0.2)
    cornell = (scenes_dir() / "cornell-box.toml").read_text()
    # An emitting tetrahedron-like mesh beside the quad light (triangle emitters)
    corners = [[300, 300, 200], [360, 300, 200], [330, 360, 200], [330, 330, 260]]
    gem = mesh_text(corners, [(0, 2, 1), (0, 1, 3), (1, 2, 3), (2, 0, 3)])
    gem = gem.replace('material = "white"\n', "emission = [4.0, 3.0, 2.0]\n")
    return {
        "triangles": write_scene(folder, few, "few.toml"),
        "bvh": write_scene(folder, many, "many.toml"),
        "mesh-light": write_scene(folder, cornell + gem, "gem.toml"),
    }


@pytest.mark.parametrize("kind", ["triangles", "bvh", "mesh-light"])
@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_mesh_scenes_match(runtime, mesh_scenes, kind, sampler):
    scene = mesh_scenes[kind]
    sets = draw(runtime, sampler, 19)
    # Brute force over the few triangles, a BVH over the many
    options = {"brute_force_limit": {"triangles": 2**62, "bvh": -1}.get(kind, BRUTE_FORCE_LIMIT)}
    tracer = PathTracer(runtime, scene, **options)
    assert (len(tracer.bvh_nodes) > 0) == (kind == "bvh")
    if kind == "mesh-light":
        assert (scene.emitters["shape"] == 2).sum() == 4 and len(scene.emitters) == 5
    radiance, _ = assert_same_trace(runtime, scene, sets, 19, **options)
    assert np.count_nonzero(radiance.sum(axis=1)) > 0


def test_nonfinite_radiance_matches(runtime):
    """Radiance 3e38 overflows once two emissions add up: the same samples are counted and
    zeroed (set on the packed emitters: scene files refuse such values)."""
    furnace = load_scene("furnace")
    emitters = furnace.emitters.copy()
    emitters["radiance"][:, 0] = 3e38
    hot = dataclasses.replace(furnace, emitters=emitters)
    sets = draw(runtime, "independent", 7, size=8, spp=4)
    radiance, result = assert_same_trace(runtime, hot, sets, 7, size=8, max_depth=2)
    assert result.nonfinite > 0 and np.all(np.isfinite(radiance))


def test_overflowing_throughput_matches(runtime):
    """Albedo 1e30 makes the throughput infinite after two bounces: inf * 0 = NaN where the
    megakernel makes it (counted as non-finite), and nowhere else."""
    scene = load_scene("cornell-box")
    materials = scene.materials.copy()
    materials["albedo"] *= 1e30
    bright = dataclasses.replace(scene, materials=materials)
    sets = draw(runtime, "independent", 9)
    radiance, result = assert_same_trace(runtime, bright, sets, 9, max_depth=3)
    assert 0 < result.nonfinite < len(radiance)


@pytest.mark.parametrize("width", [16, 8])
def test_lanes_whose_paths_end_take_new_samples(runtime, width):
    """Path regeneration: a work-item traces a chunk of 32 lanes' worth of samples, a lane whose
    path ends taking the chunk's next one. Paths of 1 to 25 vertices (Russian roulette, depth
    24, BSDF sampling only: the rays are the lanes' steps) give the megakernel's samples, and
    the kernel's steps leave lanes idle only at each chunk's end: at most 25 steps (the longest
    path) a chunk with an idle lane. One sample a lane until all have ended (SIMD_CHUNK 1, the
    kernel before regeneration) needs more steps than that allows."""
    size = 32  # 4096 samples: 8 chunks of 512 at width 16, 16 of 256 at width 8
    sets = draw(runtime, "independent", 29, size=size)
    scene = load_scene("cornell-box")
    options = {"max_depth": 24, "next_event_estimation": False, "russian_roulette": True}
    defines = {"SIMD_WIDTH": width}
    radiance, mega = assert_same_trace(
        runtime, scene, sets, 29, size, simd_defines=defines, **options
    )
    chunks = -(-len(radiance) // (32 * width))
    steps = {}
    for chunk in (32, 1):
        simd = PathTracer(
            runtime,
            scene,
            trace_kernel="simd",
            simd_defines=defines | {"SIMD_CHUNK": chunk},
            **options,
        )
        result = simd.trace(sets, 29, size, size)
        assert np.array_equal(result.to_host(), radiance) and result.rays == mega.rays
        steps[chunk] = result.steps
    assert mega.rays >= 2 * len(radiance)  # paths of several vertices
    assert mega.rays <= width * steps[32] <= mega.rays + width * chunks * 25
    assert width * steps[1] > mega.rays + width * chunks * 25


def test_empty_launch(runtime):
    """No samples: nothing traced, no rays."""
    simd = PathTracer(runtime, load_scene("mitsuba-cbox"), trace_kernel="simd")
    sets = generate_sample_sets(
        runtime, make_sampler("independent", 1), 1, rectangle_pixels(4, 0, 0, 0, 0), None, None
    )
    result = simd.trace(sets, 1, 4, 4)
    assert result.to_host().shape == (0, 3) and result.rays == 0


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (
            {"trace_kernel": "vector"},
            "trace_kernel must be one of auto, megakernel, simd, got 'vector'",
        ),
        ({"trace_kernel": None}, "trace_kernel must be one of"),
        ({"trace_kernel": "simd", "simd_defines": {"SIMD_WIDTH": 4}}, "SIMD_WIDTH must be one of"),
        ({"trace_kernel": "simd", "simd_defines": {"SIMD_CHUNK": 0}}, "SIMD_CHUNK must be a"),
        ({"trace_kernel": "simd", "simd_defines": {"SIMD_CHUNK": 2**27}}, "SIMD_CHUNK must be a"),
        ({"trace_kernel": "simd", "simd_defines": {"SIMD_CHUNK": "8"}}, "SIMD_CHUNK must be a"),
        (
            {"trace_kernel": "megakernel", "simd_defines": {"SIMD_WIDTH": 8}},
            "simd_defines need trace_kernel='simd'",
        ),
    ],
)
def test_bad_trace_kernel_is_refused_in_one_line(runtime, options, words):
    with pytest.raises(ParameterError, match=words) as err:
        PathTracer(runtime, load_scene("mitsuba-cbox"), **options)
    assert "\n" not in str(err.value)


def test_trace_kernel_is_exposed(runtime):
    scene = load_scene("mitsuba-cbox")
    assert PathTracer(runtime, scene, trace_kernel="megakernel").trace_kernel == "megakernel"
    assert PathTracer(runtime, scene, trace_kernel="simd").trace_kernel == "simd"
