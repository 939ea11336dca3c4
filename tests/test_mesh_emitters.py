"""Emitting triangle meshes (kernels/lights.h, EMITTER_TRIANGLE): the emitter pick's binary
search against the linear scan it replaces, the uniform triangle sampler against a float64
NumPy twin and a chi-square test, NEE of triangles against the twin, the Cornell box's light as
a mesh of its two triangles against the quad, NEE + MIS against BSDF sampling alone, both
tracers alike, and the scene file's emission field on meshes.

Statistics: a pixel's error is independent of the others', so over P pixels the mean error has
standard error SE = std / sqrt(P); an unbiased renderer keeps |mean error| below 4 SE (fixed
seeds: the outcome is deterministic, the bound says how far a correct one could land by chance).
"""

import math

import numpy as np
import pytest
from kernel_outputs import run_test_kernel
from scipy import stats

from clrender.pipeline import RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import SceneError, load_scene, scenes_dir
from clrender.scene_device import (
    EMITTER_SHAPES,
    pack_emitters,
    pack_quads,
    pack_triangles,
)
from clrender.trace import PathTracer
from clrender.wavefront import WavefrontPathTracer

pytestmark = pytest.mark.device

# ------------------------------------------------------------------ the sampling kernel


def random_mesh(rng, count):
    """An emitting mesh of `count` random triangles (each its own 3 vertices), with its packed
    triangles and emitters (random radiance, so random pick pdfs)."""
    positions = rng.uniform(-1.0, 1.0, (3 * count, 3))
    mesh = {
        "positions": positions,
        "indices": np.arange(3 * count).reshape(count, 3),
        "normals": None,
        "material": -1,
        "emission": None,
    }
    meshes = []
    for k in range(count):  # one mesh per triangle: a radiance each
        meshes.append(
            dict(
                mesh,
                positions=positions[3 * k : 3 * k + 3],
                indices=np.array([[0, 1, 2]]),
                emission=tuple(rng.uniform(0.1, 5.0, 3)),
            )
        )
    triangles, _ = pack_triangles(meshes)
    emitters = pack_emitters([], pack_quads([]), [], None, meshes, triangles)
    return triangles, emitters


def device_samples(runtime, triangles, emitters, points, u, quads=None):
    """The kernel's picked emitter, wi, dist, pdfW, hit pdfW and barycentrics for reference
    points (N, 3) and random triples u (N, 3)."""
    quads = pack_quads([]) if quads is None else quads
    count = len(points)
    out = {
        "picked": np.empty(count, np.uint32),
        "wi": np.empty((count, 3), np.float32),
        "dist": np.empty(count, np.float32),
        "pdf": np.empty(count, np.float32),
        "hit_pdf": np.empty(count, np.float32),
        "bary": np.empty((count, 3), np.float32),
    }
    return run_test_kernel(
        runtime,
        "mesh_lights_test.cl",
        "sample_mesh_light",
        count,
        out,
        runtime.upload(quads),
        np.uint32(len(quads)),
        runtime.upload(triangles),
        np.uint32(len(triangles)),
        runtime.upload(emitters),
        np.uint32(len(emitters)),
        runtime.upload(np.ascontiguousarray(points, np.float32)),
        runtime.upload(np.ascontiguousarray(u, np.float32)),
    )


def linear_scan_pick(cdf, u):
    """The emitter pick of main before the binary search: the first i with u < cdf[i], else
    the last emitter (float32 comparisons, as on the device)."""
    u = np.asarray(u, np.float32)
    chosen = np.full(len(u), len(cdf) - 1)
    for i in range(len(cdf) - 2, -1, -1):
        chosen = np.where(u < np.float32(cdf[i]), i, chosen)
    return chosen


def numpy_barycentrics(u):
    """Float64 twin of Triangle_SampleUniform: b0 = 1 - sqrt(u0), b1 = u1 sqrt(u0)."""
    su0 = np.sqrt(u[:, 0])
    b0 = 1.0 - su0
    b1 = u[:, 1] * su0
    return np.stack([b0, b1, 1.0 - b0 - b1], axis=-1)


