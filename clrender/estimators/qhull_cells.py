"""Voronoi cell areas of many pixels' sample sets, from SciPy's Qhull Delaunay triangulation.

Conventions. Positions are pixel-local, in W = [-1/2, 1/2]^2, float64. A batch holds P pixels in
flat arrays: pixel p's nuclei in W ("originals", the traced samples) are
positions[offsets[p]:offsets[p+1]]. Each pixel's originals are tessellated together with
*ghost* points that only shape cells and never carry a value:

- SPPP (estimators vor, vor_sn, fvor): the pixel's auxiliary nuclei in the strip W' minus W.
  The cells are those of the real point set; a W nucleus on the convex hull of W + aux nuclei
  has an unbounded cell and is reported as unbounded (its pixel must be redrawn).
- Clipped (cvor): mirror images of the originals across the four edges of W. The cell of an
  original among its mirrors is exactly its cell among the originals clipped to W.
- Periodic (pvor): translated copies x + (i, j), i, j in {-1, 0, 1}: cells on the torus W.
  For z in a periodic cell (which lies in x + [-1/2, 1/2]^2) the nearest copy of any nucleus
  is one of these 9, so the 3 x 3 copies are exact.

Cell areas come from one triangulation per call (clrender.estimators.delaunay).

Batching and exactness. Several small pixels share a Qhull call, each translated to its own slot
in a row (gap of several pixel widths). A nucleus's cell in the joint triangulation equals its
cell in its own pixel's diagram whenever all its Delaunay neighbours belong to its own pixel and
it is not on the joint hull: the joint cell is cut by those neighbours only, each of them is in
its own set, and adding points never enlarges a cell. The code checks exactly that condition
per nucleus; a pixel that fails it is recomputed alone. For clipped and periodic cells only the
ghosts within a margin m of W are built; an original's cell is accepted only if every
circumdisc around it lies inside [-1/2 - m, 1/2 + m]^2, where every ghost is present (an absent
ghost is then farther from each cell vertex than the nucleus itself, so it cannot cut the
cell); otherwise the pixel is recomputed alone with all ghosts.

Degenerate sets. Coincident points (identical coordinates; Qhull reports all but one as
"coplanar") split their common cell equally. A set Qhull cannot triangulate (fewer than 3
distinct points, or all collinear) has only unbounded cells. For the clipped estimator, nuclei
within EDGE_NUDGE of an edge of W are moved EDGE_NUDGE inside it so that each has a mirror
image distinct from itself; this moves cell boundaries by at most EDGE_NUDGE. For the periodic
estimator a nucleus on the edge x = 1/2 (or y = 1/2) is the same torus point as one on
x = -1/2 and is wrapped there.

Near-coincident nuclei. Qhull's precision is relative to the extent of the points it is given:
distinct nuclei far closer together than that (say 41 nuclei within 1e-6 of one spot) may be
dropped as "coplanar" as if they coincided, or triangulated wrongly without a sign, and their
cells and their neighbours' come out wrong (even unbounded). So after each call the end points
of Delaunay edges shorter than NEAR_COINCIDENT times the call's extent (but for an original and
its own mirror image: that lone pair Qhull resolves, see EDGE_NUDGE) and the points dropped onto
a vertex with other coordinates are flagged. A flagged pixel that shared its call is redone
alone (a smaller extent); one still flagged alone is settled exactly by half-plane clipping
(clrender.estimators.clip_cells; counted in stats.settled_pixels). Qhull's cells were seen to go
wrong from edges of about 2e-7 times the extent, on clusters of 5 to 200 nuclei. Random sets are
rarely flagged: a pixel of N uniform nuclei has a pair that close with probability about (pi/2)
(N NEAR_COINCIDENT extent)^2, 1e-3 for N = 4096 (settled in about 0.3 s), and pixels of 64
nuclei that share calls are redone alone about once in 1000. Last, clipped and torus cells are
bounded and tile W: a pixel with an unbounded cell, or whose areas do not sum to 1 within
AREA_SUM_RTOL, is settled too, and one that still fails the sum raises ClrenderError (an
internal error); the check costs under 0.1 % of the cell time.

Speed. Qhull's cost per point grows with the size of the call, so pixels are packed into calls
of about POINTS_PER_QHULL_CALL points; a large pixel gets a call of its own. The points are laid
out once per batch, pixel by pixel (originals then ghosts), as complex x + iy, so that a call's
points are a contiguous slice and one gather fetches both coordinates; each call's triangles are
processed right after the call (in cache) into that slice, and one gather maps the slice back to
the originals. bench/voronoi_speed.py measures this stage against bare Qhull on the same points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from clrender.errors import ClrenderError, ParameterError
from clrender.estimators.clip_cells import clipped_cell_areas, sppp_cell_areas, torus_cell_areas
from clrender.estimators.delaunay import QHULL_OPTIONS, TriangleTerms, as_complex, share_coincident
from clrender.samples import segments

if TYPE_CHECKING:  # scipy.spatial is imported where used: it takes ~1 s to import
    from scipy.spatial import Delaunay

# Points per Qhull call: the cost per point is flat over a range around this size and rises
# with one pixel per call (per-call overhead) and with larger calls (bench/voronoi_speed.py).
POINTS_PER_QHULL_CALL = 1200
EDGE_NUDGE = 1e-9
# Ghost margin for clipped/periodic cells, in mean nearest-neighbour distances 1/sqrt(N).
GHOST_MARGIN_SPACINGS = 5.0
# Fraction of a pixel's own extent left empty between pixels that share a Qhull call.
SLOT_GAP_FACTOR = 2.0
# Nuclei closer than this times the extent of their Qhull call are near-coincident: their pixel
# is redone alone, then settled by clipping (see "Near-coincident nuclei"). Qhull's cells were
# seen to go wrong from about 2e-7 on clusters of 5 to 200 nuclei.
NEAR_COINCIDENT = 1e-5
# Clipped and torus cells of a pixel must tile W: areas summing to 1 within this.
AREA_SUM_RTOL = 1e-9


@dataclass
class TessellationStats:
    """Counters of one cell computation."""

    qhull_calls: int = 0
    recomputed_pixels: int = 0  # pixels redone alone (joint cell not provably exact)
    degenerate_pixels: int = 0  # pixels Qhull could not triangulate (all cells unbounded)
    walked_cells: int = 0  # device cells found by the walk (the others by clipping)
    settled_pixels: int = 0  # pixels Qhull could not resolve, settled by clip_cells

    def add(self, other: TessellationStats) -> None:
        self.qhull_calls += other.qhull_calls
        self.recomputed_pixels += other.recomputed_pixels
        self.degenerate_pixels += other.degenerate_pixels
        self.walked_cells += other.walked_cells
        self.settled_pixels += other.settled_pixels


@dataclass
class CellAreas:
    """Voronoi cells of the originals (the W nuclei) of a batch.

    areas[i] is the area of original i's cell (NaN where the cell is unbounded); bounded[i]
    says whether it is bounded. inside_box[i] (only when a box was requested) says whether the
    whole cell lies in [-box, box]^2.
    """

    areas: np.ndarray
    bounded: np.ndarray
    inside_box: np.ndarray | None
    stats: TessellationStats = field(default_factory=TessellationStats)


@dataclass(frozen=True)
class _PointSet:
    """Originals and ghosts of a batch, each block sorted by pixel, in pixel-local coordinates."""

    originals: np.ndarray  # (T, 2)
    ghosts: np.ndarray  # (G, 2)
    offsets: np.ndarray  # (P + 1,) originals per pixel
    ghost_offsets: np.ndarray  # (P + 1,) ghosts per pixel
    half_extent: float  # every point lies in [-half_extent, half_extent]^2
    disc_box: float | None  # check circumdiscs against [-disc_box, disc_box]^2 (partial ghosts)
    ghost_source: np.ndarray  # (G,) the original a ghost images, or -1 (auxiliary nuclei)

    @property
    def pixel_count(self) -> int:
        return len(self.offsets) - 1

    def pixel_points(self, p: int) -> np.ndarray:
        """Pixel p's originals then its ghosts."""
        return np.concatenate(
            [
                self.originals[self.offsets[p] : self.offsets[p + 1]],
                self.ghosts[self.ghost_offsets[p] : self.ghost_offsets[p + 1]],
            ]
        )


