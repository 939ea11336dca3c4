"""Voronoi cells by half-plane clipping (clrender.estimators.clip_cells).

Against Qhull's cells (clrender.estimators.qhull_cells) where Qhull is exact: random pixels
(1e-10 relative, as in test_qhull_cells), degenerate sets, lattices; against the 60-digit
brute-force reference (tests/exact_cells.py) on clusters of nuclei down to 1e-9 apart, where
Qhull is not. Cells of some nuclei among a point set (cells_among) against scipy's Voronoi
diagram, and bit for bit whatever else is clipped with them and from whichever box.
"""

import numpy as np
import pytest
from exact_cells import exact_cells, torus_copies
from scipy.spatial import Voronoi

from clrender.estimators import qhull_cells
from clrender.estimators.clip_cells import (
    cells_among,
    clipped_cell_areas,
    sppp_cell_areas,
    torus_cell_areas,
)
from clrender.sppp import draw_sppp, sppp_eps

RTOL = 1e-10


def qhull(kind: str, nuclei: np.ndarray, aux: np.ndarray, box: float | None = None):
    """Qhull's cells of one pixel."""
    offsets = np.array([0, len(nuclei)])
    if kind == "sppp":
        return qhull_cells.sppp_cells(nuclei, offsets, aux, np.array([0, len(aux)]), box)
    cells = {"clipped": qhull_cells.clipped_cells, "periodic": qhull_cells.periodic_cells}
    return cells[kind](nuclei, offsets)


def clipped(kind: str, nuclei: np.ndarray, aux: np.ndarray, box: float | None = None):
    """(areas, bounded, inside_box) by clipping, on the positions Qhull's cells use."""
    if kind == "sppp":
        cells = sppp_cell_areas(nuclei, aux, box)
        return cells.areas, cells.bounded, cells.inside_box
    if kind == "clipped":
        areas = clipped_cell_areas(qhull_cells._nudge_inside(nuclei))
    else:
        areas = torus_cell_areas(qhull_cells._wrap_torus(nuclei))
    return areas, np.ones(len(nuclei), bool), None


def assert_same_cells(kind, nuclei, aux, box=None, rtol=RTOL):
    expected = qhull(kind, nuclei, aux, box)
    areas, bounded, inside = clipped(kind, nuclei, aux, box)
    np.testing.assert_array_equal(bounded, expected.bounded)
    np.testing.assert_allclose(areas, expected.areas, rtol=rtol, atol=0, equal_nan=True)
    if box is not None:
        np.testing.assert_array_equal(inside, expected.inside_box)


# 1. Random pixels, from 1 to 64 nuclei; SPPP with a narrow strip (half a spacing), so that
# many cells are unbounded and many reach beyond W'
@pytest.mark.parametrize("kind", ["sppp", "clipped", "periodic"])
def test_random_pixels_match_qhull(kind):
    rng = np.random.default_rng(41)
    unbounded = 0
    for n in (1, 2, 5, 16, 64):
        eps = 0.5 / np.sqrt(n)
        batch = draw_sppp(rng, n, 20, eps=eps)
        for p in range(batch.pixel_count):
            nuclei = batch.traced[batch.offsets[p] : batch.offsets[p + 1]]
            aux = batch.aux[batch.aux_offsets[p] : batch.aux_offsets[p + 1]]
            assert_same_cells(kind, nuclei, aux, 0.5 + eps if kind == "sppp" else None)
            if kind == "sppp":
                unbounded += int((~clipped(kind, nuclei, aux)[1]).sum())
    assert kind != "sppp" or unbounded > 20  # the hull test was exercised


# 2. Degenerate sets: what Qhull gives them (coincident nuclei share a cell; a set with fewer
# than 3 distinct points or all collinear has only unbounded SPPP cells)
RING = np.array([[-0.6, -0.6], [0.6, -0.6], [0.6, 0.6], [-0.6, 0.6]])
SPREAD = np.random.default_rng(3).random((6, 2)) - 0.5
LINE = np.column_stack([np.linspace(-0.4, 0.4, 5), np.full(5, 0.1)])
DEGENERATE = {
    "one": (SPREAD[:1], np.zeros((0, 2))),
    "one in a ring": (SPREAD[:1], RING),
    "two": (SPREAD[:2], np.zeros((0, 2))),
    "collinear": (LINE, np.zeros((0, 2))),
    "collinear with aux on the line": (LINE, np.array([[-0.55, 0.1], [0.55, 0.1]])),
    "collinear in a ring": (LINE, RING),
    "duplicated nuclei": (np.concatenate([SPREAD, SPREAD[:2], SPREAD[:1]]), RING),
    "a nucleus on an aux nucleus": (np.concatenate([SPREAD[:3], [[0.6, 0.6]]]), RING),
    "one point three times": (np.repeat(SPREAD[:1], 3, axis=0), np.zeros((0, 2))),
    "on W's edges": (np.array([[0.5, 0.1], [-0.5, 0.1], [0.2, 0.5], [-0.5, -0.5], [0, 0]]), RING),
}


