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

Cell areas from one triangulation. For a Delaunay triangle (a, b, c) with circumcentre o, the
part of a's Voronoi cell inside the triangle's "star" is the quadrilateral
(a, mid(a, b), o, mid(c, a)); its signed area (positive for counter-clockwise triangles) is
0.25 * cross(b - c, o - a). Summed over all triangles around a bounded cell these pieces
telescope to the cell polygon, so np.bincount over the three vertex columns gives every cell
area from one pass over the triangles. Sign conventions are fixed by |det|, so Qhull's
triangle orientation does not matter.

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

Degenerate sets. Coincident points (Qhull reports all but one as "coplanar") split their common
cell equally. A set Qhull cannot triangulate (fewer than 3 distinct points, or all collinear)
has only unbounded cells. For the clipped estimator, nuclei within EDGE_NUDGE of an edge of W
are moved EDGE_NUDGE inside it so that each has a mirror image distinct from itself; this moves
cell boundaries by at most EDGE_NUDGE. For the periodic estimator a nucleus on the edge x = 1/2
(or y = 1/2) is the same torus point as one on x = -1/2 and is wrapped there.

Speed. Qhull's cost per point grows with the size of the call on this hardware (about
1.7 us/point up to ~1000 points, 3-6 us/point for 5 000-50 000 points), so pixels are packed
into calls of about POINTS_PER_QHULL_CALL points; a large pixel gets a call of its own. All
area arithmetic runs once per batch over the concatenated triangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay, QhullError

from clrender.errors import ClrenderError, ParameterError

# SciPy's default for 2-D Delaunay ("Qt" is always added by SciPy). No "QJ": joggling moves the
# points and so changes the cells.
QHULL_OPTIONS = "Qbb Qc Qz Q12"
POINTS_PER_QHULL_CALL = 1200
EDGE_NUDGE = 1e-9
# Ghost margin for clipped/periodic cells, in mean nearest-neighbour distances 1/sqrt(N).
GHOST_MARGIN_SPACINGS = 5.0
# Fraction of a pixel's own extent left empty between pixels that share a Qhull call.
SLOT_GAP_FACTOR = 2.0


@dataclass
class TessellationStats:
    """Counters of one cell computation."""

    qhull_calls: int = 0
    recomputed_pixels: int = 0      # pixels redone alone (joint cell not provably exact)
    degenerate_pixels: int = 0      # pixels Qhull could not triangulate (all cells unbounded)

    def add(self, other: TessellationStats) -> None:
        self.qhull_calls += other.qhull_calls
        self.recomputed_pixels += other.recomputed_pixels
        self.degenerate_pixels += other.degenerate_pixels


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
    """Originals then ghosts of a batch, each block sorted by pixel, in pixel-local coordinates."""

    points: np.ndarray         # (T + G, 2)
    pixel: np.ndarray          # (T + G,) pixel index of every point
    original_count: int        # T
    offsets: np.ndarray        # (P + 1,) originals per pixel
    ghost_offsets: np.ndarray  # (P + 1,) ghosts per pixel
    half_extent: float         # every point lies in [-half_extent, half_extent]^2
    disc_box: float | None     # check circumdiscs against [-disc_box, disc_box]^2 (partial ghosts)

    @property
    def pixel_count(self) -> int:
        return len(self.offsets) - 1


# ---------------------------------------------------------------------------------------------
# Public entry points


def sppp_cells(positions: np.ndarray, offsets: np.ndarray, aux: np.ndarray,
               aux_offsets: np.ndarray, box: float | None = None) -> CellAreas:
    """Cells of the W nuclei among W + auxiliary nuclei (the paper's SPPP tessellation).

    box: also report which cells lie inside [-box, box]^2 (box = 1/2 + eps is W' for fvor).
    """
    point_set = _sppp_point_set(positions, offsets, aux, aux_offsets)
    cells, stats = _cells(point_set, box)
    suspect = _suspect_pixels(point_set, cells.bounded)
    if suspect.size:
        subset = _subset_sppp(point_set, suspect)
        redo, redo_stats = _cells(subset, box, one_pixel_per_call=True)
        _scatter_pixels(cells, redo, point_set.offsets, suspect)
        stats.add(redo_stats)
        stats.recomputed_pixels += suspect.size
    cells.stats = stats
    return cells


def clipped_cells(positions: np.ndarray, offsets: np.ndarray) -> CellAreas:
    """Cells of the originals among themselves, clipped to W (mirror images as ghosts)."""
    return _ghost_cells(_nudge_inside(positions), offsets, _mirror_ghosts)


