"""Image-level Voronoi estimators: one Poisson-Voronoi tessellation of the whole image plane.

When every pixel draws N ~ Poisson(n) nuclei uniform in its own square, the union over all
pixels is a stationary Poisson process eta of intensity n on the plane (pixels are disjoint and
the counts independent). So the nuclei of neighbouring pixels can play the part of the SPPP
auxiliary nuclei: no strip, no rejection, and every traced sample shapes the cells.

Conventions. Pixel (x, y) covers image coordinates [x, x+1] x [y, y+1]; a sample at pixel-local
(u, v) in W = [-1/2, 1/2]^2 sits at (x + 1/2 + u, y + 1/2 + v). "Plane pixels" are all integer
(x, y), inside the image or not. Cells C(x) are the Voronoi cells of eta itself, not clipped.

Estimators (v(x) = |C(x)|, sums over the traced nuclei x of pixel P, i.e. x in eta cap P):

| name    | estimate of pixel P         | bias                                               |
|---------|-----------------------------|----------------------------------------------------|
| ivor    | sum f(x) v(x)               | none: exactly unbiased (proof below)               |
| ivor_sn | sum f(x) v(x) / sum v(x)    | ratio estimator, O(1/n); 0 when P has no nucleus   |

Unbiasedness of ivor. Apply Proposition 1 (i) of the paper (Slivnyak-Mecke) to the integrand
g = f 1_P: E[sum_{x in eta} g(x) v(x)] = n int g(x) E[v_{eta + x}(x)] dx = int_P f, because
E[v_{eta + x}(x)] = 1/n for a stationary process. The sum only runs over nuclei inside P, which
are exactly P's traced samples. A pixel with N = 0 contributes the empty sum 0: that is the
value of the random variable on that event, already counted in the expectation above, so
ivor needs no conditioning on N and stays unbiased at N = 0 (ivor_sn, a ratio, does not).
The cells must be those of eta, unclipped: clipping cells to P, or summing
f(x) |C(x) cap P| over neighbours' nuclei, estimates the nearest-neighbour interpolant of f
(biased, and it needs the values of untraced guard nuclei).

Exactness (the guard band). A block of pixels is tessellated with the nuclei of the plane
pixels around it within a guard distance delta (positions only: guard nuclei are never
traced). A nucleus's cell in this finite set equals its cell in eta if it is not on the hull
and every Delaunay triangle around it has its circumdisc inside the "known" rectangle (block
grown by delta), where all nuclei of eta are present: nuclei outside that rectangle are outside
every such disc, so those triangles stay Delaunay in eta and the cell (the polygon of their
circumcentres) is unchanged. This is the empty-disc check of clrender.estimators.qhull_cells. A disc
through x has radius at most R(C(x)), the cell's circumradius, so it stays within 2 R of x; the
default delta = 2 eps(n) uses the paper's tail bound P(R > eps) and is almost never exceeded.
Fallback: a block with an uncertified cell is redone with delta doubled (up to MAX_GUARD
pixels, and never beyond the extent of a finite realisation); a cell still uncertified after
that keeps its area in the finite set (0 if unbounded there) and is counted in
stats.uncertified_nuclei. With the default delta no widening occurred in any test or benchmark.

Image border: the guard band reaches beyond the image; clrender.estimators.image_plane gives
its pixels RNG keys ("frame", the default, or "periodic").

Computation. A run of pixels (a render tile) is cut into rectangular blocks of about
BLOCK_POINTS nuclei, nearly square, and none more than twice a square block's width (a run's
partial rows are cut into such pieces); each block is one Qhull Delaunay, given coordinates
relative to the centre of the known rectangle (Qhull's precision is relative to their size).
Cell areas come from the circumcentre quadrilaterals, computed from the image coordinates
themselves and summed with np.bincount (clrender.estimators.delaunay), per-pixel sums from
np.bincount. Triangles are put in a canonical order (vertices sorted by a unique point id, rows
sorted) before summing, so a certified cell's area does not depend on the tiling or blocking.

Near-coincident nuclei. Qhull resolves nuclei only down to a fraction of its coordinates' size:
closer ones (41 nuclei within 1e-6 pixel of a spot, in a block of ~10 pixels) are dropped as
"coplanar" as if they coincided or triangulated wrongly, without a sign, and their cells come
out wrong by factors up to 1e11 (clrender.estimators.qhull_cells, "Near-coincident nuclei",
has the measurements). So when a block's triangulation has an edge shorter than
near_coincident_length(n, delta), or a point dropped onto a vertex with other coordinates, the
block's points within that length of another (found by a k-d tree) are settled exactly by
half-plane clipping within the known rectangle (clrender.estimators.clip_cells.cells_among),
and with them every traced nucleus whose cell borders theirs, in the clipped cells or in
Qhull's triangles; a settled cell is certified by the same empty-disc rule (its circumdiscs in
the known rectangle) and counted in stats.settled_nuclei. The length is NEAR_COINCIDENT (the
rule of qhull_cells) times the largest extent Qhull can be given by a block of run_blocks with
guard delta, not the block's own, so that which cells are settled does not depend on the
blocking; a settled cell's bits do not either (clip_cells, "Reproducibility"). Two exceptions,
each giving the same areas to rounding: a widened block whose own extent is larger uses that
instead, and may settle a pair that another blocking leaves to Qhull; and a wrong triangle of
Qhull's may add a cell that is no true neighbour in one block and not in another. Random
nuclei are seldom settled: a block of M points holds a pair that close with probability about
M pi n length^2 / 2, under 1 % at n = 64 (length 1.1e-4 pixel), settled in ~15 ms (the block's
Qhull call takes ~50 ms); the check itself costs ~0.1 % of a block's time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from clrender.errors import ParameterError
from clrender.estimators.clip_cells import cells_among
from clrender.estimators.delaunay import QHULL_OPTIONS, TriangleTerms, as_complex, share_coincident
from clrender.estimators.image_plane import (
    DEFAULT_BORDER,
    PixelPoints,
    PixelRect,
    PointSource,
    check_border,
    grid_from_points,
    tile_point_source,
)
from clrender.estimators.qhull_cells import NEAR_COINCIDENT
from clrender.estimators.registry import ESTIMATORS, PixelSums
from clrender.samples import SampleSets
from clrender.sppp import DEFAULT_ALPHA, sppp_eps

if TYPE_CHECKING:  # scipy.spatial is imported where used: it takes ~1 s to import
    from scipy.spatial import Delaunay

    from clrender.runtime import Runtime

BLOCK_POINTS = 6000  # nuclei per Qhull call (block pixels only, guard excluded)
MAX_GUARD = 16.0  # widest guard (pixels) the fallback tries


def guard_distance(n: float, alpha: float = DEFAULT_ALPHA) -> float:
    """Default guard width delta = 2 eps(n) in pixels: the discs around a nucleus stay within
    2 R of it, and eps bounds R(C(x)) with the paper's tail bound alpha."""
    return 2.0 * sppp_eps(n, alpha)