# ---------------------------------------------------------------------------------------------
# Public entry points


def sppp_cells(
    positions: np.ndarray,
    offsets: np.ndarray,
    aux: np.ndarray,
    aux_offsets: np.ndarray,
    box: float | None = None,
) -> CellAreas:
    """Cells of the W nuclei among W + auxiliary nuclei (the paper's SPPP tessellation).

    box: also report which cells lie inside [-box, box]^2 (box = 1/2 + eps is W' for fvor).
    """
    point_set = _sppp_point_set(positions, offsets, aux, aux_offsets)
    cells, stats, near = _cells(point_set, box)
    suspect = np.union1d(_suspect_pixels(point_set, cells.bounded), np.flatnonzero(near))
    if suspect.size:
        subset = _subset_sppp(point_set, suspect)
        redo, redo_stats, redo_near = _cells(subset, box, one_pixel_per_call=True)
        redo_stats.settled_pixels += _settle_sppp(redo, subset, np.flatnonzero(redo_near), box)
        _scatter_pixels(cells, redo, point_set.offsets, suspect)
        stats.add(redo_stats)
        stats.recomputed_pixels += suspect.size
    cells.stats = stats
    return cells


def clipped_cells(positions: np.ndarray, offsets: np.ndarray) -> CellAreas:
    """Cells of the originals among themselves, clipped to W (mirror images as ghosts)."""
    return _ghost_cells(_nudge_inside(positions), offsets, _mirror_ghosts, clipped_cell_areas)