@pytest.mark.parametrize("kind", ["sppp", "clipped", "periodic"])
@pytest.mark.parametrize("case", sorted(DEGENERATE))
def test_degenerate_sets_match_qhull(kind, case):
    nuclei, aux = DEGENERATE[case]
    # Edge nuclei are 1e-9 from their mirror images: Qhull's cells there agree to ~1e-8
    rtol = 1e-7 if case == "on W's edges" else RTOL
    assert_same_cells(kind, nuclei, aux, 0.55 if kind == "sppp" else None, rtol)


# 3. Exactly cocircular nuclei (a lattice): every cell a square, whatever the ties
def test_lattice_cells_are_its_squares():
    side = (np.arange(8) + 0.5) / 8 - 0.5
    lattice = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    np.testing.assert_allclose(clipped_cell_areas(lattice), 1 / 64, rtol=1e-12)
    np.testing.assert_allclose(torus_cell_areas(lattice), 1 / 64, rtol=1e-12)
    wider = (np.arange(-1, 9) + 0.5) / 8 - 0.5  # one more row and column on each side
    frame = np.stack(np.meshgrid(wider, wider), -1).reshape(-1, 2)
    frame = frame[np.abs(frame).max(axis=1) > 0.5]  # as auxiliary nuclei
    cells = sppp_cell_areas(lattice, frame, 0.5 + 1e-12)
    assert cells.bounded.all() and cells.inside_box.all()
    np.testing.assert_allclose(cells.areas, 1 / 64, rtol=1e-12)


# 4. Clusters of nuclei down to 1e-9 apart, in W and in its corner: the exact cells
@pytest.mark.parametrize("scale", [1e-6, 1e-9])
@pytest.mark.parametrize("spot", [(0.13, -0.21), (0.5 - 5.1e-7, -0.5 + 5.1e-7)])
def test_clusters_match_exact_cells(scale, spot):
    rng = np.random.default_rng(43)
    cluster = np.array(spot) + min(scale, 1e-6) * (rng.random((41, 2)) - 0.5)
    nuclei = np.concatenate([rng.random((30, 2)) - 0.5, cluster])
    nudged = qhull_cells._nudge_inside(nuclei)
    wrapped = qhull_cells._wrap_torus(nuclei)
    none = np.zeros((0, 2))
    expected, _ = exact_cells(nudged, none, (-0.5, -0.5), (0.5, 0.5))
    np.testing.assert_allclose(clipped_cell_areas(nudged), expected, rtol=1e-12)
    expected, _ = exact_cells(wrapped, torus_copies(wrapped), wrapped - 0.5, wrapped + 0.5)
    np.testing.assert_allclose(torus_cell_areas(wrapped), expected, rtol=1e-12)
    aux = draw_sppp(rng, 71, 1, eps=sppp_eps(71)).aux
    expected, touches = exact_cells(nuclei, aux, (-8.0, -8.0), (8.0, 8.0))
    settled = sppp_cell_areas(nuclei, aux)
    np.testing.assert_array_equal(settled.bounded, ~touches)
    np.testing.assert_allclose(settled.areas, np.where(touches, np.nan, expected), rtol=1e-12)


# 5. Coincident nuclei share their cell equally, inside a cluster too
def test_coincident_nuclei_share_their_cell():
    rng = np.random.default_rng(44)
    distinct = np.concatenate([rng.random((20, 2)) - 0.5, 0.1 + 1e-7 * rng.random((5, 2))])
    twice = np.concatenate([distinct, distinct[[0, 22, 22]]])
    for cell_areas in (clipped_cell_areas, torus_cell_areas):
        alone, shared = cell_areas(distinct), cell_areas(twice)
        np.testing.assert_allclose(shared[[0, 25]], alone[0] / 2, rtol=1e-12)
        np.testing.assert_allclose(shared[[22, 26, 27]], alone[22] / 3, rtol=1e-12)
        assert shared.sum() == pytest.approx(1.0, abs=1e-12)