def near_coincident_length(n: float, delta: float) -> float:
    """Nuclei of a block closer than this (pixels) are settled by clipping: NEAR_COINCIDENT
    times the largest extent (|coordinate|, block centred) that a block of run_blocks with
    guard delta gives Qhull, so that it is the same for every blocking (module docstring)."""
    _, rows, columns = _block_shape(n)
    return NEAR_COINCIDENT * (0.5 * max(rows, columns) + delta)


# ---------------------------------------------------------------------------------------------
# Cells of one block


@dataclass
class RegionCells:
    """Cells of the traced nuclei (the first traced_count points) of one tessellation."""

    areas: np.ndarray  # (T,) float64, NaN where the cell is not certified
    certified: np.ndarray  # (T,) bool: provably the cell of the complete process
    settled: int = 0  # traced nuclei whose cells were settled by clipping (near-coincident)


def region_cells(
    points: np.ndarray,
    traced_count: int,
    known: tuple[float, ...],
    ids: np.ndarray | None = None,
    near_length: float = 0.0,
) -> RegionCells:
    """Voronoi cell areas of points[:traced_count] among all points, one Qhull call.

    known = (x0, y0, x1, y1): the rectangle in which `points` hold every nucleus of the
    process; a cell is certified when it is bounded and all its Delaunay circumdiscs lie in
    `known`. ids (unique per point) fix a canonical triangle order (bit-reproducible areas).
    Nuclei closer than near_length (at least NEAR_COINCIDENT times the extent of Qhull's
    coordinates) and their neighbours are settled by clipping (module docstring).
    """
    from scipy.spatial import Delaunay, QhullError

    t = traced_count
    if t == 0:
        return RegionCells(np.zeros(0), np.zeros(0, bool))
    points = np.asarray(points, np.float64)
    known = np.asarray(known, np.float64)
    # Qhull's precision is relative to the size of its coordinates: the block centred
    local = points - 0.5 * (known[:2] + known[2:])
    try:
        tri = Delaunay(local, qhull_options=QHULL_OPTIONS)
    except (QhullError, ValueError):  # < 3 points or collinear: no bounded cell
        return RegionCells(np.full(t, np.nan), np.zeros(t, bool))
    simplices = tri.simplices if ids is None else _canonical(tri.simplices, ids)
    # Cell geometry from the image coordinates themselves: no block-dependent rounding
    areas, bad, shortest = _areas_and_flags(tri, points, simplices, known)
    near_length = max(near_length, NEAR_COINCIDENT * float(np.abs(local).max()))
    settled = 0
    # Nuclei nearer than near_length: a shorter edge (a correct triangulation holds the edge
    # from every point to its nearest neighbour) or a point dropped onto a distinct vertex
    if (shortest < near_length * near_length).any() or _dropped_apart(tri, points).size:
        settled = _settle_near_coincident(points, t, tri, simplices, known, near_length, areas, bad)
    return RegionCells(np.where(bad[:t], np.nan, areas[:t]), ~bad[:t], settled)


