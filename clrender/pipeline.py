"""The render pipeline, tile by tile:

    sample sets (kernels/sampling.cl, clrender.sampling.generate_sample_sets)
      -> radiance of each traced sample (a RadianceSource: the path tracer or an analytic image)
      -> one estimate per pixel (clrender.estimators: the registry entry says how)
      -> film (clrender.film)

The estimator is validated once, when RenderSettings is made (its registry entry, checked
against the sampler); the pipeline then asks that entry (its cells, whether the device forms
its sums, whether it is image-level), never the name.

A tile is a run of consecutive pixels (scanline order) holding about `tile_samples` samples,
so memory stays bounded whatever the resolution and spp. With `overlap`, the host estimator of
tile k runs on a worker thread while the main thread has the device draw and trace tile k + 1;
pyopencl, NumPy and Qhull release the GIL in their long calls, so wall time approaches
max(device, host) instead of their sum.

Rejections: a pixel whose SPPP tessellation leaves a nucleus of W with an unbounded cell is
redrawn through clrender.estimators.estimate_with_redraw: its sample set is generated again with
its redraw number incremented (the same launch path as a tile, on a list of pixels), traced
and estimated again; after a few redraws the driver widens eps, and after its last round it
falls back to the mc estimate of the last draw (counted as `unresolved_pixels`).
Non-finite radiance is counted, and its pixels flagged: see clrender.film.

Voronoi cells: with `voronoi_backend = "device"` (the default) the SPPP cells of vor, vor_sn
and fvor, and pvor's cells on the torus, are computed by a device kernel queued right after the
tracing, and a second kernel forms each pixel's weighted sums
(clrender.estimators.device_cells.device_sppp_sums, device_periodic_sums): no per-sample array
comes back, and the host stage only divides. A tile with a cell the kernel cannot
certify has those pixels settled on the host (their samples read back, cells by Qhull). With
"qhull" the host computes the cells with Qhull.

Timing: `device_seconds` is the time the main thread spends drawing sample sets, tracing
(and computing device Voronoi cells) and downloading; `host_seconds` the estimator stage's
own time (the image-level estimators ivor and ivor_sn also draw their guard nuclei there, on
a second OpenCL context so that no kernel object is shared between threads).

Determinism: every random number depends on (seed, pixel, sample, dimension, redraw) only;
a per-pixel estimator sees only its pixel's samples; the image-level ones (ivor, ivor_sn) see
neighbouring pixels' nuclei too, regenerated from the same random numbers whatever the tile,
and sum their triangles in a canonical order; so the image is bit-identical whatever the tile
size and with or without overlap.

Ctrl-C (KeyboardInterrupt) stops the render between device calls: the tile whose estimates
are in flight is finished (without its redraws), and `render` returns the partial film with
`stats.interrupted` set.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.estimators import image
from clrender.estimators.device_cells import (
    TORUS_COPIES,
    DeviceSums,
    device_periodic_sums,
    device_sppp_sums,
    settle_undecided,
)
from clrender.estimators.pixel import estimate
from clrender.estimators.redraw import estimate_with_redraw
from clrender.estimators.registry import Estimator, check_compatible
from clrender.film import Film, check_image_memory
from clrender.radiance import RadianceSource
from clrender.runtime import Runtime
from clrender.samples import SampleSets
from clrender.sampling import SamplerConfig, check_seed, generate_sample_sets, make_sampler
from clrender.sppp import auxiliary_count

DEFAULT_TILE_SAMPLES = 4_000_000
# Where the SPPP Voronoi cells of vor, vor_sn and fvor are computed: the device kernel
# (clrender.estimators.device_cells; exact, pixels it cannot certify recomputed with Qhull) or Qhull
# on the host (clrender.estimators.qhull_cells). Redraws always use Qhull.
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

ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class RenderSettings:
    width: int
    height: int
    sampler: SamplerConfig
    estimator: Estimator  # a name is accepted and replaced by its registry entry
    seed: int = 0
    tile_samples: int = DEFAULT_TILE_SAMPLES
    overlap: bool = True
    voronoi_backend: str = "device"

    def __post_init__(self) -> None:
        self.check_fields()
        object.__setattr__(self, "estimator", check_compatible(self.estimator, self.sampler.name))
        # pvor over stratified or Sobol points is unbiased only under a random toroidal shift
        # of each pixel's set (torus cell areas are shift-invariant): on for it, off otherwise
        shift = self.estimator.cells == "periodic" and self.sampler.kind.low_discrepancy_positions
        if shift != self.sampler.toroidal_shift:
            object.__setattr__(self, "sampler", replace(self.sampler, toroidal_shift=shift))
        self.sampler.path_arguments((self.width, self.height))  # zsobol: does the image fit?
        # Auxiliary nuclei shape only the SPPP cells: drawn for the estimators that use them (a
        # settings object made by dataclasses.replace from another gets them back if needed).
        wanted = auxiliary_count(self.sampler.n, self.sampler.eps) if self.sampler.eps else 0
        n_aux = wanted if self.estimator.needs_aux else 0
        if n_aux != self.sampler.n_aux:
            object.__setattr__(self, "sampler", replace(self.sampler, n_aux=n_aux))
        if self.voronoi_backend not in VORONOI_BACKENDS:
            raise ParameterError(
                f"unknown Voronoi backend {self.voronoi_backend!r}; accepted: "
                f"{', '.join(VORONOI_BACKENDS)}"
            )

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
        check_image_memory(self.width, self.height)

    @property
    def device_cells(self) -> bool:
        """Whether the tiles' cells come from the device kernel (the SPPP cells of vor, vor_sn,
        fvor; pvor's torus cells)."""
        return self.voronoi_backend == "device" and self.estimator.device_sums

    @property
    def pixel_count(self) -> int:
        return self.width * self.height


