"""Per-pixel sample sets drawn on the device (kernels/sampling.cl), and the sampler of every
later path dimension (kernels/sampler.h).

Samplers (positions; path dimensions; the sample counts n each accepts):
  independent       i.i.d. uniform points in W = [-1/2, 1/2]^2; Philox paths; any n.
  stratified        every dimension stratified: a jittered sqrt(n) x sqrt(n) grid per dimension
                    pair, n jittered strata per 1D dimension, each with its own random
                    permutation of the strata over the samples; n a perfect square.
  stratified-pixel  the pixel position alone stratified (the grid in order); Philox paths; n a
                    perfect square. (Named "stratified" before every dimension was.)
  sobol             padded Owen-scrambled Sobol in every dimension; any n (a power of two makes
                    each pixel's points and each later pair a (0, m, 2)-net).
  zsobol            one Owen-scrambled Sobol sequence over the image in Morton order of the
                    pixels (blue-noise error across pixels); n a power of two, and
                    2 log2(padded resolution) + log2(n) <= 32.
  sppp              the paper's stretched-window Poisson point process: N ~ Poisson(n) uniform
                    nuclei in W, traced, plus n' auxiliary nuclei uniform by area over the strip
                    W' \\ W; Philox paths; any n.
  sppp-sobol        SPPP positions as sppp; the path dimensions of the N traced samples from the
                    padded sobol sequence (sample index 0 .. N-1); any n.
A sampler never changes n: a count it cannot use is a ParameterError naming the nearest ones.
Positions are pixel-local; pixel (x, y) covers image coordinates [x, x+1] x [y, y+1], so a
sample at local (u, v) sits at image position (x + 1/2 + u, y + 1/2 + v).

toroidal_shift: shift each pixel's whole point set by one random vector on the torus W (a
Cranley-Patterson rotation). The render settings turn it on for pvor over stratified, sobol and
zsobol points: torus Voronoi areas are shift-invariant, which makes pvor unbiased over them.

A launch takes a list of global pixel indices (y * width + x) and their redraw numbers, so a
tile and a set of rejected pixels to redraw use the same path, and every number depends on
(seed, pixel, sample, dimension, redraw) only (and, for zsobol, on the image size).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.runtime import Runtime
from clrender.samples import SampleSets
from clrender.sppp import (
    DEFAULT_ALPHA,
    MAX_EPS,
    auxiliary_count,
    check_alpha,
    check_intensity,
    sppp_eps,
)

# Position kinds (kernels/sampling.cl) and path kinds (kernels/sampler.h).
POSITIONS_INDEPENDENT, POSITIONS_STRATIFIED_IN_ORDER, POSITIONS_SPPP, POSITIONS_FROM_SAMPLER = (
    range(4)
)
PATHS_INDEPENDENT, PATHS_STRATIFIED, PATHS_SOBOL, PATHS_ZSOBOL = range(4)


@dataclass(frozen=True)
class SamplerKind:
    """What a sampler name means: how it places positions, how it samples path dimensions, and
    which counts n it takes ("any", "square" or "power of two")."""

    positions: int
    paths: int
    counts: str
    description: str

    @property
    def is_sppp(self) -> bool:
        return self.positions == POSITIONS_SPPP

    @property
    def low_discrepancy_positions(self) -> bool:
        """Positions that are not i.i.d. uniform or Poisson (a toroidal shift makes pvor
        unbiased over them)."""
        return self.positions in (POSITIONS_STRATIFIED_IN_ORDER, POSITIONS_FROM_SAMPLER)


SAMPLERS: dict[str, SamplerKind] = {
    "independent": SamplerKind(
        POSITIONS_INDEPENDENT, PATHS_INDEPENDENT, "any", "i.i.d. uniform, every dimension"
    ),
    "stratified": SamplerKind(
        POSITIONS_FROM_SAMPLER,
        PATHS_STRATIFIED,
        "square",
        "jittered strata in every dimension, randomly permuted per dimension",
    ),
    "stratified-pixel": SamplerKind(
        POSITIONS_STRATIFIED_IN_ORDER,
        PATHS_INDEPENDENT,
        "square",
        "jittered strata for the pixel position only, i.i.d. path dimensions",
    ),
    "sobol": SamplerKind(
        POSITIONS_FROM_SAMPLER, PATHS_SOBOL, "any", "padded Owen-scrambled Sobol, every dimension"
    ),
    "zsobol": SamplerKind(
        POSITIONS_FROM_SAMPLER,
        PATHS_ZSOBOL,
        "power of two",
        "one Owen-scrambled Sobol sequence in Morton order of the pixels (blue-noise error)",
    ),
    "sppp": SamplerKind(
        POSITIONS_SPPP, PATHS_INDEPENDENT, "any", "stretched-window Poisson, i.i.d. paths"
    ),
    "sppp-sobol": SamplerKind(
        POSITIONS_SPPP,
        PATHS_SOBOL,
        "any",
        "stretched-window Poisson positions, padded Owen-scrambled Sobol paths",
    ),
}
RENAMED_SAMPLERS = {"uniform": "independent"}
# Traced sample indices share the 32-bit counter with auxiliary nuclei (see kernels/rng.h).
MAX_SAMPLES_PER_PIXEL = 0x40000000
# Strata of float32 jitter stay distinct well below 2^24 of them.
MAX_STRATIFIED_SAMPLES = 1 << 20
# Samples per work-item of fill_traced_from_sampler (kernels/sampling.cl: SIMD_WIDTH, the
# default of kernels/simd_lanes.h).
FILL_LANES = 16
# zsobol's image-wide index: Morton bits of the padded resolution, then log2(n) sample bits.
ZSOBOL_INDEX_BITS = 32


@dataclass(frozen=True)
class SamplerConfig:
    """A validated sampler: its name, intensity n and, for SPPP, eps and the auxiliary count."""

    name: str
    n: int
    alpha: float = DEFAULT_ALPHA
    eps: float = 0.0
    n_aux: int = 0
    toroidal_shift: bool = False

    @property
    def kind(self) -> SamplerKind:
        return SAMPLERS[self.name]

    @property
    def is_sppp(self) -> bool:
        return self.kind.is_sppp

    @property
    def strata(self) -> int:
        return math.isqrt(self.n) if self.kind.counts == "square" else 0

    @property
    def has_auxiliary(self) -> bool:
        return self.n_aux > 0

    def path_arguments(self, image_size: tuple[int, int] | None) -> tuple:
        """The kernels' path-sampler arguments: kind, n, strata, and zsobol's log2(n) and index
        bits (zsobol needs the image size; the others ignore it)."""
        log2_count = bits = 0
        if self.kind.paths == PATHS_ZSOBOL:
            if image_size is None:
                raise ParameterError("the zsobol sampler needs the image size of the launch")
            log2_count, bits = zsobol_layout(self.n, *image_size)
        return (
            np.int32(self.kind.paths),
            np.uint32(self.n),
            np.uint32(self.strata),
            np.uint32(log2_count),
            np.uint32(bits),
        )


def zsobol_layout(n: int, width: int, height: int) -> tuple[int, int]:
    """(log2 n, bits of the image-wide index): the Morton code of the resolution padded to a
    power of two, then the sample; ParameterError if it does not fit 32 bits."""
    resolution_bits = max(0, (max(width, height) - 1).bit_length())
    log2_count = n.bit_length() - 1
    bits = 2 * resolution_bits + log2_count
    if 2 * resolution_bits > ZSOBOL_INDEX_BITS:
        raise ParameterError(
            f"the zsobol sampler indexes pixels in {ZSOBOL_INDEX_BITS} bits: a {width} x "
            f"{height} image is too large (largest side 65536); use the sobol sampler"
        )
    if bits > ZSOBOL_INDEX_BITS:
        most = 1 << (ZSOBOL_INDEX_BITS - 2 * resolution_bits)
        raise ParameterError(
            f"the zsobol sampler indexes pixels x samples in {ZSOBOL_INDEX_BITS} bits: a "
            f"{width} x {height} image (padded to {1 << resolution_bits} square) takes "
            f"{2 * resolution_bits} bits, leaving at most {most} samples per pixel, got {n}; "
            "use the sobol sampler"
        )
    return log2_count, bits


def sampler_kind(name: str) -> SamplerKind:
    """The sampler's entry, or a one-line error listing the names."""
    if name in RENAMED_SAMPLERS:
        raise ParameterError(
            f"the {name!r} sampler is now called {RENAMED_SAMPLERS[name]!r}; accepted: "
            f"{', '.join(SAMPLERS)}"
        )
    if name not in SAMPLERS:
        raise ParameterError(f"unknown sampler {name!r}; accepted: {', '.join(SAMPLERS)}")
    return SAMPLERS[name]


