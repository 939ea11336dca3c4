"""The render pipeline, tile by tile:

    sample sets (kernels/sampling.cl, clrender.sampling.generate_sample_sets)
      -> radiance of each traced sample (a RadianceSource: the path tracer or an analytic image)
      -> one estimate per pixel and estimator (clrender.estimators: the registry entry says how)
      -> one film per estimator, and the per-pixel layers (clrender.film)

Several estimators share one trace: each tile is drawn and traced once, each kind of cells
is computed once (the device sums of vor, vor_sn and fvor are one kernel call, and carry the
plain sums mc and mc_n need), and every estimator gets its own image. A pixel that one of
them rejects (an unbounded SPPP cell) is redrawn for all the per-pixel estimators, which
then use the same accepted draw; so the rejecting estimators' images (vor, vor_sn, fvor) are
the ones they get alone, and the non-rejecting per-pixel ones (mc, mc_n, cvor, pvor) differ
from theirs alone in the redrawn pixels (alone they keep draw 0). The image-level estimators (ivor,
ivor_sn) never reject and keep draw 0 (and its layers: first_draw_layers). pvor's toroidal
shift over stratified or Sobol points moves every estimator's points.

The estimators are validated once, when RenderSettings is made (their registry entries,
checked against the sampler); the pipeline then asks the entries (their cells, whether the
device forms their sums, whether they are image-level), never the names.

A tile is a run of consecutive pixels (scanline order) holding about `tile_samples` samples,
so memory stays bounded whatever the resolution and spp. With `overlap`, the host estimator of
tile k runs on a worker thread while the main thread has the device draw and trace tile k + 1;
pyopencl, NumPy and Qhull release the GIL in their long calls, so wall time approaches
max(device, host) instead of their sum. The device is kept fed: tile k + 1's sample sets,
trace, device sums and reads are queued (queue_tile) before the host waits for tile k's results
(QueuedTile.collect), so the device does not idle while the host reads one tile and prepares
the next; at most two tiles are held at once. SPPP's sample sets read their Poisson counts
back before the fill: the count pass runs on the runtime's side queue, and tile k + 1's is
queued before tile k's fill and trace, so its read waits for it alone, not for the tile in
flight (a device that runs commands in the order they became ready, as PoCL's CPU device,
would otherwise run it after tile k's trace).

Rejections: a pixel whose SPPP tessellation leaves a nucleus of W with an unbounded cell is
redrawn through clrender.estimators.estimate_with_redraw: its sample set is generated again with
its redraw number incremented (the same launch path as a tile, on a list of pixels), traced
and estimated again; after a few redraws the driver widens eps, and after its last round it
falls back to the mc estimate of the last draw (counted as `unresolved_pixels`).
Non-finite radiance is counted, and its pixels flagged: see clrender.film.

Voronoi cells: with `voronoi_backend = "device"` (the default) the SPPP cells of vor, vor_sn
and fvor, pvor's cells on the torus and cvor's cells clipped to W, are computed by a device
kernel queued right after the tracing, and a second kernel forms each pixel's weighted sums
(clrender.estimators.device_cells.device_sppp_sums, device_periodic_sums,
device_clipped_sums): no per-sample array
comes back, and the host stage only divides. A tile with a cell the kernel cannot
certify has those pixels settled on the host (their samples read back, cells by Qhull). The
image-level estimators' cells (ivor, ivor_sn) are computed on the device too, pixel by pixel
with its neighbours' nuclei, in the estimator stage (clrender.estimators.image_device; pixels
with a cell it cannot certify go to Qhull). With "qhull" the host computes all cells with
Qhull.

Timing (RenderStats): the time of each device stage (stage_seconds: sample sets, tracing,
voronoi, moments, readback; device_seconds is their sum) on the device's own clock, from the
device being free for the stage to its commands done (StageClock: profiling markers; a tile's
stages are queued back to back and the tile waits for their end markers, in order, then for
its results; on a queue without profiling, the main thread's time, each stage ending with a
wait), the estimator stage's own time per group of estimators sharing a tessellation
(estimator_seconds; host_seconds is their sum with the redraws' host part), and
compile_seconds, the program builds and kernel creation met on the way (first uses in a
process: programs are cached), taken out of the stages (PoCL's code generation at a kernel's
first launch is not seen: on a cold cache it stays in that launch's stage); run_seconds is
the wall time without the builds met on the main thread. The per-pixel layers' host time is
layer_seconds (in host_seconds). The image-level estimators ivor and
ivor_sn also draw their guard nuclei in the estimator stage, on a second OpenCL context so
that no kernel object is shared between threads.

Determinism: every random number depends on (seed, pixel, sample, dimension, redraw) only;
a per-pixel estimator sees only its pixel's samples; the image-level ones (ivor, ivor_sn) see
neighbouring pixels' nuclei too, regenerated from the same random numbers whatever the tile,
and sum their triangles in a canonical order (on the device each pixel's diagram is its own,
sized by the sampler's n); so the image is bit-identical whatever the tile size and with or
without overlap.

Ctrl-C (KeyboardInterrupt) stops the render between device calls: the tile whose estimates
are in flight is finished (without its redraws), and `render` returns the partial film with
`stats.interrupted` set.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np
import pyopencl as cl

from clrender import interrupts
from clrender.errors import ParameterError
from clrender.estimators import image
from clrender.estimators.device_cells import (
    MIRROR_COPIES,
    TORUS_COPIES,
    DeviceSums,
    PendingSums,
    queue_device_sums,
    resolve_precision,
    settle_undecided,
)
from clrender.estimators.pixel import estimate_all
from clrender.estimators.redraw import estimate_with_redraw
from clrender.estimators.registry import Estimator, PixelSums, check_compatible
from clrender.estimators.variance import PixelMoments, mc_variance
from clrender.film import Film, PixelLayers, check_image_memory, physical_memory
from clrender.radiance import DeviceRadiance, PendingRadiance, RadianceSource, SampleRadiance
from clrender.runtime import Runtime, describe_device, profiling_queue, thread_build_seconds
from clrender.samples import SampleSets
from clrender.sampling import (
    DeviceSampleSets,
    PendingCounts,
    SamplerConfig,
    check_seed,
    generate_sample_sets,
    make_sampler,
    queue_counts,
)
from clrender.sppp import auxiliary_count

DEFAULT_TILE_SAMPLES = 4_000_000
# The least host memory a sample of a tile in flight takes (measured peak over a baseline on a
# one-pixel render of 5 M samples: 20 B for mc summed on the device, 45 B for vor_sn): a tile
# needing more than the machine has at this rate cannot render.
MIN_BYTES_PER_TILE_SAMPLE = 20
# The device memory a tile holds: per nucleus of the tile (tile_nuclei_per_pixel) and per pixel, in
# its largest buffer and in all its buffers in flight with the next tile's queued beside them.
# Bounds of the runtime memory pool's measured peaks over renders of every estimator family, n = 1
# to 256: per nucleus up to 12 B in one buffer (the traced samples' float3 radiance) and 20-125 B in
# all (the most with vor_sn, fvor, mc_n, cvor and pvor in one render, whose pool holds each kind's
# buffers); per pixel up to 112 B in one buffer (cvor's and pvor's per-pixel records) and about
# 90-410 B in all (held by tests/test_device_memory.py). The image-level cells (ivor, ivor_sn) hold,
# per nucleus of their launch (about CHUNK_NUCLEI, at least one pixel's neighbourhood of (2 ring +
# 1)^2 pixels, at most the image's), 8 B in their largest buffer and about 31-33 B in all.
TILE_NUCLEUS_BYTES = (12, 160)  # (largest buffer, all buffers)
TILE_PIXEL_BYTES = (128, 512)
IMAGE_CELLS_NUCLEUS_BYTES = (8, 48)
# The share of the device's global memory a render's tiles may take (the scene, the programs
# and other processes keep the rest).
DEVICE_MEMORY_SHARE = 0.5
# Where the Voronoi cells of vor, vor_sn, fvor, pvor, cvor, ivor and ivor_sn are computed: the
# device kernel (clrender.estimators.device_cells, image_device; exact, pixels it cannot certify
# recomputed with Qhull) or Qhull on the host (qhull_cells, image). Redraws always use Qhull.
VORONOI_BACKENDS = ("device", "qhull")
# Split even small images into this many tiles (when tiles of MIN_TILE_PIXELS allow it), so
# that the device and the host stage have something to overlap and progress moves.
TARGET_TILE_COUNT = 16
MIN_TILE_PIXELS = 256
# The redraw schedule of estimate_with_redraw's defaults (3 redraws at the sampler's eps, then
# a widening eps, 12 draws in all), counted from the tile's first draw, which the pipeline
# makes itself: the driver starts at the first redraw.
REDRAWS_BEFORE_ENLARGE = 3 - 1
MAX_REDRAW_ROUNDS = 12 - 1
# The device stages a render times (RenderStats.stage_seconds, StageClock).
DEVICE_STAGES = ("sample_sets", "tracing", "voronoi", "moments", "readback")

ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class RenderSettings:
    """What to render. `estimator` is one estimator (a name or a registry entry), or a list of
    them: one trace, one image per estimator. Made, it holds the first, and
    `extra_estimators` the others. A list always names every estimator (extra_estimators is
    then replaced); one estimator replaces the first and keeps the others, so
    dataclasses.replace(settings, seed=1) keeps them all and replace(settings, estimator=[...])
    sets a new list."""

    width: int
    height: int
    sampler: SamplerConfig
    estimator: Estimator  # a name is accepted and replaced by its registry entry
    seed: int = 0
    tile_samples: int = DEFAULT_TILE_SAMPLES
    overlap: bool = True
    voronoi_backend: str = "device"
    extra_estimators: tuple[Estimator, ...] = ()

    def __post_init__(self) -> None:
        self.check_fields()
        self.resolve_estimators()
        # pvor over stratified or Sobol points is unbiased only under a random toroidal shift
        # of each pixel's set (torus cell areas are shift-invariant): on for it (and so for
        # every estimator of the render), off otherwise
        periodic = any(entry.cells == "periodic" for entry in self.estimators)
        shift = periodic and self.sampler.kind.low_discrepancy_positions
        if shift != self.sampler.toroidal_shift:
            object.__setattr__(self, "sampler", replace(self.sampler, toroidal_shift=shift))
        self.sampler.path_arguments((self.width, self.height))  # zsobol: does the image fit?
        # Auxiliary nuclei shape only the SPPP cells: drawn for the estimators that use them (a
        # settings object made by dataclasses.replace from another gets them back if needed).
        wanted = auxiliary_count(self.sampler.n, self.sampler.eps) if self.sampler.eps else 0
        n_aux = wanted if any(entry.needs_aux for entry in self.estimators) else 0
        if n_aux != self.sampler.n_aux:
            object.__setattr__(self, "sampler", replace(self.sampler, n_aux=n_aux))
        if self.voronoi_backend not in VORONOI_BACKENDS:
            raise ParameterError(
                f"unknown Voronoi backend {self.voronoi_backend!r}; accepted: "
                f"{', '.join(VORONOI_BACKENDS)}"
            )
        check_tile_memory(self)

    def check_fields(self) -> None:
        """One-line ParameterErrors for values of the wrong type or range (the Python API's
        edge: the command line checks the same before it builds settings)."""
        for name in ("width", "height", "tile_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ParameterError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.sampler, SamplerConfig):
            raise ParameterError(
                f"sampler must be a SamplerConfig (clrender.sampling.make_sampler(name, spp)), "
                f"got {type(self.sampler).__name__} {self.sampler!r}"
            )
        check_seed(self.seed)

    def resolve_estimators(self) -> None:
        """Registry entries for `estimator` (one, or a list) and `extra_estimators`, each
        checked against the sampler; a name given twice is an error."""
        given = self.estimator
        many = isinstance(given, list | tuple)
        if many and not given:
            raise ParameterError("no estimator given: name at least one")
        names = list(given) if many else [given, *self.extra_estimators]
        entries = [check_compatible(name, self.sampler.name) for name in names]
        seen = [entry.name for entry in entries]
        twice = sorted({name for name in seen if seen.count(name) > 1})
        if twice:
            raise ParameterError(f"estimator {twice[0]!r} is named twice: name each once")
        object.__setattr__(self, "estimator", entries[0])
        object.__setattr__(self, "extra_estimators", tuple(entries[1:]))
        check_image_memory(self.width, self.height, estimators=len(entries))

    @property
    def estimators(self) -> tuple[Estimator, ...]:
        """Every estimator of the render, the first (`estimator`) first."""
        return (self.estimator, *self.extra_estimators)

    @property
    def device_cell_kinds(self) -> tuple[str, ...]:
        """The kinds of Voronoi cells the device computes for the tiles ("sppp": vor, vor_sn,
        fvor; "periodic": pvor; "clipped": cvor), each with its per-pixel sums."""
        if self.voronoi_backend != "device":
            return ()
        kinds = [entry.cells for entry in self.estimators if entry.device_sums]
        return tuple(dict.fromkeys(kinds))

    @property
    def device_sum_kinds(self) -> tuple[str, ...]:
        """What the device sums per pixel after tracing: the device cell kinds, or "plain"
        (sum f and sum f^2 alone) when every estimator needs no cells (mc, mc_n): then no
        per-sample array leaves the device either."""
        kinds = self.device_cell_kinds
        if not kinds and all(entry.cells == "none" for entry in self.estimators):
            return ("plain",)
        return kinds

    @property
    def device_cells(self) -> bool:
        """Whether the tiles' cells and sums come from the device right after the tracing (the
        SPPP cells of vor, vor_sn, fvor; pvor's torus cells; cvor's cells clipped to W). The
        image-level cells (ivor, ivor_sn) come from the device in the estimator stage instead."""
        return bool(self.device_cell_kinds)

    @property
    def needs_host_samples(self) -> bool:
        """Whether the tiles' sample sets and radiance come back to the host: for an estimator
        the device sums do not serve (mc and mc_n are served by any device sums)."""
        kinds = self.device_sum_kinds
        return any(
            not (entry.cells in kinds or (entry.cells == "none" and kinds))
            for entry in self.estimators
        )

    @property
    def pixel_count(self) -> int:
        return self.width * self.height


@dataclass
class RenderStats:
    tiles: int = 0
    traced_samples: int = 0
    rays: int = 0
    device_seconds: float = 0.0  # the device stages below, summed (compile excluded)
    host_seconds: float = 0.0  # estimator stage (Voronoi cells and sums), redraws' host part
    wall_seconds: float = 0.0
    # program builds and kernel creation (first uses in a process): during the render (in
    # wall_seconds, out of the stages), and before it, for its radiance source (api.render)
    compile_seconds: float = 0.0
    main_compile_seconds: float = 0.0  # the part met on the main thread
    setup_compile_seconds: float = 0.0
    # a cluster render's wait for its workers' set-up (clrender.cluster.render_on): in
    # wall_seconds, out of run_seconds
    worker_setup_seconds: float = 0.0
    # seconds per device stage (DEVICE_STAGES; StageClock: the device's clock): drawing sample
    # sets, tracing, device Voronoi cells and sums (with the host's settling of undecided
    # pixels), the plain sums, read-back
    stage_seconds: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(DEVICE_STAGES, 0.0)
    )
    # host seconds per estimator; estimators that share a tessellation are timed together,
    # under their names joined by "+" (e.g. "vor+vor_sn")
    estimator_seconds: dict[str, float] = field(default_factory=dict)
    redraw_host_seconds: float = 0.0  # host part of the redraws (in host_seconds)
    layer_seconds: float = 0.0  # the per-pixel layers' host time (in host_seconds)
    redrawn_pixels: int = 0  # pixel redraws after a rejection (a pixel may count twice)
    eps_enlargements: int = 0  # redraw rounds that needed a wider eps
    unresolved_pixels: int = 0  # still rejected after every redraw: mc estimate of the last
    nonfinite_samples: int = 0  # NaN/Inf radiance, from the source's count or found on the host
    interrupted: bool = False

    @property
    def run_seconds(self) -> float:
        """Wall time without the program builds met on the render's main thread (rates use
        it; the estimator thread's builds may overlap tracing, so they stay in), nor a cluster
        render's wait for its workers' set-up."""
        return max(self.wall_seconds - self.main_compile_seconds - self.worker_setup_seconds, 0.0)


@dataclass
class RenderResult:
    film: Film  # the first estimator's
    stats: RenderStats
    # as the render ran: a local render's tile_samples lowered to fit the device (a cluster
    # render's workers fit their own tiles; it reports the requested value)
    settings: RenderSettings
    films: dict[str, Film] = field(default_factory=dict)  # every estimator's, by name
    layers: PixelLayers | None = None
    # draw 0's layers, when image-level estimators (which keep draw 0) share the render with
    # rejecting ones (whose redrawn pixels' layers are in `layers`)
    first_draw_layers: PixelLayers | None = None
    # The paths the radiance came from: scattering vertices per path and whether Russian
    # roulette ended them (None for sources without paths, such as analytic images)
    max_depth: int | None = None
    russian_roulette: bool | None = None
    # What the pipeline does not know (clrender.report.RenderLabels: scene, device,
    # provenance), recorded by clrender.render for save()
    labels: object | None = None
    # The OpenCL device that rendered it (Runtime.describe) and the precision of its Voronoi
    # cells and sums ("mixed" with cl_khr_fp64, else "single"); a cluster render's, as its
    # tasks reported them, each in sorted order joined by "; ", None when no task finished
    device: str | None = None
    device_precision: str | None = None
    # The kernel that traced its paths (clrender.trace.TRACE_KERNELS, or "wavefront"); a
    # cluster render's as its tasks reported them, sorted and joined by "; "; None without
    # paths (an analytic image)
    trace_kernel: str | None = None
    # Finished tasks per worker (address: count, by address) of a render through an executor
    # (render_on: {"this process": n} on a LocalExecutor); None for a plain local render
    tasks_by_worker: dict[str, int] | None = None
    # The fingerprint of the OpenCL sources its tasks' workers built (render_on: "; " between
    # several, a worker that cannot tell "unknown"); None for a local render: this process's
    kernels_sha256: str | None = None
    # Likewise the fingerprint of the clrender Python code its tasks' workers ran
    # (clrender.provenance.code_fingerprint)
    code_sha256: str | None = None

    def __post_init__(self) -> None:
        if not self.films:  # a result made of one film
            self.films = {self.settings.estimator.name: self.film}

    def layers_of(self, estimator: str) -> PixelLayers | None:
        """The layers of the draws an estimator's image comes from."""
        entry = next(entry for entry in self.settings.estimators if entry.name == estimator)
        if entry.image_level and self.first_draw_layers is not None:
            return self.first_draw_layers
        return self.layers

    def save(self, output: str | os.PathLike) -> dict:
        """Write OUT.exr and OUT.png (with several estimators OUT.<estimator>.exr and .png
        each) as the command line does: RGB, per-pixel layers, metadata with provenance;
        atomically, a failed write keeps the old files (clrender.outputs.save). Returns the
        paths written, by estimator."""
        from clrender.outputs import save

        return save(self, output)

    @property
    def image(self) -> np.ndarray:
        """(height, width, 3) float32 linear RGB of the first estimator, row 0 at the top (0
        where not rendered)."""
        return self.film.image()

    @property
    def images(self) -> dict[str, np.ndarray]:
        """Every estimator's image, by name, in the order they were named."""
        return {name: film.image() for name, film in self.films.items()}

    def __repr__(self) -> str:
        """One line: what was rendered and how it ended (the dataclass's own repr would print
        every film's arrays)."""
        settings, stats = self.settings, self.stats
        done = min(film.rendered_count for film in self.films.values())
        state = (
            "complete"
            if done == self.film.pixel_count
            else f"partial {done}/{self.film.pixel_count} pixels"
        )
        return (
            f"<RenderResult {settings.width}x{settings.height} {settings.sampler.name} "
            f"{settings.sampler.n} spp seed {settings.seed} "
            f"[{', '.join(self.films)}] {stats.wall_seconds:.3g} s {state}"
            + (f" on {self.device}" if self.device else "")
            + ">"
        )

    def _repr_png_(self) -> bytes:
        """Jupyter's rich display: every estimator's image, named (clrender.display)."""
        import io

        from clrender.display import preview

        buffer = io.BytesIO()
        preview(self).save(buffer, format="PNG")
        return buffer.getvalue()


