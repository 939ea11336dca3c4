"""Voronoi cell areas of per-pixel SPPP sample sets, of sample sets on the torus and of sample
sets clipped to W, on the OpenCL device.

The device counterpart of clrender.estimators.qhull_cells.sppp_cells (SciPy Qhull on the host):
the same cells (each pixel's W nuclei among its W + auxiliary nuclei), the same CellAreas
result, so the estimators vor, vor_sn and fvor can use either. kernels/voronoi_cells.cl sorts
each pixel's nuclei into a grid; then, per traced nucleus, walks around its cell among the
nuclei of the 3 x 3 grid block around it (next neighbour = first crossing bisector; both ways
round at once, meeting half-way: two independent chains of steps) and clips
that polygon with any nucleus beyond the block that lies in a disc through the nucleus centred
on a vertex, which proves the cell exact; cells the walk cannot decide are clipped from a box
(see the kernel's header). stats.walked_cells counts the walked cells (about 99.98 % of random
SPPP cells).

Entry points:
  device_sppp_cells(runtime, sample_sets, box)     the positions already on the device
                                                   (clrender.sampling.DeviceSampleSets)
  device_sppp_cells_from_arrays(runtime, positions, offsets, aux, aux_offsets, box)
                                                   NumPy arrays, uploaded (tests, benchmarks)
  sppp_cells_backend(runtime)                      a drop-in for qhull_cells.sppp_cells
  device_sppp_sums(runtime, sample_sets, radiance, box)
                                                   the cells and then each pixel's sums of
                                                   vor, vor_sn and fvor (registry.PixelSums)
                                                   on the device: only the sums come back
  device_plain_sums(runtime, sample_sets, radiance, precision)
                                                   no cells: each pixel's sum f and sum f^2
                                                   alone (mc, mc_n, the variance layer)
  queue_device_sums(runtime, kind, sample_sets, radiance, box)
                                                   any of the sums above ("plain", "sppp",
                                                   "periodic", "clipped") queued with their
                                                   read-back, not waited for (PendingSums)
  device_periodic_cells_from_arrays(runtime, positions, offsets)
  device_periodic_sums(runtime, sample_sets, radiance)
                                                   the same for pvor's cells on the torus W
                                                   (qhull_cells.periodic_cells on the host)
  device_clipped_cells_from_arrays(runtime, positions, offsets)
  device_clipped_sums(runtime, sample_sets, radiance)
                                                   the same for cvor's cells clipped to W
                                                   (qhull_cells.clipped_cells on the host)

Torus cells: a first kernel writes each traced nucleus (wrapped into [-1/2, 1/2)^2) and its 8
translates by (i, j) in {-1, 0, 1}^2, and the translates play the auxiliary nuclei: a torus cell
lies in x + [-1/2, 1/2]^2, where the nearest copy of every nucleus is one of the 9, so every
traced cell is exact and bounded (no redraw). The translates are rounded to float32, which moves
them by up to 6e-8: areas agree with Qhull's on the exact translates to about 1e-7 (relative),
and a pixel's areas sum to 1 within that.

Cells clipped to W: a first kernel writes each traced nucleus and its 4 mirror images in W's
sides, and the mirrors play the auxiliary nuclei: the bisector of a nucleus and its mirror is
the side, and no mirror is nearer than its nucleus to a point of W, so every traced cell is
exactly its cell among the pixel's nuclei clipped to W, bounded. The mirrors are rounded to
float32 as the translates are, with the same effect on areas (a side moves by up to 3e-8).

Cells the kernel cannot decide (more than VORONOI_MAX_VERTICES vertices during clipping, a
bounded cell reaching beyond the start box, exactly collinear neighbours) flag their pixel;
those pixels are recomputed on the host with sppp_cells, so the result is always the exact
diagram (device_sppp_sums only flags them: its caller redoes them). stats.recomputed_pixels
counts them (and stats.qhull_calls the host calls they took).

Precision: the device sees float32 positions (the sampler's format); arrays are rounded to
float32 on upload, and host fallbacks use the rounded values, so every pixel's cells are those
of one point set. precision: "single" (all float32: areas within ~1e-5 relative of Qhull's on
the worst cells), "mixed" (float32 clipping, final vertices and areas in float64 from the input
coordinates: ~1e-14), "double" (all float64), "auto" (mixed where the device has cl_khr_fp64,
else single; CLRENDER_NO_FP64 set: single everywhere, to test that path on any device). On
PoCL mixed costs the same as single. Sums are accumulated in the area
precision, sample by sample in sample order (so they do not depend on the launch).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pyopencl as cl

from clrender.errors import DeviceError, ParameterError
from clrender.estimators.pixel import cell_sums
from clrender.estimators.qhull_cells import (
    CellAreas,
    TessellationStats,
    clipped_cells,
    periodic_cells,
    sppp_cells,
)
from clrender.estimators.registry import PixelSums
from clrender.runtime import Runtime, has_fp64, launch_global_size
from clrender.samples import SampleSets, segments
from clrender.sampling import DeviceSampleSets

KERNEL_FILE = "voronoi_cells.cl"
SUMS_KERNEL_FILE = "voronoi_sums.cl"
# kernels/voronoi_sums.cl: per-pixel values and flag bits
SUMS_PER_PIXEL = 14
MOMENTS_PER_PIXEL = 6  # pixel_moments: sum f, sum f^2
SUMS_REDRAW, SUMS_FALLBACK = 1, 2
STATUS_BOUNDED, STATUS_INSIDE, STATUS_FALLBACK, STATUS_WALKED = 1, 2, 4, 8
STATUS_WALKED_ONE_WAY = 16  # diagnostic: walked one way only (a tie stopped the two-way walk)
# Mean nuclei per grid cell of a pixel's neighbour grid, tuned with bench/device_voronoi_speed
# --variants GRID_SIDE=S: about 4.2 (a 3 x 3 block of ~38 nuclei) took 2-5 % less cell kernel CPU
# than 3.5 at SPPP n = 64, 256, 1024 and 4096. Finer grids cost more (the search beyond the
# smaller block runs more often), coarser ones too (each walk step scans a larger block).
GRID_NUCLEI_PER_CELL = 4.2
MAX_GRID_SIDE = 256
# The start box is the grid's square scaled by this factor: a bounded cell that reaches beyond it
# is recomputed on the host (rare: such cells belong to sets of a handful of nuclei).
START_BOX_SCALE = 8.0
MAX_VERTICES = 32
# auto: "mixed" where the device has cl_khr_fp64, else "single".
PRECISIONS = ("auto", "single", "mixed", "double")

# Reads some pixels' sample sets back to the host, for fallbacks.
FetchPixels = Callable[[np.ndarray], SampleSets]
# Torus cells: every traced nucleus has itself and 8 translates in the layout.
TORUS_COPIES = 9
# Clipped cells: every traced nucleus has itself and its 4 mirror images in W's sides.
MIRROR_COPIES = 5
# The tessellations the device computes, and their host reference for the pixels it leaves.
CELL_KINDS = ("sppp", "periodic", "clipped")
# Those whose every cell is bounded (no redraw: an unbounded one means the kernel failed).
BOUNDED_KINDS = ("periodic", "clipped")


def host_cells(kind: str, sets: SampleSets, box: float | None) -> CellAreas:
    """Qhull's cells of a kind for some pixels' sample sets (the device's fallback)."""
    if kind == "periodic":
        return periodic_cells(sets.traced, sets.offsets)
    if kind == "clipped":
        return clipped_cells(sets.traced, sets.offsets)
    return sppp_cells(sets.traced, sets.offsets, sets.aux, sets.aux_offsets, box)


@dataclass(frozen=True)
class CellLayout:
    """A launch's point layout: traced nuclei then auxiliary ones in one float2 buffer."""

    positions: cl.Buffer
    traced_offsets: np.ndarray  # (P + 1,) int64
    aux_offsets: np.ndarray  # (P + 1,) int64, relative to the first auxiliary nucleus
    half_extent: float  # the grid covers [-half_extent, half_extent]^2
    grid_side: int  # cells per side of every pixel's grid
    traced_extent: float  # the traced nuclei lie in [-traced_extent, traced_extent]^2
    kind: str = "sppp"  # "periodic": the auxiliary nuclei are torus translates; "clipped":
    # mirror images
    intensity: float = 1.0  # the sampler's n (PixelSums.n)
    # Image-level cells (built with VORONOI_INSIDE_DISCS): a cell with another nucleus this
    # close is not certified
    near_length: float = 0.0

    @property
    def pixel_count(self) -> int:
        return len(self.traced_offsets) - 1

    @property
    def traced_total(self) -> int:
        return int(self.traced_offsets[-1])


# ---------------------------------------------------------------------------------------------
# Public entry points


def device_sppp_cells(
    runtime: Runtime,
    sample_sets: DeviceSampleSets,
    box: float | None = None,
    precision: str = "auto",
) -> CellAreas:
    """Cells of the W nuclei of a launch's SPPP sample sets, from the positions on the device.

    box: also report which cells lie inside [-box, box]^2 (box = 1/2 + eps is W' for fvor).
    """
    layout = _sample_set_layout(sample_sets)

    def fetch(wanted: np.ndarray) -> SampleSets:
        # one read-back (fallbacks are rare)
        return sample_sets.to_host(runtime.queue).subset(wanted)

    return _cells(runtime, layout, box, precision, fetch)


def device_sppp_cells_from_arrays(
    runtime: Runtime,
    positions: np.ndarray,
    offsets: np.ndarray,
    aux: np.ndarray,
    aux_offsets: np.ndarray,
    box: float | None = None,
    precision: str = "auto",
) -> CellAreas:
    """The same cells from NumPy arrays (sppp_cells' arguments), uploaded as float32."""
    traced32, aux32 = _check_arrays(positions, offsets, aux, aux_offsets)
    offsets = np.asarray(offsets, np.int64)
    aux_offsets = np.asarray(aux_offsets, np.int64)
    flat = np.concatenate([traced32, aux32])
    extent = float(np.abs(flat).max()) if len(flat) else 0.5
    buffer, upload = runtime.upload_async(flat)  # held until _cells has read its results
    side = grid_side(len(flat), len(offsets) - 1)
    traced_extent = float(np.abs(traced32).max()) if len(traced32) else 0.0
    layout = CellLayout(buffer, offsets, aux_offsets, max(extent, 0.5), side, traced_extent)

    def fetch(wanted: np.ndarray) -> SampleSets:
        return SampleSets(traced32, offsets, 1.0, aux32, aux_offsets, 0.0).subset(wanted)

    cells = _cells(runtime, layout, box, precision, fetch)
    del upload
    return cells


def sppp_cells_backend(runtime: Runtime, precision: str = "auto") -> Callable[..., CellAreas]:
    """A drop-in for qhull_cells.sppp_cells (same arguments, same result) that runs on the
    device: lets the host estimators use device cells without other changes."""

    def cells(positions, offsets, aux, aux_offsets, box: float | None = None) -> CellAreas:
        return device_sppp_cells_from_arrays(
            runtime, positions, offsets, aux, aux_offsets, box, precision
        )

    return cells


def device_periodic_cells_from_arrays(
    runtime: Runtime, positions: np.ndarray, offsets: np.ndarray, precision: str = "auto"
) -> CellAreas:
    """Cells on the torus W of each pixel's nuclei (qhull_cells.periodic_cells' arguments),
    uploaded as float32; no inside-box flags."""
    return _copies_cells_from_arrays(runtime, positions, offsets, precision, "periodic")


def device_clipped_cells_from_arrays(
    runtime: Runtime, positions: np.ndarray, offsets: np.ndarray, precision: str = "auto"
) -> CellAreas:
    """Cells of each pixel's nuclei among themselves clipped to W (qhull_cells.clipped_cells'
    arguments), uploaded as float32; no inside-box flags."""
    return _copies_cells_from_arrays(runtime, positions, offsets, precision, "clipped")


def _copies_cells_from_arrays(
    runtime: Runtime, positions: np.ndarray, offsets: np.ndarray, precision: str, kind: str
) -> CellAreas:
    """Torus or clipped cells (kind) of arrays, whose positions must lie in W."""
    empty = np.zeros((0, 2))
    traced32, _ = _check_arrays(positions, offsets, empty, np.zeros(len(np.asarray(offsets))))
    outside = np.flatnonzero((np.abs(traced32) > 0.5).any(axis=1))
    if len(outside):  # the kernels wrap (mirror) W's points only, and the grid spans W's copies
        x, y = np.asarray(positions, np.float64).reshape(-1, 2)[outside[0]]
        what = "torus cells" if kind == "periodic" else "cells clipped to W"
        raise ParameterError(
            f"{what} need positions in W = [-1/2, 1/2]^2, got ({x:g}, {y:g}) at index {outside[0]}"
        )
    offsets = np.asarray(offsets, np.int64)
    buffer, upload = runtime.upload_async(traced32)
    defines = kernel_defines(runtime, precision)
    mean_count = len(traced32) / max(len(offsets) - 1, 1)
    layout = _copies_layout(runtime, buffer, offsets, mean_count, defines, kind)

    def fetch(wanted: np.ndarray) -> SampleSets:
        return SampleSets(traced32, offsets, 1.0).subset(wanted)

    cells = _cells(runtime, layout, None, precision, fetch)
    del upload
    return cells


@dataclass(frozen=True)
class DeviceSums:
    """Per-pixel results of device_sppp_sums: the sums, the pixels that must be redrawn (an
    unbounded cell) or recomputed on the host (a cell the kernel could not decide: their sums
    are not valid), each pixel's count of non-finite radiance samples (counted as 0 in the
    sums) and of traced samples."""

    sums: PixelSums
    redraw: np.ndarray  # (P,) bool
    fallback: np.ndarray  # (P,) bool
    nonfinite: np.ndarray  # (P,) int64

    @property
    def counts(self) -> np.ndarray:
        """(P,) traced samples per pixel."""
        return self.sums.counts


def device_sppp_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, box: float, precision: str = "auto"
) -> DeviceSums:
    """The PixelSums of vor, vor_sn and fvor for a launch's SPPP sample sets, with their cells
    and radiance ((T, 3) float32 device buffer, traced-sample order) kept on the device: only
    SUMS_PER_PIXEL values and a flag byte per pixel come back. box = 1/2 + eps (W')."""
    return queue_device_sums(runtime, "sppp", sample_sets, radiance, box, precision).result()