def make_sampler(
    name: str,
    n: int,
    alpha: float = DEFAULT_ALPHA,
    eps: float | None = None,
    toroidal_shift: bool = False,
) -> SamplerConfig:
    """Check the parameters and derive eps and n' for SPPP (eps may be forced, e.g. enlarged
    after repeated rejections)."""
    kind = sampler_kind(name)
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise ParameterError(f"spp (samples per pixel) must be a positive integer, got {n!r}")
    check_intensity(n)
    if n >= MAX_SAMPLES_PER_PIXEL // 2:
        raise ParameterError(
            f"spp (samples per pixel) must be below {MAX_SAMPLES_PER_PIXEL // 2}, got {n}"
        )
    check_alpha(alpha)
    n = int(n)
    if kind.counts == "square" and math.isqrt(n) ** 2 != n:
        root = math.isqrt(n)
        raise ParameterError(
            f"the {name} sampler needs n to be a perfect square, got {n} "
            f"(nearest: {root * root} or {(root + 1) ** 2})"
        )
    if kind.counts == "square" and n > MAX_STRATIFIED_SAMPLES:
        raise ParameterError(
            f"the {name} sampler takes at most {MAX_STRATIFIED_SAMPLES} samples per pixel (its "
            f"strata are jittered in float32), got {n}; use the sobol sampler"
        )
    if kind.counts == "power of two" and n & (n - 1):
        below = 1 << (n.bit_length() - 1)
        raise ParameterError(
            f"the {name} sampler needs n to be a power of two, got {n} "
            f"(nearest: {below} or {2 * below})"
        )
    if not kind.is_sppp:
        return SamplerConfig(name, n, alpha, toroidal_shift=bool(toroidal_shift))
    eps = sppp_eps(n, alpha) if eps is None else float(eps)
    if not (math.isfinite(eps) and 0.0 < eps <= MAX_EPS):
        raise ParameterError(
            f"eps (strip width, in pixels) must be in (0, {MAX_EPS:g}], got {eps!r} "
            f"(the paper's choice for n = {n}: {sppp_eps(n, alpha):.3g})"
        )
    return SamplerConfig(name, n, alpha, eps, auxiliary_count(n, eps), bool(toroidal_shift))


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
    image_size: tuple[int, int] | None = None  # (width, height) if the launch was given it
    # the uploads' events (each holds its host array, and dropping it waits for the copy): kept
    # with the sets, so that drawing them does not wait for the device
    uploads: tuple = ()
    # the events of the work drawing them ran on the runtime's side queue (SPPP's count pass:
    # complete once the sets are made), for a clock that times the device stages
    side_events: tuple = ()

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
        return self.queue_to_host(queue)()

    def queue_to_host(self, queue: cl.CommandQueue) -> Callable[[], SampleSets]:
        """Queue to_host's read-back without a wait; the function returned waits for it and
        gives the host copy (it holds the array the read fills)."""
        flat = np.empty((self.traced_total + self.aux_total, 2), np.float32)
        read = (
            cl.enqueue_copy(queue, flat, self.positions, is_blocking=False) if len(flat) else None
        )
        aux_offsets = np.arange(self.pixel_count + 1, dtype=np.int64) * self.config.n_aux

        def host() -> SampleSets:
            if read is not None:
                read.wait()
            return SampleSets(
                flat[: self.traced_total],
                self.traced_offsets,
                self.config.n,
                flat[self.traced_total :],
                aux_offsets,
                self.config.eps if self.config.is_sppp else None,
                self.redraws,
            )

        return host


