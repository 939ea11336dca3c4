"""Voronoi cells by half-plane clipping (clrender.estimators.clip_cells).

Against Qhull's cells (clrender.estimators.qhull_cells) where Qhull is exact: random pixels
(1e-10 relative, as in test_qhull_cells), degenerate sets, lattices; against the 60-digit
brute-force reference (tests/exact_cells.py) on clusters of nuclei down to 1e-9 apart, where
Qhull is not.
"""

import numpy as np
import pytest
from exact_cells import exact_cells, torus_copies

from clrender.estimators import qhull_cells
from clrender.estimators.clip_cells import clipped_cell_areas, sppp_cell_areas, torus_cell_areas
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