def device_periodic_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, precision: str = "auto"
) -> DeviceSums:
    """The PixelSums of pvor (area and weighted; no kept sums: NaN, as on the host) for a
    launch's sample sets, from their cells on the torus W, all on the device. No pixel is
    redrawn: a cell the kernel leaves undecided or unbounded flags its pixel as fallback."""
    return queue_device_sums(runtime, "periodic", sample_sets, radiance, None, precision).result()


def device_clipped_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, precision: str = "auto"
) -> DeviceSums:
    """The PixelSums of cvor (area and weighted; no kept sums: NaN, as on the host) for a
    launch's sample sets, from their cells clipped to W, all on the device; as
    device_periodic_sums otherwise."""
    return queue_device_sums(runtime, "clipped", sample_sets, radiance, None, precision).result()


class PendingSums:
    """Device sums queued with the reads of their results, not waited for: result() waits for
    the reads (once) and makes the DeviceSums. It holds the host arrays the reads fill (and
    their events: dropping one waits for its read)."""

    def __init__(self, make: Callable[[], DeviceSums], events: Sequence[cl.Event] = ()):
        self._make: Callable[[], DeviceSums] | None = make
        self._events = [event for event in events if event is not None]
        self._result: DeviceSums | None = None

    def result(self) -> DeviceSums:
        if self._result is None:
            if self._events:
                cl.wait_for_events(self._events)
            self._result, self._make, self._events = self._make(), None, []
        return self._result