def periodic_cells(positions: np.ndarray, offsets: np.ndarray) -> CellAreas:
    """Cells of the originals on the torus W (translated copies as ghosts)."""
    return _ghost_cells(_wrap_torus(positions), offsets, _periodic_ghosts, torus_cell_areas)


def qhull_point_arrays(
    positions: np.ndarray, offsets: np.ndarray, aux: np.ndarray, aux_offsets: np.ndarray
) -> list[np.ndarray]:
    """The point arrays sppp_cells hands to Qhull (for timing bare Delaunay on the same points)."""
    layout = _call_layout(_sppp_point_set(positions, offsets, aux, aux_offsets), False)
    bounds = layout.call_bounds
    return [
        layout.call_points(call)[0]
        for call in range(len(bounds) - 1)
        if bounds[call + 1] > bounds[call]
    ]


# ---------------------------------------------------------------------------------------------
# Point sets


def _sppp_point_set(positions, offsets, aux, aux_offsets) -> _PointSet:
    positions = np.asarray(positions, dtype=np.float64)
    aux = np.asarray(aux, dtype=np.float64)
    half_extent = 0.5
    for block in (positions, aux):
        if len(block):
            half_extent = max(half_extent, float(block.max()), -float(block.min()))
    return _PointSet(
        positions,
        aux,
        np.asarray(offsets),
        np.asarray(aux_offsets),
        half_extent,
        None,
        np.full(len(aux), -1),
    )


def _subset_sppp(point_set: _PointSet, pixels: np.ndarray) -> _PointSet:
    """The same point set restricted to some pixels (renumbered 0..len(pixels)-1)."""
    orig_idx, orig_offsets = segments(point_set.offsets, pixels)
    ghost_idx, ghost_offsets = segments(point_set.ghost_offsets, pixels)
    return _PointSet(
        point_set.originals[orig_idx],
        point_set.ghosts[ghost_idx],
        orig_offsets,
        ghost_offsets,
        point_set.half_extent,
        None,
        point_set.ghost_source[ghost_idx],
    )


def _nudge_inside(positions: np.ndarray) -> np.ndarray:
    limit = 0.5 - EDGE_NUDGE
    return np.clip(np.asarray(positions, dtype=np.float64), -limit, limit)


def _wrap_torus(positions: np.ndarray) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    return np.where(positions >= 0.5, positions - 1.0, positions)


def _near_edges(positions: np.ndarray, margin: float) -> tuple[np.ndarray, ...]:
    """Masks of originals within `margin` of the right, left, top and bottom edges of W."""
    x, y = positions[:, 0], positions[:, 1]
    return x >= 0.5 - margin, x <= margin - 0.5, y >= 0.5 - margin, y <= margin - 0.5


# Mirror across right, left, top, bottom edge: (x, y) -> (sx x + tx, sy y + ty).
_MIRROR_MAPS = np.array([[-1, 1, 1, 0], [-1, -1, 1, 0], [1, 0, -1, 1], [1, 0, -1, -1]], float)


