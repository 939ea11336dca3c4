"""Exact Voronoi cells by half-plane clipping: how the host settles the pixels whose Qhull
cells cannot be trusted (clusters of nearly coincident nuclei; see
clrender.estimators.qhull_cells, "Near-coincident nuclei"), and the cells of such nuclei in the
image-level tessellation (clrender.estimators.image).

The cell of nucleus a among nuclei Q is the intersection of the half-planes
(z - a) . d <= |d|^2 / 2, d = q - a, q in Q. Each cell is clipped from a start polygon by its
neighbours in order of distance; once the cell's security radius (twice its largest vertex
distance from a) is below the distance of the next neighbour, no farther nucleus can cut it (its
bisector lies beyond every vertex) and the cell is final. The three tessellations of qhull_cells:

- clipped (cvor): start from W; the neighbours are the pixel's other nuclei.
- torus (pvor): start from a + [-1/2, 1/2]^2, which holds the torus cell (the nucleus's own
  translates cut nothing inside it); the neighbours are the 9 translates x + (i, j),
  i, j in {-1, 0, 1}, of every nucleus.
- SPPP (vor, vor_sn, fvor): the W nuclei among W + auxiliary nuclei. A cell is unbounded exactly
  when its nucleus lies on the convex hull of all the nuclei, that is when the directions to all
  the other nuclei fit in a closed half-plane (largest angular gap >= pi, within GAP_TOLERANCE).
  That is decided first, from the nearest neighbours when they already surround the nucleus,
  else from all the nuclei; bounded cells are clipped from the box of half-size
  SPPP_START_BOX times the set's extent (a cell still touching that box at the end counts as
  unbounded: its nucleus lies within rounding of the hull).
- Some nuclei among a point set (cells_among, for the image-level blocks): start from a given
  box; the neighbours are all the points. Besides the areas it reports each cell's Delaunay
  circumdiscs (their bounding box, for the blocks' certification) and the points that border
  the cells.

Coincident nuclei (identical coordinates) share their cell equally, as in qhull_cells.

Precision. Each cell is computed in coordinates relative to its own nucleus a, and every
polygon edge remembers what it lies on: the bisector of a and a site (the neighbour that cut it),
or a side of the start box. A new vertex where two bisectors meet is the circumcentre of a and
their two sites, computed from the triangle's vertex opposite its longest side, so that within a
cluster both edge vectors are exact differences of nearby coordinates (solving the two nearly
parallel bisectors of a far nucleus and two cluster nuclei directly loses 8 digits to
cancellation); where a bisector meets a box side it is solved in a's frame. Never an
interpolation between possibly distant vertices: the arithmetic of a cell is scale-free, and
the cells of a cluster of nuclei 1e-9 apart are as accurate (relative, ~1e-15) as those of
well-spread nuclei. (A crossing whose solve lands off its edge, nearly parallel lines, is
interpolated along the edge instead.)

Vectorisation. All the cells of a pixel are clipped together, as polygons in arrays of
(cells, capacity) grown when needed, with vertex counts. The only Python loop is over
neighbour rank: every open cell advances one neighbour in its own distance-sorted list
(scipy.spatial.cKDTree, asked for more neighbours when an open cell has used its list up), and
finished cells leave the working arrays. A random pixel of 4096 nuclei takes 0.2 to 0.4 s (any
of the three tessellations), one of 64 nuclei about 0.02 s.

Reproducibility (cells_among). A cell's vertices are circumcentres of its nucleus and two of its
neighbours, computed when the later of the two clips the polygon, in neighbour order; a cell
that ends clear of its start box therefore does not depend on that box. Each cell is clipped by
its own sites in distance order, each once (when the lists grow, every cell resumes after the
sites it has used, ties at the last distance included), whatever other cells are clipped with
it; and its area is summed exactly rounded (math.fsum), so neither the polygon's first vertex
nor the arrays' width matter. Such a cell has the same bits in any point set that holds its
neighbours (barring a point within rounding of one of its circumcircles), which the
image-level estimators need across blockings.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clrender.estimators.delaunay import as_complex

if TYPE_CHECKING:  # scipy.spatial is imported where used: it takes ~1 s to import
    from scipy.spatial import cKDTree

# Neighbours asked of the k-d tree at first (more when an open cell has used them up).
FIRST_NEIGHBOURS = 16
# The SPPP start box, in multiples of the set's extent (bounded cells near the hull are large).
SPPP_START_BOX = 1e15
# A nucleus is on the hull when its largest angular gap is at least pi - GAP_TOLERANCE.
GAP_TOLERANCE = 1e-12
# The security test 4 R^2 < |d_next|^2 with a margin for the rounding of the tree's distances.
SECURITY_MARGIN = 1.0 + 1e-9
# Directions held at once by the hull test over all the nuclei (memory: 16 bytes each).
HULL_TEST_DIRECTIONS = 1 << 22


def clipped_cell_areas(nuclei: np.ndarray) -> np.ndarray:
    """Areas of the cells of the nuclei ((K, 2) in W) among themselves, clipped to W."""
    nuclei = np.asarray(nuclei, np.float64).reshape(-1, 2)
    return _clipped_areas(nuclei, nuclei, -0.5 - nuclei, 0.5 - nuclei)


def torus_cell_areas(nuclei: np.ndarray) -> np.ndarray:
    """Areas of the cells of the nuclei ((K, 2) in [-1/2, 1/2)^2) on the torus W."""
    nuclei = np.asarray(nuclei, np.float64).reshape(-1, 2)
    shifts = [(0.0, 0.0)] + [
        (i, j) for i in (-1.0, 0.0, 1.0) for j in (-1.0, 0.0, 1.0) if (i, j) != (0.0, 0.0)
    ]
    copies = np.concatenate([nuclei + np.array(s) for s in shifts])
    half = np.full(nuclei.shape, 0.5)
    return _clipped_areas(nuclei, copies, -half, half)


@dataclass(frozen=True)
class SpppCells:
    """Cells of a pixel's W nuclei among W + auxiliary nuclei: areas (NaN where unbounded),
    bounded, and inside_box (whole cell in [-box, box]^2; None when no box was asked)."""

    areas: np.ndarray
    bounded: np.ndarray
    inside_box: np.ndarray | None


def sppp_cell_areas(nuclei: np.ndarray, aux: np.ndarray, box: float | None = None) -> SpppCells:
    """Cells of the W nuclei ((K, 2)) among themselves and the auxiliary nuclei ((A, 2))."""
    from scipy.spatial import cKDTree

    nuclei = np.asarray(nuclei, np.float64).reshape(-1, 2)
    points = np.concatenate([nuclei, np.asarray(aux, np.float64).reshape(-1, 2)])
    count = len(nuclei)
    areas = np.full(count, np.nan)
    bounded = np.zeros(count, bool)
    inside = np.zeros(count, bool) if box is not None else None
    if count == 0:
        return SpppCells(areas, bounded, inside)
    tree = cKDTree(points)
    bounded = ~_on_hull(nuclei, points, tree)
    cells = np.flatnonzero(bounded)
    if cells.size:
        extent = SPPP_START_BOX * max(float(np.abs(points).max()), 0.5)
        here = nuclei[cells]
        polygons = _clip_all(here, points, tree, -extent - here, extent - here)
        reach = polygons.reach(as_complex(here))
        touches = reach >= extent * (1.0 - 1e-9)
        bounded[cells[touches]] = False
        ok = ~touches
        areas[cells[ok]] = polygons.areas()[ok] / _multiplicity(here[ok], tree)
        if inside is not None:
            inside[cells[ok]] = reach[ok] <= box
    return SpppCells(areas, bounded, inside)


@dataclass(frozen=True)
class CellsAmong:
    """Cells of some nuclei of a point set within a box (cells_among): areas; disc_boxes (K, 4)
    x0, y0, x1, y1, the bounding box of each cell's Delaunay circumdiscs (the discs centred at
    its vertices through its nucleus); neighbours, the indices of the points whose bisector
    bounds one of the cells (sorted, unique)."""

    areas: np.ndarray
    disc_boxes: np.ndarray
    neighbours: np.ndarray


def cells_among(
    points: np.ndarray, which: np.ndarray, box: tuple[float, ...], tree: cKDTree | None = None
) -> CellsAmong:
    """Cells of points[which] among all the points ((M, 2)), clipped to box = (x0, y0, x1, y1)
    (each nucleus inside it); tree: a cKDTree of the points, if one is at hand.

    A cell whose disc box lies inside the box comes out with the same bits from any such box,
    any point set that holds its neighbours, and whatever other cells are computed with it
    (module docstring, "Reproducibility").
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64).reshape(-1, 2)
    which = np.asarray(which, np.int64)
    if which.size == 0:
        return CellsAmong(np.zeros(0), np.zeros((0, 4)), np.zeros(0, np.int64))
    tree = cKDTree(points) if tree is None else tree
    nuclei = points[which]
    lo = np.array(box[:2], np.float64) - nuclei
    hi = np.array(box[2:], np.float64) - nuclei
    polygons = _clip_all(nuclei, points, tree, lo, hi)
    here = as_complex(nuclei)
    sites = polygons.bisector_sites()
    found = tree.query_ball_point(np.column_stack([sites.real, sites.imag]), 0.0)
    neighbours = np.unique(np.fromiter(itertools.chain.from_iterable(found), np.int64))
    areas = polygons.fsum_areas() / _multiplicity(nuclei, tree)
    return CellsAmong(areas, polygons.disc_boxes(here), neighbours)