def queue_device_sums(
    runtime: Runtime,
    kind: str,
    sample_sets: DeviceSampleSets,
    radiance,
    box: float | None = None,
    precision: str = "auto",
) -> PendingSums:
    """Queue a launch's per-pixel sums of one kind ("plain": device_plain_sums; "sppp" with
    box: device_sppp_sums; "periodic", "clipped") and their read-back, without a wait: the
    in-order queue may take the next launch's work before PendingSums.result() is asked."""
    if kind == "plain":
        return _plain_sums(runtime, sample_sets, radiance, precision)
    if kind == "sppp":
        layout = _sample_set_layout(sample_sets)
        return _device_sums(runtime, layout, radiance, box, precision)
    if kind in BOUNDED_KINDS:
        return _copies_sums(runtime, sample_sets, radiance, precision, kind)
    raise ParameterError(
        f"unknown kind of device sums {kind!r}; accepted: plain, {', '.join(CELL_KINDS)}"
    )


def _copies_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, precision: str, kind: str
) -> PendingSums:
    """device_periodic_sums or device_clipped_sums (kind)."""
    defines = kernel_defines(runtime, precision)
    layout = _copies_layout(
        runtime,
        sample_sets.positions,
        np.asarray(sample_sets.traced_offsets, np.int64),
        sample_sets.config.n,
        defines,
        kind,
    )
    pending = _device_sums(runtime, layout, radiance, None, precision)

    def make() -> DeviceSums:
        device = pending.result()
        nan = np.full(layout.pixel_count, np.nan)
        sums = replace(device.sums, kept_area=nan, kept_weighted=np.full((len(nan), 3), np.nan))
        fallback = device.fallback | device.redraw
        return replace(device, sums=sums, redraw=np.zeros_like(fallback), fallback=fallback)

    return PendingSums(make)