@dataclass
class PendingCounts:
    """SPPP's count pass of a launch, queued on the runtime's side queue with its read
    (queue_counts): until result() it holds the buffers and the array the read fills."""

    n: int
    seed: int
    pixels: np.ndarray
    redraws: np.ndarray
    counts: np.ndarray
    read: cl.Event | None
    kernel_event: cl.Event | None
    buffers: tuple = ()

    def matches(self, config: SamplerConfig, seed: int, pixels: np.ndarray, redraws) -> bool:
        """Whether these are the counts of that launch (they depend on n, the seed, the pixels
        and their redraw numbers only, not on eps)."""
        return (
            config.is_sppp
            and (self.n, self.seed) == (config.n, seed)
            and np.array_equal(self.pixels, pixels)
            and np.array_equal(self.redraws, redraws)
        )

    def result(self) -> tuple[np.ndarray, cl.Event | None]:
        """The counts, once read (a wait for the side queue alone), and the count kernel's
        event."""
        if self.read is not None:
            self.read.wait()
        self.buffers = ()
        return self.counts, self.kernel_event


def queue_counts(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray | None = None,
) -> PendingCounts:
    """Queue SPPP's count pass of a launch and its read on the runtime's side queue without a
    wait, to hand to generate_sample_sets later (the render queues the next tile's before this
    tile's fill and trace: a device that runs commands in the order they became ready, as
    PoCL's CPU device does, then runs it before that trace, and the next tile's sample sets
    wait for nothing)."""
    if not config.is_sppp:
        raise ParameterError(f"only SPPP samplers count samples on the device, not {config.name}")
    pixels, redraws = _check_launch(seed, pixels, redraws)
    return _queue_count(runtime, config, seed, pixels, redraws)