# ---------------------------------------------------------------------------------------------
# Clipping


@dataclass
class _Polygons:
    """Convex polygons, one per cell, in coordinates relative to the cell's nucleus: vertex j of
    cell i is v[i, j] (complex x + iy, j < count[i]). The edge from it to the next vertex lies
    on the bisector of the nucleus and site[i, j] (absolute coordinates) where side[i, j] < 0,
    else on side side[i, j] of the cell's start box [x0, x1] x [y0, y1] (relative): side 0
    (bottom) is y = box[i, 0] = y0, 1 (right) x = x1, 2 (top) y = y1, 3 (left) x = x0."""

    v: np.ndarray  # (K, capacity) complex128
    site: np.ndarray  # (K, capacity) complex128
    side: np.ndarray  # (K, capacity) int8
    box: np.ndarray  # (K, 4) float64: y0, x1, y1, x0
    count: np.ndarray  # (K,) int64

    @staticmethod
    def boxes(lo: np.ndarray, hi: np.ndarray) -> _Polygons:
        """Boxes [lo, hi] ((K, 2) corners relative to the nuclei), counter-clockwise from the
        lower left."""
        x0, y0, x1, y1 = lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]
        v = np.column_stack([x0 + 1j * y0, x1 + 1j * y0, x1 + 1j * y1, x0 + 1j * y1])
        side = np.tile(np.arange(4, dtype=np.int8), (len(lo), 1))
        box = np.column_stack([y0, x1, y1, x0])
        return _Polygons(v, np.zeros_like(v), side, box, np.full(len(lo), 4))

    def take(self, rows: np.ndarray) -> _Polygons:
        return _Polygons(
            self.v[rows], self.site[rows], self.side[rows], self.box[rows], self.count[rows]
        )

    def valid(self) -> np.ndarray:
        return np.arange(self.v.shape[1]) < self.count[:, None]

    def next_index(self) -> np.ndarray:
        j = np.arange(self.v.shape[1])
        return np.where(j + 1 < self.count[:, None], j + 1, 0)

    def radius_squared(self) -> np.ndarray:
        """Largest squared vertex distance from the nucleus, per cell."""
        return np.where(self.valid(), _norm2(self.v), 0.0).max(axis=1)

    def areas(self) -> np.ndarray:
        """Shoelace areas (the nucleus is inside, so every term is >= 0: no cancellation)."""
        nxt = np.take_along_axis(self.v, self.next_index(), axis=1)
        cross = (self.v.conjugate() * nxt).imag
        return 0.5 * np.where(self.valid(), cross, 0.0).sum(axis=1)

    def reach(self, nuclei: np.ndarray) -> np.ndarray:
        """Largest |x| or |y| of a vertex in absolute coordinates, per cell."""
        x = np.abs(self.v.real + nuclei.real[:, None])
        y = np.abs(self.v.imag + nuclei.imag[:, None])
        return np.where(self.valid(), np.maximum(x, y), 0.0).max(axis=1)

    def fsum_areas(self) -> np.ndarray:
        """Shoelace areas with each cell's terms summed exactly rounded (math.fsum): the same
        bits whichever vertex a polygon starts from and whatever the arrays' capacity."""
        nxt = np.take_along_axis(self.v, self.next_index(), axis=1)
        cross = self.v.real * nxt.imag - self.v.imag * nxt.real
        rows = zip(cross, self.count, strict=True)
        return np.array([0.5 * math.fsum(row[:k]) for row, k in rows], np.float64)

    def disc_boxes(self, nuclei: np.ndarray) -> np.ndarray:
        """(K, 4) x0, y0, x1, y1: the bounding box of the discs centred at each cell's vertices
        through its nucleus (its Delaunay circumdiscs), absolute coordinates."""
        valid = self.valid()
        radius = np.sqrt(_norm2(self.v))
        lo_x = np.where(valid, self.v.real - radius, np.inf).min(axis=1)
        lo_y = np.where(valid, self.v.imag - radius, np.inf).min(axis=1)
        hi_x = np.where(valid, self.v.real + radius, -np.inf).max(axis=1)
        hi_y = np.where(valid, self.v.imag + radius, -np.inf).max(axis=1)
        x, y = nuclei.real, nuclei.imag
        return np.column_stack([x + lo_x, y + lo_y, x + hi_x, y + hi_y])

    def bisector_sites(self) -> np.ndarray:
        """The sites (absolute, complex) of the edges that lie on bisectors, all cells."""
        return self.site[self.valid() & (self.side < 0)]