def _canonical(simplices: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Each triangle's vertices sorted by id, triangles sorted by their id triples."""
    order = np.argsort(ids[simplices], axis=1)
    s = np.take_along_axis(simplices, order, axis=1)
    key = ids[s]
    return s[np.lexsort((key[:, 2], key[:, 1], key[:, 0]))]


def _areas_and_flags(
    tri: Delaunay, points: np.ndarray, s: np.ndarray, known: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell areas of every point, the flags "not certified" (hull, disc outside known), and
    each triangle's shortest squared edge."""
    count = len(points)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = TriangleTerms(as_complex(points), np.ascontiguousarray(s.T, dtype=np.intp))
        ux, uy = t.circumcentre_offset()
        cx, cy = t.za.real + ux, t.za.imag + uy
        radius = np.sqrt(ux * ux + uy * uy)
        inside = (
            (cx - radius >= known[0])
            & (cx + radius <= known[2])
            & (cy - radius >= known[1])
            & (cy + radius <= known[3])
        )
    area_a, area_b, area_c = t.pieces
    areas = (
        np.bincount(s[:, 0], area_a, count)
        + np.bincount(s[:, 1], area_b, count)
        + np.bincount(s[:, 2], area_c, count)
    )
    bad = np.zeros(count, bool)
    bad[np.unique(tri.convex_hull)] = True
    bad[s[~(inside & np.isfinite(area_a + area_b + area_c))].ravel()] = True
    share_coincident(tri, areas, bad)
    third = t.e2 - t.e1
    shortest = np.minimum(np.minimum(t.l1, t.l2), third.real * third.real + third.imag * third.imag)
    return areas, bad, shortest


def _dropped_apart(tri: Delaunay, points: np.ndarray) -> np.ndarray:
    """The points Qhull dropped as "coplanar" onto a vertex with other coordinates, and those
    vertices (exact duplicates, rightly shared by share_coincident, left out)."""
    if not len(tri.coplanar):
        return np.zeros(0, np.int64)
    dropped, kept = tri.coplanar[:, 0], tri.coplanar[:, 2]
    apart = (points[dropped] != points[kept]).any(axis=1)
    return np.union1d(dropped[apart], kept[apart])


def _settle_near_coincident(
    points: np.ndarray,
    traced_count: int,
    tri: Delaunay,
    s: np.ndarray,
    known: np.ndarray,
    near_length: float,
    areas: np.ndarray,
    bad: np.ndarray,
) -> int:
    """Settle by clipping (clip_cells.cells_among, within `known`) the cells of the traced
    nuclei that are within near_length of another point or border the cell of one (in the
    clipped cells, or in Qhull's triangles, which may be wrong there), written over areas and
    bad; returns how many. The near points are found by a k-d tree, not from Qhull's edges,
    so that they do not depend on Qhull's errors."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    pairs = tree.query_pairs(near_length, output_type="ndarray")
    near = np.union1d(pairs.ravel(), _dropped_apart(tri, points))
    near_cells = cells_among(points, near, known, tree)
    bordering = np.union1d(near_cells.neighbours, s[np.isin(s, near).any(axis=1)].ravel())
    others = np.setdiff1d(bordering[bordering < traced_count], near)
    settled = 0
    for nuclei, cells in ((near, near_cells), (others, cells_among(points, others, known, tree))):
        traced = nuclei < traced_count
        index = nuclei[traced]
        discs = cells.disc_boxes[traced]
        areas[index] = cells.areas[traced]
        bad[index] = ~(
            (discs[:, 0] >= known[0])
            & (discs[:, 1] >= known[1])
            & (discs[:, 2] <= known[2])
            & (discs[:, 3] <= known[3])
        )
        settled += index.size
    return settled


# ---------------------------------------------------------------------------------------------
# Estimates over a run of pixels


@dataclass
class ImageVoronoiStats:
    blocks: int = 0
    qhull_calls: int = 0
    traced_nuclei: int = 0
    guard_nuclei: int = 0  # untraced nuclei handed to Qhull (on the device: every pixel's
    # auxiliary nuclei, its neighbours', so each nucleus counts once per pixel it neighbours)
    widened_blocks: int = 0  # blocks redone with a doubled guard (fallback)
    uncertified_nuclei: int = 0  # cells still not provably exact after the last widening
    settled_nuclei: int = 0  # cells settled by clipping (near-coincident nuclei, neighbours)
    empty_pixels: int = 0  # pixels with N = 0
    device_pixels: int = 0  # pixels whose cells all came from the device (image_device)

    def add(self, other: ImageVoronoiStats) -> None:
        for name in self.__dataclass_fields__:
            setattr(self, name, getattr(self, name) + getattr(other, name))


@dataclass
class BlockResult:
    sums: np.ndarray  # (P,) or (P, C): sum f v per block pixel
    area_sums: np.ndarray  # (P,): sum v per block pixel
    counts: np.ndarray  # (P,): nuclei per block pixel
    ids: np.ndarray  # traced nuclei ids
    areas: np.ndarray  # their cell areas
    stats: ImageVoronoiStats = field(default_factory=ImageVoronoiStats)


def estimate_block(
    source: PointSource,
    rect: PixelRect,
    delta: float,
    extent: tuple[float, ...] | None = None,
    near_length: float = 0.0,
) -> BlockResult:
    """One block: tessellate rect's nuclei with the guard nuclei within delta of rect, and
    widen the guard (doubling delta, up to MAX_GUARD) while a cell is not certified. Nuclei
    closer than near_length (near_coincident_length; at least the block's own) are settled."""
    stats = ImageVoronoiStats(blocks=1)
    traced = source(*rect.coords())
    while True:
        cells, guard_count = _block_cells(source, rect, delta, traced, extent, near_length)
        stats.qhull_calls += 1
        if cells.certified.all() or delta >= MAX_GUARD:
            break
        delta = min(2.0 * delta, MAX_GUARD)
        stats.widened_blocks += 1
    owner = np.repeat(np.arange(rect.count), traced.counts)
    areas = np.where(cells.certified, cells.areas, np.nan_to_num(cells.areas))
    weighted = traced.values * (areas if traced.values.ndim == 1 else areas[:, None])
    stats.traced_nuclei = len(owner)
    stats.guard_nuclei = guard_count
    stats.uncertified_nuclei = int((~cells.certified).sum())
    stats.settled_nuclei = cells.settled
    stats.empty_pixels = int((traced.counts == 0).sum())
    return BlockResult(
        bincount_columns(owner, weighted, rect.count),
        np.bincount(owner, areas, rect.count),
        traced.counts,
        traced.ids,
        areas,
        stats,
    )


def _block_cells(
    source: PointSource,
    rect: PixelRect,
    delta: float,
    traced: PixelPoints,
    extent: tuple[float, ...] | None,
    near_length: float,
) -> tuple[RegionCells, int]:
    known = (rect.x0 - delta, rect.y0 - delta, rect.x1 + delta, rect.y1 + delta)
    if extent is not None:  # a finite realisation holds no nuclei beyond its extent
        known = (
            max(known[0], extent[0]),
            max(known[1], extent[1]),
            min(known[2], extent[2]),
            min(known[3], extent[3]),
        )
    xs, ys = rect.grown(math.ceil(delta)).coords()
    ring = ~rect.contains(xs, ys)
    guard = source(xs[ring], ys[ring])
    p = guard.positions
    near = (p[:, 0] > known[0]) & (p[:, 0] < known[2]) & (p[:, 1] > known[1]) & (p[:, 1] < known[3])
    points = np.concatenate([traced.positions, p[near]])
    ids = np.concatenate([traced.ids, guard.ids[near]])
    cells = region_cells(points, len(traced.positions), known, ids, near_length)
    return cells, int(near.sum())


def bincount_columns(owner: np.ndarray, weights: np.ndarray, count: int) -> np.ndarray:
    if weights.ndim == 1:
        return np.bincount(owner, weights, count)
    return np.column_stack(
        [np.bincount(owner, weights[:, c], count) for c in range(weights.shape[1])]
    )


def _block_shape(n: float) -> tuple[int, int, int]:
    """(pixels, rows, columns): blocks of about BLOCK_POINTS nuclei, i.e. `pixels` pixels,
    nearly square (rows high), a thin run cut into blocks at most `columns` wide (twice a
    square block's width), so that no block is much longer than a square one."""
    pixels = max(1, round(BLOCK_POINTS / n))
    side = max(1, math.isqrt(pixels))
    return pixels, side, 2 * max(1, pixels // side)


def run_blocks(width: int, start: int, stop: int, n: float) -> list[PixelRect]:
    """Rectangular blocks covering the scanline run of pixels [start, stop) of an image of the
    given width: the partial first row, the full rows, the partial last row, each cut into
    blocks of about BLOCK_POINTS nuclei (at most as long as _block_shape allows)."""
    rows = []
    y_first, x_first = divmod(start, width)
    y_last, x_last = divmod(stop, width)  # stop is exclusive
    if y_first == y_last:
        rows.append(PixelRect(x_first, y_first, x_last, y_first + 1))
    else:
        rows.append(PixelRect(x_first, y_first, width, y_first + 1))
        rows.append(PixelRect(0, y_first + 1, width, y_last))
        rows.append(PixelRect(0, y_last, x_last, y_last + 1))
    pixels, side, columns = _block_shape(n)
    return [block for rect in rows if rect.count for block in _cut(rect, side, pixels, columns)]


def _cut(rect: PixelRect, side: int, pixels: int, columns: int) -> list[PixelRect]:
    bh = min(rect.height, side)
    bw = min(rect.width, max(1, pixels // bh), columns)
    return [
        PixelRect(x, y, min(x + bw, rect.x1), min(y + bh, rect.y1))
        for y in range(rect.y0, rect.y1, bh)
        for x in range(rect.x0, rect.x1, bw)
    ]


@dataclass
class RunEstimate:
    """Per-pixel sums of a scanline run of pixels, in run order, over the image tessellation
    (weighted: sum f v, area: sum v), with the cells of the run's traced nuclei."""

    sums: PixelSums
    ids: np.ndarray  # traced nuclei ids, block by block
    areas: np.ndarray  # their cell areas
    stats: ImageVoronoiStats

    @property
    def estimates(self) -> dict[str, np.ndarray]:
        """Every image-level estimator of the registry: name -> (P,) or (P, C)."""
        return image_estimates(self.sums)


def image_estimates(sums: PixelSums) -> dict[str, np.ndarray]:
    return {name: entry.formula(sums) for name, entry in ESTIMATORS.items() if entry.image_level}


def estimate_run(
    source: PointSource,
    width: int,
    start: int,
    stop: int,
    n: float,
    delta: float,
    extent: tuple[float, ...] | None = None,
) -> RunEstimate:
    """The image-level sums of the image pixels start .. stop - 1 (scanline order)."""
    stats = ImageVoronoiStats()
    blocks = run_blocks(width, start, stop, n)
    if not blocks:
        return empty_run(n, stats)
    near_length = near_coincident_length(n, delta)
    results = [estimate_block(source, block, delta, extent, near_length) for block in blocks]
    index = np.concatenate([ys * width + xs - start for xs, ys in (b.coords() for b in blocks)])
    order = np.argsort(index)
    for r in results:
        stats.add(r.stats)
    sums = PixelSums(
        np.concatenate([r.counts for r in results])[order],
        n,
        weighted=np.concatenate([r.sums for r in results])[order],
        area=np.concatenate([r.area_sums for r in results])[order],
    )
    return RunEstimate(
        sums,
        np.concatenate([r.ids for r in results]),
        np.concatenate([r.areas for r in results]),
        stats,
    )


def empty_run(n: float, stats: ImageVoronoiStats) -> RunEstimate:
    """The estimate of a run without pixels."""
    empty = np.zeros(0)
    return RunEstimate(
        PixelSums(np.zeros(0, np.int64), n, weighted=empty, area=empty),
        np.zeros(0, np.int64),
        empty,
        stats,
    )


# ---------------------------------------------------------------------------------------------
# Plain NumPy entry point (analytic tests and benchmarks)


def draw_plane_poisson(
    rng: np.random.Generator, n: float, extent: tuple[float, float, float, float]
) -> np.ndarray:
    """A Poisson process of intensity n on the rectangle extent = (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = extent
    count = rng.poisson(n * (x1 - x0) * (y1 - y0))
    return np.column_stack([rng.uniform(x0, x1, count), rng.uniform(y0, y1, count)])


@dataclass
class ImageEstimate:
    """Per-pixel estimates (name -> (H, W) or (H, W, C)), the cell area of every input point
    (NaN outside the image) and the statistics."""

    estimates: dict[str, np.ndarray]
    areas: np.ndarray
    stats: ImageVoronoiStats


def estimate_image(
    positions: np.ndarray,
    values: np.ndarray,
    width: int,
    height: int,
    n: float,
    frame: float,
    delta: float | None = None,
    start: int = 0,
    stop: int | None = None,
    runtime: Runtime | None = None,
) -> ImageEstimate:
    """ivor and ivor_sn of every image pixel from one realisation of the process.

    positions: (M, 2) image coordinates of a Poisson(n) realisation on the image grown by
    `frame` on each side, i.e. [-frame, W + frame] x [-frame, H + frame]; values: (M,) or
    (M, C), used for the points inside the image only. start/stop select a scanline run of
    pixels (the tiling a renderer would use); pixels outside the run are NaN. With a runtime
    the cells are computed on its device (clrender.estimators.image_device), else by Qhull.
    """
    positions = np.asarray(positions, np.float64)
    values = np.asarray(values, np.float64)
    if positions.ndim != 2 or positions.shape[1] != 2 or len(values) != len(positions):
        raise ParameterError("positions must be (M, 2) and values (M,) or (M, C)")
    if width < 1 or height < 1:
        raise ParameterError(f"the image must be at least 1 x 1 pixels, got {width} x {height}")
    if not frame >= 0:
        raise ParameterError(
            f"frame (how far the realisation reaches beyond the image) must be >= 0, got {frame}"
        )
    stop = width * height if stop is None else stop
    if not 0 <= start <= stop <= width * height:
        raise ParameterError(
            f"the run of pixels [start, stop) = [{start}, {stop}) must lie within the image's "
            f"{width * height} pixels, start <= stop"
        )
    delta = guard_distance(n) if delta is None else delta
    ring = math.ceil(frame)
    grid = grid_from_points(
        PixelRect(0, 0, width, height).grown(ring), positions, values, np.arange(len(positions))
    )
    extent = (-frame, -frame, width + frame, height + frame)
    if runtime is None:
        run = estimate_run(grid.take, width, start, stop, n, delta, extent)
    else:
        from clrender.estimators.image_device import estimate_run_device

        run = estimate_run_device(runtime, grid.take, width, start, stop, n, delta, extent)
    areas = np.full(len(positions), np.nan)
    areas[run.ids] = run.areas
    estimates = {}
    for name, est in run.estimates.items():
        full = np.full((width * height,) + est.shape[1:], np.nan)
        full[start:stop] = est
        estimates[name] = full.reshape((height, width) + est.shape[1:])
    return ImageEstimate(estimates, areas, run.stats)


# ---------------------------------------------------------------------------------------------
# Renderer adapter: a tile of traced samples, guard nuclei regenerated on the device


def estimate_tile_image(
    runtime,
    config,
    seed: int,
    width: int,
    height: int,
    pixels: np.ndarray,
    samples: SampleSets,
    values: np.ndarray,
    border: str = DEFAULT_BORDER,
    delta: float | None = None,
    device_cells: bool = False,
) -> RunEstimate:
    """ivor and ivor_sn of a render tile (a scanline run of global pixel indices, each drawn
    with redraw number 0 by an SPPP sampler config): the tile's sample sets and the values of
    their traced samples. Returns the run's sums and estimates in tile order. device_cells:
    the cells on runtime's device (clrender.estimators.image_device), else by Qhull."""
    pixels = np.asarray(pixels, np.int64)
    if not config.is_sppp:
        raise ParameterError(
            "image-level Voronoi estimators need Poisson counts: use an "
            f"SPPP sampler (sppp, sppp-sobol), got {config.name!r}"
        )
    start = int(pixels[0]) if len(pixels) else 0
    if len(pixels) and not np.array_equal(pixels, np.arange(start, start + len(pixels))):
        raise ParameterError("image-level Voronoi estimation needs a scanline run of pixels")
    check_border(border)
    delta = guard_distance(config.n, config.alpha) if delta is None else float(delta)
    ring = math.ceil(delta)
    if device_cells:
        from clrender.estimators.image_device import device_ring, estimate_run_device

        ring = max(ring, device_ring(delta))
    source = tile_point_source(
        runtime, config, seed, width, height, pixels, samples, values, ring, border
    )
    stop = start + len(pixels)
    if device_cells:
        return estimate_run_device(runtime, source, width, start, stop, config.n, delta)
    return estimate_run(source, width, start, stop, config.n, delta)