def generate_sample_sets(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray | None = None,
    image_size: tuple[int, int] | None = None,
    queued_counts: PendingCounts | None = None,
) -> DeviceSampleSets:
    """Draw the sample sets of the given pixels on the device (count, prefix sum, fill).
    image_size (width, height): needed by zsobol, whose sequence spans the image. Only SPPP
    counts on the device (N ~ Poisson(n)); the fixed-count samplers' n needs no count pass and
    no read-back. SPPP's count pass runs on the runtime's side queue, and the host waits for
    it alone, not for the work queued before it on the main queue (the tile in flight's trace);
    queued_counts, that pass queued earlier (queue_counts), is used when it is this launch's (a
    ParameterError otherwise).
    The main queue's uploads are enqueued without a wait: the queue runs them in order before
    the kernels, and the sets keep their events (dropping one waits for its copy, whose host
    array must live until then), so nothing else here waits for the device."""
    pixels, redraws = _check_launch(seed, pixels, redraws)
    path_arguments = config.path_arguments(image_size)
    image_width = 1 if image_size is None else int(image_size[0])
    if image_size is not None and len(pixels) and int(pixels.max()) >= image_width * image_size[1]:
        raise ParameterError(
            f"pixel index {int(pixels.max())} outside the {image_width} x {image_size[1]} image"
        )
    side_events: tuple = ()
    if queued_counts is not None and not queued_counts.matches(config, seed, pixels, redraws):
        raise ParameterError(
            "the counts queued ahead (queue_counts) are not those of this launch's sampler, "
            "seed, pixels and redraws"
        )
    if config.is_sppp:
        pending = queued_counts or _queue_count(runtime, config, seed, pixels, redraws)
        counts, count_event = pending.result()
        side_events = () if count_event is None else (count_event,)
    else:
        counts = np.full(len(pixels), config.n, np.uint32)
    pixels_buf, pixels_copy = runtime.upload_async(pixels)
    redraws_buf, redraws_copy = runtime.upload_async(redraws)
    offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
    if offsets[-1] >= 2**32:
        raise ParameterError("too many samples in one launch (over 2^32): use smaller tiles")
    offsets_buf, offsets_copy = runtime.upload_async(offsets.astype(np.uint32))
    total = int(offsets[-1]) + config.n_aux * len(pixels)
    positions = runtime.allocate(8 * total)
    group_copy = _launch_fill(
        runtime,
        config,
        seed,
        pixels_buf,
        redraws_buf,
        offsets,
        offsets_buf,
        positions,
        path_arguments,
        image_width,
    )
    return DeviceSampleSets(
        config,
        pixels,
        redraws,
        offsets,
        positions,
        offsets_buf,
        pixels_buf,
        redraws_buf,
        None if image_size is None else (int(image_size[0]), int(image_size[1])),
        (pixels_copy, redraws_copy, offsets_copy, group_copy),
        side_events,
    )