@dataclass
class TileSamples:
    """The device stage's output for a list of pixels: host sample sets and radiance (when an
    estimator or the variance layer needs them) and the per-pixel sums of each kind of device
    cells."""

    pixels: np.ndarray  # (P,) uint32 global pixel indices
    redraws: np.ndarray  # (P,) uint32 redraw numbers
    sets: SampleSets | None  # None when no estimator needs host samples
    radiance: np.ndarray | None  # (T, 3) float32, traced-sample order; None with sets
    rays: int
    source_nonfinite: int
    sums: dict[str, DeviceSums] = field(default_factory=dict)  # by cell kind

    @property
    def counts(self) -> np.ndarray:
        """(P,) traced samples per pixel."""
        if self.sets is not None:
            return np.asarray(self.sets.counts, np.int64)
        return np.asarray(next(iter(self.sums.values())).counts, np.int64)

    @property
    def traced_count(self) -> int:
        return int(self.counts.sum())

    def moments(self, values: np.ndarray | None = None) -> PixelMoments:
        """Each pixel's count, sum f and sum f^2: from the host samples (values: their radiance
        with non-finite rows zeroed, if already made) or the device sums' plain sums."""
        if self.sets is not None:
            values = zero_nonfinite(self.radiance) if values is None else values
            return PixelMoments.of_samples(self.sets, values)
        device = next(iter(self.sums.values())).sums
        return PixelMoments(self.counts, device.value, device.square)