# 6. Cells of some nuclei among a point set (cells_among, how the image-level estimators settle
# near-coincident nuclei): Qhull's cells, and the same bits whatever is clipped with them
def test_cells_among_match_voronoi():
    # Random points on [0, 6]^2 (n = 64): the cells inside [1, 5]^2, their neighbours and the
    # bounding boxes of their circumdiscs against scipy.spatial.Voronoi (1e-10 relative).
    rng = np.random.default_rng(45)
    points = 6.0 * rng.random((rng.poisson(64 * 36), 2))
    which = np.flatnonzero(((points > 1.0) & (points < 5.0)).all(axis=1))
    cells = cells_among(points, which, (0.0, 0.0, 6.0, 6.0))
    vor = Voronoi(points)
    areas, discs, neighbours = [], [], set()
    for i in which:  # reference only: a loop over a thousand regions
        vertices = vor.vertices[vor.regions[vor.point_region[i]]]
        x, y = vertices.T
        areas.append(0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))
        r = np.hypot(*(vertices - points[i]).T)
        discs.append([(x - r).min(), (y - r).min(), (x + r).max(), (y + r).max()])
        ridges = vor.ridge_points[(vor.ridge_points == i).any(axis=1)]
        neighbours.update(ridges[ridges != i].tolist())
    np.testing.assert_allclose(cells.areas, areas, rtol=1e-10)
    np.testing.assert_allclose(cells.disc_boxes, discs, rtol=1e-10)
    assert set(cells.neighbours.tolist()) == neighbours


@pytest.mark.parametrize("case", ["random with a cluster", "lattice"])
def test_cells_among_do_not_depend_on_batch_or_box(case):
    # Each cell clipped alone, with all the others (a cluster's cells grow the neighbour
    # lists of all of them), and from another box: bit for bit. The lattice has ties at every
    # distance, where the lists grow too.
    rng = np.random.default_rng(46)
    if case == "lattice":
        side = np.arange(12) / 12.0
        points = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    else:
        cluster = 0.43 + 1e-7 * (rng.random((41, 2)) - 0.5)
        points = np.concatenate([rng.random((200, 2)), cluster])
    which = np.flatnonzero(((points > 0.25) & (points < 0.75)).all(axis=1))
    box = (0.0, 0.0, 1.0, 1.0)
    together = cells_among(points, which, box)
    wider = cells_among(points, which, (-3.0, -1.0, 2.0, 5.0))
    alone = [cells_among(points, [i], box) for i in which]
    assert np.array_equal(wider.areas, together.areas)
    assert np.array_equal(wider.disc_boxes, together.disc_boxes)
    assert np.array_equal([cells.areas[0] for cells in alone], together.areas)
    assert np.array_equal(np.concatenate([c.disc_boxes for c in alone]), together.disc_boxes)


def test_ties_at_the_last_distance_when_lists_grow():
    # A nucleus at the origin among the 36 integer points at distance 65 (65^2 = 4225 has 36
    # representations as a sum of two squares): its list of FIRST_NEIGHBOURS runs out in the
    # middle of those ties; the longer list must resume after the 15 used, and skip none.
    # Against the 60-digit reference, alone and in a batch with a ring point's (big) cell.
    ring = [(x, y) for x in range(-65, 66) for y in range(-65, 66) if x * x + y * y == 65**2]
    assert len(ring) == 36
    outer = [(130.0 * np.cos(t), 130.0 * np.sin(t)) for t in np.arange(64) * np.pi / 32]
    points = np.concatenate([[[0.0, 0.0]], np.array(ring, float), np.array(outer)])
    box = (-200.0, -200.0, 200.0, 200.0)
    expected, _ = exact_cells(points[:1], points[1:], box[:2], box[2:])
    alone = cells_among(points, [0], box)
    np.testing.assert_allclose(alone.areas, expected, rtol=1e-12)
    assert set(alone.neighbours.tolist()) == set(range(1, 37))
    batch = cells_among(points, [0, 5], box)
    assert batch.areas[0] == alone.areas[0]