def periodic_cells(positions: np.ndarray, offsets: np.ndarray) -> CellAreas:
    """Cells of the originals on the torus W (translated copies as ghosts)."""
    return _ghost_cells(_wrap_torus(positions), offsets, _periodic_ghosts)


def qhull_point_arrays(positions: np.ndarray, offsets: np.ndarray, aux: np.ndarray,
                       aux_offsets: np.ndarray) -> list[np.ndarray]:
    """The point arrays sppp_cells hands to Qhull (for timing bare Delaunay on the same points)."""
    point_set = _sppp_point_set(positions, offsets, aux, aux_offsets)
    return [pts for pts, _, _ in _call_layouts(point_set, one_pixel_per_call=False)]


# ---------------------------------------------------------------------------------------------
# Point sets


def _pixel_of(offsets: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))


def _sppp_point_set(positions, offsets, aux, aux_offsets) -> _PointSet:
    positions = np.asarray(positions, dtype=np.float64)
    aux = np.asarray(aux, dtype=np.float64)
    points = np.concatenate([positions, aux])
    half_extent = float(np.abs(points).max()) if len(points) else 0.5
    return _PointSet(points, np.concatenate([_pixel_of(offsets), _pixel_of(aux_offsets)]),
                     len(positions), np.asarray(offsets), np.asarray(aux_offsets),
                     max(half_extent, 0.5), None)


def _subset_sppp(point_set: _PointSet, pixels: np.ndarray) -> _PointSet:
    """The same point set restricted to some pixels (renumbered 0..len(pixels)-1)."""
    t = point_set.original_count
    orig_idx, orig_offsets = _segments(point_set.offsets, pixels)
    ghost_idx, ghost_offsets = _segments(point_set.ghost_offsets, pixels)
    points = np.concatenate([point_set.points[orig_idx], point_set.points[t + ghost_idx]])
    return _PointSet(points, np.concatenate([_pixel_of(orig_offsets), _pixel_of(ghost_offsets)]),
                     len(orig_idx), orig_offsets, ghost_offsets, point_set.half_extent, None)


