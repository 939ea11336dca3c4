"""The render pipeline, tile by tile:

    sample sets (kernels/sampling.cl, clrender.sampling.generate_sample_sets)
      -> radiance of each traced sample (a RadianceSource: the path tracer or an analytic image)
      -> one estimate per pixel (clrender.estimators, on the host: Voronoi cells by Qhull)
      -> film (clrender.film)

A tile is a run of consecutive pixels (scanline order) holding about `tile_samples` samples,
so memory stays bounded whatever the resolution and spp. With `overlap`, the host estimator of
tile k runs on a worker thread while the main thread has the device draw and trace tile k + 1;
pyopencl, NumPy and Qhull release the GIL in their long calls, so wall time approaches
max(device, host) instead of their sum.

Rejections: a pixel whose SPPP tessellation leaves a nucleus of W with an unbounded cell is
redrawn: its sample set is generated again with the redraw number incremented (the same
launch path as a tile, on a list of pixels), traced and estimated again, up to MAX_REDRAWS
times; a pixel still rejected after that is flagged. Non-finite radiance: see clrender.film.

Determinism: every random number depends on (seed, pixel, sample, dimension, redraw) only, and
the estimator of a pixel sees only that pixel's samples, so the image is bit-identical
whatever the tile size and with or without overlap.

Ctrl-C (KeyboardInterrupt) stops the render between device calls: the tile whose estimates
are in flight is finished (without its redraws), and `render` returns the partial film with
`stats.interrupted` set.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from clrender.errors import ParameterError
from clrender.estimators import PixelSamples, estimate, estimator_info
from clrender.film import Film
from clrender.radiance import RadianceSource
from clrender.runtime import Runtime
from clrender.sampling import HostSampleSets, SamplerConfig, generate_sample_sets

DEFAULT_TILE_SAMPLES = 4_000_000
# Split even small images into this many tiles (when tiles of MIN_TILE_PIXELS allow it), so
# that the device and the host stage have something to overlap and progress moves.
TARGET_TILE_COUNT = 16
MIN_TILE_PIXELS = 256
# A pixel is redrawn at most this many times; the paper bounds one draw's rejection
# probability by alpha = 1e-3, so a pixel failing 4 draws in a row means something is off.
MAX_REDRAWS = 4

ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class RenderSettings:
    width: int
    height: int
    sampler: SamplerConfig
    estimator: str
    seed: int = 0
    tile_samples: int = DEFAULT_TILE_SAMPLES
    overlap: bool = True

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
    unresolved_pixels: int = 0  # still rejected after MAX_REDRAWS redraws: flagged
    nonfinite_samples: int = 0  # NaN/Inf radiance, from the source's count or found on the host
    interrupted: bool = False


@dataclass
class RenderResult:
    film: Film
    stats: RenderStats
    settings: RenderSettings


@dataclass
class TileSamples:
    """The device stage's output for a list of pixels: host sample sets and radiance."""

    pixels: np.ndarray  # (P,) uint32 global pixel indices
    redraws: np.ndarray  # (P,) uint32 redraw numbers
    sets: HostSampleSets
    radiance: np.ndarray  # (T, 3) float32, traced-sample order
    rays: int
    source_nonfinite: int


@dataclass
class TileEstimate:
    """The host stage's output: one estimate per pixel, with per-pixel flags."""

    pixels: np.ndarray
    redraws: np.ndarray
    estimates: np.ndarray  # (P, 3) float64, NaN where needs_redraw
    flagged: np.ndarray  # (P,) bool: a sample with non-finite radiance
    needs_redraw: np.ndarray  # (P,) bool
    nonfinite_samples: int


def check_compatible(estimator: str, sampler: str) -> None:
    """A one-line error if the estimator needs auxiliary nuclei the sampler does not draw."""
    info = estimator_info(estimator)
    if info.needs_aux and sampler != "sppp":
        raise ParameterError(
            f"estimator {estimator!r} needs the auxiliary nuclei of the sppp sampler, and the "
            f"{sampler!r} sampler draws none: use --sampler sppp, or an estimator that works "
            "with any sampler (mc, mc_n, cvor, pvor)"
        )


