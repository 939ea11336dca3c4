"""Image-level Voronoi cells (ivor, ivor_sn) on the OpenCL device.

clrender.estimators.image tessellates blocks of pixels with Qhull on the host (about 0.6 ms a
pixel at n = 64). Here every pixel is its own small diagram instead, computed by the SPPP cell
kernels (kernels/voronoi_cells.cl): its traced nuclei, with the nuclei of the plane pixels
within `ring` pixels of it as auxiliary nuclei, all relative to the pixel's centre and rounded
to float32 as the kernels take them (within 2^-24 (1/2 + ring) pixel of the image coordinates:
6e-8 for the pixel's own, up to 2.7e-7 at ring 4). A pixel without nuclei gets no diagram.

Exactness. A traced nucleus's cell among these nuclei is its cell in the whole process when
every vertex's disc through the nucleus (the Delaunay circumdiscs of the cell's triangles) lies
in the known square [-1/2 - ring, 1/2 + ring]^2, which holds every nucleus of the process
there: a nucleus outside it is outside every such disc, so it cuts nothing. The kernel tests
that (VORONOI_INSIDE_DISCS) with a margin of CERTIFY_MARGIN pixel for the rounding of the
vertices (a margin only sends more pixels to the host). The host's rule is the same
(image._areas_and_flags, with the block grown by delta instead of the pixel by ring). ring is
ceil(delta), at least 1, for delta the host's guard distance 2 eps(n), which bounds 2 R(C(x))
with the tail probability alpha: few cells fail it. The rounding would decide the bisector of
two nuclei closer than about 1e-4 pixel (errors up to 1e-2 in their cells were measured): a
cell with another nucleus within image.near_coincident_length (the layout's near_length; also
coincident ones) is not certified either, and the host settles it exactly as it does its own.

Pixels with a cell that is not certified (or unbounded, or undecided by the kernel) are
estimated on the host exactly as image.estimate_run does, one pixel a block
(image.estimate_block, the guard widened while needed). Every pixel's result depends on its
own neighbourhood alone, never on the tiling or on which other pixels share a launch: the grid
is sized by the sampler's n, not by the launch. Launches take runs of pixels of about
CHUNK_NUCLEI auxiliary nuclei, so the memory does not grow with the tile.
"""

from __future__ import annotations

import math

import numpy as np

from clrender.estimators.device_cells import (
    STATUS_BOUNDED,
    STATUS_FALLBACK,
    STATUS_INSIDE,
    CellLayout,
    grid_side,
    launch_cell_kernels,
    precision_setup,
)
from clrender.estimators.image import (
    ImageVoronoiStats,
    RunEstimate,
    bincount_columns,
    empty_run,
    estimate_block,
    near_coincident_length,
)
from clrender.estimators.image_plane import PixelRect, PointSource
from clrender.estimators.registry import PixelSums
from clrender.runtime import Runtime
from clrender.samples import segments

# Pixels by which the certifying square is shrunk: far above the rounding of float32 vertices
# (about 1e-7 pixel at the ring's distance), far below a cell's size.
CERTIFY_MARGIN = 1e-4
# Auxiliary nuclei (expected) of one launch: pixels go to the device in runs this large, which
# bounds the host and device memory whatever the tile (each nucleus is copied to every pixel
# within the ring: (2 ring + 1)^2 - 1 times).
CHUNK_NUCLEI = 1 << 20


def device_ring(delta: float) -> int:
    """Plane pixels around a pixel whose nuclei join its diagram: ceil(delta), at least 1."""
    return max(1, math.ceil(delta))


def neighbour_offsets(ring: int) -> tuple[np.ndarray, np.ndarray]:
    """(dx, dy) of the (2 ring + 1)^2 - 1 plane pixels around a pixel, row by row."""
    dy, dx = np.divmod(np.arange((2 * ring + 1) ** 2), 2 * ring + 1)
    keep = (dx != ring) | (dy != ring)
    return dx[keep] - ring, dy[keep] - ring


def estimate_run_device(
    runtime: Runtime,
    source: PointSource,
    width: int,
    start: int,
    stop: int,
    n: float,
    delta: float,
    extent: tuple[float, ...] | None = None,
    precision: str = "auto",
    ring: int | None = None,
) -> RunEstimate:
    """image.estimate_run's result (the image-level sums of pixels start .. stop - 1, in
    scanline order) with the cells computed on the device, pixel by pixel (module docstring).
    extent: a finite realisation's (x0, y0, x1, y1): no nuclei beyond it. ring: the pixels
    around each pixel whose nuclei join its diagram (default device_ring(delta)). Launches of
    at most CHUNK_NUCLEI auxiliary nuclei (expected), which bounds the memory."""
    ring = device_ring(delta) if ring is None else ring
    chunk = max(1, int(CHUNK_NUCLEI / ((2 * ring + 1) ** 2 * max(n, 1.0))))
    parts = [
        _estimate_pixels(
            runtime,
            source,
            width,
            first,
            min(first + chunk, stop),
            n,
            delta,
            extent,
            precision,
            ring,
        )
        for first in range(start, stop, chunk)
    ]
    stats = ImageVoronoiStats()
    for part in parts:
        stats.add(part.stats)
    if not parts:
        return empty_run(n, stats)
    sums = PixelSums(
        np.concatenate([part.sums.counts for part in parts]),
        n,
        weighted=np.concatenate([part.sums.weighted for part in parts]),
        area=np.concatenate([part.sums.area for part in parts]),
    )
    ids = np.concatenate([part.ids for part in parts])
    return RunEstimate(sums, ids, np.concatenate([part.areas for part in parts]), stats)