@dataclass
class RenderStats:
    tiles: int = 0
    traced_samples: int = 0
    rays: int = 0
    device_seconds: float = 0.0  # sample sets + radiance + downloads, as the main thread waits
    host_seconds: float = 0.0  # estimator stage (Voronoi cells and sums)
    wall_seconds: float = 0.0
    redrawn_pixels: int = 0  # pixel redraws after a rejection (a pixel may count twice)
    eps_enlargements: int = 0  # redraw rounds that needed a wider eps
    unresolved_pixels: int = 0  # still rejected after every redraw: mc estimate of the last
    nonfinite_samples: int = 0  # NaN/Inf radiance, from the source's count or found on the host
    interrupted: bool = False


@dataclass
class RenderResult:
    film: Film
    stats: RenderStats
    settings: RenderSettings

    @property
    def image(self) -> np.ndarray:
        """(height, width, 3) float32 linear RGB, row 0 at the top (0 where not rendered)."""
        return self.film.image()


@dataclass
class TileSamples:
    """The device stage's output for a list of pixels: host sample sets and radiance, or
    (device cells) only the per-pixel sums of the Voronoi estimators."""

    pixels: np.ndarray  # (P,) uint32 global pixel indices
    redraws: np.ndarray  # (P,) uint32 redraw numbers
    sets: SampleSets | None  # None with sums
    radiance: np.ndarray | None  # (T, 3) float32, traced-sample order; None with sums
    rays: int
    source_nonfinite: int
    sums: DeviceSums | None = None  # per-pixel sums computed on the device

    @property
    def traced_count(self) -> int:
        return int(self.sums.counts.sum()) if self.sums is not None else len(self.radiance)


@dataclass
class TileEstimate:
    """The host stage's output: one estimate per pixel, with per-pixel flags."""

    pixels: np.ndarray
    redraws: np.ndarray
    estimates: np.ndarray  # (P, 3) float64, NaN where needs_redraw
    flagged: np.ndarray  # (P,) bool: a sample with non-finite radiance
    needs_redraw: np.ndarray  # (P,) bool
    nonfinite_samples: int
    seconds: float = 0.0  # time the estimate took (added to the stats on the main thread)