def _segments(offsets: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the concatenated segments offsets[p]:offsets[p+1] for p in pixels, and the
    offsets of those segments in the concatenation."""
    starts = offsets[pixels]
    lengths = offsets[pixels + 1] - starts
    new_offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    index = np.arange(new_offsets[-1]) - np.repeat(new_offsets[:-1] - starts, lengths)
    return index, new_offsets


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
    ghosts = np.column_stack([maps[:, 0] * positions[source, 0] + maps[:, 1],
                              maps[:, 2] * positions[source, 1] + maps[:, 3]])
    return ghosts, source


_SHIFTS = np.array([(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)],
                   float)


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
    pixel = _pixel_of(offsets)
    ghost_pixel = pixel[source]
    ghost_offsets = np.searchsorted(ghost_pixel, np.arange(len(offsets)))
    full = margin >= 1.0
    half_extent = 1.5 if full else 0.5 + margin
    return _PointSet(np.concatenate([positions, ghosts]), np.concatenate([pixel, ghost_pixel]),
                     len(positions), offsets, ghost_offsets, half_extent,
                     None if full else 0.5 + margin)


def _ghost_cells(positions: np.ndarray, offsets: np.ndarray, make_ghosts) -> CellAreas:
    offsets = np.asarray(offsets)
    margin = _ghost_margin(offsets)
    point_set = _ghost_point_set(positions, offsets, make_ghosts, margin)
    cells, stats = _cells(point_set, None)
    suspect = _suspect_pixels(point_set, cells.bounded)
    if suspect.size:
        index, sub_offsets = _segments(offsets, suspect)
        subset = _ghost_point_set(positions[index], sub_offsets, make_ghosts, 1.0)
        redo, redo_stats = _cells(subset, None, one_pixel_per_call=True)
        if not redo.bounded.all():
            raise ClrenderError("internal error: a clipped/periodic Voronoi cell came out "
                                "unbounded; please report the sample set")
        _scatter_pixels(cells, redo, offsets, suspect)
        stats.add(redo_stats)
        stats.recomputed_pixels += suspect.size
    cells.stats = stats
    return cells


def _suspect_pixels(point_set: _PointSet, exact: np.ndarray) -> np.ndarray:
    """Pixels with an original whose cell is not (provably) exact and bounded."""
    bad = ~exact
    if not bad.any():
        return np.zeros(0, np.int64)
    return np.unique(point_set.pixel[: point_set.original_count][bad])


def _scatter_pixels(cells: CellAreas, redo: CellAreas, offsets: np.ndarray,
                    pixels: np.ndarray) -> None:
    index, _ = _segments(offsets, pixels)
    cells.areas[index] = redo.areas
    cells.bounded[index] = redo.bounded
    if cells.inside_box is not None:
        cells.inside_box[index] = redo.inside_box


# ---------------------------------------------------------------------------------------------
# Qhull calls


def _call_layouts(point_set: _PointSet, one_pixel_per_call: bool):
    """Yield (points, point-set indices, pixels) for each Qhull call: whole pixels, packed to
    about POINTS_PER_QHULL_CALL points, each pixel translated to its own slot along x."""
    counts = np.diff(point_set.offsets) + np.diff(point_set.ghost_offsets)
    starts = np.cumsum(counts) - counts
    if one_pixel_per_call:
        call_of_pixel = np.arange(len(counts))
    else:
        call_of_pixel = starts // POINTS_PER_QHULL_CALL
        # Renumber so that calls are consecutive integers.
        call_of_pixel = np.concatenate([[0], np.cumsum(np.diff(call_of_pixel) > 0)])
    first = np.flatnonzero(np.diff(call_of_pixel, prepend=-1) != 0)
    bounds = np.append(first, len(counts))
    slot_width = 2.0 * point_set.half_extent * (1.0 + SLOT_GAP_FACTOR)
    t = point_set.original_count
    for p0, p1 in zip(bounds[:-1], bounds[1:], strict=True):
        o0, o1 = point_set.offsets[p0], point_set.offsets[p1]
        g0, g1 = point_set.ghost_offsets[p0], point_set.ghost_offsets[p1]
        index = np.concatenate([np.arange(o0, o1), np.arange(t + g0, t + g1)])
        points = point_set.points[index]
        if p1 - p0 > 1:
            points[:, 0] += (point_set.pixel[index] - p0) * slot_width
        yield points, index, np.arange(p0, p1)


def _concat_or_empty(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


# ---------------------------------------------------------------------------------------------
# Areas from triangles


def _cells(point_set: _PointSet, box: float | None,
           one_pixel_per_call: bool = False) -> tuple[CellAreas, TessellationStats]:
    """Areas and exactness flags of the originals' cells; see the module docstring.

    Each Qhull call's triangles are processed right after the call, while they are in cache.
    """
    stats = TessellationStats()
    total = len(point_set.points)
    areas = np.zeros(total)
    suspect = np.zeros(total, bool)    # cell not provably that of the pixel's own diagram
    outside = np.zeros(total, bool) if box is not None else None
    failed_alone, failed_shared = [], []
    for points, index, pixels in _call_layouts(point_set, one_pixel_per_call):
        if len(points) == 0:
            continue
        stats.qhull_calls += 1
        try:
            tri = Delaunay(points, qhull_options=QHULL_OPTIONS)
        except (QhullError, ValueError):
            # Too few or collinear points: judged per pixel below.
            (failed_alone if len(pixels) == 1 else failed_shared).append(pixels)
            continue
        local = _call_cells(tri, point_set, index, len(pixels) > 1, box)
        areas[index], suspect[index] = local[0], local[1]
        if outside is not None:
            outside[index] = local[2]

    # Pixels Qhull could not triangulate: redone alone if they shared the call; alone, every
    # cell is unbounded (or it is an error if the set was not degenerate).
    failed_alone = _concat_or_empty(failed_alone)
    _mark_pixels(point_set, _concat_or_empty(failed_shared), suspect)
    _mark_pixels(point_set, failed_alone, suspect)
    _check_degenerate(point_set, failed_alone)
    stats.degenerate_pixels += len(failed_alone)

    t = point_set.original_count
    bounded = ~suspect[:t]
    cell_areas = np.where(bounded, areas[:t], np.nan)
    inside = None if outside is None else bounded & ~outside[:t]
    return CellAreas(cell_areas, bounded, inside), stats


def _call_cells(tri: Delaunay, point_set: _PointSet, index: np.ndarray, multi_pixel: bool,
                box: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Areas, suspect flags and outside-box flags of one Qhull call's points."""
    count = len(index)
    s = tri.simplices
    geometry = _triangle_geometry(point_set.points[index], s)
    areas = (np.bincount(s[:, 0], geometry.area_a, count)
             + np.bincount(s[:, 1], geometry.area_b, count)
             + np.bincount(s[:, 2], geometry.area_c, count))

    suspect = np.zeros(count, bool)
    rows, cols = np.nonzero(tri.neighbors == -1)     # hull edge: opposite vertex has no neighbour
    suspect[s[rows, (cols + 1) % 3]] = True
    suspect[s[rows, (cols + 2) % 3]] = True
    bad_triangle = ~np.isfinite(geometry.area_a + geometry.area_b + geometry.area_c)
    if multi_pixel:
        pixel_of_vertex = point_set.pixel[index][s]
        bad_triangle |= ((pixel_of_vertex[:, 0] != pixel_of_vertex[:, 1])
                         | (pixel_of_vertex[:, 0] != pixel_of_vertex[:, 2]))
    if point_set.disc_box is not None:
        bad_triangle |= _disc_leaves_box(geometry, point_set.disc_box)
    suspect[s[bad_triangle].ravel()] = True

    outside = None
    if box is not None:
        outside = np.zeros(count, bool)
        outside[s[_centre_outside_box(geometry, box)].ravel()] = True

    # Coincident points: the vertex Qhull kept and the points it dropped share the cell.
    if len(tri.coplanar):
        dropped, kept = tri.coplanar[:, 0], tri.coplanar[:, 2]
        areas /= 1.0 + np.bincount(kept, minlength=count)
        areas[dropped] = areas[kept]
        suspect[dropped] = suspect[kept]
        if outside is not None:
            outside[dropped] = outside[kept]
    return areas, suspect, outside


@dataclass(frozen=True)
class _TriangleGeometry:
    """Per-triangle quantities: vertex a's position, circumcentre offset u = o - a, and the
    signed areas each vertex's cell gets from the triangle."""

    ax: np.ndarray
    ay: np.ndarray
    ux: np.ndarray
    uy: np.ndarray
    area_a: np.ndarray
    area_b: np.ndarray
    area_c: np.ndarray


def _triangle_geometry(points: np.ndarray, simplices: np.ndarray) -> _TriangleGeometry:
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    a, b, c = simplices[:, 0], simplices[:, 1], simplices[:, 2]
    ax, ay = x.take(a), y.take(a)
    e1x, e1y = x.take(b) - ax, y.take(b) - ay
    e2x, e2y = x.take(c) - ax, y.take(c) - ay
    l1 = e1x * e1x + e1y * e1y
    l2 = e2x * e2x + e2y * e2y
    dot = e1x * e2x + e1y * e2y
    det = e1x * e2y - e1y * e2x
    with np.errstate(divide="ignore", invalid="ignore"):
        # With U = (e2y l1 - e1y l2, e1x l2 - e2x l1), o - a = U / (2 det); the quadrilateral
        # areas 0.25 cross(b - c, o - a) etc. reduce to these forms (k = 1 / (8 |det|)).
        k = 0.125 / np.abs(det)
        half_tri = 0.25 * np.abs(det)
        t1 = l1 * (l2 - dot)
        t2 = l2 * (l1 - dot)
        area_a = k * (t1 + t2)
        area_b = half_tri - k * t2
        area_c = half_tri - k * t1
        inv = 0.5 / det
        ux = (e2y * l1 - e1y * l2) * inv
        uy = (e1x * l2 - e2x * l1) * inv
    return _TriangleGeometry(ax, ay, ux, uy, area_a, area_b, area_c)


def _disc_leaves_box(g: _TriangleGeometry, half: float) -> np.ndarray:
    radius = np.sqrt(g.ux * g.ux + g.uy * g.uy)
    with np.errstate(invalid="ignore"):
        return ~((np.abs(g.ax + g.ux) + radius <= half) & (np.abs(g.ay + g.uy) + radius <= half))


def _centre_outside_box(g: _TriangleGeometry, half: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return ~((np.abs(g.ax + g.ux) <= half) & (np.abs(g.ay + g.uy) <= half))


def _mark_pixels(point_set: _PointSet, pixels: np.ndarray, suspect: np.ndarray) -> None:
    """Mark every point of the given pixels as not exact (unbounded unless redone)."""
    orig, _ = _segments(point_set.offsets, pixels)
    ghost, _ = _segments(point_set.ghost_offsets, pixels)
    suspect[orig] = True
    suspect[point_set.original_count + ghost] = True


def _check_degenerate(point_set: _PointSet, pixels: np.ndarray) -> None:
    """Raise if Qhull rejected a one-pixel set that has >= 3 distinct non-collinear points."""
    t = point_set.original_count
    for p in pixels:  # rare: only pixels whose whole set is degenerate get here
        pts = np.concatenate([
            point_set.points[point_set.offsets[p]:point_set.offsets[p + 1]],
            point_set.points[t + point_set.ghost_offsets[p]:t + point_set.ghost_offsets[p + 1]]])
        if not _is_degenerate(pts):
            raise ClrenderError(f"Qhull failed on a non-degenerate set of {len(pts)} points "
                                "(not collinear, >= 3 distinct); please report the sample set")


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
