"""BSDF tests through kernels/bsdf_test.cl: chi-square tests of every sampling routine against
its pdf, consistency of sample weights with eval/pdf, energy conservation, reciprocity, and the
dielectric's discrete Fresnel choice and refraction law.

Chi-square (pbrt's test): directions binned on the sphere in cells of equal solid angle
(uniform in cos theta and phi); expected counts from the pdf integrated over each cell with a
64 x 64 midpoint rule; cells with expected count < 5 pooled; rejected when p < 0.01 / (number
of chi-square tests in this file).
"""

import math

import numpy as np
import pyopencl as cl
import pytest
from scipy import stats

from clrender.runtime import padded_global_size
from clrender.scene import ALUMINIUM_ETA, ALUMINIUM_K
from clrender.scene_device import MATERIAL_DTYPE, MATERIAL_TYPES

THETA_BINS, PHI_BINS, SUB = 10, 20, 64
SAMPLES = 200_000
CHI2_TESTS = 9
SIGNIFICANCE = 0.01 / CHI2_TESTS


def material(kind, albedo=(0.5, 0.6, 0.7), ior=1.5, alpha=0.3, eta=ALUMINIUM_ETA, k=ALUMINIUM_K):
    record = np.zeros(1, MATERIAL_DTYPE)
    record["type"] = MATERIAL_TYPES[kind]
    record["two_sided"] = 1
    record["albedo"] = albedo
    record["eta"] = (ior, ior, ior) if kind == "dielectric" else eta
    record["k"] = k
    record["alpha"] = alpha
    return record


class BsdfKernels:
    def __init__(self, runtime):
        self.runtime = runtime
        self.sample_kernel = runtime.kernel("bsdf_test.cl", "bsdf_sample")
        self.eval_kernel = runtime.kernel("bsdf_test.cl", "bsdf_eval")

    def _buffers(self, *arrays):
        ctx = self.runtime.context
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        return [cl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(a)) for a in arrays]

    def _outputs(self, *shapes):
        return [np.empty(shape, np.float32) for shape in shapes]

    def _run(self, kernel, count, inputs, outputs):
        rt = self.runtime
        out_bufs = [cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, size=o.nbytes) for o in outputs]
        kernel(
            rt.queue,
            (padded_global_size(count),),
            (rt.local_size,),
            np.uint32(count),
            *inputs,
            *out_bufs,
        )
        for host, buf in zip(outputs, out_bufs, strict=True):
            cl.enqueue_copy(rt.queue, host, buf)
        return outputs

    def sample(self, mat, wo, u):
        count = len(wo)
        inputs = self._buffers(mat, wo.astype(np.float32), u.astype(np.float32))
        return self._run(
            self.sample_kernel, count, inputs, self._outputs((count, 3), (count, 3), count)
        )

    def eval(self, mat, wo, wi):
        count = len(wo)
        inputs = self._buffers(mat, wo.astype(np.float32), wi.astype(np.float32))
        return self._run(self.eval_kernel, count, inputs, self._outputs((count, 3), count))


@pytest.fixture(scope="module")
def bsdf(runtime):
    return BsdfKernels(runtime)


def direction(theta_deg, phi_deg=30.0):
    theta, phi = math.radians(theta_deg), math.radians(phi_deg)
    return np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )


def uniforms(seed, count):
    return np.random.default_rng(seed).random((count, 3))


def sphere_grid(theta_bins, phi_bins, sub):
    """Midpoints of a (theta_bins*sub) x (phi_bins*sub) grid uniform in (cos theta, phi)."""
    cos_theta = 1.0 - (np.arange(theta_bins * sub) + 0.5) * (2.0 / (theta_bins * sub))
    phi = (np.arange(phi_bins * sub) + 0.5) * (2.0 * math.pi / (phi_bins * sub))
    c, p = np.meshgrid(cos_theta, phi, indexing="ij")
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    return np.stack([s * np.cos(p), s * np.sin(p), c], axis=-1).reshape(-1, 3)


def bin_index(w, theta_bins, phi_bins):
    cos_theta = np.clip(w[:, 2], -1.0, 1.0)
    ti = np.minimum(((1.0 - cos_theta) / 2.0 * theta_bins).astype(int), theta_bins - 1)
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2.0 * math.pi)
    pi = np.minimum((phi / (2.0 * math.pi) * phi_bins).astype(int), phi_bins - 1)
    return ti * phi_bins + pi