def pixels_per_tile(settings: RenderSettings) -> int:
    """Tile length in pixels: within the sample budget, and about TARGET_TILE_COUNT tiles. The
    budget counts every nucleus a pixel's cells hold: auxiliary ones, torus translates."""
    per_pixel = settings.sampler.n + settings.sampler.n_aux
    if settings.device_cells and settings.estimator.cells == "periodic":
        per_pixel = settings.sampler.n * TORUS_COPIES
    budget = max(1, settings.tile_samples // per_pixel)
    spread = max(MIN_TILE_PIXELS, math.ceil(settings.pixel_count / TARGET_TILE_COUNT))
    return min(budget, spread)


def plan_tiles(settings: RenderSettings) -> range:
    """The first pixel of each tile; tile k covers [starts[k], starts[k] + step) clipped to
    the image, in scanline order (pixel arrays are made one tile at a time)."""
    if settings.tile_samples <= 0:
        raise ParameterError(f"tile_samples must be positive, got {settings.tile_samples}")
    return range(0, settings.pixel_count, pixels_per_tile(settings))


def tile_pixels(settings: RenderSettings, start: int) -> np.ndarray:
    """Global indices of the tile starting at pixel `start`."""
    stop = min(start + pixels_per_tile(settings), settings.pixel_count)
    return np.arange(start, stop, dtype=np.uint32)


# --- the two stages ----------------------------------------------------------------------


def trace_tile(
    runtime: Runtime,
    source: RadianceSource,
    sampler: SamplerConfig,
    seed: int,
    pixels: np.ndarray,
    redraws: np.ndarray,
    device_cells: str | None = None,
) -> TileSamples:
    """Device stage: draw the pixels' sample sets and get their radiance. With device_cells
    ("sppp" or "periodic"), that kind of Voronoi cells and each pixel's weighted sums are
    queued after the tracing and only the sums come back (if the kernel left pixels undecided,
    the samples come back too and the host settles those pixels with Qhull); otherwise the
    sample sets and radiance are brought to the host."""
    device_sets = generate_sample_sets(
        runtime, sampler, seed, pixels, redraws, (source.width, source.height)
    )
    pending = source.trace(device_sets, seed)
    if device_cells:
        radiance = pending.to_device(runtime)
        if device_cells == "periodic":
            box = None
            sums = device_periodic_sums(runtime, device_sets, radiance.buffer)
        else:
            box = 0.5 + sampler.eps
            sums = device_sppp_sums(runtime, device_sets, radiance.buffer, box)
        if sums.fallback.any():
            values = pending.to_host().values.astype(np.float64)
            values[~np.isfinite(values).all(axis=1)] = 0.0  # as in the sums kernel
            host_sets = device_sets.to_host(runtime.queue)
            sums = settle_undecided(sums, host_sets, values, box, device_cells)
        return TileSamples(
            pixels, redraws, None, None, radiance.ray_count, radiance.device_nonfinite, sums=sums
        )
    sets = device_sets.to_host(runtime.queue)
    radiance = pending.to_host()
    return TileSamples(
        pixels, redraws, sets, radiance.values, radiance.ray_count, radiance.device_nonfinite
    )


def estimate_tile(
    settings: RenderSettings, tile: TileSamples, host_runtime: Runtime
) -> TileEstimate:
    """Host stage: one estimate per pixel. Samples with non-finite radiance are counted, enter
    the estimator as 0 and flag their pixel. host_runtime serves the image-level estimators,
    which draw their guard nuclei on the device."""
    if tile.sums is not None:
        return sums_estimate(settings, tile)
    values = tile.radiance.astype(np.float64)
    bad_samples = ~np.isfinite(values).all(axis=1)
    values[bad_samples] = 0.0
    flagged = np.bincount(tile.sets.pixel_index, bad_samples, len(tile.pixels)) > 0
    if settings.estimator.image_level:
        estimates, needs_redraw = image_estimates(settings, tile, values, host_runtime)
    else:
        estimates, needs_redraw = pixel_estimates(settings, tile.sets, values)
    return TileEstimate(
        tile.pixels,
        tile.redraws,
        estimates.reshape(len(tile.pixels), 3),
        flagged,
        needs_redraw,
        int(np.count_nonzero(bad_samples)) + tile.source_nonfinite,
    )


def sums_estimate(settings: RenderSettings, tile: TileSamples) -> TileEstimate:
    """Host stage of a tile whose Voronoi sums the device formed: the estimator's division.
    Non-finite radiance counted 0 in the sums and flags its pixel."""
    device = tile.sums
    estimates = settings.estimator.formula(device.sums)
    estimates = np.where(device.redraw[:, None], np.nan, estimates)
    return TileEstimate(
        tile.pixels,
        tile.redraws,
        estimates,
        device.nonfinite > 0,
        device.redraw,
        int(device.nonfinite.sum()) + tile.source_nonfinite,
    )


def pixel_estimates(
    settings: RenderSettings, sets: SampleSets, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(estimates, needs_redraw) of a per-pixel estimator (clrender.estimators.pixel)."""
    result = estimate(settings.estimator, sets, values)
    return result.estimates, result.needs_redraw


def image_estimates(
    settings: RenderSettings, tile: TileSamples, values: np.ndarray, host_runtime: Runtime
) -> tuple[np.ndarray, np.ndarray]:
    """(estimates, no redraws) of an image-level estimator (clrender.estimators.image)."""
    run = image.estimate_tile_image(
        host_runtime,
        settings.sampler,
        settings.seed,
        settings.width,
        settings.height,
        tile.pixels,
        tile.sets,
        values,
    )
    return settings.estimator.formula(run.sums), np.zeros(len(tile.pixels), bool)


def sibling_runtime(runtime: Runtime) -> Runtime:
    """A second context and queue on the same device, for device calls from the estimator
    thread: kernel objects (and their arguments) are never shared between threads."""
    context = cl.Context([runtime.device])
    return Runtime(runtime.device, context, cl.CommandQueue(context), runtime.local_size)


# --- the pipeline ------------------------------------------------------------------------


class TilePipeline:
    """Runs the stages over the tiles and records results on the film and in the stats."""

    def __init__(self, runtime: Runtime, source: RadianceSource, settings: RenderSettings):
        self.runtime = runtime
        self.source = source
        self.settings = settings
        self.film = Film(settings.width, settings.height)
        self.stats = RenderStats()
        self.in_flight: Future | None = None  # the estimate of the previous tile
        needs_device = settings.estimator.image_level and settings.overlap
        self.host_runtime = sibling_runtime(runtime) if needs_device else runtime

    def trace(
        self, pixels: np.ndarray, redraws: np.ndarray, sampler: SamplerConfig | None = None
    ) -> TileSamples:
        start = time.perf_counter()
        # Tiles use the device cells if configured; redraws go through Qhull in the driver.
        use_device = sampler is None and self.settings.device_cells
        device_cells = self.settings.estimator.cells if use_device else None
        sampler = sampler or self.settings.sampler
        tile = trace_tile(
            self.runtime, self.source, sampler, self.settings.seed, pixels, redraws, device_cells
        )
        self.stats.device_seconds += time.perf_counter() - start
        self.stats.traced_samples += tile.traced_count
        self.stats.rays += tile.rays
        return tile

    def estimate(self, tile: TileSamples) -> TileEstimate:
        """The host stage (on the worker thread when overlapping: it touches no stats)."""
        start = time.perf_counter()
        result = estimate_tile(self.settings, tile, self.host_runtime)
        result.seconds = time.perf_counter() - start
        return result

    def record(self, result: TileEstimate) -> None:
        """Store the accepted pixels of an estimate on the film."""
        self.stats.host_seconds += result.seconds
        self.stats.nonfinite_samples += result.nonfinite_samples
        accepted = ~result.needs_redraw
        self.film.record(
            result.pixels[accepted], result.estimates[accepted], result.flagged[accepted]
        )

    def finish(self, result: TileEstimate) -> None:
        """Record a tile and redraw its rejected pixels (device work: on the main thread)."""
        self.record(result)
        rejected = result.needs_redraw
        if rejected.any():
            self.redraw(result.pixels[rejected], result.redraws[rejected])

    def redraw(self, pixels: np.ndarray, redraws: np.ndarray) -> None:
        """Estimate rejected pixels again from new draws, through the bounded redraw driver.
        Non-finite radiance is left in: it makes the pixel's estimate non-finite, which the
        film flags."""
        start = time.perf_counter()
        device_before = self.stats.device_seconds
        draws = PixelRedraws(self, pixels, redraws)
        sampler = self.settings.sampler
        outcome = estimate_with_redraw(
            self.settings.estimator,
            draws.draw,
            len(pixels),
            sampler.n,
            eps=sampler.eps,
            alpha=sampler.alpha,
            redraws_before_enlarge=REDRAWS_BEFORE_ENLARGE,
            max_rounds=MAX_REDRAW_ROUNDS,
            on_exhausted="mc",
        )
        estimates = outcome.estimates[self.settings.estimator.name].reshape(len(pixels), 3)
        self.film.record(pixels, estimates, np.zeros(len(pixels), bool))
        self.stats.redrawn_pixels += outcome.stats.redraws + len(pixels)
        self.stats.eps_enlargements += outcome.stats.eps_enlargements
        self.stats.unresolved_pixels += outcome.stats.exhausted_pixels
        device = self.stats.device_seconds - device_before
        self.stats.host_seconds += time.perf_counter() - start - device

    def run(self, tiles: range, progress: ProgressCallback | None) -> None:
        """Trace tile k + 1 while tile k is estimated (on a worker thread if overlapping)."""
        self.stats.tiles = len(tiles)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="estimator") as pool:
            try:
                for start in tiles:
                    pixels = tile_pixels(self.settings, start)
                    tile = self.trace(pixels, np.zeros(len(pixels), np.uint32))
                    self.finish_in_flight(progress)
                    self.in_flight = self.start_estimate(pool, tile)
                self.finish_in_flight(progress)
            except KeyboardInterrupt:
                self.stats.interrupted = True
                if self.in_flight is not None and not self.in_flight.cancel():
                    self.record(self.in_flight.result())  # finished work is kept, not redrawn
                self.in_flight = None

    def finish_in_flight(self, progress: ProgressCallback | None) -> None:
        if self.in_flight is not None:
            done, self.in_flight = self.in_flight, None
            self.finish(done.result())
            self.report(progress)

    def start_estimate(self, pool: ThreadPoolExecutor, tile: TileSamples) -> Future:
        if self.settings.overlap:
            return pool.submit(self.estimate, tile)
        done: Future = Future()
        done.set_result(self.estimate(tile))
        return done

    def report(self, progress: ProgressCallback | None) -> None:
        if progress is not None:
            progress(self.film.rendered_count, self.film.pixel_count)


class PixelRedraws:
    """The draw of estimate_with_redraw for a list of rejected pixels: each draw increments the
    drawn pixels' redraw numbers and traces them like a tile."""

    def __init__(self, pipeline: TilePipeline, pixels: np.ndarray, redraws: np.ndarray):
        self.pipeline = pipeline
        self.pixels = pixels
        self.redraws = redraws.astype(np.uint32)

    def draw(self, ids: np.ndarray, eps: float) -> tuple[SampleSets, np.ndarray]:
        self.redraws[ids] += 1
        config = self.pipeline.settings.sampler
        sampler = make_sampler(config.name, config.n, config.alpha, eps, config.toroidal_shift)
        tile = self.pipeline.trace(self.pixels[ids], self.redraws[ids], sampler)
        self.pipeline.stats.nonfinite_samples += tile.source_nonfinite + int(
            np.count_nonzero(~np.isfinite(tile.radiance).all(axis=1))
        )
        return tile.sets, tile.radiance.astype(np.float64)


def render(
    runtime: Runtime,
    source: RadianceSource,
    settings: RenderSettings,
    progress: ProgressCallback | None = None,
) -> RenderResult:
    """Render the source's image with the settings' sampler and estimator."""
    if (source.width, source.height) != (settings.width, settings.height):
        raise ParameterError(
            f"the radiance source renders {source.width} x {source.height}, "
            f"the settings ask for {settings.width} x {settings.height}"
        )
    pipeline = TilePipeline(runtime, source, settings)
    tiles = plan_tiles(settings)
    start = time.perf_counter()
    pipeline.run(tiles, progress)
    pipeline.stats.wall_seconds = time.perf_counter() - start
    return RenderResult(pipeline.film, pipeline.stats, settings)
