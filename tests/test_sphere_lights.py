"""Spherical area emitters (kernels/lights.h): the cone sampling of the visible cap against a
float64 NumPy twin and a chi-square test, its pdf integrated over the sphere of directions,
renders against exact answers, NEE + MIS against BSDF sampling alone, both tracers alike, and
the scene file's emission field.

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
from clrender.scene import SceneError, load_scene
from clrender.scene_device import EMITTER_DTYPE, EMITTER_SHAPES, SPHERE_DTYPE
from clrender.trace import PathTracer
from clrender.wavefront import WavefrontPathTracer

# ------------------------------------------------------------------ the sampling kernel


def sphere_records(center, radius, pick_pdf=1.0):
    sphere = np.zeros(1, SPHERE_DTYPE)
    sphere["center"], sphere["radius"], sphere["material"], sphere["emitter"] = (
        center,
        radius,
        -1,
        0,
    )
    emitter = np.zeros(1, EMITTER_DTYPE)
    emitter["shape"], emitter["index"] = EMITTER_SHAPES["sphere"], 0
    emitter["radiance"], emitter["area"] = 1.0, 4 * math.pi * radius**2
    emitter["pick_pdf"], emitter["pick_cdf"] = pick_pdf, 1.0
    return sphere, emitter


def device_samples(runtime, center, radius, points, u, pick_pdf=1.0):
    """The kernel's (wi, dist, pdfW, hit pdfW) for reference points (N, 3) and u (N, 2)."""
    sphere, emitter = sphere_records(center, radius, pick_pdf)
    count = len(points)
    out = {
        "wi": np.empty((count, 3), np.float32),
        "dist": np.empty(count, np.float32),
        "pdf": np.empty(count, np.float32),
        "hit_pdf": np.empty(count, np.float32),
    }
    return run_test_kernel(
        runtime,
        "lights_test.cl",
        "sample_sphere_light",
        count,
        out,
        runtime.upload(sphere),
        runtime.upload(emitter),
        np.uint32(1),
        runtime.upload(np.ascontiguousarray(points, np.float32)),
        runtime.upload(np.ascontiguousarray(u, np.float32)),
    )


def duff_frame(n):
    """Frame_FromNormal (kernels/bsdf.h) in float64: s, t around the unit normals n (N, 3)."""
    sign = np.copysign(1.0, n[:, 2])
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], -1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], -1)
    return s, t


def numpy_cone_samples(center, radius, points, u):
    """The float64 twin of Light_SampleSphereCone: (wi, dist, cone pdfW); pdf 0 inside."""
    to_center = np.asarray(center, np.float64) - points
    dc = np.linalg.norm(to_center, axis=1)
    axis = to_center / dc[:, None]
    sin2_max = radius**2 / dc**2
    cos_max = np.sqrt(np.maximum(1 - sin2_max, 0.0))
    one_minus_cos = u[:, 0] * (1 - cos_max)
    cos_theta = 1 - one_minus_cos
    sin_theta = np.sqrt(one_minus_cos * (2 - one_minus_cos))
    phi = 2 * np.pi * u[:, 1]
    s, t = duff_frame(axis)
    wi = (
        (sin_theta * np.cos(phi))[:, None] * s
        + (sin_theta * np.sin(phi))[:, None] * t
        + cos_theta[:, None] * axis
    )
    # Near root of |p + s wi - c| = r, by the textbook quadratic
    b = np.einsum("ij,ij->i", wi, to_center)
    dist = b - np.sqrt(np.maximum(b**2 - (dc**2 - radius**2), 0.0))
    pdf = np.where(dc > radius, 1 / (2 * np.pi * (1 - cos_max)), 0.0)
    return wi, dist, pdf


CENTER, RADIUS = np.array([0.3, -0.2, 1.1]), 0.7


def reference_points(rng, count, sin_theta_max):
    """Points at distance RADIUS / sin_theta_max from CENTER in random directions."""
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    return CENTER + (RADIUS / sin_theta_max) * v