def _clip(poly: _Polygons, nuclei: np.ndarray, sites: np.ndarray) -> _Polygons:
    """Each polygon i clipped to the side of the bisector of nuclei[i] and sites[i] that holds
    the nucleus (complex absolute coordinates). A site on its nucleus (a coincident neighbour)
    leaves the polygon as it is."""
    d = sites - nuclei
    half_d2 = 0.5 * _norm2(d)
    s = (poly.v * d.conjugate()[:, None]).real - half_d2[:, None]  # <= 0: inside
    valid = poly.valid()
    nxt = poly.next_index()
    s_next = np.take_along_axis(s, nxt, axis=1)
    if not (valid & (s > 0)).any():
        return poly
    keep = valid & (s <= 0)
    exits = valid & (s < 0) & (s_next > 0)
    enters = valid & (s > 0) & (s_next < 0)
    crossing = exits | enters

    # Where the polygon crosses the bisector: on the edge from vertex j to j + 1
    row, col = np.nonzero(crossing)
    p, q = poly.v[row, col], poly.v[row, nxt[row, col]]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        on_bisector = _circumcentre(nuclei[row], poly.site[row, col], sites[row])
        on_box = _box_crossing(poly.box[row], poly.side[row, col], d[row], half_d2[row])
        found = np.where(poly.side[row, col] < 0, on_bisector, on_box)
        # Nearly parallel lines: where the solve lands off the edge, interpolate along it
        edge = q - p
        t = ((found - p) * edge.conjugate()).real / _norm2(edge)
        interpolated = p + (s[row, col] / (s[row, col] - s_next[row, col])) * edge
    good = np.isfinite(found) & (t >= -1e-9) & (t <= 1.0 + 1e-9)
    cross_at = np.where(good, found, interpolated)

    # New polygons: each kept vertex, then the crossing point on its outgoing edge (if any).
    # Edge lines: an exit point's edge, and that of a kept vertex on the bisector whose next
    # vertex is outside, run along the new bisector; every other point keeps the line of the
    # edge it starts (an entry point lies on that edge).
    emitted = keep.astype(np.int64) + crossing
    position = np.cumsum(emitted, axis=1) - emitted
    count = emitted.sum(axis=1)
    shape = (len(count), max(poly.v.shape[1], int(count.max())))
    v = np.zeros(shape, np.complex128)
    site = np.zeros(shape, np.complex128)
    side = np.full(shape, -1, np.int8)

    kr, kc = np.nonzero(keep)
    along = (s[kr, kc] == 0) & (s_next[kr, kc] > 0)
    at = position[kr, kc]
    v[kr, at] = poly.v[kr, kc]
    site[kr, at] = np.where(along, sites[kr], poly.site[kr, kc])
    side[kr, at] = np.where(along, -1, poly.side[kr, kc])

    exit_point = exits[row, col]
    at = position[row, col] + keep[row, col]
    v[row, at] = cross_at
    site[row, at] = np.where(exit_point, sites[row], poly.site[row, col])
    side[row, at] = np.where(exit_point, -1, poly.side[row, col])
    return _Polygons(v, site, side, poly.box, count)