def integrated_pdf(bsdf, mat, wo):
    """Integral of pdfW over each bin, and of f |cos| over the sphere (the albedo)."""
    grid = sphere_grid(THETA_BINS, PHI_BINS, SUB)
    f, pdf = bsdf.eval(mat, np.tile(wo, (len(grid), 1)), grid)
    cell = 4.0 * math.pi / len(grid)
    pdf_grid = pdf.astype(np.float64).reshape(THETA_BINS, SUB, PHI_BINS, SUB)
    per_bin = pdf_grid.sum(axis=(1, 3)).reshape(-1) * cell
    albedo = (f.astype(np.float64) * np.abs(grid[:, 2:3])).sum(axis=0) * cell
    return per_bin, albedo


def chi2_pvalue(observed, expected):
    order = np.argsort(expected)
    obs, exp = observed[order].astype(np.float64), expected[order]
    # Pool the cells with small expected counts into one
    small = exp < 5.0
    pooled_obs, pooled_exp = obs[~small], exp[~small]
    if small.any() and exp[small].sum() > 0.0:
        pooled_obs = np.append(pooled_obs, obs[small].sum())
        pooled_exp = np.append(pooled_exp, exp[small].sum())
    # Samples where the pdf integrates to zero are an outright failure
    if small.any() and exp[small].sum() == 0.0 and obs[small].sum() > 0:
        return 0.0
    stat = ((pooled_obs - pooled_exp) ** 2 / pooled_exp).sum()
    dof = len(pooled_exp) - 1
    return stats.chi2.sf(stat, dof)


CHI2_CASES = [
    ("diffuse", {}, 10.0),
    ("diffuse", {}, 75.0),
    ("roughconductor", {"alpha": 0.3}, 0.0),
    ("roughconductor", {"alpha": 0.3}, 45.0),
    ("roughconductor", {"alpha": 0.3}, 80.0),
    ("roughconductor", {"alpha": 0.7}, 30.0),
    ("roughconductor", {"alpha": 0.7}, 85.0),
    ("roughconductor", {"alpha": 0.15}, 20.0),
    ("roughconductor", {"alpha": 1.0}, 60.0),
]


@pytest.mark.parametrize(("kind", "params", "theta_o"), CHI2_CASES)
def test_sampling_matches_pdf_chi_square(bsdf, kind, params, theta_o):
    mat = material(kind, **params)
    wo = direction(theta_o)
    wi, weight, pdf = bsdf.sample(mat, np.tile(wo, (SAMPLES, 1)), uniforms(7, SAMPLES))
    valid = pdf > 0
    observed = np.bincount(
        bin_index(wi[valid].astype(np.float64), THETA_BINS, PHI_BINS),
        minlength=THETA_BINS * PHI_BINS,
    )
    per_bin, _ = integrated_pdf(bsdf, mat, wo)
    # Failed samples (below the horizon) are the pdf's missing mass
    assert abs(valid.mean() - per_bin.sum()) < 5 * math.sqrt(0.25 / SAMPLES) + 2e-3
    p_value = chi2_pvalue(observed, per_bin * SAMPLES)
    assert p_value > SIGNIFICANCE, f"chi-square p = {p_value:.3g} for {kind} {params} {theta_o}"


@pytest.mark.parametrize(
    ("kind", "params"),
    [("diffuse", {}), ("roughconductor", {"alpha": 0.2}), ("roughconductor", {"alpha": 0.8})],
)
def test_sample_weight_and_pdf_agree_with_eval(bsdf, kind, params):
    mat = material(kind, **params)
    wo = np.array([direction(t, 17.0 * t) for t in np.linspace(0.0, 85.0, 4096)])
    wi, weight, pdf = bsdf.sample(mat, wo, uniforms(3, len(wo)))
    f, pdf_eval = bsdf.eval(mat, wo, wi)
    ok = pdf > 0
    # Rough lobes at grazing angles send many samples below the horizon (weight 0)
    assert ok.mean() > 0.6
    np.testing.assert_allclose(pdf[ok], pdf_eval[ok], rtol=2e-4)
    expected = f[ok] * np.abs(wi[ok, 2:3]) / pdf[ok, None]
    np.testing.assert_allclose(weight[ok], expected, rtol=2e-4, atol=1e-7)