def device_plain_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, precision: str = "auto"
) -> DeviceSums:
    """Each pixel's sum f and sum f^2 (PixelSums value and square) and non-finite count, from a
    launch's radiance ((T, 3) float32 device buffer, traced-sample order) left on the device:
    the plain sums of device_sppp_sums, the same arithmetic (bit-identical), without cells. No
    pixel is redrawn or recomputed."""
    return _plain_sums(runtime, sample_sets, radiance, precision).result()


def _plain_sums(
    runtime: Runtime, sample_sets: DeviceSampleSets, radiance, precision: str
) -> PendingSums:
    """device_plain_sums, queued (queue_device_sums)."""
    pixels = sample_sets.pixel_count
    defines, real = precision_setup(runtime, precision)
    moments = np.zeros((pixels, MOMENTS_PER_PIXEL), real)
    nonfinite = np.zeros(pixels, np.uint32)
    if sample_sets.traced_total and pixels:
        moments_buf = runtime.allocate(moments.nbytes)
        nonfinite_buf = runtime.allocate(nonfinite.nbytes)
        kernel = runtime.kernel(SUMS_KERNEL_FILE, "pixel_moments", defines)
        launch_per_pixel(
            runtime,
            kernel,
            pixels,
            sample_sets.offsets_buffer,
            radiance,
            moments_buf,
            nonfinite_buf,
        )
        events = [
            cl.enqueue_copy(runtime.queue, moments, moments_buf, is_blocking=False),
            cl.enqueue_copy(runtime.queue, nonfinite, nonfinite_buf, is_blocking=False),
        ]
    counts = np.diff(np.asarray(sample_sets.traced_offsets, np.int64))
    n = sample_sets.config.n

    def make() -> DeviceSums:
        values = moments.astype(np.float64)
        sums = PixelSums(counts, n, value=values[:, 0:3], square=values[:, 3:6])
        none = np.zeros(pixels, bool)
        return DeviceSums(sums, none, none.copy(), nonfinite.astype(np.int64))

    return PendingSums(make, events if sample_sets.traced_total and pixels else ())