@pytest.mark.parametrize("sin_theta_max", [0.999, 0.9, 0.5, 0.05, 1e-3])
def test_cone_samples_match_the_numpy_twin(runtime, sin_theta_max):
    """Known answers: directions, distances and pdfs of the kernel against float64, from far
    (a 0.06 degree cone, where 1 - cos theta_max in float32 would lose most digits) to nearly
    on the sphere; the hit pdf of the same direction equals the sample's."""
    rng = np.random.default_rng(5)
    points = reference_points(rng, 2000, sin_theta_max)
    u = rng.random((2000, 2))
    got = device_samples(runtime, CENTER, RADIUS, points, u, pick_pdf=0.25)
    wi, dist, pdf = numpy_cone_samples(
        CENTER, RADIUS, points.astype(np.float32), u.astype(np.float32)
    )
    np.testing.assert_allclose(got["wi"], wi, atol=3e-6)
    dc = RADIUS / sin_theta_max
    # Distance: float32 rounding of the point (dc) and, at the cap's rim, of the chord
    np.testing.assert_allclose(got["dist"], dist, atol=2e-5 * dc + 2e-3 * RADIUS, rtol=1e-5)
    np.testing.assert_allclose(got["pdf"], 0.25 * pdf, rtol=2e-5)
    assert np.array_equal(got["hit_pdf"], got["pdf"])
    # The sampled point lies on the sphere, on the side facing the reference point
    hit = points + got["dist"][:, None] * got["wi"]
    assert np.abs(np.linalg.norm(hit - CENTER, axis=1) - RADIUS).max() < 4e-6 * dc + 1e-5
    outward = np.einsum("ij,ij->i", hit - CENTER, -got["wi"])
    assert outward.min() > -1e-3 * RADIUS