def _box_crossing(box: np.ndarray, side: np.ndarray, d: np.ndarray, half_d2: np.ndarray):
    """Where side `side` of each start box (relative coordinates) meets the bisector
    x d.x + y d.y = |d|^2 / 2 (relative to the nucleus). Runs under np.errstate."""
    fixed = box[np.arange(len(side)), np.maximum(side, 0)]  # the side's fixed coordinate
    vertical = (side == 1) | (side == 3)
    # On a vertical side x is fixed and y follows from the bisector, and the other way round
    y = (half_d2 - fixed * d.real) / d.imag
    x = (half_d2 - fixed * d.imag) / d.real
    return np.where(vertical, fixed + 1j * y, x + 1j * fixed)


def _circumcentre(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Circumcentres of triangles (a, b, c) (complex), relative to a. Computed from the vertex
    opposite the longest side, so that both edge vectors are the short ones: within a cluster
    they are exact differences of nearby coordinates."""
    ab, ac, bc = b - a, c - a, c - b
    l_ab, l_ac, l_bc = _norm2(ab), _norm2(ac), _norm2(bc)
    from_b = (l_ac >= l_ab) & (l_ac >= l_bc)  # longest side ac: from b
    from_c = ~from_b & (l_ab >= l_bc)  # longest side ab: from c
    base = np.where(from_b, ab, np.where(from_c, ac, 0))
    e1 = np.where(from_b, -ab, np.where(from_c, -ac, ab))
    e2 = np.where(from_b, bc, np.where(from_c, -bc, ac))
    l1, l2 = _norm2(e1), _norm2(e2)
    det = (e1.conjugate() * e2).imag
    return base + 1j * (e1 * l2 - e2 * l1) / (2.0 * det)


def _norm2(z: np.ndarray) -> np.ndarray:
    return z.real**2 + z.imag**2


def _clip_all(
    nuclei: np.ndarray, points: np.ndarray, tree: cKDTree, lo: np.ndarray, hi: np.ndarray
) -> _Polygons:
    """The cells of the nuclei ((K, 2)) among the points ((M, 2), in `tree`, the nuclei among
    them), each clipped from its box [lo, hi] ((K, 2) corners relative to its nucleus), by
    neighbour rank until secured."""
    here = as_complex(nuclei)
    sites = as_complex(points)
    finished = _Polygons.boxes(lo, hi)
    poly = finished
    total = len(points)
    width = min(FIRST_NEIGHBOURS, total)
    dist, index = _query(tree, nuclei, width)
    open_cells = np.arange(len(here))  # cells still being clipped
    rank = np.zeros(len(here), np.int64)  # next neighbour of each open cell
    while open_cells.size:
        rows = np.arange(open_cells.size)
        # Open cells that have used their list up get a longer one (every open cell does,
        # and resumes after the sites it has used: none is clipped twice)
        if width < total and (rank >= width).any():
            last, used, used_count = dist[rows, rank - 1], index, rank
            width = min(4 * width, total)
            dist, index = _query(tree, nuclei[open_cells], width)
            rank = _resume(dist, index, last, used, used_count)
        used_up = rank >= width  # (only when width == total: nothing left to clip by)
        site = np.where(used_up, here, sites[index[rows, np.minimum(rank, width - 1)]])
        poly = _clip(poly, here, site)
        rank += 1

        # A cell is final once no further neighbour can reach it
        used_up = rank >= width
        next_d = dist[rows, np.minimum(rank, width - 1)]
        secured = 4.0 * poly.radius_squared() * SECURITY_MARGIN < next_d * next_d
        done = np.where(used_up, width == total, secured)
        if done.any():
            finished = _store(finished, open_cells[done], poly.take(np.flatnonzero(done)))
            keep = np.flatnonzero(~done)
            open_cells, here, poly = open_cells[keep], here[keep], poly.take(keep)
            rank, dist, index = rank[keep], dist[keep], index[keep]
    return finished


def _query(tree: cKDTree, nuclei: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    dist, index = tree.query(nuclei, k=width)
    return dist.reshape(len(nuclei), width), index.reshape(len(nuclei), width)


def _resume(
    dist: np.ndarray, index: np.ndarray, last: np.ndarray, used: np.ndarray, used_count: np.ndarray
) -> np.ndarray:
    """Where each cell resumes in its longer neighbour list (dist, index; rows sorted by
    distance) after the sites it has used (the first used_count[i] of used[i], the last at
    distance last[i]). Every nearer site was used. Of the sites at distance last, those used are
    moved to the front of their run (index is changed in place), so that no site is clipped
    twice: a cell's clipping then does not depend on when the lists grew, that is on which
    other cells it is clipped with."""
    rank = (dist <= last[:, None]).sum(axis=1)
    at_last = dist == last[:, None]
    for i in np.flatnonzero(at_last.sum(axis=1) > 1):  # rare: ties at the last distance
        run = np.flatnonzero(at_last[i])
        sites = index[i, run]
        done = np.isin(sites, used[i, : used_count[i]])
        index[i, run] = np.concatenate([sites[done], sites[~done]])
        rank[i] = run[0] + int(done.sum())
    return rank


def _store(finished: _Polygons, cells: np.ndarray, poly: _Polygons) -> _Polygons:
    """finished with the rows `cells` replaced by poly (capacity grown to fit)."""
    capacity = max(finished.v.shape[1], poly.v.shape[1])
    finished, poly = _widen(finished, capacity), _widen(poly, capacity)
    finished.v[cells] = poly.v
    finished.site[cells] = poly.site
    finished.side[cells] = poly.side
    finished.count[cells] = poly.count
    return finished


def _widen(poly: _Polygons, capacity: int) -> _Polygons:
    pad = ((0, 0), (0, capacity - poly.v.shape[1]))
    if pad[1][1] <= 0:
        return poly
    side = np.pad(poly.side, pad, constant_values=-1)
    return _Polygons(np.pad(poly.v, pad), np.pad(poly.site, pad), side, poly.box, poly.count)


def _clipped_areas(
    nuclei: np.ndarray, points: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Areas of the nuclei's cells among the points, clipped from the boxes [lo, hi] (relative
    corners), shared equally between coincident nuclei."""
    from scipy.spatial import cKDTree

    if len(nuclei) == 0:
        return np.zeros(0)
    tree = cKDTree(points)
    return _clip_all(nuclei, points, tree, lo, hi).areas() / _multiplicity(nuclei, tree)


def _multiplicity(nuclei: np.ndarray, tree: cKDTree) -> np.ndarray:
    """How many of the tree's points share each nucleus's coordinates (itself included)."""
    return np.asarray(tree.query_ball_point(nuclei, 0.0, return_length=True))


# ---------------------------------------------------------------------------------------------
# Unbounded SPPP cells


def _on_hull(nuclei: np.ndarray, points: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Whether each nucleus lies on the convex hull of the points: its nearest neighbours
    settle most (they surround the nucleus), all the points settle the rest."""
    width = min(FIRST_NEIGHBOURS, len(points))
    _, index = _query(tree, nuclei, width)
    on_hull = _largest_gap(points[index] - nuclei[:, None, :]) >= np.pi - GAP_TOLERANCE
    unsure = np.flatnonzero(on_hull)
    if unsure.size and width < len(points):
        rows = max(1, HULL_TEST_DIRECTIONS // len(points))
        for chunk in np.array_split(unsure, -(-unsure.size // rows)):  # bounded memory
            directions = points[None, :, :] - nuclei[chunk, None, :]
            on_hull[chunk] = _largest_gap(directions) >= np.pi - GAP_TOLERANCE
    return on_hull


def _largest_gap(directions: np.ndarray) -> np.ndarray:
    """Largest angle between consecutive directions around each row's nucleus ((K, M, 2);
    zero directions, coincident points, are left out; 2 pi when fewer than two remain)."""
    zero = (directions[..., 0] == 0) & (directions[..., 1] == 0)
    angle = np.arctan2(directions[..., 1], directions[..., 0])  # in [-pi, pi]
    angle[zero] = 4.0  # sorted last, then left out
    angle.sort(axis=1)
    present = (~zero).sum(axis=1)
    gaps = np.diff(angle, axis=1)
    gaps[~(np.arange(gaps.shape[1]) < (present - 1)[:, None])] = 0.0
    first = angle[:, 0]
    last = np.take_along_axis(angle, np.maximum(present - 1, 0)[:, None], axis=1)[:, 0]
    wrap = np.where(present >= 2, first + 2 * np.pi - last, 2 * np.pi)
    return np.maximum(gaps.max(axis=1, initial=0.0), wrap)