def _device_sums(
    runtime: Runtime, layout: CellLayout, radiance, box: float | None, precision: str
) -> PendingSums:
    """Cells and per-pixel sums of a layout on the device (see device_sppp_sums), queued."""
    pixels = layout.pixel_count
    defines, real = precision_setup(runtime, precision)
    sums = np.zeros((pixels, SUMS_PER_PIXEL), real)
    flags = np.zeros(pixels, np.uint8)
    nonfinite = np.zeros(pixels, np.uint32)
    events = []
    if layout.traced_total and pixels:
        areas, status, offsets, upload = _enqueue_cells(
            runtime, layout, box, defines, np.dtype(real).itemsize
        )
        sums_buf, flags_buf = runtime.allocate(sums.nbytes), runtime.allocate(flags.nbytes)
        nonfinite_buf = runtime.allocate(nonfinite.nbytes)
        reduce = runtime.kernel(SUMS_KERNEL_FILE, "voronoi_pixel_sums", defines)
        launch_per_pixel(
            runtime,
            reduce,
            pixels,
            offsets,
            radiance,
            areas,
            status,
            sums_buf,
            flags_buf,
            nonfinite_buf,
        )
        events = [  # the upload's event is held until the reads are waited for
            upload,
            cl.enqueue_copy(runtime.queue, sums, sums_buf, is_blocking=False),
            cl.enqueue_copy(runtime.queue, flags, flags_buf, is_blocking=False),
            cl.enqueue_copy(runtime.queue, nonfinite, nonfinite_buf, is_blocking=False),
        ]

    def make() -> DeviceSums:
        values = sums.astype(np.float64)
        pixel_sums = PixelSums(
            np.diff(layout.traced_offsets),
            layout.intensity,
            area=values[:, 0],
            weighted=values[:, 1:4],
            kept_area=values[:, 4],
            kept_weighted=values[:, 5:8],
            value=values[:, 8:11],
            square=values[:, 11:14],
        )
        return DeviceSums(
            pixel_sums,
            (flags & SUMS_REDRAW) != 0,
            (flags & SUMS_FALLBACK) != 0,
            nonfinite.astype(np.int64),
        )

    return PendingSums(make, events)