def test_points_inside_or_on_the_sphere_get_no_sample(runtime):
    """The outward emitter is invisible from inside: pdf 0 (NEE adds nothing there)."""
    rng = np.random.default_rng(6)
    v = rng.normal(size=(100, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    points = CENTER + RADIUS * rng.random(100)[:, None] * v
    got = device_samples(runtime, CENTER, RADIUS, points, rng.random((100, 2)))
    assert np.all(got["pdf"] == 0.0) and np.all(got["hit_pdf"] == 0.0)


@pytest.mark.parametrize("sin_theta_max", [0.95, 0.5, 0.1])
def test_cone_pdf_integrates_to_one_over_the_sphere_of_directions(runtime, sin_theta_max):
    """Quadrature over all directions (a fine grid in world spherical coordinates, each
    direction tested against the sphere in float64): the kernel's pdf integrates to 1."""
    point = np.array([[0.1, 0.4, -0.3]])
    center = point[0] + (RADIUS / sin_theta_max) * np.array([0.48, 0.6, 0.64])
    pdf = float(device_samples(runtime, center, RADIUS, point, np.full((1, 2), 0.5))["hit_pdf"][0])
    n_theta, n_phi = 3000, 6000
    cos_theta = 1 - 2 * (np.arange(n_theta) + 0.5) / n_theta  # equal solid angle rows
    phi = 2 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    sin_theta = np.sqrt(1 - cos_theta**2)
    to_center = center - point[0]
    total = 0.0
    for start in range(0, n_theta, 500):
        rows = slice(start, start + 500)
        d = np.stack(
            [
                sin_theta[rows, None] * np.cos(phi),
                sin_theta[rows, None] * np.sin(phi),
                np.broadcast_to(cos_theta[rows, None], (len(cos_theta[rows]), n_phi)),
            ],
            -1,
        )
        b = d @ to_center
        hits = (b > 0) & (b**2 >= to_center @ to_center - RADIUS**2)
        total += hits.sum()
    integral = pdf * total * 4 * np.pi / (n_theta * n_phi)
    assert integral == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("sin_theta_max", [0.99, 0.6, 0.1])
def test_cone_samples_pass_a_chi_square_test(runtime, sin_theta_max):
    """Directions binned by (1 - cos theta) / (1 - cos theta_max) and by azimuth (8 x 8
    equal-probability bins under the pdf): chi-square against uniform counts, p > 1e-3."""
    rng = np.random.default_rng(7)
    count = 64000
    point = reference_points(rng, 1, sin_theta_max)
    points = np.repeat(point, count, axis=0)
    got = device_samples(runtime, CENTER, RADIUS, points, rng.random((count, 2)))
    axis = (CENTER - point[0]) / np.linalg.norm(CENTER - point[0])
    wi = got["wi"].astype(np.float64)
    one_minus_cos_max = 1 - math.sqrt(1 - sin_theta_max**2)
    # 1 - cos theta without cancellation: |wi - axis|^2 / 2
    one_minus_cos = 0.5 * np.sum((wi - axis) ** 2, axis=1)
    s, t = duff_frame(axis[None, :])
    phi = np.arctan2(wi @ t[0], wi @ s[0]) % (2 * np.pi)
    radial = np.clip(one_minus_cos / one_minus_cos_max, 0, 1 - 1e-12)
    counts, _, _ = np.histogram2d(radial, phi / (2 * np.pi), bins=8, range=[[0, 1], [0, 1]])
    chi2 = ((counts - count / 64) ** 2 / (count / 64)).sum()
    assert stats.chi2.sf(chi2, 63) > 1e-3, chi2


# ------------------------------------------------------------------ renders

PLATE_SCENE = """
[camera]
look_from = {look_from}
look_at = {look_at}
fov = {fov}
resolution = [{size}, {size}]

[materials.plate]
type = "diffuse"
albedo = [0.5, 0.25, 0.8]

[[shapes]]
name = "plate"
type = "quad"
corner = [-10.0, 0.0, -10.0]
edge1 = [0.0, 0.0, 20.0]
edge2 = [20.0, 0.0, 0.0]
material = "plate"

[[shapes]]
name = "lamp"
type = "sphere"
center = [0.0, 2.0, 0.0]
radius = 0.5
emission = [4.0, 2.0, 1.0]
"""
ALBEDO, LAMP = np.array([0.5, 0.25, 0.8]), np.array([4.0, 2.0, 1.0])


def toml_list(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def write_scene(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_scene(path)


def render_image(runtime, tracer, size, spp, seed=3, sampler="stratified"):
    source = PathTracerSource(tracer, size, size)
    settings = RenderSettings(size, size, make_sampler(sampler, spp), "mc", seed)
    result = render(runtime, source, settings)
    assert result.film.complete and result.stats.nonfinite_samples == 0
    return result.film.image().astype(np.float64)


@pytest.mark.parametrize(
    ("target", "expected"),
    [
        # Straight below the centre at d = 2: rho L (r / d)^2
        ([0.0, 0.0, 0.0], ALBEDO * LAMP * (0.5 / 2.0) ** 2),
        # At 1.5 to the side: distance 2.5 to the centre, cos 0.8 from the normal (the whole
        # sphere above the horizon): rho L (r / dc)^2 cos
        ([1.5, 0.0, 0.0], ALBEDO * LAMP * (0.5 / 2.5) ** 2 * 0.8),
    ],
)
@pytest.mark.parametrize("depth", [1, 4])
def test_plate_under_a_sphere_light_has_the_exact_radiance(
    runtime, tmp_path, target, expected, depth
):
    """A diffuse plane lit by an emitting sphere (radiance L, radius r) entirely above its
    horizon: irradiance pi L sin^2 theta_max cos, radiance rho / pi times that. The camera's
    0.2-degree view puts every pixel on the target point (the irradiance varies by under 1e-5
    across it); nothing else scatters, so any depth gives the same answer."""
    look_from = np.array(target) + [0.0, 3.0, 6.0]
    text = PLATE_SCENE.format(look_from=toml_list(look_from), look_at=target, fov=0.2, size=16)
    tracer = PathTracer(runtime, write_scene(tmp_path, text), max_depth=depth)
    errors = (render_image(runtime, tracer, 16, 16) - expected).reshape(-1, 3)
    se = errors.std(axis=0, ddof=1) / math.sqrt(len(errors))
    assert np.all(np.abs(errors.mean(axis=0)) <= 4 * se + 1e-4 * expected), (errors.mean(0), se)


def test_sphere_light_seen_directly_shows_its_radiance(runtime, tmp_path):
    """Every pixel of a view filled by the sphere shows L exactly (a pure emitter)."""
    text = PLATE_SCENE.format(look_from=[0.0, 3.0, 6.0], look_at=[0.0, 2.0, 0.0], fov=2.0, size=8)
    tracer = PathTracer(runtime, write_scene(tmp_path, text), max_depth=3)
    image = render_image(runtime, tracer, 8, 4)
    assert np.array_equal(image, np.broadcast_to(LAMP, image.shape))


def test_sphere_light_is_invisible_from_inside(runtime, tmp_path):
    """The camera inside the lamp: the one-sided outward emitter shows nothing, and lights
    nothing through its back (the plate seen through it stays black)."""
    text = PLATE_SCENE.format(look_from=[0.0, 2.1, 0.0], look_at=[0.0, 0.0, 0.3], fov=30.0, size=8)
    with pytest.warns(UserWarning, match="inside"):
        scene = write_scene(tmp_path, text)
    image = render_image(runtime, PathTracer(runtime, scene, max_depth=3), 8, 4)
    assert np.all(image == 0.0)


MIS_SCENE = """
[camera]
look_from = [0.0, 2.5, 6.0]
look_at = [0.0, 0.5, 0.0]
fov = 40.0
resolution = [24, 24]

[materials.floor]
type = "diffuse"
albedo = [0.6, 0.6, 0.6]

[materials.metal]
type = "roughconductor"
alpha = 0.08

[materials.chalk]
type = "diffuse"
albedo = [0.3, 0.5, 0.7]

[[shapes]]
name = "floor"
type = "quad"
corner = [-4.0, 0.0, -4.0]
edge1 = [0.0, 0.0, 8.0]
edge2 = [8.0, 0.0, 0.0]
material = "floor"

[[shapes]]
name = "plate"
type = "quad"
corner = [-2.0, 0.2, -1.0]
edge1 = [0.0, 1.5, -0.6]
edge2 = [4.0, 0.0, 0.0]
material = "metal"

[[shapes]]
name = "panel"
type = "quad"
corner = [-3.0, 3.0, -2.0]
edge1 = [0.6, 0.0, 0.0]
edge2 = [0.0, 0.0, 0.6]
emission = [2.0, 2.0, 2.0]

[[shapes]]
name = "big lamp"
type = "sphere"
center = [-1.0, 1.6, 2.0]
radius = 0.4
emission = [3.0, 2.0, 1.0]

[[shapes]]
name = "small lamp"
type = "sphere"
center = [1.2, 1.0, 1.5]
radius = 0.08
emission = [40.0, 60.0, 80.0]
material = "chalk"
"""


@pytest.fixture(scope="module")
def mis_scene(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("mis"), MIS_SCENE)


def test_mis_scene_has_quad_and_sphere_emitters(mis_scene):
    emitters = mis_scene.emitters
    assert list(emitters["shape"]) == [0, 1, 1] and list(emitters["index"]) == [2, 0, 1]
    assert list(mis_scene.spheres["emitter"]) == [1, 2] and mis_scene.quads["emitter"][2] == 0
    power = emitters["area"] * emitters["radiance"].mean(axis=1)
    np.testing.assert_allclose(emitters["pick_pdf"], power / power.sum(), rtol=1e-6)
    np.testing.assert_allclose(emitters["area"][1], 4 * math.pi * 0.16, rtol=1e-6)


def test_nee_with_mis_matches_bsdf_sampling_alone(runtime, mis_scene):
    """Quad and sphere lights (one sphere also reflecting), a glossy plate and a diffuse floor
    at depth 3: NEE + MIS and BSDF sampling alone estimate the same image. Per pixel the
    difference of the two renders has mean 0; over the 576 pixels its mean stays within 4 SE
    (BSDF sampling alone is the noisy one). A light pdf off by a factor (say the cone's 2 pi
    or the pick pdf forgotten) shifts the NEE image by far more."""
    size, spp = 24, 256
    images = [
        render_image(
            runtime,
            PathTracer(runtime, mis_scene, max_depth=3, next_event_estimation=nee),
            size,
            spp,
        )
        for nee in (True, False)
    ]
    diff = (images[0] - images[1]).reshape(-1, 3)
    se = diff.std(axis=0, ddof=1) / math.sqrt(len(diff))
    assert np.all(np.abs(diff.mean(axis=0)) < 4 * se), (diff.mean(axis=0), se)
    # The sphere lights matter: their direct light is most of the floor's
    assert images[0].mean() > 0.05


def test_wavefront_matches_the_megakernel_with_sphere_lights(runtime, mis_scene):
    """Bit for bit, ray and non-finite counts, in three chunks, with and without NEE."""
    size = 16
    pixels = rectangle_pixels(size, 0, 0, size, size)
    sets = generate_sample_sets(runtime, make_sampler("sobol", 16), 9, pixels, None, (size, size))
    for nee in (True, False):
        options = {"max_depth": 4, "next_event_estimation": nee}
        a = PathTracer(runtime, mis_scene, **options).trace(sets, 9, size, size)
        b = WavefrontPathTracer(runtime, mis_scene, wave_paths=1500, **options).trace(
            sets, 9, size, size
        )
        radiance = a.to_host()
        assert np.array_equal(radiance, b.to_host())
        assert a.rays == b.rays and a.nonfinite == b.nonfinite == 0
        # With NEE nearly every path that meets the floor gathers light
        assert np.count_nonzero(radiance.sum(axis=1)) > (len(radiance) // 2 if nee else 100)


# ------------------------------------------------------------------ scene files


def test_sphere_emission_is_read(mis_scene):
    assert mis_scene.sphere_names == ["big lamp", "small lamp"]
    np.testing.assert_array_equal(mis_scene.emitters["radiance"][2], [40.0, 60.0, 80.0])
    assert mis_scene.spheres["material"][0] == -1  # a pure emitter
    assert mis_scene.material_names[mis_scene.spheres["material"][1]] == "chalk"


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("emission = [3.0, 2.0, 1.0]", "emission = [3.0, -2.0, 1.0]", ["'big lamp'", "'emission'"]),
        ("emission = [3.0, 2.0, 1.0]", "emission = [3.0, 2.0]", ["'big lamp'", "'emission'"]),
        ("emission = [3.0, 2.0, 1.0]", 'emission = "bright"', ["'big lamp'", "'emission'"]),
        ("emission = [3.0, 2.0, 1.0]", "emission = [3.0, nan, 1.0]", ["'big lamp'", "'emission'"]),
        # Without emission (or black) and without a material: nothing to render it with
        (
            "emission = [3.0, 2.0, 1.0]",
            "emission = [0.0, 0.0, 0.0]",
            ["'big lamp'", "'material'", "missing"],
        ),
    ],
)
def test_bad_sphere_emission_is_refused_in_one_line(tmp_path, old, new, words):
    with pytest.raises(SceneError) as info:
        write_scene(tmp_path, MIS_SCENE.replace(old, new))
    message = str(info.value)
    assert "\n" not in message and all(word in message for word in words), message


def test_a_box_still_cannot_emit(tmp_path):
    box = """
[[shapes]]
name = "crate"
type = "box"
min = [0.0, 0.0, 0.0]
max = [1.0, 1.0, 1.0]
emission = [1.0, 1.0, 1.0]
"""
    with pytest.raises(
        SceneError, match="'crate'.*'emission'.*only quads, spheres and meshes emit"
    ):
        write_scene(tmp_path, MIS_SCENE + box)