@pytest.mark.parametrize("theta_o", [0.0, 40.0, 70.0, 89.0])
@pytest.mark.parametrize(
    ("kind", "params"),
    [
        ("diffuse", {"albedo": (1.0, 1.0, 1.0)}),
        ("roughconductor", {"alpha": 0.3, "eta": (1.0, 1.0, 1.0), "k": (1e4, 1e4, 1e4)}),
        ("roughconductor", {"alpha": 0.5}),
        ("roughconductor", {"alpha": 1.0}),
    ],
)
def test_energy_conservation(bsdf, kind, params, theta_o):
    """Directional albedo <= 1, by the sample weights and by integrating f |cos| on a grid
    (both estimates must agree); a white diffuse surface reflects exactly 1."""
    mat = material(kind, **params)
    wo = direction(theta_o)
    _, weight, _ = bsdf.sample(mat, np.tile(wo, (SAMPLES, 1)), uniforms(11, SAMPLES))
    by_sampling = weight.astype(np.float64).mean(axis=0)
    se = weight.astype(np.float64).std(axis=0) / math.sqrt(SAMPLES)
    _, by_grid = integrated_pdf(bsdf, mat, wo)
    assert np.all(by_sampling <= 1.0 + 5 * se + 1e-6)
    assert np.all(by_grid <= 1.0 + 2e-3)
    np.testing.assert_allclose(by_sampling, by_grid, atol=5 * se.max() + 3e-3)
    if kind == "diffuse":
        np.testing.assert_allclose(by_sampling, 1.0, rtol=1e-6)


def test_rough_conductor_loses_little_energy_when_smooth(bsdf):
    """A perfect mirror (F = 1) with a small alpha reflects almost everything: the GGX
    normalisation is right, not just bounded."""
    mat = material("roughconductor", alpha=0.05, eta=(1.0, 1.0, 1.0), k=(1e4, 1e4, 1e4))
    _, weight, _ = bsdf.sample(mat, np.tile(direction(30.0), (SAMPLES, 1)), uniforms(5, SAMPLES))
    assert weight.mean() > 0.99


@pytest.mark.parametrize(
    ("kind", "params"),
    [("diffuse", {}), ("roughconductor", {"alpha": 0.1}), ("roughconductor", {"alpha": 0.6})],
)
def test_reciprocity(bsdf, kind, params):
    mat = material(kind, **params)
    rng = np.random.default_rng(2)
    wo = rng.normal(size=(20_000, 3))
    wi = rng.normal(size=(20_000, 3))
    wo[:, 2], wi[:, 2] = np.abs(wo[:, 2]), np.abs(wi[:, 2])
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    f_forward, _ = bsdf.eval(mat, wo, wi)
    f_backward, _ = bsdf.eval(mat, wi, wo)
    assert np.all(f_forward >= 0) and np.any(f_forward > 0)
    np.testing.assert_allclose(f_forward, f_backward, rtol=2e-5, atol=1e-7)


def fresnel_dielectric(cos_i, eta):
    cos_i = np.asarray(cos_i, np.float64)
    eta = np.where(cos_i < 0, 1.0 / eta, eta)
    cos_i = np.abs(cos_i)
    sin2_t = (1.0 - cos_i**2) / eta**2
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (r_par**2 + r_perp**2))


@pytest.mark.parametrize("theta_o", [0.0, 30.0, 60.0, 85.0, 150.0, 135.0, 125.0])
def test_dielectric_choice_and_directions(bsdf, theta_o):
    """Reflect with probability F (binomial test), mirror and Snell directions, weights 1 for
    reflection and 1/eta'^2 for refraction, Eval and PdfW zero (a delta BSDF). Angles over 90
    degrees start inside the glass; 125 and 135 degrees are past the critical angle (41.8)."""
    ior = 1.5
    mat = material("dielectric", ior=ior)
    wo = direction(theta_o)
    count = 50_000
    wi, weight, pdf = bsdf.sample(mat, np.tile(wo, (count, 1)), uniforms(13, count))
    fresnel = float(fresnel_dielectric(wo[2], ior))
    reflected = wi[:, 2] * wo[2] > 0
    sigma = math.sqrt(max(fresnel * (1 - fresnel), 1e-12) / count)
    assert abs(reflected.mean() - fresnel) <= 5 * sigma + 1e-9
    np.testing.assert_allclose(pdf[reflected], fresnel, rtol=1e-5)
    mirror = np.array([-wo[0], -wo[1], wo[2]])
    np.testing.assert_allclose(wi[reflected], np.tile(mirror, (reflected.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(weight[reflected], 1.0, rtol=1e-6)
    if fresnel < 1.0:
        eta_rel = ior if wo[2] > 0 else 1.0 / ior
        refr = wi[~reflected]
        sin_o = math.sqrt(1.0 - wo[2] ** 2)
        np.testing.assert_allclose(np.hypot(refr[:, 0], refr[:, 1]), sin_o / eta_rel, atol=2e-6)
        np.testing.assert_allclose(np.linalg.norm(refr, axis=1), 1.0, atol=2e-6)
        np.testing.assert_allclose(pdf[~reflected], 1.0 - fresnel, rtol=1e-5)
        np.testing.assert_allclose(weight[~reflected], 1.0 / eta_rel**2, rtol=1e-6)
    f, pdf_eval = bsdf.eval(mat, np.tile(wo, (16, 1)), wi[:16])
    assert np.all(f == 0) and np.all(pdf_eval == 0)