def settle_undecided(
    device: DeviceSums,
    host_sets: SampleSets,
    values: np.ndarray,
    box: float | None,
    kind: str = "sppp",
) -> DeviceSums:
    """device with the pixels it flagged as undecided (device.fallback) settled on the host:
    their cells (of the kind: "sppp", "periodic" or "clipped") by Qhull from the host copy of
    the sample sets (float32 as on the device), their sums from `values` ((T, C), the traced
    samples' radiance with non-finite rows zeroed), their redraw flags from the cells."""
    pixels = np.flatnonzero(device.fallback)
    subset = host_sets.subset(pixels)
    cells = host_cells(kind, subset, box)
    settled = cell_sums(subset, values[segments(host_sets.offsets, pixels)[0]], cells, kept=True)
    merged = replace(device.sums)
    for name in ("area", "weighted", "kept_area", "kept_weighted"):
        column = np.array(getattr(device.sums, name))
        column[pixels] = getattr(settled, name)
        setattr(merged, name, column)
    redraw = device.redraw.copy()
    redraw[pixels] = np.bincount(subset.pixel_index, ~cells.bounded, len(pixels)) > 0
    return replace(device, sums=merged, redraw=redraw, fallback=np.zeros_like(device.fallback))


def kernel_defines(runtime: Runtime, precision: str) -> dict[str, object]:
    """Build options for the precision; DeviceError if the device has no double support."""
    return _defines(resolve_precision(runtime, precision))


def _defines(precision: str) -> dict[str, object]:
    """Build options of a resolved precision ("single", "mixed" or "double")."""
    defines: dict[str, object] = {"VORONOI_MAX_VERTICES": MAX_VERTICES}
    if precision == "mixed":
        defines["VORONOI_AREA_DOUBLE"] = True
    elif precision == "double":
        defines["VORONOI_DOUBLE"] = True
    return defines


def resolve_precision(runtime: Runtime, precision: str) -> str:
    """ "single", "mixed" or "double"; DeviceError if double is asked of a device without it."""
    if precision not in PRECISIONS:
        raise ParameterError(f"unknown precision {precision!r}; accepted: {', '.join(PRECISIONS)}")
    fp64 = has_fp64(runtime.device)
    if precision == "auto":
        return "mixed" if fp64 else "single"
    if precision != "single" and not fp64:
        raise DeviceError(
            f"device {runtime.describe()} has no cl_khr_fp64 (double precision), "
            f"which precision={precision!r} needs: use 'single' or 'auto'"
        )
    return precision


def grid_side(layout_points: int, pixels: int) -> int:
    """Cells per side of each pixel's neighbour grid, from the mean nuclei per pixel."""
    mean = layout_points / max(pixels, 1)
    side = round(math.sqrt(mean / GRID_NUCLEI_PER_CELL))
    return int(min(max(side, 1), MAX_GRID_SIDE))


# ---------------------------------------------------------------------------------------------
# Launch and host fallback


def _sample_set_layout(sample_sets: DeviceSampleSets) -> CellLayout:
    """The layout of a launch's SPPP sample sets (n_aux auxiliary nuclei per pixel). The grid
    follows the sampler, not the launch: a pixel's cells are then bit-identical whatever tile
    it is computed in."""
    config = sample_sets.config
    aux_offsets = np.arange(sample_sets.pixel_count + 1, dtype=np.int64) * config.n_aux
    return CellLayout(
        sample_sets.positions,
        np.asarray(sample_sets.traced_offsets, np.int64),
        aux_offsets,
        0.5 + config.eps,
        grid_side(config.n + config.n_aux, 1),
        0.5,  # traced samples lie in W
        intensity=config.n,
    )


def _copies_layout(
    runtime: Runtime,
    positions: cl.Buffer,
    traced_offsets: np.ndarray,
    mean_count: float,
    defines: dict[str, object],
    kind: str,
) -> CellLayout:
    """Queue the copies of a launch's traced nuclei that make their cells those of the kind:
    torus translates ("periodic", voronoi_periodic_copies: the wrapped nuclei, then 8 translates
    each, pixel p's from 8 traced_offsets[p]) or mirror images ("clipped",
    voronoi_mirror_copies: the nuclei, then 4 mirrors each); their layout. Either way the copies
    lie in W's 3 x 3 neighbourhood at the density of the nuclei in W: mean_count (the sampler's
    n) sizes the grid, so a pixel's cells do not depend on the launch."""
    copies = TORUS_COPIES if kind == "periodic" else MIRROR_COPIES
    traced = int(traced_offsets[-1])
    nuclei = runtime.allocate(8 * copies * max(traced, 1))
    if traced:
        name = "voronoi_periodic_copies" if kind == "periodic" else "voronoi_mirror_copies"
        runtime.launch_1d(
            runtime.kernel(KERNEL_FILE, name, defines),
            traced,
            np.uint32(traced),
            positions,
            nuclei,
        )
    return CellLayout(
        nuclei,
        traced_offsets,
        (copies - 1) * traced_offsets,
        1.5,
        grid_side(TORUS_COPIES * mean_count, 1),
        0.5,  # in W (wrapped into [-1/2, 1/2)^2 on the torus)
        kind=kind,
        intensity=mean_count,
    )


