"""Per-pixel sample sets drawn on the device (kernels/sampling.cl).

Samplers:
  uniform     exactly n i.i.d. uniform points in W = [-1/2, 1/2]^2;
  stratified  one jittered point in each cell of a sqrt(n) x sqrt(n) grid (n a perfect square);
  sppp        the paper's stretched-window Poisson point process: N ~ Poisson(n) uniform nuclei
              in W, traced, plus n' auxiliary nuclei uniform by area over the strip W' \\ W.
Positions are pixel-local; pixel (x, y) covers image coordinates [x, x+1] x [y, y+1], so a
sample at local (u, v) sits at image position (x + 1/2 + u, y + 1/2 + v).

A launch takes a list of global pixel indices (y * width + x) and their redraw numbers, so a
tile and a set of rejected pixels to redraw use the same path, and every number depends on
(seed, pixel, sample, dimension, redraw) only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.runtime import Runtime, padded_global_size
from clrender.samples import SampleSets
from clrender.sppp import DEFAULT_ALPHA, auxiliary_count, check_alpha, check_intensity, sppp_eps

SAMPLERS = {"uniform": 0, "stratified": 1, "sppp": 2}
# Traced sample indices share the 32-bit counter with auxiliary nuclei (see kernels/rng.h).
MAX_SAMPLES_PER_PIXEL = 0x40000000


@dataclass(frozen=True)
class SamplerConfig:
    """A validated sampler: its name, intensity n and, for SPPP, eps and the auxiliary count."""

    name: str
    n: int
    alpha: float = DEFAULT_ALPHA
    eps: float = 0.0
    n_aux: int = 0

    @property
    def strata(self) -> int:
        return math.isqrt(self.n) if self.name == "stratified" else 0

    @property
    def has_auxiliary(self) -> bool:
        return self.n_aux > 0


def make_sampler(
    name: str, n: int, alpha: float = DEFAULT_ALPHA, eps: float | None = None
) -> SamplerConfig:
    """Check the parameters and derive eps and n' for SPPP (eps may be forced, e.g. enlarged
    after repeated rejections)."""
    if name not in SAMPLERS:
        raise ParameterError(f"unknown sampler {name!r}; accepted: {', '.join(SAMPLERS)}")
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise ParameterError(f"n (samples per pixel) must be a positive integer, got {n!r}")
    check_intensity(n)
    if n >= MAX_SAMPLES_PER_PIXEL // 2:
        raise ParameterError(
            f"n (samples per pixel) must be below {MAX_SAMPLES_PER_PIXEL // 2}, got {n}"
        )
    check_alpha(alpha)
    if name == "stratified" and math.isqrt(n) ** 2 != n:
        root = math.isqrt(n)
        raise ParameterError(
            f"the stratified sampler needs n to be a perfect square, got {n} "
            f"(nearest: {root * root} or {(root + 1) ** 2})"
        )
    if name != "sppp":
        return SamplerConfig(name, int(n), alpha)
    eps = sppp_eps(n, alpha) if eps is None else float(eps)
    if not (math.isfinite(eps) and eps > 0.0):
        raise ParameterError(f"eps (strip width) must be a positive finite number, got {eps!r}")
    return SamplerConfig(name, int(n), alpha, eps, auxiliary_count(n, eps))


def rectangle_pixels(width: int, x0: int, y0: int, rect_width: int, rect_height: int) -> np.ndarray:
    """Global indices (y * width + x) of the pixels of a rectangle of the image, row by row."""
    ys, xs = np.mgrid[y0 : y0 + rect_height, x0 : x0 + rect_width]
    return (ys * width + xs).ravel().astype(np.uint32)


@dataclass
class DeviceSampleSets:
    """A launch's sample sets, kept on the device for the tracing kernel.

    positions: float2 buffer, traced samples of all pixels first (pixel p's are
    [traced_offsets[p], traced_offsets[p+1])), then n_aux auxiliary nuclei per pixel.
    """

    config: SamplerConfig
    pixels: np.ndarray  # (P,) uint32 global pixel indices
    redraws: np.ndarray  # (P,) uint32 redraw numbers
    traced_offsets: np.ndarray  # (P + 1,) int64 host copy
    positions: cl.Buffer
    offsets_buffer: cl.Buffer  # traced_offsets as uint32, on the device
    pixels_buffer: cl.Buffer  # pixels as uint32, on the device
    redraws_buffer: cl.Buffer  # redraws as uint32, on the device

    @property
    def pixel_count(self) -> int:
        return len(self.pixels)

    @property
    def traced_total(self) -> int:
        return int(self.traced_offsets[-1])

    @property
    def aux_total(self) -> int:
        return self.config.n_aux * self.pixel_count

    def to_host(self, queue: cl.CommandQueue) -> SampleSets:
        """The host copy (float32 positions, as on the device), in one read-back."""
        flat = np.empty((self.traced_total + self.aux_total, 2), np.float32)
        if len(flat):
            cl.enqueue_copy(queue, flat, self.positions)
        aux_offsets = np.arange(self.pixel_count + 1, dtype=np.int64) * self.config.n_aux
        return SampleSets(
            flat[: self.traced_total],
            self.traced_offsets,
            self.config.n,
            flat[self.traced_total :],
            aux_offsets,
            self.config.eps if self.config.name == "sppp" else None,
            self.redraws,
        )


def generate_sample_sets(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray | None = None,
) -> DeviceSampleSets:
    """Draw the sample sets of the given pixels on the device (count, prefix sum, fill)."""
    pixels, redraws = _check_launch(seed, pixels, redraws)
    pixels_buf, redraws_buf = runtime.upload(pixels), runtime.upload(redraws)
    counts = _launch_count(runtime, config, seed, pixels_buf, redraws_buf, len(pixels))
    offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
    if offsets[-1] >= 2**32:
        raise ParameterError("too many samples in one launch (over 2^32): use smaller tiles")
    offsets_buf = runtime.upload(offsets.astype(np.uint32))
    total = int(offsets[-1]) + config.n_aux * len(pixels)
    positions = runtime.allocate(8 * total)
    _launch_fill(
        runtime,
        config,
        seed,
        pixels_buf,
        redraws_buf,
        offsets_buf,
        positions,
        len(pixels),
        int(offsets[-1]),
    )
    return DeviceSampleSets(
        config, pixels, redraws, offsets, positions, offsets_buf, pixels_buf, redraws_buf
    )


def _launch_fill(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels_buf: cl.Buffer,
    redraws_buf: cl.Buffer,
    offsets_buf: cl.Buffer,
    positions: cl.Buffer,
    pixel_count: int,
    traced_total: int,
) -> None:
    queue, local = runtime.queue, (runtime.local_size,)
    if traced_total:
        fill = runtime.kernel("sampling.cl", "fill_traced")
        fill(
            queue,
            (padded_global_size(traced_total),),
            local,
            np.uint32(pixel_count),
            np.uint32(seed),
            np.int32(SAMPLERS[config.name]),
            np.uint32(config.n),
            np.uint32(config.strata),
            np.uint32(traced_total),
            pixels_buf,
            redraws_buf,
            offsets_buf,
            positions,
        )
    if config.n_aux and pixel_count:
        fill = runtime.kernel("sampling.cl", "fill_auxiliary")
        fill(
            queue,
            (padded_global_size(config.n_aux * pixel_count),),
            local,
            np.uint32(pixel_count),
            np.uint32(seed),
            np.float32(config.eps),
            np.uint32(config.n_aux),
            np.uint32(traced_total),
            pixels_buf,
            redraws_buf,
            positions,
        )


def count_samples(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray | None = None,
) -> np.ndarray:
    """Only the first pass: each pixel's number of traced samples (N ~ Poisson(n) for SPPP)."""
    pixels, redraws = _check_launch(seed, pixels, redraws)
    return _launch_count(
        runtime, config, seed, runtime.upload(pixels), runtime.upload(redraws), len(pixels)
    )