@pytest.mark.parametrize("count", [1, 2, 7, 64, 257])
def test_pick_is_the_linear_scan(runtime, count):
    """The binary search picks exactly the emitter the linear scan picked, for random u and
    for u at every CDF boundary, one float32 step below and above it, 0 and just below 1."""
    rng = np.random.default_rng(5 + count)
    triangles, emitters = random_mesh(rng, count)
    cdf = emitters["pick_cdf"]
    edges = np.concatenate([cdf, np.nextafter(cdf, 0), np.nextafter(cdf, 2)]).astype(np.float32)
    u0 = np.concatenate(
        [rng.random(2000, np.float32), edges, np.float32([0.0, np.nextafter(1.0, 0.0), 1.0])]
    )
    u = np.stack([u0, np.full_like(u0, 0.3), np.full_like(u0, 0.6)], axis=-1)
    picked = device_samples(runtime, triangles, emitters, np.zeros((len(u), 3)), u)["picked"]
    np.testing.assert_array_equal(picked, linear_scan_pick(cdf, u0))
    # Every emitter is picked by some u (the test covers the whole range)
    assert len(np.unique(picked)) == count


def test_triangle_samples_match_the_numpy_twin(runtime):
    """Known answers on fixed u: the barycentrics, the emitter point's direction, distance and
    pdfW = pick_pdf dist^2 / (cos_light area) against float64, 0 behind the triangle; the hit
    pdf (Light_HitPdfW, for MIS) equals the sample's."""
    rng = np.random.default_rng(11)
    triangles, emitters = random_mesh(rng, 9)
    n = 4000
    u = rng.random((n, 3)).astype(np.float32)
    points = rng.uniform(-3.0, 3.0, (n, 3))
    out = device_samples(runtime, triangles, emitters, points, u)
    u64 = u.astype(np.float64)
    bary = numpy_barycentrics(u64[:, 1:])
    np.testing.assert_allclose(out["bary"], bary, rtol=0, atol=2e-7)
    np.testing.assert_allclose(out["bary"].sum(axis=1), 1.0, atol=2e-7)
    picked = linear_scan_pick(emitters["pick_cdf"], u[:, 0])
    np.testing.assert_array_equal(out["picked"], picked)
    tri = triangles[emitters["index"][picked]]
    p0, p1, p2 = (tri[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    y = bary[:, :1] * p0 + bary[:, 1:2] * p1 + bary[:, 2:] * p2
    to_light = y - points.astype(np.float32).astype(np.float64)
    dist = np.linalg.norm(to_light, axis=1)
    wi = to_light / dist[:, None]
    normal = np.cross(p1 - p0, p2 - p0)
    area = 0.5 * np.linalg.norm(normal, axis=1)
    cos_light = -np.einsum("ij,ij->i", normal / (2 * area)[:, None], wi)
    pick_pdf = emitters["pick_pdf"][picked].astype(np.float64)
    pdf = np.where(cos_light > 0, pick_pdf * dist**2 / (np.abs(cos_light) * area), 0.0)
    np.testing.assert_allclose(out["dist"], dist, rtol=1e-5)
    np.testing.assert_allclose(out["wi"], wi, atol=1e-5)
    # Away from grazing angles (where the cosine is ill-conditioned) the pdf is float-exact
    steady = np.abs(cos_light) > 1e-2
    assert steady.sum() > 0.9 * n and (cos_light > 0).sum() > 0.3 * n
    np.testing.assert_allclose(out["pdf"][steady], pdf[steady], rtol=2e-4)
    front = steady & (cos_light > 0)
    np.testing.assert_allclose(out["hit_pdf"][front], out["pdf"][front], rtol=1e-6)
    # The emitter's stored area is the triangle's
    np.testing.assert_allclose(
        emitters["area"],
        0.5
        * np.linalg.norm(
            np.cross(triangles["p1"] - triangles["p0"], triangles["p2"] - triangles["p0"]), axis=1
        ),
        rtol=1e-6,
    )


def simplex_cell_probabilities(bins):
    """Probability of each (b1, b2) cell of a bins x bins grid on [0, 1]^2 under the uniform
    distribution on the triangle b1 + b2 <= 1: cells below the diagonal 2 / bins^2, cells the
    diagonal halves 1 / bins^2 (the diagonal passes through their corners), the rest 0."""
    i, j = np.meshgrid(np.arange(bins), np.arange(bins), indexing="ij")
    return np.where(i + j < bins - 1, 2.0, np.where(i + j == bins - 1, 1.0, 0.0)) / bins**2


def chi_square_pvalue(b1, b2, bins=12):
    counts, _, _ = np.histogram2d(b1, b2, bins=bins, range=[[0, 1], [0, 1]])
    expected = simplex_cell_probabilities(bins) * len(b1)
    inside = expected > 0
    assert counts[~inside].sum() == 0
    return stats.chisquare(counts[inside], expected[inside]).pvalue


def test_triangle_barycentrics_pass_a_chi_square_test(runtime):
    """200000 device samples on 12 x 12 cells of (b1, b2) (78 non-empty): uniform on the
    triangle at p > 1e-3 (fixed seed); the naive sampler b0 = 1 - u0 (not uniform by area)
    fails the same test by far."""
    rng = np.random.default_rng(23)
    triangles, emitters = random_mesh(rng, 1)
    n = 200_000
    u = rng.random((n, 3)).astype(np.float32)
    bary = device_samples(runtime, triangles, emitters, np.zeros((n, 3)), u)["bary"]
    assert chi_square_pvalue(bary[:, 1], bary[:, 2]) > 1e-3
    naive_b0 = 1.0 - u[:, 1].astype(np.float64)
    naive_b1 = u[:, 2] * (1.0 - naive_b0)
    assert chi_square_pvalue(naive_b1, 1.0 - naive_b0 - naive_b1) < 1e-12


# ------------------------------------------------------------------ scenes

LIGHT_QUAD = """[[shapes]]
name = "light"  # one-sided, facing down: cross(edge1, edge2) = -y; it does not reflect
type = "quad"
corner = [213.0, 554.0, 227.0]
edge1 = [130.0, 0.0, 0.0]
edge2 = [0.0, 0.0, 105.0]
emission = [24.0, 24.0, 24.0]
"""
# The same quad as a mesh: corner, corner + edge1, corner + edge1 + edge2, corner + edge2,
# counter-clockwise seen from below (normal -y)
LIGHT_MESH = """[[shapes]]
name = "light"
type = "mesh"
positions = [[213.0, 554.0, 227.0], [343.0, 554.0, 227.0], [343.0, 554.0, 332.0],
             [213.0, 554.0, 332.0]]
indices = [[0, 1, 2], [0, 2, 3]]
emission = [24.0, 24.0, 24.0]
"""


def octahedron(center, radius, emission):
    """An emitting octahedron mesh (8 triangles, counter-clockwise seen from outside)."""
    c = np.asarray(center, np.float64)
    axes = np.eye(3)
    positions = [c + s * radius * axes[k] for k in range(3) for s in (1.0, -1.0)]
    indices = []
    for sx in (0, 1):
        for sy in (0, 1):
            for sz in (0, 1):
                face = [sx, 2 + sy, 4 + sz]
                if (sx + sy + sz) % 2:  # an odd number of negative axes: flip to face out
                    face = [face[0], face[2], face[1]]
                indices.append(face)
    rows = ", ".join("[" + ", ".join(f"{x:.1f}" for x in p) + "]" for p in positions)
    return f"""[[shapes]]
name = "gem"
type = "mesh"
positions = [{rows}]
indices = {indices}
emission = {list(map(float, emission))}
"""


def cornell_text() -> str:
    text = (scenes_dir() / "cornell-box.toml").read_text()
    assert LIGHT_QUAD in text
    return text


def write_scene(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_scene(path)


@pytest.fixture(scope="module")
def cornell_scenes(tmp_path_factory):
    """The Cornell box with its quad light, with the light as a 2-triangle mesh, and with that
    mesh light plus an emitting octahedron (10 triangle emitters)."""
    folder = tmp_path_factory.mktemp("mesh-lights")
    text = cornell_text()
    mesh_text = text.replace(LIGHT_QUAD, LIGHT_MESH)
    gem_text = mesh_text + "\n" + octahedron([400.0, 110.0, 120.0], 60.0, [6.0, 3.0, 1.0])
    return (
        load_scene("cornell-box"),
        write_scene(folder, mesh_text, "mesh.toml"),
        write_scene(folder, gem_text, "gem.toml"),
    )


def test_mesh_light_records(cornell_scenes):
    """The mesh light's two triangles are emitters 0 and 1 with half the quad's area and half
    its pick pdf each, so Light_PdfW (pick_pdf dist^2 / (cos area)) of a triangle is the quad's
    bit for bit at the same point: pick_pdf and area are the quad's times exactly 1/2. The
    octahedron's outward normals and its 8 emitters follow."""
    quad_scene, mesh_scene, gem_scene = cornell_scenes
    quad = quad_scene.emitters
    tri = mesh_scene.emitters
    assert list(tri["shape"]) == [EMITTER_SHAPES["triangle"]] * 2 and list(tri["index"]) == [0, 1]
    assert list(mesh_scene.triangles["emitter"]) == [0, 1]
    assert np.all(tri["pick_pdf"] == np.float32(0.5)) and quad["pick_pdf"][0] == 1.0
    assert np.all(tri["area"] * np.float32(2) == quad["area"][0])
    np.testing.assert_array_equal(tri["pick_cdf"], [0.5, 1.0])
    gem = gem_scene.triangles[2:]
    normals = np.cross(gem["p1"] - gem["p0"], gem["p2"] - gem["p0"])
    outward = (gem["p0"] + gem["p1"] + gem["p2"]) / 3 - np.array([400.0, 110.0, 120.0])
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)
    assert list(gem_scene.triangles["emitter"]) == list(range(10))
    power = gem_scene.emitters["area"] * gem_scene.emitters["radiance"].mean(axis=1)
    np.testing.assert_allclose(gem_scene.emitters["pick_pdf"], power / power.sum(), rtol=1e-6)


def render_image(runtime, tracer, size, spp, seed=3, sampler="stratified"):
    source = PathTracerSource(tracer, size, size)
    settings = RenderSettings(size, size, make_sampler(sampler, spp), "mc", seed)
    result = render(runtime, source, settings)
    assert result.film.complete and result.stats.nonfinite_samples == 0
    return result.film.image().astype(np.float64)


def assert_same_expectation(a, b):
    """Per pixel the difference of two unbiased renders of one image has mean 0: over the
    pixels its mean stays within 4 SE in every channel."""
    diff = (a - b).reshape(-1, 3)
    se = diff.std(axis=0, ddof=1) / math.sqrt(len(diff))
    assert np.all(np.abs(diff.mean(axis=0)) < 4 * se), (diff.mean(axis=0), se)


def test_mesh_light_renders_as_the_quad_light(runtime, cornell_scenes):
    """The Cornell box lit by its quad and by the same quad as two triangles (the points they
    sample differ, so the images differ sample by sample): the same expected image, 24 x 24 at
    64 spp, depth 3. Seen directly (depth 0, the same camera rays) the two images are equal."""
    quad_scene, mesh_scene, _ = cornell_scenes
    images = [
        render_image(runtime, PathTracer(runtime, scene, max_depth=3), 24, 64)
        for scene in (quad_scene, mesh_scene)
    ]
    assert_same_expectation(*images)
    assert images[1].mean() > 0.1
    # A ray that hits the light shows exactly its radiance (depth 0: emission only)
    direct = [
        render_image(runtime, PathTracer(runtime, scene, max_depth=0), 24, 4)
        for scene in (quad_scene, mesh_scene)
    ]
    assert direct[0].max() > 0.0
    np.testing.assert_array_equal(direct[0], direct[1])


def test_nee_with_mis_matches_bsdf_sampling_alone(runtime, cornell_scenes):
    """The mesh light and an emitting octahedron (10 triangle emitters, picked by power), depth
    3: NEE + MIS and BSDF sampling alone estimate the same image (mean difference within 4 SE
    over 576 pixels). A triangle's pdf off by a factor (the pick pdf, the area) shifts the NEE
    image by far more."""
    _, _, gem_scene = cornell_scenes
    images = [
        render_image(
            runtime,
            PathTracer(runtime, gem_scene, max_depth=3, next_event_estimation=nee),
            24,
            256,
        )
        for nee in (True, False)
    ]
    assert_same_expectation(*images)
    assert images[0].mean() > 0.1


@pytest.mark.parametrize("brute_force_limit", [2**62, -1])
def test_wavefront_matches_the_megakernel_with_mesh_lights(
    runtime, cornell_scenes, brute_force_limit
):
    """Bit for bit, ray and non-finite counts, in three chunks, with and without NEE, by brute
    force and through the BVH (the megakernel's; the wavefront picks its own from the scene)."""
    _, _, gem_scene = cornell_scenes
    size = 16
    pixels = rectangle_pixels(size, 0, 0, size, size)
    sets = generate_sample_sets(runtime, make_sampler("sobol", 16), 9, pixels, None, (size, size))
    for nee in (True, False):
        options = {"max_depth": 4, "next_event_estimation": nee}
        a = PathTracer(runtime, gem_scene, brute_force_limit=brute_force_limit, **options).trace(
            sets, 9, size, size
        )
        b = WavefrontPathTracer(runtime, gem_scene, wave_paths=1500, **options).trace(
            sets, 9, size, size
        )
        radiance = a.to_host()
        assert np.array_equal(radiance, b.to_host())
        assert a.rays == b.rays and a.nonfinite == b.nonfinite == 0
        # With NEE nearly every path gathers light; without, enough paths reach an emitter
        assert np.count_nonzero(radiance.sum(axis=1)) > (len(radiance) // 2 if nee else 100)


def test_back_of_an_emitting_mesh_is_dark(runtime, tmp_path):
    """A one-sided emitter: the light turned to face up (clockwise seen from below) emits
    towards the ceiling only. At depth 1 everything below the light's plane (the lower half of
    the image: floor, boxes, walls) gets exactly nothing, and the light's back shows black;
    facing down, the same light lights all of it."""
    flipped = LIGHT_MESH.replace("[[0, 1, 2], [0, 2, 3]]", "[[0, 2, 1], [0, 3, 2]]")
    folder = tmp_path
    images = [
        render_image(runtime, PathTracer(runtime, write_scene(folder, text), max_depth=1), 16, 4)
        for text in (
            cornell_text().replace(LIGHT_QUAD, flipped),
            cornell_text().replace(LIGHT_QUAD, LIGHT_MESH),
        )
    ]
    lower = slice(8, 16)
    assert images[0][lower].max() == 0.0
    assert np.all(images[1][lower].max(axis=(1, 2)) > 0.0)


@pytest.mark.parametrize(
    ("emission", "words"),
    [
        ("[1.0, -1.0, 1.0]", ["('thing')", "'emission'", ">= 0 (RGB)"]),
        ("[1.0, 1.0]", ["('thing')", "'emission'"]),
        ('"bright"', ["('thing')", "'emission'"]),
    ],
)
def test_bad_mesh_emission_is_refused_in_one_line(tmp_path, emission, words):
    text = cornell_text() + (
        '[[shapes]]\nname = "thing"\ntype = "mesh"\n'
        "positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n"
        f"indices = [[0, 1, 2]]\nemission = {emission}\n"
    )
    with pytest.raises(SceneError) as info:
        write_scene(tmp_path, text)
    message = str(info.value)
    assert "\n" not in message and all(w in message for w in words), message


def test_an_emitting_mesh_needs_no_material(tmp_path):
    text = cornell_text().replace(LIGHT_QUAD, LIGHT_MESH)
    scene = write_scene(tmp_path, text)
    assert list(scene.triangles["material"]) == [-1, -1]
