"""Stretched-window Poisson point process (SPPP): its parameters and a NumPy generator.

W = [-1/2, 1/2]^2 is the pixel, W' = [-1/2-eps, 1/2+eps]^2 the stretched window. A pixel's
SPPP set is N ~ Poisson(n) nuclei uniform in W (traced) plus n' = floor(n (4 eps + 4 eps^2))
auxiliary nuclei uniform by area over the strip W' minus W (never traced, they only shape
Voronoi cells). eps is the root, on the decreasing branch, of
4 pi n^2 eps^2 exp(-pi n eps^2) = alpha, the paper's bound on the rejection probability.
The OpenCL kernels in kernels/sampling.cl draw the same distribution; this module is the
host-side reference used by the estimators' tests and the analytic benchmark.
"""

from __future__ import annotations

import math

import numpy as np

from clrender.errors import ParameterError
from clrender.samples import SampleSets

DEFAULT_ALPHA = 1e-3
# Widest strip accepted, in pixels: the paper's choice is below 3 even for n = 1 and
# alpha = 1e-9; wider strips only multiply the auxiliary nuclei ((1 + 2 eps)^2 - 1 per sample).
# The redraw driver's enlargements stop there too.
MAX_EPS = 4.0


def check_intensity(n: float) -> None:
    if not (isinstance(n, int | float | np.integer | np.floating) and math.isfinite(n) and n > 0):
        raise ParameterError(f"spp (samples per pixel) must be a positive number, got {n!r}")


def check_alpha(alpha: float) -> None:
    if not (isinstance(alpha, int | float | np.floating) and 0.0 < alpha < 1.0):
        raise ParameterError(
            f"alpha (rejection bound) must lie in the open interval (0, 1), got {alpha!r}"
        )


def sppp_eps(n: float, alpha: float = DEFAULT_ALPHA) -> float:
    """The stretch eps of W' for intensity n: the root of 4 pi n^2 eps^2 exp(-pi n eps^2) =
    alpha on the decreasing branch (u = pi n eps^2 > 1). n = 10 000 gives 0.0256."""
    check_intensity(n)
    check_alpha(alpha)
    # With u = pi n eps^2 the equation reads u - ln u = ln(4 n / alpha); u - ln u grows for u > 1.
    target = math.log(4.0 * n / alpha)
    if target <= 1.0:  # u - ln u >= 1 everywhere: the bound is below alpha for any eps
        return 0.0
    # Newton's method from the right of the root: u - ln u is convex and increasing there, so
    # the steps decrease monotonically to the root (quadratically: 5-7 steps). Not SciPy's
    # brentq: importing scipy.optimize costs every SPPP render ~0.3 s of start-up.
    u = target + math.log(target) + 2.0
    for _ in range(100):
        step = (u - math.log(u) - target) / (1.0 - 1.0 / u)
        u -= step
        if step <= 4e-16 * u:
            break
    return math.sqrt(u / (math.pi * n))


def rejection_bound(n: float, eps: float) -> float:
    """The paper's bound on the probability that a W nucleus has an unbounded cell."""
    u = math.pi * n * eps * eps
    return 4.0 * n * u * math.exp(-u)


def auxiliary_count(n: float, eps: float) -> int:
    """n' = floor(n (4 eps + 4 eps^2)): the strip's area times the intensity."""
    return int(math.floor(n * (4.0 * eps + 4.0 * eps * eps)))


def sample_strip(rng: np.random.Generator, count: int, eps: float) -> np.ndarray:
    """count points uniform by area over W' minus W (corners at the same density as edges).

    The strip is cut into four rectangles: top and bottom (1 + 2 eps) x eps, which hold the
    corners, and left and right 1 x eps; one is chosen with probability proportional to area.
    """
    long_side = 1.0 + 2.0 * eps
    area_tb = long_side * eps
    area_lr = eps
    total = 2.0 * area_tb + 2.0 * area_lr
    pick = rng.random(count) * total
    along = rng.random(count)
    across = rng.random(count) * eps
    pts = np.empty((count, 2))
    # Rectangle index from the cumulative areas: bottom, top, left, right.
    is_bottom = pick < area_tb
    is_top = ~is_bottom & (pick < 2 * area_tb)
    is_left = ~is_bottom & ~is_top & (pick < 2 * area_tb + area_lr)
    is_right = ~(is_bottom | is_top | is_left)
    tb_x = -0.5 - eps + along * long_side
    pts[is_bottom] = np.column_stack([tb_x[is_bottom], -0.5 - across[is_bottom]])
    pts[is_top] = np.column_stack([tb_x[is_top], 0.5 + across[is_top]])
    lr_y = -0.5 + along
    pts[is_left] = np.column_stack([-0.5 - across[is_left], lr_y[is_left]])
    pts[is_right] = np.column_stack([0.5 + across[is_right], lr_y[is_right]])
    return pts


def draw_sppp(
    rng: np.random.Generator,
    n: float,
    pixels: int,
    alpha: float = DEFAULT_ALPHA,
    eps: float | None = None,
) -> SampleSets:
    """SPPP sample sets for `pixels` independent pixels (NumPy reference generator)."""
    eps = sppp_eps(n, alpha) if eps is None else float(eps)
    counts = rng.poisson(n, size=pixels)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    traced = rng.random((int(offsets[-1]), 2)) - 0.5
    n_aux = auxiliary_count(n, eps)
    aux = sample_strip(rng, n_aux * pixels, eps)
    aux_offsets = np.arange(pixels + 1, dtype=np.int64) * n_aux
    return SampleSets(traced, offsets, n, aux, aux_offsets, eps)