def precision_setup(runtime: Runtime, precision: str) -> tuple[dict[str, object], type]:
    """(build options, NumPy type of the areas) for the precision."""
    resolved = resolve_precision(runtime, precision)
    return _defines(resolved), np.float32 if resolved == "single" else np.float64


def _cells(
    runtime: Runtime, layout: CellLayout, box: float | None, precision: str, fetch: FetchPixels
) -> CellAreas:
    defines, real = precision_setup(runtime, precision)
    areas, status = launch_cell_kernels(runtime, layout, box, defines, real)
    bounded = (status & STATUS_BOUNDED) != 0
    cells = CellAreas(
        np.where(bounded, areas.astype(np.float64), np.nan),
        bounded,
        (status & STATUS_INSIDE) != 0 if box is not None else None,
        TessellationStats(walked_cells=int(((status & STATUS_WALKED) != 0).sum())),
    )
    undecided = (status & STATUS_FALLBACK) != 0
    if layout.kind in BOUNDED_KINDS:
        undecided |= ~bounded  # never expected: every torus or clipped cell is bounded
    fallback = _fallback_pixels(layout.traced_offsets, undecided)
    if fallback.size:
        _recompute_on_host(cells, layout, fallback, fetch, box)
    return cells


def launch_cell_kernels(
    runtime: Runtime, layout: CellLayout, box: float | None, defines: dict[str, object], real: type
) -> tuple[np.ndarray, np.ndarray]:
    """Run both kernels; (areas, status) of every traced nucleus."""
    traced = layout.traced_total
    areas = np.empty(traced, real)
    status = np.empty(traced, np.uint8)
    if traced == 0:
        return areas, status
    areas_buf, status_buf, _, upload = _enqueue_cells(runtime, layout, box, defines, areas.itemsize)
    # One wait: the in-order queue finishes the upload and the first copy before the second
    # (the first copy's event is kept until then: dropping it unfinished waits, holding the GIL)
    first_copy = cl.enqueue_copy(runtime.queue, areas, areas_buf, is_blocking=False)
    cl.enqueue_copy(runtime.queue, status, status_buf)
    del upload, first_copy
    return areas, status


def _enqueue_cells(
    runtime: Runtime,
    layout: CellLayout,
    box: float | None,
    defines: dict[str, object],
    area_bytes: int,
):
    """Queue the grid and cell kernels of a non-empty layout; (areas, status, offsets) device
    buffers (offsets: the traced offsets, then the auxiliary ones) and the offsets' upload
    event, to hold until a blocking read (Runtime.upload_async)."""
    traced, pixels = layout.traced_total, layout.pixel_count
    total = traced + int(layout.aux_offsets[-1])
    side = layout.grid_side
    if total >= 2**32 or pixels * (side * side + 1) >= 2**32:  # also bounds the work-items
        raise ParameterError("too many nuclei in one launch (over 2^32): use smaller tiles")
    # Traced then auxiliary offsets in one buffer (each blocking upload costs a round trip)
    offsets, upload = runtime.upload_async(
        np.concatenate([layout.traced_offsets, layout.aux_offsets]).astype(np.uint32)
    )
    cell_start = runtime.allocate(4 * pixels * (side * side + 1))
    sorted_points = runtime.allocate(8 * total)
    sorted_index = runtime.allocate(4 * total)
    cell_of = runtime.allocate(4 * total)  # the grid build's scratch
    areas_buf = runtime.allocate(area_bytes * traced)
    status_buf = runtime.allocate(traced)
    # Undecided until a work-item decides: a nucleus no work-item reached costs a host
    # recomputation, never a stale area
    if traced:
        cl.enqueue_fill_buffer(runtime.queue, status_buf, np.uint8(STATUS_FALLBACK), 0, traced)
    half = np.float32(layout.half_extent)

    build = runtime.kernel(KERNEL_FILE, "voronoi_build_grid", defines)
    launch_per_pixel(
        runtime,
        build,
        pixels,
        np.uint32(traced),
        np.int32(side),
        half,
        layout.positions,
        offsets,
        cell_start,
        sorted_points,
        sorted_index,
        cell_of,
    )
    compute = runtime.kernel(KERNEL_FILE, "voronoi_cell_areas", defines)
    span_first, span_side = traced_span(layout)
    runtime.launch_1d(
        compute,
        pixels * span_side * span_side,
        np.uint32(pixels),
        np.uint32(traced),
        np.int32(side),
        np.int32(span_first),
        np.int32(span_side),
        half,
        np.float32(layout.half_extent * START_BOX_SCALE),
        np.float32(box if box is not None else np.inf),
        np.float32(layout.near_length),
        offsets,
        cell_start,
        sorted_points,
        sorted_index,
        areas_buf,
        status_buf,
    )
    return areas_buf, status_buf, offsets, upload