def _estimate_pixels(
    runtime: Runtime,
    source: PointSource,
    width: int,
    start: int,
    stop: int,
    n: float,
    delta: float,
    extent: tuple[float, ...] | None,
    precision: str,
    ring: int,
) -> RunEstimate:
    """estimate_run_device over one launch's pixels start .. stop - 1 (at least one)."""
    ys, xs = np.divmod(np.arange(start, stop, dtype=np.int64), width)
    count = len(xs)
    # Every nucleus of the run's bounding rectangle grown by the ring, pixel by pixel
    rect = PixelRect(int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    rect = rect.grown(ring)
    plane = source(*rect.coords())
    plane_offsets = np.concatenate([[0], np.cumsum(plane.counts)])
    # The run's pixels and the neighbours of those with nuclei, as pixels of the rectangle
    cell = (ys - rect.y0) * rect.width + xs - rect.x0
    own, traced_offsets = segments(plane_offsets, cell)
    traced_counts = np.diff(traced_offsets)
    dx, dy = neighbour_offsets(ring)
    around = (cell[:, None] + dy * rect.width + dx)[traced_counts > 0]
    guard, _ = segments(plane_offsets, around.ravel())
    guard_counts = np.zeros(count, np.int64)
    guard_counts[traced_counts > 0] = plane.counts[around].sum(axis=1)
    owner = np.repeat(np.arange(count), traced_counts)
    # Relative to each pixel's centre, rounded to float32 as the kernels take them
    centres = np.column_stack([xs, ys]).astype(np.float64) + 0.5
    local = (plane.positions[own] - centres[owner]).astype(np.float32)
    aux = (plane.positions[guard] - np.repeat(centres, guard_counts, axis=0)).astype(np.float32)
    values, ids = plane.values[own], plane.ids[own]

    aux_offsets = np.concatenate([[0], np.cumsum(guard_counts)]).astype(np.int64)
    near_length = near_coincident_length(n, delta)
    areas, status = _device_cells(
        runtime, local, aux, traced_offsets, aux_offsets, ring, n, near_length, precision
    )
    certified = (status & (STATUS_BOUNDED | STATUS_INSIDE | STATUS_FALLBACK)) == (
        STATUS_BOUNDED | STATUS_INSIDE
    )
    host = np.bincount(owner, ~certified, count) > 0
    if extent is not None:  # a finite realisation: no nuclei are known beyond its extent
        host |= (
            (xs - ring < extent[0])
            | (ys - ring < extent[1])
            | (xs + 1 + ring > extent[2])
            | (ys + 1 + ring > extent[3])
        )
    areas = np.where(certified, areas, 0.0)

    stats = ImageVoronoiStats(
        guard_nuclei=len(aux),
        empty_pixels=int((traced_counts == 0).sum()),
        device_pixels=int(count - host.sum()),
    )
    for p in np.flatnonzero(host):
        block = estimate_block(
            source,
            PixelRect(int(xs[p]), int(ys[p]), int(xs[p]) + 1, int(ys[p]) + 1),
            delta,
            extent,
            near_length,
        )
        areas[traced_offsets[p] : traced_offsets[p + 1]] = block.areas
        block.stats.empty_pixels = 0  # counted above
        stats.add(block.stats)
    stats.traced_nuclei = len(owner)
    weighted = values * (areas if values.ndim == 1 else areas[:, None])
    sums = PixelSums(
        traced_counts,
        n,
        weighted=bincount_columns(owner, weighted, count),
        area=np.bincount(owner, areas, count),
    )
    return RunEstimate(sums, ids, areas, stats)


def _device_cells(
    runtime: Runtime,
    local: np.ndarray,
    aux: np.ndarray,
    traced_offsets: np.ndarray,
    aux_offsets: np.ndarray,
    ring: int,
    n: float,
    near_length: float,
    precision: str,
) -> tuple[np.ndarray, np.ndarray]:
    """(areas float64, status) of the traced nuclei, each pixel's diagram on its own; a cell
    with another nucleus within near_length is not certified (the cell kernel's near_length)."""
    if len(local) == 0:
        return np.zeros(0), np.zeros(0, np.uint8)
    buffer, upload = runtime.upload_async(np.concatenate([local, aux]))
    half_extent = 0.5 + ring
    layout = CellLayout(
        buffer,
        traced_offsets,
        aux_offsets,
        half_extent,
        grid_side(round((2 * ring + 1) ** 2 * n), 1),  # the sampler's density, not the launch's
        0.5,
        kind="image",
        intensity=n,
        near_length=1.05 * near_length,  # 5 % wider for the rounding of the relative positions
    )
    defines, real = precision_setup(runtime, precision)
    defines["VORONOI_INSIDE_DISCS"] = True
    areas, status = launch_cell_kernels(
        runtime, layout, half_extent - CERTIFY_MARGIN, defines, real
    )
    del upload
    return areas.astype(np.float64), status