@dataclass
class TileEstimate:
    """The host stage's output: one estimate per pixel and estimator, with per-pixel flags."""

    pixels: np.ndarray
    redraws: np.ndarray
    estimates: dict[str, np.ndarray]  # name -> (P, 3) float64, NaN where needs_redraw
    flagged: np.ndarray  # (P,) bool: a sample with non-finite radiance
    needs_redraw: np.ndarray  # (P,) bool
    nonfinite_samples: int
    counts: np.ndarray  # (P,) traced samples: the layers
    variance: np.ndarray  # (P, 3) float32 mc variance: the layers
    seconds: dict[str, float] = field(default_factory=dict)  # host time per estimator group
    layer_seconds: float = 0.0  # host time of the layers
    compile_seconds: float = 0.0  # program builds on the estimator thread
    counted: bool = False  # its times and counts are on the render's stats (record)


def tile_nuclei_per_pixel(settings: RenderSettings) -> int:
    """The samples a pixel adds to its tile: traced and auxiliary ones, or its torus translates
    (mirror images) when the device computes periodic (clipped) cells."""
    per_pixel = settings.sampler.n + settings.sampler.n_aux
    if "periodic" in settings.device_cell_kinds:
        per_pixel = max(per_pixel, settings.sampler.n * TORUS_COPIES)
    if "clipped" in settings.device_cell_kinds:
        per_pixel = max(per_pixel, settings.sampler.n * MIRROR_COPIES)
    return per_pixel