def pixels_per_tile(settings: RenderSettings) -> int:
    """Tile length in pixels: within the sample budget, and about TARGET_TILE_COUNT tiles."""
    per_pixel = settings.sampler.n + settings.sampler.n_aux
    budget = max(1, settings.tile_samples // per_pixel)
    spread = max(MIN_TILE_PIXELS, math.ceil(settings.pixel_count / TARGET_TILE_COUNT))
    return min(budget, spread)


def plan_tiles(settings: RenderSettings) -> list[np.ndarray]:
    """Consecutive runs of global pixel indices covering the image."""
    if settings.tile_samples <= 0:
        raise ParameterError(f"tile_samples must be positive, got {settings.tile_samples}")
    step = pixels_per_tile(settings)
    return [
        np.arange(start, min(start + step, settings.pixel_count), dtype=np.uint32)
        for start in range(0, settings.pixel_count, step)
    ]


# --- the two stages ----------------------------------------------------------------------


def trace_tile(
    runtime: Runtime,
    source: RadianceSource,
    settings: RenderSettings,
    pixels: np.ndarray,
    redraws: np.ndarray,
) -> TileSamples:
    """Device stage: draw the pixels' sample sets, get their radiance, bring both to the host."""
    device_sets = generate_sample_sets(runtime, settings.sampler, settings.seed, pixels, redraws)
    pending = source.trace(device_sets, settings.seed)
    sets = device_sets.to_host(runtime.queue)
    radiance = pending.to_host()
    return TileSamples(
        pixels, redraws, sets, radiance.values, radiance.ray_count, radiance.device_nonfinite
    )


def estimate_tile(settings: RenderSettings, tile: TileSamples) -> TileEstimate:
    """Host stage: one estimate per pixel. Samples with non-finite radiance are counted, enter
    the estimator as 0 and flag their pixel."""
    values = tile.radiance.astype(np.float64)
    bad_samples = ~np.isfinite(values).all(axis=1)
    values[bad_samples] = 0.0
    counts = tile.sets.counts()
    owner = np.repeat(np.arange(len(tile.pixels)), counts)
    flagged = np.bincount(owner, bad_samples, len(tile.pixels)) > 0
    sets = tile.sets
    samples = PixelSamples(
        sets.traced.astype(np.float64),
        values,
        sets.offsets,
        float(settings.sampler.n),
        sets.aux.astype(np.float64),
        sets.aux_offsets,
        settings.sampler.eps,
    )
    result = estimate(settings.estimator, samples)
    return TileEstimate(
        tile.pixels,
        tile.redraws,
        result.estimates.reshape(len(tile.pixels), 3),
        flagged,
        result.needs_redraw,
        int(np.count_nonzero(bad_samples)) + tile.source_nonfinite,
    )


# --- the pipeline ------------------------------------------------------------------------


class TilePipeline:
    """Runs the stages over the tiles and records results on the film and in the stats."""

    def __init__(self, runtime: Runtime, source: RadianceSource, settings: RenderSettings):
        self.runtime = runtime
        self.source = source
        self.settings = settings
        self.film = Film(settings.width, settings.height)
        self.stats = RenderStats()

    def trace(self, pixels: np.ndarray, redraws: np.ndarray) -> TileSamples:
        start = time.perf_counter()
        tile = trace_tile(self.runtime, self.source, self.settings, pixels, redraws)
        self.stats.device_seconds += time.perf_counter() - start
        self.stats.traced_samples += len(tile.radiance)
        self.stats.rays += tile.rays
        return tile

    def estimate(self, tile: TileSamples) -> TileEstimate:
        start = time.perf_counter()
        result = estimate_tile(self.settings, tile)
        self.stats.host_seconds += time.perf_counter() - start
        return result

    def record(self, result: TileEstimate) -> None:
        """Store the accepted pixels of an estimate on the film."""
        self.stats.nonfinite_samples += result.nonfinite_samples
        accepted = ~result.needs_redraw
        self.film.record(
            result.pixels[accepted], result.estimates[accepted], result.flagged[accepted]
        )

    def finish(self, result: TileEstimate) -> None:
        """Record a tile, redrawing its rejected pixels (on the calling thread) until accepted
        or MAX_REDRAWS is reached; pixels still rejected are flagged."""
        self.record(result)
        rejected = result.needs_redraw
        while rejected.any() and int(result.redraws[rejected].max()) < MAX_REDRAWS:
            pixels, redraws = result.pixels[rejected], result.redraws[rejected] + 1
            self.stats.redrawn_pixels += len(pixels)
            result = self.estimate(self.trace(pixels, redraws))
            self.record(result)
            rejected = result.needs_redraw
        if rejected.any():
            self.stats.unresolved_pixels += int(rejected.sum())
            pixels = result.pixels[rejected]
            self.film.record(pixels, np.full((len(pixels), 3), np.nan), np.ones(len(pixels), bool))

    def run(self, tiles: list[np.ndarray], progress: ProgressCallback | None) -> None:
        """Trace tile k + 1 while tile k is estimated (on a worker thread if overlapping)."""
        self.stats.tiles = len(tiles)
        in_flight: Future | None = None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="estimator") as pool:
            try:
                for pixels in tiles:
                    tile = self.trace(pixels, np.zeros(len(pixels), np.uint32))
                    if in_flight is not None:
                        self.finish(in_flight.result())
                        self.report(progress)
                    in_flight = self.start_estimate(pool, tile)
                if in_flight is not None:
                    self.finish(in_flight.result())
                    self.report(progress)
            except KeyboardInterrupt:
                self.stats.interrupted = True
                if in_flight is not None and not in_flight.cancel():
                    self.record(in_flight.result())  # finished work is kept, redraws are not

    def start_estimate(self, pool: ThreadPoolExecutor, tile: TileSamples) -> Future:
        if self.settings.overlap:
            return pool.submit(self.estimate, tile)
        done: Future = Future()
        done.set_result(self.estimate(tile))
        return done

    def report(self, progress: ProgressCallback | None) -> None:
        if progress is not None:
            progress(self.film.rendered_count, self.film.pixel_count)


def render(
    runtime: Runtime,
    source: RadianceSource,
    settings: RenderSettings,
    progress: ProgressCallback | None = None,
) -> RenderResult:
    """Render the source's image with the given sampler and estimator."""
    check_compatible(settings.estimator, settings.sampler.name)
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