def pixel_stride(runtime: Runtime, kernel: cl.Kernel, pixels: int) -> int:
    """The work-items between two pixels of a kernel that runs one work-item per pixel: on a
    CPU device, so that the pixels fill the whole padded launch (kernels/voronoi_common.h
    Voronoi_SpreadPixel says why; the launch is then pixels x stride work-items, padded to a
    whole work-group); elsewhere 1 (a GPU would run mostly empty SIMD groups)."""
    if not runtime.device.type & cl.device_type.CPU:
        return 1
    padded = launch_global_size(pixels, runtime.kernel_local_size(kernel))
    return max(1, -(-padded // max(pixels, 1)))


def launch_per_pixel(runtime: Runtime, kernel: cl.Kernel, pixels: int, *args) -> cl.Event:
    """Launch a one-work-item-per-pixel kernel (arguments: pixel_count, pixel_stride, then
    args) with its pixels spread over the launch."""
    stride = pixel_stride(runtime, kernel, pixels)
    return runtime.launch_1d(kernel, pixels * stride, np.uint32(pixels), np.uint32(stride), *args)


def traced_span(layout: CellLayout) -> tuple[int, int]:
    """(first, count): the grid rows (and columns) that can hold traced nuclei, the same in x
    and y. A nucleus at x goes to grid column floor((x + half_extent) grid_side / (2
    half_extent)), clamped (VoronoiGrid_Index), which rises with x: the columns of -traced_extent
    and +traced_extent bound those of the traced nuclei. Both ends are widened by 1e-4 cell,
    far more than the float rounding of the device's index."""
    side, half = layout.grid_side, layout.half_extent
    cell = 2.0 * half / side
    reach = layout.traced_extent + 1e-4 * cell

    def index(x: float) -> int:
        return min(max(math.floor((x + half) / cell), 0), side - 1)

    first = index(-reach)
    return first, index(reach) - first + 1


def _fallback_pixels(traced_offsets: np.ndarray, flagged: np.ndarray) -> np.ndarray:
    if not flagged.any():
        return np.zeros(0, np.int64)
    owner = np.repeat(np.arange(len(traced_offsets) - 1), np.diff(traced_offsets))
    return np.unique(owner[flagged])


def _recompute_on_host(
    cells: CellAreas, layout: CellLayout, pixels: np.ndarray, fetch: FetchPixels, box: float | None
) -> None:
    """Exact cells of the given pixels from Qhull, written over the device's."""
    redo = host_cells(layout.kind, fetch(pixels), box)
    index = segments(layout.traced_offsets, pixels)[0]
    cells.areas[index] = redo.areas
    cells.bounded[index] = redo.bounded
    if cells.inside_box is not None:
        cells.inside_box[index] = redo.inside_box
    cells.stats.add(redo.stats)
    cells.stats.recomputed_pixels = redo.stats.recomputed_pixels + len(pixels)


def _check_arrays(positions, offsets, aux, aux_offsets) -> tuple[np.ndarray, np.ndarray]:
    """float32 (T, 2) and (A, 2) copies; ParameterError on bad shapes, offsets or values."""
    traced = np.ascontiguousarray(positions, np.float32).reshape(-1, 2)
    aux32 = np.ascontiguousarray(aux, np.float32).reshape(-1, 2)
    offsets, aux_offsets = np.asarray(offsets), np.asarray(aux_offsets)
    for name, off, total in (
        ("offsets", offsets, len(traced)),
        ("aux_offsets", aux_offsets, len(aux32)),
    ):
        if (
            off.ndim != 1
            or len(off) < 1
            or off[0] != 0
            or off[-1] != total
            or (np.diff(off) < 0).any()
        ):
            raise ParameterError(f"{name} must rise from 0 to {total}")
    if len(offsets) != len(aux_offsets):
        raise ParameterError("offsets and aux_offsets must describe the same pixels")
    if not (np.isfinite(traced).all() and np.isfinite(aux32).all()):
        raise ParameterError("positions must be finite")
    return traced, aux32