def pixels_per_tile(settings: RenderSettings) -> int:
    """Tile length in pixels: within the sample budget, and about TARGET_TILE_COUNT tiles. The
    budget counts every nucleus a pixel's cells hold (tile_nuclei_per_pixel)."""
    budget = max(1, settings.tile_samples // tile_nuclei_per_pixel(settings))
    spread = max(MIN_TILE_PIXELS, math.ceil(settings.pixel_count / TARGET_TILE_COUNT))
    return min(budget, spread)


def check_tile_memory(settings: RenderSettings, memory: int | None = None) -> None:
    """ParameterError, before any work, if one tile's samples cannot fit in host memory: a
    pixel's samples are never split between tiles, so a huge spp makes a huge tile whatever
    tile_samples says."""
    memory = physical_memory() if memory is None else memory
    per_pixel = tile_nuclei_per_pixel(settings)
    samples = min(pixels_per_tile(settings), settings.pixel_count) * per_pixel
    need = samples * MIN_BYTES_PER_TILE_SAMPLE
    if memory is not None and need > memory:
        raise ParameterError(
            f"a tile of {samples:,} samples ({per_pixel:,} a pixel, never split between tiles) "
            f"needs at least {need / 2**30:.1f} GiB of host memory, more than this machine's "
            f"{memory / 2**30:.1f} GiB: use fewer samples per pixel (or fewer per tile)"
        )


def tile_device_bytes(settings: RenderSettings, pixels: int) -> tuple[int, int]:
    """(largest buffer, all buffers) on the device for a tile of the given pixels."""
    nuclei = pixels * tile_nuclei_per_pixel(settings)
    largest = max(TILE_NUCLEUS_BYTES[0] * nuclei, TILE_PIXEL_BYTES[0] * pixels)
    return largest, TILE_NUCLEUS_BYTES[1] * nuclei + TILE_PIXEL_BYTES[1] * pixels


def image_cells_device_bytes(settings: RenderSettings) -> tuple[int, int]:
    """(largest buffer, all buffers) of the image-level cells' launch on the device: (0, 0)
    when the render has none there."""
    if settings.voronoi_backend != "device" or not any(
        entry.image_level for entry in settings.estimators
    ):
        return 0, 0
    from clrender.estimators.image_device import CHUNK_NUCLEI, device_ring

    delta = image.guard_distance(settings.sampler.n, settings.sampler.alpha)
    neighbourhood = math.ceil((2 * device_ring(delta) + 1) ** 2 * settings.sampler.n)
    launch = min(max(CHUNK_NUCLEI, neighbourhood), settings.pixel_count * neighbourhood)
    return (
        IMAGE_CELLS_NUCLEUS_BYTES[0] * neighbourhood,
        IMAGE_CELLS_NUCLEUS_BYTES[1] * launch,
    )


def fit_tiles_to_device(settings: RenderSettings, device: cl.Device) -> RenderSettings:
    """The settings with tiles small enough for the device's memory (its global memory and its
    largest allocation, queried): tile_samples lowered where needed, which changes no pixel
    (images do not depend on the tiling). ParameterError, before any work, when one pixel's
    samples alone are too many: a pixel is never split between tiles."""
    total = int(DEVICE_MEMORY_SHARE * device.global_mem_size)
    largest = int(device.max_mem_alloc_size)
    cells_buffer, reserve = image_cells_device_bytes(settings)
    pixel_buffer, pixel_held = tile_device_bytes(settings, 1)
    if max(pixel_buffer, cells_buffer) > largest or pixel_held + reserve > total:
        raise ParameterError(
            f"one pixel's {settings.sampler.n:,} samples need "
            f"{(pixel_held + reserve) / 2**30:.2f} GiB of device memory (a buffer of "
            f"{max(pixel_buffer, cells_buffer) / 2**30:.2f} GiB), more than the "
            f"{total / 2**30:.2f} GiB (allocations up to {largest / 2**30:.2f} GiB) a render "
            f"may take on {describe_device(device)}: use fewer samples per pixel"
        )
    pixels = min((total - reserve) // pixel_held, largest // pixel_buffer)
    if pixels_per_tile(settings) <= pixels:
        return settings
    return replace(settings, tile_samples=pixels * tile_nuclei_per_pixel(settings))


def plan_tiles(settings: RenderSettings) -> range:
    """The first pixel of each tile; tile k covers [starts[k], starts[k] + step) clipped to
    the image, in scanline order (pixel arrays are made one tile at a time)."""
    if settings.tile_samples <= 0:
        raise ParameterError(f"tile_samples must be positive, got {settings.tile_samples}")
    return range(0, settings.pixel_count, pixels_per_tile(settings))


def tile_pixels(settings: RenderSettings, start: int, end: int | None = None) -> np.ndarray:
    """Global indices of the tile starting at pixel `start` (clipped to the image, or to `end`
    when the tiles cover a range of it)."""
    end = settings.pixel_count if end is None else min(end, settings.pixel_count)
    stop = min(start + pixels_per_tile(settings), end)
    return np.arange(start, stop, dtype=np.uint32)


class StageClock:
    """Seconds per device stage, with the main thread's program builds taken out and counted as
    compile time. On a queue that records when its commands run (Runtime.profiled: the
    runtimes clrender makes), a stage is timed on the device's clock, between a marker queued
    as it starts and one queued as it ends: from the device being free for it (done with the
    work queued before it, or idle) until its commands are done, plus the device time of the
    commands it ran on another queue and handed to the clock (`with clock.stage(name) as side:
    side.append(event)`; SPPP's count pass on Runtime.side_queue, which may run beside the
    work queued before the stage). Its commands are queued without a wait: the device runs a
    tile's stages back to back; settle() waits for their end markers, in order
    (QueuedTile.collect, before the tile's results), and adds their times. A stage that met a
    program build (a first use in the process), and every stage on a queue without profiling,
    ends with a wait for the device and takes the main thread's time less the builds: a build may
    overlap the device's earlier work, so the device's clock less the build would undercount
    (such a stage may instead include a part of the work queued before it). A device that
    cannot report the markers' times gets the main thread's time from the stage's start to the
    end of its queuing."""

    def __init__(self, stats: RenderStats, queue: cl.CommandQueue | None = None):
        self.stats = stats
        self.queue = queue
        profiling = cl.command_queue_properties.PROFILING_ENABLE
        self.profiled = queue is not None and bool(queue.properties & profiling)
        # stages queued and not yet settled: (name, start marker, end marker, main-thread
        # seconds of the queuing, the events of its commands on other queues)
        self.queued: list[tuple[str, cl.Event, cl.Event, float, list[cl.Event]]] = []

    @contextmanager
    def stage(self, name: str) -> Iterator[list[cl.Event]]:
        """Time the commands queued inside the block as the stage `name`; the block may append
        to the list it is given the events of commands it ran on another queue."""
        start, built = time.perf_counter(), thread_build_seconds()
        first = None
        side: list[cl.Event] = []
        if self.profiled:
            first = cl.enqueue_marker(self.queue)
            self.queue.flush()  # a driver that batches commands starts the clock now
        try:
            yield side
        finally:
            compile_seconds = self.add_builds(built)
            if first is not None and compile_seconds == 0:
                last = cl.enqueue_marker(self.queue)
                self.queue.flush()
                self.queued.append((name, first, last, time.perf_counter() - start, side))
            else:
                if self.queue is not None:
                    self.queue.finish()
                self.add(name, max(time.perf_counter() - start - compile_seconds, 0.0))

    def add_builds(self, since: float) -> float:
        """Count the main thread's program builds since `since` (thread_build_seconds) as
        compile time; their seconds."""
        compile_seconds = thread_build_seconds() - since
        self.stats.compile_seconds += compile_seconds
        self.stats.main_compile_seconds += compile_seconds
        return compile_seconds

    def take(self) -> list[tuple[str, cl.Event, cl.Event, float, list[cl.Event]]]:
        """The stages queued so far, to settle later (a queued tile's: QueuedTile)."""
        taken, self.queued = self.queued, []
        return taken

    def settle(
        self, stages: list[tuple[str, cl.Event, cl.Event, float, list[cl.Event]]] | None = None
    ) -> None:
        """Wait for the given stages (taken earlier), or for those queued since the last take,
        in their order, and add their device times to the stats; a later tile's stages queued
        behind them are not waited for."""
        if stages is None:
            stages = self.take()
        # Every stage waited for before any is counted: an interrupt inside a wait (a tile
        # dropped) adds none of its stages' times
        for _, _, last, _, side in stages:
            for event in (last, *side):
                event.wait()
        for name, first, last, queuing_seconds, side in stages:
            try:
                seconds = (last.profile.end - first.profile.end) * 1e-9
                seconds += sum(event.profile.end - event.profile.start for event in side) * 1e-9
            except cl.Error:  # profiling information not available here
                seconds = queuing_seconds
            self.add(name, seconds)

    def add(self, name: str, seconds: float) -> None:
        self.stats.stage_seconds[name] += seconds
        self.stats.device_seconds += seconds


# --- the two stages ----------------------------------------------------------------------


def trace_tile(
    runtime: Runtime,
    source: RadianceSource,
    sampler: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray,
    device_kinds: Sequence[str] = (),
    host_samples: bool = True,
    clock: StageClock | None = None,
) -> TileSamples:
    """Device stage: draw the pixels' sample sets and get their radiance. For each kind in
    device_kinds ("sppp", "periodic", "clipped"), that kind of Voronoi cells and each pixel's
    weighted sums are formed on the device after the tracing, and only the sums come back (if
    the kernel left pixels undecided, the samples come back too and the host settles those
    pixels with Qhull); "plain" forms each pixel's sum f and sum f^2 alone (RenderSettings.
    device_sum_kinds). With host_samples (or without device kinds) the sample sets and radiance
    come to the host as well. queue_tile, then QueuedTile.collect."""
    clock = clock or StageClock(RenderStats(), runtime.queue)
    args = (runtime, source, sampler, seed, pixels, redraws, device_kinds, host_samples)
    return queue_tile(*args, clock).collect(clock)


def queue_tile(
    runtime: Runtime,
    source: RadianceSource,
    sampler: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray,
    device_kinds: Sequence[str],
    host_samples: bool,
    clock: StageClock,
    queued_counts: PendingCounts | None = None,
) -> QueuedTile:
    """trace_tile's device work queued without a wait (sample sets, trace, device sums and the
    reads of what comes to the host): the host may queue the next tile's before it waits for
    this one's (QueuedTile.collect). A source computed on the host (an analytic image) waits
    for the sample sets here. queued_counts: the tile's SPPP count pass, queued earlier
    (clrender.sampling.queue_counts)."""
    with clock.stage("sample_sets") as side:
        device_sets = generate_sample_sets(
            runtime,
            sampler,
            seed,
            pixels,
            redraws,
            (source.width, source.height),
            queued_counts,
        )
        side.extend(device_sets.side_events)
    with clock.stage("tracing"):
        pending = source.trace(device_sets, seed)
        radiance = pending.to_device(runtime)  # the ray counters are read later
    sums: dict[str, PendingSums] = {}
    for kind in device_kinds:
        with clock.stage("moments" if kind == "plain" else "voronoi"):
            box = sppp_box(sampler) if kind == "sppp" else None
            sums[kind] = queue_device_sums(runtime, kind, device_sets, radiance.buffer, box)
    keep_samples = host_samples or not device_kinds
    reads = None
    if keep_samples:
        with clock.stage("readback"):
            reads = (device_sets.queue_to_host(runtime.queue), pending.queue_to_host())
    return QueuedTile(
        runtime,
        sampler,
        pixels,
        redraws,
        device_sets,
        pending,
        radiance,
        sums,
        reads,
        keep_samples,
        clock.take(),
    )


@dataclass
class QueuedTile:
    """A tile whose device work is queued (queue_tile): until collect() it holds the tile's
    device buffers and the host arrays its reads fill."""

    runtime: Runtime
    sampler: SamplerConfig
    pixels: np.ndarray
    redraws: np.ndarray
    device_sets: DeviceSampleSets
    pending: PendingRadiance
    radiance: DeviceRadiance
    sums: dict[str, PendingSums]
    reads: tuple[Callable[[], SampleSets], Callable[[], SampleRadiance]] | None
    keep_samples: bool
    stages: list  # the clock's stages of the queued work (StageClock.take)

    def collect(self, clock: StageClock) -> TileSamples:
        """Wait for the tile's results (the device may go on with work queued after them) and
        make its TileSamples; pixels the device cells left undecided are settled here (their
        samples read back, behind whatever was queued since). The stages are waited for first,
        in their order, and their results after: Intel's CPU runtime runs a kernel on the
        waiting host thread too when the host waits for that kernel or a marker queued after
        it, but not for a read queued behind a marker (the tile's trace ran on one thread
        instead of two: bench/host_wait.py)."""
        clock.settle(self.stages)
        sums = {kind: pending.result() for kind, pending in self.sums.items()}
        sets = values = None
        if self.reads is not None:
            sets, values = self.reads[0](), self.reads[1]().values
        if any(s.fallback.any() for s in sums.values()):
            if sets is None:
                with clock.stage("readback"):
                    sets = self.device_sets.to_host(self.runtime.queue)
                    values = self.pending.to_host().values
            with clock.stage("voronoi"):
                finite = zero_nonfinite(values)
                for kind, device in sums.items():
                    if device.fallback.any():
                        box = sppp_box(self.sampler) if kind == "sppp" else None
                        sums[kind] = settle_undecided(device, sets, finite, box, kind)
            clock.settle()
        return TileSamples(
            self.pixels,
            self.redraws,
            sets if self.keep_samples else None,
            values if self.keep_samples else None,
            self.radiance.ray_count,
            self.radiance.device_nonfinite,
            sums,
        )


def sppp_box(sampler: SamplerConfig) -> float:
    """Half the side of W' = [-1/2 - eps, 1/2 + eps]^2, the SPPP cells' box."""
    return 0.5 + sampler.eps


def zero_nonfinite(values: np.ndarray) -> np.ndarray:
    """float64 copy of (T, 3) radiance with non-finite rows set to 0 (as the sums kernel)."""
    return finite_values(values)[0]


def finite_values(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(zero_nonfinite(values), the (T,) mask of the rows that were not finite)."""
    values = values.astype(np.float64)
    bad = ~np.isfinite(values).all(axis=1)
    values[bad] = 0.0
    return values, bad


def estimator_groups(settings: RenderSettings) -> list[tuple[Estimator, ...]]:
    """The estimators grouped by the cells they share (computed once per group), in order."""
    groups: dict[str, list[Estimator]] = {}
    for entry in settings.estimators:
        groups.setdefault(entry.cells, []).append(entry)
    return [tuple(group) for group in groups.values()]


def estimate_tile(
    settings: RenderSettings, tile: TileSamples, host_runtime: Runtime
) -> TileEstimate:
    """Host stage: one estimate per pixel and estimator, each group of estimators sharing a
    tessellation timed apart. Samples with non-finite radiance are counted, enter the
    estimators as 0 and flag their pixel. host_runtime serves the image-level estimators,
    which draw their guard nuclei on the device."""
    count = len(tile.pixels)
    values = None
    if tile.sets is not None:
        values, bad_samples = finite_values(tile.radiance)
        flagged = np.bincount(tile.sets.pixel_index, bad_samples, count) > 0
        nonfinite = int(np.count_nonzero(bad_samples))
    else:
        device = next(iter(tile.sums.values()))
        flagged, nonfinite = device.nonfinite > 0, int(device.nonfinite.sum())
    start = time.perf_counter()
    moments = tile.moments(values)
    layer_seconds = time.perf_counter() - start
    estimates: dict[str, np.ndarray] = {}
    seconds: dict[str, float] = {}
    needs_redraw = np.zeros(count, bool)
    for group in estimator_groups(settings):
        start = time.perf_counter()
        results, rejected = group_estimates(settings, tile, group, values, moments, host_runtime)
        needs_redraw |= rejected
        estimates.update(results)
        seconds["+".join(entry.name for entry in group)] = time.perf_counter() - start
    for entry in settings.estimators:
        if not entry.image_level:
            estimates[entry.name] = np.where(needs_redraw[:, None], np.nan, estimates[entry.name])
    start = time.perf_counter()
    variance = mc_variance(moments, settings.sampler)
    layer_seconds += time.perf_counter() - start
    return TileEstimate(
        tile.pixels,
        tile.redraws,
        estimates,
        flagged,
        needs_redraw,
        nonfinite + tile.source_nonfinite,
        moments.counts,
        variance,
        seconds,
        layer_seconds,
    )


def group_estimates(
    settings: RenderSettings,
    tile: TileSamples,
    group: tuple[Estimator, ...],
    values: np.ndarray | None,
    moments: PixelMoments,
    host_runtime: Runtime,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """({name: (P, 3) estimates}, needs_redraw) of estimators sharing one kind of cells: from
    the device sums of that kind, the plain sums of the moments (mc, mc_n: the host samples'
    or the device sums'), the image-level tessellation, or the host samples."""
    kind = group[0].cells
    count = len(tile.pixels)
    if kind in tile.sums:
        device = tile.sums[kind]
        return {entry.name: entry.formula(device.sums) for entry in group}, device.redraw
    if kind == "none":
        plain = PixelSums(moments.counts, settings.sampler.n, value=moments.value)
        return {entry.name: entry.formula(plain) for entry in group}, np.zeros(count, bool)
    if kind == "image":
        run = image.estimate_tile_image(
            host_runtime,
            settings.sampler,
            settings.seed,
            settings.width,
            settings.height,
            tile.pixels,
            tile.sets,
            values,
            device_cells=settings.voronoi_backend == "device",
        )
        return {entry.name: entry.formula(run.sums) for entry in group}, np.zeros(count, bool)
    results = estimate_all(group, tile.sets, values)
    rejected = np.logical_or.reduce([result.needs_redraw for result in results.values()])
    return {name: result.estimates.reshape(count, 3) for name, result in results.items()}, rejected


def sibling_runtime(runtime: Runtime) -> Runtime:
    """A second context and queue on the same device, for device calls from the estimator
    thread: kernel objects (and their arguments) are never shared between threads. Made once
    per runtime, so that its programs are built once per process too."""
    if runtime.sibling is None:
        context = cl.Context([runtime.device])
        queue = profiling_queue(context)
        runtime.sibling = Runtime(runtime.device, context, queue, runtime.local_size)
    return runtime.sibling


# --- the pipeline ------------------------------------------------------------------------


class TilePipeline:
    """Runs the stages over the tiles and records results on the films, the layers and the
    stats."""

    def __init__(self, runtime: Runtime, source: RadianceSource, settings: RenderSettings):
        self.runtime = runtime
        self.source = source
        settings = fit_tiles_to_device(settings, runtime.device)
        self.settings = settings
        self.films = {
            entry.name: Film(settings.width, settings.height) for entry in settings.estimators
        }
        self.layers = PixelLayers(settings.width, settings.height)
        # The image-level estimators keep draw 0 of a pixel the others redraw: their layers
        image_level = any(entry.image_level for entry in settings.estimators)
        rejecting = any(entry.needs_aux for entry in settings.estimators)
        both = image_level and rejecting
        self.first_draw_layers = PixelLayers(settings.width, settings.height) if both else None
        # Without double precision the device's plain sums are float32: mc, mc_n and the
        # variance layer then come from the host samples (float64, as every other render)
        single = resolve_precision(runtime, "auto") == "single"
        self.host_samples = settings.needs_host_samples or single
        # What the device sums for the tiles (the plain sums only when the host lacks samples)
        kinds = settings.device_sum_kinds
        self.device_kinds = () if kinds == ("plain",) and self.host_samples else kinds
        self.stats = RenderStats()
        self.clock = StageClock(self.stats, runtime.queue)
        self.in_flight: Future | None = None  # the estimate of the previous tile
        needs_device = image_level and settings.overlap
        self.host_runtime = sibling_runtime(runtime) if needs_device else runtime

    @property
    def film(self) -> Film:
        return self.films[self.settings.estimator.name]

    def queue(
        self,
        pixels: np.ndarray,
        redraws: np.ndarray,
        sampler: SamplerConfig | None = None,
        queued_counts: PendingCounts | None = None,
    ) -> QueuedTile:
        """Queue a tile's device work (collect: wait for it); queued_counts: its SPPP count
        pass, queued ahead (count_ahead)."""
        # Tiles use the device cells if configured; redraws go through Qhull in the driver.
        redraw = sampler is not None
        return queue_tile(
            self.runtime,
            self.source,
            sampler or self.settings.sampler,
            self.settings.seed,
            pixels,
            redraws,
            () if redraw else self.device_kinds,
            redraw or self.host_samples,
            self.clock,
            queued_counts,
        )

    def count_ahead(self, tiles: range, index: int, end: int | None) -> PendingCounts | None:
        """Queue the SPPP count pass of tile `index` of `tiles` (None past the last tile or
        for a sampler with fixed counts)."""
        sampler = self.settings.sampler
        if not sampler.is_sppp or index >= len(tiles):
            return None
        pixels = tile_pixels(self.settings, tiles[index], end)
        zeros = np.zeros(len(pixels), np.uint32)
        # (outside a stage: a first use builds sampling.cl here, counted as compile time)
        built = thread_build_seconds()
        try:
            return queue_counts(self.runtime, sampler, self.settings.seed, pixels, zeros)
        finally:
            self.clock.add_builds(built)

    def collect(self, queued: QueuedTile) -> TileSamples:
        tile = queued.collect(self.clock)
        self.stats.traced_samples += tile.traced_count
        self.stats.rays += tile.rays
        return tile

    def trace(
        self, pixels: np.ndarray, redraws: np.ndarray, sampler: SamplerConfig | None = None
    ) -> TileSamples:
        return self.collect(self.queue(pixels, redraws, sampler))

    def estimate(self, tile: TileSamples) -> TileEstimate:
        """The host stage (on the worker thread when overlapping: it touches no stats)."""
        start, built = time.perf_counter(), thread_build_seconds()
        result = estimate_tile(self.settings, tile, self.host_runtime)
        result.compile_seconds = thread_build_seconds() - built
        elapsed = time.perf_counter() - start - result.compile_seconds
        # The parts' own times, scaled so that they sum to the stage's time without builds
        total = sum(result.seconds.values()) + result.layer_seconds
        scale = elapsed / total if total > 0 else 0.0
        result.seconds = {name: seconds * scale for name, seconds in result.seconds.items()}
        result.layer_seconds *= scale
        return result

    def record(self, result: TileEstimate) -> None:
        """Store the accepted pixels of an estimate on the films and the layers, and its times
        and counts on the stats. Recording it again (an interrupt inside the first recording,
        finished by run()'s handler) stores the same pixels and counts nothing twice."""
        accepted = ~result.needs_redraw
        for entry in self.settings.estimators:
            keep = np.ones_like(accepted) if entry.image_level else accepted
            self.films[entry.name].record(
                result.pixels[keep], result.estimates[entry.name][keep], result.flagged[keep]
            )
        self.layers.record(
            result.pixels[accepted],
            result.counts[accepted],
            result.redraws[accepted],
            result.variance[accepted],
        )
        if self.first_draw_layers is not None:
            self.first_draw_layers.record(
                result.pixels, result.counts, result.redraws, result.variance
            )
        if result.counted:
            return
        result.counted = True
        for name, seconds in result.seconds.items():
            self.stats.estimator_seconds[name] = (
                self.stats.estimator_seconds.get(name, 0.0) + seconds
            )
            self.stats.host_seconds += seconds
        self.stats.layer_seconds += result.layer_seconds
        self.stats.host_seconds += result.layer_seconds
        self.stats.compile_seconds += result.compile_seconds
        if not self.settings.overlap:  # the estimate ran on the main thread
            self.stats.main_compile_seconds += result.compile_seconds
        self.stats.nonfinite_samples += result.nonfinite_samples

    def redraw_rejected(self, result: TileEstimate) -> None:
        """Redraw a recorded tile's rejected pixels (device work: on the main thread)."""
        rejected = result.needs_redraw
        if rejected.any():
            self.redraw(result.pixels[rejected], result.redraws[rejected])

    def redraw(self, pixels: np.ndarray, redraws: np.ndarray) -> None:
        """Estimate rejected pixels again from new draws, through the bounded redraw driver:
        every per-pixel estimator of a pixel uses the same accepted draw (the image-level ones
        kept their estimate: they never reject). Non-finite radiance is left in: it makes the
        pixel's estimate non-finite, which the film flags."""
        start = time.perf_counter()
        device_before = self.stats.device_seconds
        compile_before = self.stats.compile_seconds
        draws = PixelRedraws(self, pixels, redraws)
        sampler = self.settings.sampler
        per_pixel = [entry for entry in self.settings.estimators if not entry.image_level]
        outcome = estimate_with_redraw(
            per_pixel,
            draws.draw,
            len(pixels),
            sampler.n,
            eps=sampler.eps,
            alpha=sampler.alpha,
            redraws_before_enlarge=REDRAWS_BEFORE_ENLARGE,
            max_rounds=MAX_REDRAW_ROUNDS,
            on_exhausted="mc",
        )
        for entry in per_pixel:
            estimates = outcome.estimates[entry.name].reshape(len(pixels), 3)
            self.films[entry.name].record(pixels, estimates, np.zeros(len(pixels), bool))
        moments = draws.moments
        self.layers.record(pixels, moments.counts, draws.redraws, mc_variance(moments, sampler))
        self.stats.redrawn_pixels += outcome.stats.redraws + len(pixels)
        self.stats.eps_enlargements += outcome.stats.eps_enlargements
        self.stats.unresolved_pixels += outcome.stats.exhausted_pixels
        elsewhere = (self.stats.device_seconds - device_before) + (
            self.stats.compile_seconds - compile_before
        )
        host = time.perf_counter() - start - elsewhere
        self.stats.host_seconds += host
        self.stats.redraw_host_seconds += host

    def run(
        self,
        tiles: range,
        progress: ProgressCallback | None,
        end: int | None = None,
        on_done: Callable[[], None] | None = None,
    ) -> None:
        """With overlap, trace tile k + 1 while tile k is estimated on a worker thread, and
        keep the device fed: once tile k - 1 is recorded, tile k + 1's work is queued before the
        host waits for tile k's results (so at most two tiles are held: one queued, the other
        queued or being estimated). Without overlap, one tile at a time: its device work, then
        its estimate. Tiles are clipped to pixel `end` when they cover a range of the image
        (clrender.cluster). SPPP's count pass of tile k + 1 is queued before tile k's work.
        `on_done` is called as the last step of the interruptible work
        (clrender.interrupts.work_done: the command holds the signals from there on)."""
        self.stats.tiles = len(tiles)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="estimator") as pool:
            try:
                if self.settings.overlap:
                    # The thread starts before a tile is handed over: the pool joins only the
                    # threads it has listed, which an interrupt inside Thread.start leaves out
                    pool.submit(int).result()
                queued: QueuedTile | None = None
                ahead = self.count_ahead(tiles, 0, end)
                for index, start in enumerate(tiles):
                    self.finish_in_flight(progress)
                    pixels = tile_pixels(self.settings, start, end)
                    counts, ahead = ahead, self.count_ahead(tiles, index + 1, end)
                    zeros = np.zeros(len(pixels), np.uint32)
                    following = self.queue(pixels, zeros, queued_counts=counts)
                    if not self.settings.overlap:
                        queued, following = following, None
                    if queued is not None:
                        self.start_estimate(pool, self.collect(queued))
                    queued = following
                self.finish_in_flight(progress)
                if queued is not None:
                    self.start_estimate(pool, self.collect(queued))
                self.finish_in_flight(progress)
                if on_done is not None:
                    on_done()
            except KeyboardInterrupt:
                self.stats.interrupted = True
                # The estimate handed to the thread runs to its end (the interrupt may have
                # come as it was handed over: it is in in_flight from before), and is kept
                # (finished work, not redrawn); one the interrupt kept from the thread never
                # started
                pool.shutdown(wait=True)
                # An estimate that failed is dropped, and the interrupt kept: a signal that
                # came during a build on the thread may have failed that build (the compiler's
                # signal handler removes its temporary files)
                estimate = self.in_flight
                if estimate is not None and estimate.done() and estimate.exception() is None:
                    self.record(estimate.result())
                self.in_flight = None

    def finish_in_flight(self, progress: ProgressCallback | None) -> None:
        if self.in_flight is not None:
            # Cleared once it is recorded: an interrupt before leaves it to run()'s handler,
            # which records it (record() counts its stats once)
            estimate = self.in_flight.result()
            self.record(estimate)
            self.in_flight = None
            self.redraw_rejected(estimate)
            self.report(progress)

    def start_estimate(self, pool: ThreadPoolExecutor, tile: TileSamples) -> None:
        """Estimate the tile, on the worker thread with overlap; its future is in_flight
        before the work is handed over, so that an interrupt at any moment finds it there."""
        self.in_flight = future = Future()
        if self.settings.overlap:
            pool.submit(self.estimate_into, future, tile)
        else:  # on this thread: an interrupt inside leaves the future unfinished
            future.set_running_or_notify_cancel()
            future.set_result(self.estimate(tile))

    def estimate_into(self, future: Future, tile: TileSamples) -> None:
        """The worker thread's task: the tile's estimate, or its error, in `future`."""
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(self.estimate(tile))
        except BaseException as err:  # noqa: BLE001 (raised on the main thread, by result())
            future.set_exception(err)

    def report(self, progress: ProgressCallback | None) -> None:
        if progress is not None:
            progress(self.film.rendered_count, self.film.pixel_count)


class PixelRedraws:
    """The draw of estimate_with_redraw for a list of rejected pixels: each draw increments the
    drawn pixels' redraw numbers and traces them like a tile. A pixel's last draw is its
    accepted one (or the one whose mc estimate it keeps): its moments are kept for the
    layers."""

    def __init__(self, pipeline: TilePipeline, pixels: np.ndarray, redraws: np.ndarray):
        self.pipeline = pipeline
        self.pixels = pixels
        self.redraws = redraws.astype(np.uint32)
        count = len(pixels)
        self.moments = PixelMoments(
            np.zeros(count, np.int64), np.zeros((count, 3)), np.zeros((count, 3))
        )

    def draw(self, ids: np.ndarray, eps: float) -> tuple[SampleSets, np.ndarray]:
        self.redraws[ids] += 1
        config = self.pipeline.settings.sampler
        sampler = make_sampler(config.name, config.n, config.alpha, eps, config.toroidal_shift)
        tile = self.pipeline.trace(self.pixels[ids], self.redraws[ids], sampler)
        self.pipeline.stats.nonfinite_samples += tile.source_nonfinite + int(
            np.count_nonzero(~np.isfinite(tile.radiance).all(axis=1))
        )
        moments = tile.moments()
        self.moments.counts[ids] = moments.counts
        self.moments.value[ids] = moments.value
        self.moments.square[ids] = moments.square
        return tile.sets, tile.radiance.astype(np.float64)


def render(
    runtime: Runtime,
    source: RadianceSource,
    settings: RenderSettings,
    progress: ProgressCallback | None = None,
) -> RenderResult:
    """Render the source's image with the settings' sampler and estimators (one image each,
    from the same traced samples)."""
    if (source.width, source.height) != (settings.width, settings.height):
        raise ParameterError(
            f"the radiance source renders {source.width} x {source.height}, "
            f"the settings ask for {settings.width} x {settings.height}"
        )
    pipeline = TilePipeline(runtime, source, settings)
    tiles = plan_tiles(pipeline.settings)
    start = time.perf_counter()
    pipeline.run(tiles, progress, on_done=interrupts.work_done)
    pipeline.stats.wall_seconds = time.perf_counter() - start
    tracer = getattr(source, "tracer", None)
    return RenderResult(
        pipeline.film,
        pipeline.stats,
        pipeline.settings,  # as run: tile_samples lowered where the device needed it
        pipeline.films,
        pipeline.layers,
        pipeline.first_draw_layers,
        max_depth=None if tracer is None else tracer.max_depth,
        russian_roulette=None if tracer is None else tracer.russian_roulette,
        device=runtime.describe(),
        device_precision=resolve_precision(runtime, "auto"),
        trace_kernel=None if tracer is None else tracer.trace_kernel,
    )