def _launch_fill(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels_buf: cl.Buffer,
    redraws_buf: cl.Buffer,
    offsets: np.ndarray,
    offsets_buf: cl.Buffer,
    positions: cl.Buffer,
    path_arguments: tuple,
    image_width: int,
) -> cl.Event | None:
    """Fill the traced samples (a work-item per 8 samples of a pixel, or per FILL_LANES for a
    path sampler's positions), then the auxiliary nuclei (a work-item per 8 of a pixel).
    Returns the event of the upload it queued (SPPP's group offsets), to keep as
    upload_async's are kept, or None."""
    pixel_count, traced_total = len(offsets) - 1, int(offsets[-1])
    group_copy = None
    if traced_total and config.kind.positions == POSITIONS_FROM_SAMPLER:
        fill = runtime.kernel("sampling.cl", "fill_traced_from_sampler")
        runtime.launch_1d(
            fill,
            pixel_count * -(-config.n // FILL_LANES),
            np.uint32(pixel_count),
            np.uint32(seed),
            *path_arguments[:3],
            np.uint32(image_width),
            *path_arguments[3:],
            np.int32(config.toroidal_shift),
            pixels_buf,
            redraws_buf,
            offsets_buf,
            positions,
        )
    elif traced_total:
        group_total, group_offsets_buf, group_copy = _traced_groups(
            runtime, config, offsets, offsets_buf
        )
        fill = runtime.kernel("sampling.cl", "fill_traced")
        runtime.launch_1d(
            fill,
            group_total,
            np.uint32(pixel_count),
            np.uint32(seed),
            np.int32(config.kind.positions),
            np.uint32(config.n),
            np.uint32(config.strata),
            np.int32(config.toroidal_shift),
            np.uint32(group_total),
            pixels_buf,
            redraws_buf,
            offsets_buf,
            group_offsets_buf,
            positions,
        )
    if config.n_aux and pixel_count:
        fill = runtime.kernel("sampling.cl", "fill_auxiliary")
        runtime.launch_1d(
            fill,
            (config.n_aux + 7) // 8 * pixel_count,  # a work-item per 8 nuclei of a pixel
            np.uint32(pixel_count),
            np.uint32(seed),
            np.float32(config.eps),
            np.uint32(config.n_aux),
            np.uint32(traced_total),
            pixels_buf,
            redraws_buf,
            positions,
        )
    return group_copy


def _traced_groups(
    runtime: Runtime, config: SamplerConfig, offsets: np.ndarray, offsets_buf: cl.Buffer
) -> tuple[int, cl.Buffer, cl.Event | None]:
    """fill_traced's work: the number of groups of up to 8 traced samples of one pixel, and for
    SPPP (variable counts) each pixel's first group, a prefix sum of ceil(count / 8), uploaded
    without a wait (its event returned; fixed counts find the pixel by a division: the traced
    offsets stand in, unread)."""
    pixel_count = len(offsets) - 1
    if not config.is_sppp:
        return (config.n + 7) // 8 * pixel_count, offsets_buf, None
    group_offsets = np.zeros(pixel_count + 1, np.int64)
    np.cumsum((np.diff(offsets) + 7) // 8, out=group_offsets[1:])
    buffer, copy = runtime.upload_async(group_offsets.astype(np.uint32))
    return int(group_offsets[-1]), buffer, copy


def count_samples(
    runtime: Runtime,
    config: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray | None = None,
) -> np.ndarray:
    """Only the first pass: each pixel's number of traced samples (N ~ Poisson(n) for SPPP)."""
    pixels, redraws = _check_launch(seed, pixels, redraws)
    return _queue_count(runtime, config, seed, pixels, redraws).result()[0]


def _queue_count(
    runtime: Runtime, config: SamplerConfig, seed: int, pixels: np.ndarray, redraws: np.ndarray
) -> PendingCounts:
    """Each pixel's traced-sample count, from the count kernel on the runtime's side queue,
    read without a wait: the read waits for the count pass alone, not for the work queued
    before it on the main queue. Its buffers are plain ones made from the host arrays (copied
    as they are made), not the pool's (Runtime.side_queue)."""
    pixels, redraws = pixels.copy(), redraws.copy()  # (the caller may reuse its arrays)
    pixel_count = len(pixels)
    counts = np.empty(pixel_count, np.uint32)
    if not pixel_count:
        return PendingCounts(config.n, seed, pixels, redraws, counts, None, None)
    queue = runtime.side_queue
    copy_in = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    pixels_buf = cl.Buffer(runtime.context, copy_in, hostbuf=pixels)
    redraws_buf = cl.Buffer(runtime.context, copy_in, hostbuf=redraws)
    counts_buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, counts.nbytes)
    count = runtime.kernel("sampling.cl", "count_samples")
    event = runtime.launch_1d(
        count,
        pixel_count,
        np.uint32(pixel_count),
        np.uint32(seed),
        np.int32(config.kind.positions),
        np.uint32(config.n),
        np.float32(config.n),
        pixels_buf,
        redraws_buf,
        counts_buf,
        queue=queue,
    )
    read = cl.enqueue_copy(queue, counts, counts_buf, is_blocking=False)
    queue.flush()  # a driver that batches commands starts it now
    buffers = (pixels_buf, redraws_buf, counts_buf)
    return PendingCounts(config.n, seed, pixels, redraws, counts, read, event, buffers)


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