def _launch_count(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels_buf: cl.Buffer,
    redraws_buf: cl.Buffer,
    pixel_count: int,
) -> np.ndarray:
    counts_buf = runtime.allocate(4 * pixel_count)
    count = runtime.kernel("sampling.cl", "count_samples")
    count(
        runtime.queue,
        (padded_global_size(pixel_count),),
        (runtime.local_size,),
        np.uint32(pixel_count),
        np.uint32(seed),
        np.int32(SAMPLERS[config.name]),
        np.uint32(config.n),
        np.float32(config.n),
        pixels_buf,
        redraws_buf,
        counts_buf,
    )
    counts = np.empty(pixel_count, np.uint32)
    cl.enqueue_copy(runtime.queue, counts, counts_buf)
    return counts


def _check_launch(
    seed: int, pixels: np.ndarray, redraws: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    check_seed(seed)
    pixels = np.ascontiguousarray(pixels, np.uint32)
    if redraws is None:
        return pixels, np.zeros(len(pixels), np.uint32)
    redraws = np.ascontiguousarray(redraws, np.uint32)
    if redraws.shape != pixels.shape:
        raise ParameterError(
            f"redraws must match pixels in shape, got {redraws.shape} and {pixels.shape}"
        )
    return pixels, redraws


def check_seed(seed: int) -> None:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed < 2**32:
        raise ParameterError(f"seed must be an integer in [0, 2^32), got {seed!r}")