def _mirror_ghosts(positions: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Mirror images across the edges of W that lie within `margin` of W, sorted by original."""
    right, left, top, bottom = _near_edges(positions, margin)
    source, kind = np.nonzero(np.column_stack([right, left, top, bottom]))
    maps = _MIRROR_MAPS[kind]
    ghosts = np.column_stack(
        [
            maps[:, 0] * positions[source, 0] + maps[:, 1],
            maps[:, 2] * positions[source, 1] + maps[:, 3],
        ]
    )
    return ghosts, source


_SHIFTS = np.array(
    [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)], float
)


def _periodic_ghosts(positions: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Translates x + (i, j) that lie within `margin` of W, sorted by original."""
    right, left, top, bottom = _near_edges(positions, margin)
    every = np.ones(len(positions), bool)
    # A shift by -1 in x keeps the copy near W only for originals near the right edge, etc.
    x_ok = {-1.0: right, 0.0: every, 1.0: left}
    y_ok = {-1.0: top, 0.0: every, 1.0: bottom}
    mask = np.column_stack([x_ok[dx] & y_ok[dy] for dx, dy in _SHIFTS])
    source, kind = np.nonzero(mask)
    return positions[source] + _SHIFTS[kind], source


def _ghost_margin(offsets: np.ndarray) -> float:
    pixels = max(len(offsets) - 1, 1)
    mean_count = max((offsets[-1] - offsets[0]) / pixels, 1.0)
    return GHOST_MARGIN_SPACINGS / math.sqrt(mean_count)


def _ghost_point_set(positions, offsets, make_ghosts, margin: float) -> _PointSet:
    """Originals plus their ghosts within `margin` (margin >= 1: all ghosts, provably exact)."""
    offsets = np.asarray(offsets)
    ghosts, source = make_ghosts(positions, margin)
    # Ghosts come sorted by original, so pixel p's are those of originals offsets[p]...
    ghost_offsets = np.searchsorted(source, offsets)
    full = margin >= 1.0
    half_extent = 1.5 if full else 0.5 + margin
    return _PointSet(
        positions,
        ghosts,
        offsets,
        ghost_offsets,
        half_extent,
        None if full else 0.5 + margin,
        source,
    )


def _ghost_cells(positions: np.ndarray, offsets: np.ndarray, make_ghosts, clip_areas) -> CellAreas:
    """Clipped or torus cells: Qhull among ghosts (make_ghosts), suspect pixels redone alone,
    those still near-coincident or unbounded alone, and any whose areas do not sum to 1,
    settled by clip_areas (clip_cells)."""
    offsets = np.asarray(offsets)
    margin = _ghost_margin(offsets)
    point_set = _ghost_point_set(positions, offsets, make_ghosts, margin)
    cells, stats, near = _cells(point_set, None)
    suspect = np.union1d(_suspect_pixels(point_set, cells.bounded), np.flatnonzero(near))
    if suspect.size:
        index, sub_offsets = segments(offsets, suspect)
        subset = _ghost_point_set(positions[index], sub_offsets, make_ghosts, 1.0)
        redo, redo_stats, redo_near = _cells(subset, None, one_pixel_per_call=True)
        # Every clipped or torus cell is bounded: an unbounded one is Qhull's failure too
        settle = np.union1d(np.flatnonzero(redo_near), _suspect_pixels(subset, redo.bounded))
        redo_stats.settled_pixels += _settle_ghost_cells(redo, subset, settle, clip_areas)
        _scatter_pixels(cells, redo, offsets, suspect)
        stats.add(redo_stats)
        stats.recomputed_pixels += suspect.size

    # The cells of a pixel tile W: a pixel whose areas miss that is settled, and must then pass
    unsure = _area_sum_failures(cells.areas, offsets)
    if unsure.size:
        stats.settled_pixels += _settle_ghost_cells(cells, point_set, unsure, clip_areas)
        if _area_sum_failures(cells.areas, offsets).size:
            raise ClrenderError(
                "internal error: clipped/periodic Voronoi cell areas of a pixel do not sum "
                "to 1 even after clipping; please report the sample set"
            )
    cells.stats = stats
    return cells


def _area_sum_failures(areas: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The pixels with nuclei whose cell areas do not sum to 1 within AREA_SUM_RTOL."""
    filled = np.flatnonzero(offsets[1:] > offsets[:-1])
    if not filled.size:
        return filled
    # Empty pixels left out, each sum runs from a filled pixel's start to the next one's
    sums = np.add.reduceat(areas[offsets[0] : offsets[-1]], offsets[filled] - offsets[0])
    return filled[~(np.abs(sums - 1.0) <= AREA_SUM_RTOL)]


def _settle_ghost_cells(
    cells: CellAreas, point_set: _PointSet, pixels: np.ndarray, clip_areas
) -> int:
    """Clipped or torus cells of some pixels of a point set, by clipping (clip_areas, from
    clip_cells), written over cells; returns the number of pixels."""
    for p in pixels:  # rare: pixels Qhull could not resolve
        own = slice(point_set.offsets[p], point_set.offsets[p + 1])
        cells.areas[own] = clip_areas(point_set.originals[own])
        cells.bounded[own] = True
    return len(pixels)


def _settle_sppp(
    cells: CellAreas, point_set: _PointSet, pixels: np.ndarray, box: float | None
) -> int:
    """SPPP cells of some pixels of a point set, by clipping (clip_cells), written over
    cells; returns the number of pixels."""
    for p in pixels:  # rare: pixels with near-coincident nuclei
        own = slice(point_set.offsets[p], point_set.offsets[p + 1])
        aux = point_set.ghosts[point_set.ghost_offsets[p] : point_set.ghost_offsets[p + 1]]
        settled = sppp_cell_areas(point_set.originals[own], aux, box)
        cells.areas[own] = settled.areas
        cells.bounded[own] = settled.bounded
        if cells.inside_box is not None:
            cells.inside_box[own] = settled.inside_box
    return len(pixels)


def _suspect_pixels(point_set: _PointSet, exact: np.ndarray) -> np.ndarray:
    """Pixels with an original whose cell is not (provably) exact and bounded."""
    bad = np.flatnonzero(~exact)
    if not bad.size:
        return np.zeros(0, np.int64)
    return np.unique(np.searchsorted(point_set.offsets, bad, side="right") - 1)


def _scatter_pixels(
    cells: CellAreas, redo: CellAreas, offsets: np.ndarray, pixels: np.ndarray
) -> None:
    index, _ = segments(offsets, pixels)
    cells.areas[index] = redo.areas
    cells.bounded[index] = redo.bounded
    if cells.inside_box is not None:
        cells.inside_box[index] = redo.inside_box


# ---------------------------------------------------------------------------------------------
# Qhull calls


@dataclass(frozen=True)
class _Layout:
    """A point set laid out for Qhull: pixel by pixel, each pixel's originals then its ghosts,
    so that every Qhull call is one contiguous run of whole pixels. Points are complex128
    x + iy, so that one gather moves both coordinates."""

    z: np.ndarray  # (N,) pixel-local positions, laid out
    owner: np.ndarray  # (N,) the original a point is or images (auxiliary nuclei: their own)
    counts: np.ndarray  # (P,) points per pixel
    original_at: np.ndarray  # (T,) laid-out index of every original
    call_bounds: list[int]  # (C + 1,) laid-out index where each call starts
    call_pixels: list[int]  # (C + 1,) first pixel of each call
    slot_width: float  # distance between the slots of pixels that share a call

    def call_points(self, call: int) -> tuple[np.ndarray, np.ndarray | None]:
        """What Qhull gets for one call, (K, 2) float64 with pixel k of the call moved by
        k * slot_width along x, and each point's slot k (None for a one-pixel call)."""
        z = self.z[self.call_bounds[call] : self.call_bounds[call + 1]]
        p0, p1 = self.call_pixels[call], self.call_pixels[call + 1]
        if p1 - p0 == 1:
            return z.view(np.float64).reshape(-1, 2), None
        slot = np.repeat(np.arange(p1 - p0, dtype=np.int32), self.counts[p0:p1])
        moved = z + slot * self.slot_width
        return moved.view(np.float64).reshape(-1, 2), slot


def _call_layout(point_set: _PointSet, one_pixel_per_call: bool) -> _Layout:
    """Pack whole pixels into calls of about POINTS_PER_QHULL_CALL points (a large pixel gets a
    call of its own)."""
    offsets, ghost_offsets = point_set.offsets, point_set.ghost_offsets
    orig_counts = offsets[1:] - offsets[:-1]
    ghost_counts = ghost_offsets[1:] - ghost_offsets[:-1]
    counts = orig_counts + ghost_counts
    ends = np.cumsum(counts)
    starts = ends - counts
    total = int(ends[-1]) if len(ends) else 0
    original_at = np.arange(len(point_set.originals)) + np.repeat(
        starts - offsets[:-1], orig_counts
    )
    ghost_at = np.arange(len(point_set.ghosts)) + np.repeat(
        starts + orig_counts - ghost_offsets[:-1], ghost_counts
    )
    z = np.empty(total, np.complex128)
    z[original_at] = as_complex(point_set.originals)
    z[ghost_at] = as_complex(point_set.ghosts)
    owner = np.empty(total, np.int64)
    owner[original_at] = np.arange(len(point_set.originals))
    source = point_set.ghost_source
    owner[ghost_at] = np.where(
        source >= 0, source, len(point_set.originals) + np.arange(len(source))
    )
    if one_pixel_per_call:
        call_pixels = np.arange(len(counts) + 1)
    else:
        call_of_pixel = starts // POINTS_PER_QHULL_CALL
        # A call starts at pixel 0 and wherever starts // POINTS_PER_QHULL_CALL steps; the
        # last entry is the end sentinel (pixel count).
        new_call = np.ones(len(counts) + 1, bool)
        new_call[1:-1] = call_of_pixel[1:] != call_of_pixel[:-1]
        call_pixels = np.flatnonzero(new_call)
    call_bounds = np.concatenate([starts, [total]])[call_pixels]
    slot_width = 2.0 * point_set.half_extent * (1.0 + SLOT_GAP_FACTOR)
    return _Layout(
        z, owner, counts, original_at, call_bounds.tolist(), call_pixels.tolist(), slot_width
    )


# ---------------------------------------------------------------------------------------------
# Areas from triangles


def _cells(
    point_set: _PointSet, box: float | None, one_pixel_per_call: bool = False
) -> tuple[CellAreas, TessellationStats, np.ndarray]:
    """Areas and exactness flags of the originals' cells, and which pixels hold
    near-coincident nuclei ((P,) bool); see the module docstring.

    Each Qhull call's triangles are processed right after the call, while they are in cache,
    into the call's contiguous range of the laid-out arrays.
    """
    from scipy.spatial import Delaunay, QhullError

    stats = TessellationStats()
    layout = _call_layout(point_set, one_pixel_per_call)
    total = len(layout.z)
    areas = np.zeros(total)
    suspect = np.zeros(total, bool)  # cell not provably that of the pixel's own diagram
    near = np.zeros(total, bool)  # near-coincident with another point (see _call_cells)
    outside = np.zeros(total, bool) if box is not None else None
    failed_alone = []
    bounds, first_pixels = layout.call_bounds, layout.call_pixels
    with np.errstate(divide="ignore", invalid="ignore"):
        for call in range(len(bounds) - 1):
            lo, hi = bounds[call], bounds[call + 1]
            if lo == hi:
                continue
            stats.qhull_calls += 1
            points, slot = layout.call_points(call)
            try:
                tri = Delaunay(points, qhull_options=QHULL_OPTIONS)
            except (QhullError, ValueError):
                # Too few or collinear points: every cell of the call is suspect; pixels that
                # shared the call are redone alone, a pixel alone is judged below.
                suspect[lo:hi] = True
                if slot is None:
                    failed_alone.append(first_pixels[call])
                continue
            _call_cells(
                tri,
                layout.z[lo:hi],
                layout.owner[lo:hi],
                slot,
                NEAR_COINCIDENT * float(np.abs(points).max()),
                point_set.disc_box,
                box,
                areas[lo:hi],
                suspect[lo:hi],
                near[lo:hi],
                None if outside is None else outside[lo:hi],
            )

    # Pixels Qhull could not triangulate alone: every cell is unbounded (or it is an error if
    # the set was not degenerate).
    _check_degenerate(point_set, failed_alone)
    stats.degenerate_pixels += len(failed_alone)

    at = layout.original_at
    bounded = ~suspect[at]
    cell_areas = np.where(bounded, areas[at], np.nan)
    inside = None if outside is None else bounded & ~outside[at]
    near_before = np.concatenate([[0], np.cumsum(near)])  # near points before each point
    ends = np.cumsum(layout.counts)
    near_pixels = near_before[ends] > near_before[ends - layout.counts]
    return CellAreas(cell_areas, bounded, inside), stats, near_pixels


def _call_cells(
    tri: Delaunay,
    z: np.ndarray,
    owner: np.ndarray,
    slot: np.ndarray | None,
    near_length: float,
    disc_box: float | None,
    box: float | None,
    areas: np.ndarray,
    suspect: np.ndarray,
    near: np.ndarray,
    outside: np.ndarray | None,
) -> None:
    """Areas, suspect flags, near-coincident flags and outside-box flags of one Qhull call's
    points z, written into areas, suspect, near and outside (views of the call's range).
    owner: the original each point is or images; slot: each point's pixel slot (None: one
    pixel); near_length: NEAR_COINCIDENT times the call's extent. Runs under
    np.errstate(divide="ignore", invalid="ignore")."""
    count = len(z)
    s = np.ascontiguousarray(tri.simplices.T, dtype=np.intp)  # (3, M): vertices a, b, c
    t = TriangleTerms(z, s)
    local_areas = np.bincount(s.ravel(), t.pieces.ravel(), count)

    # Hull edge: the vertex opposite it has no neighbour; both its end points are unbounded.
    row, col = np.divmod(np.flatnonzero(tri.neighbors < 0), 3)
    suspect[s[(col + 1) % 3, row]] = True
    suspect[s[(col + 2) % 3, row]] = True

    # Triangles that make their vertices' cells suspect: degenerate, across pixels, or with a
    # circumdisc that may reach absent ghosts.
    bad = np.abs(t.det) > 0
    np.logical_not(bad, out=bad)
    if slot is not None:
        slot_a = slot.take(s[0])
        bad |= slot_a != slot.take(s[1])
        bad |= slot_a != slot.take(s[2])
    if disc_box is not None or box is not None:
        cx, cy, radius = t.circumcircle()
        if disc_box is not None:
            bad |= ~((np.abs(cx) + radius <= disc_box) & (np.abs(cy) + radius <= disc_box))
        if box is not None:
            out = ~((np.abs(cx) <= box) & (np.abs(cy) <= box))
            outside[s[:, np.flatnonzero(out)]] = True
    suspect[s[:, np.flatnonzero(bad)]] = True
    _flag_near_coincident(tri, t, z, owner, near_length, near)

    share_coincident(tri, local_areas, suspect, outside)
    areas[:] = local_areas


def _flag_near_coincident(
    tri: Delaunay,
    t: TriangleTerms,
    z: np.ndarray,
    owner: np.ndarray,
    near_length: float,
    near: np.ndarray,
) -> None:
    """Flag (in near) the end points of triangle edges shorter than near_length, except an
    original and its own mirror image (harmless, and common near W's edges), and the points
    Qhull dropped as "coplanar" on a vertex with other coordinates (not exact duplicates)."""
    s = tri.simplices
    limit = near_length * near_length
    short = t.l1 < limit
    short |= t.l2 < limit
    third = t.e2 - t.e1
    short |= third.real * third.real + third.imag * third.imag < limit
    for i, j in ((0, 1), (0, 2), (1, 2)):  # the few short triangles, edge by edge
        a, b = s[short, i], s[short, j]
        edge = z[b] - z[a]
        flagged = (edge.real**2 + edge.imag**2 < limit) & (owner[a] != owner[b])
        near[a[flagged]] = True
        near[b[flagged]] = True
    if len(tri.coplanar):
        dropped, kept = tri.coplanar[:, 0], tri.coplanar[:, 2]
        distinct = z[dropped] != z[kept]
        near[dropped[distinct]] = True
        near[kept[distinct]] = True


def _check_degenerate(point_set: _PointSet, pixels: list[int]) -> None:
    """Raise if Qhull rejected a one-pixel set that has >= 3 distinct non-collinear points."""
    for p in pixels:  # rare: only pixels whose whole set is degenerate get here
        pts = point_set.pixel_points(p)
        if not _is_degenerate(pts):
            raise ClrenderError(
                f"Qhull failed on a non-degenerate set of {len(pts)} points "
                "(not collinear, >= 3 distinct); please report the sample set"
            )


def _is_degenerate(points: np.ndarray) -> bool:
    """Fewer than 3 distinct points, or all on one line (relative tolerance 1e-12)."""
    if not np.isfinite(points).all():
        raise ParameterError("sample positions must be finite")
    distinct = np.unique(points, axis=0)
    if len(distinct) < 3:
        return True
    centred = distinct - distinct.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    return bool(singular[1] <= 1e-12 * singular[0])
