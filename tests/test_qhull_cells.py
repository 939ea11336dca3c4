"""Voronoi cell areas (clrender.estimators.qhull_cells) against scipy.spatial.Voronoi polygons.

Reference areas: the shoelace formula over scipy.spatial.Voronoi's region vertices, on each
pixel's own point set (W + aux nuclei; originals + all 4 mirrors; originals + all 8 copies).
Tolerance 1e-10 relative: both sides are float64 circumcentre arithmetic on the same points,
which agree to ~1e-13 on these sets; 1e-10 still fails on any wrong triangle or sign.
"""

import numpy as np
import pytest
from scipy.spatial import Voronoi

from clrender.estimators import qhull_cells
from clrender.estimators.qhull_cells import clipped_cells, periodic_cells, sppp_cells
from clrender.sppp import draw_sppp

RTOL = 1e-10


def shoelace(vertices: np.ndarray) -> float:
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def scipy_areas(points: np.ndarray, count: int) -> np.ndarray:
    """Areas of the cells of points[:count] (NaN for unbounded cells)."""
    vor = Voronoi(points)
    areas = np.full(count, np.nan)
    for i in range(count):
        region = vor.regions[vor.point_region[i]]
        if region and -1 not in region:
            areas[i] = shoelace(vor.vertices[region])
    return areas


def pixel_slices(batch, p):
    return (
        slice(batch.offsets[p], batch.offsets[p + 1]),
        slice(batch.aux_offsets[p], batch.aux_offsets[p + 1]),
    )


def mirrored(x: np.ndarray) -> np.ndarray:
    return np.concatenate(
        [
            x,
            np.c_[1 - x[:, 0], x[:, 1]],
            np.c_[-1 - x[:, 0], x[:, 1]],
            np.c_[x[:, 0], 1 - x[:, 1]],
            np.c_[x[:, 0], -1 - x[:, 1]],
        ]
    )


def periodic_copies(x: np.ndarray) -> np.ndarray:
    shifts = [(0, 0)] + [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)]
    return np.concatenate([x + np.array(s, float) for s in shifts])


@pytest.fixture(scope="module")
def batch():
    # n = 100 with a small eps so that some pixels have unbounded W cells as well.
    return draw_sppp(np.random.default_rng(11), 100, 30, eps=0.08)


def test_sppp_areas_match_scipy_voronoi(batch):
    cells = sppp_cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets)
    unbounded_seen = 0
    for p in range(batch.pixel_count):
        w, a = pixel_slices(batch, p)
        points = np.concatenate([batch.traced[w], batch.aux[a]])
        ref = scipy_areas(points, len(batch.traced[w]))
        got = cells.areas[w]
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        np.testing.assert_array_equal(cells.bounded[w], ~np.isnan(ref))
        np.testing.assert_allclose(got[~np.isnan(ref)], ref[~np.isnan(ref)], rtol=RTOL)
        unbounded_seen += int(np.isnan(ref).sum())
    assert unbounded_seen > 0  # the unbounded-cell detection was exercised


def test_clipped_areas_match_mirrored_scipy_voronoi_and_tile_w(batch):
    cells = clipped_cells(batch.traced, batch.offsets)
    for p in range(batch.pixel_count):
        w, _ = pixel_slices(batch, p)
        x = batch.traced[w]
        np.testing.assert_allclose(cells.areas[w], scipy_areas(mirrored(x), len(x)), rtol=RTOL)
        assert cells.areas[w].sum() == pytest.approx(1.0, abs=1e-12)


def test_periodic_areas_match_nine_copies_and_tile_torus(batch):
    cells = periodic_cells(batch.traced, batch.offsets)
    for p in range(batch.pixel_count):
        w, _ = pixel_slices(batch, p)
        x = batch.traced[w]
        np.testing.assert_allclose(
            cells.areas[w], scipy_areas(periodic_copies(x), len(x)), rtol=RTOL
        )
        assert cells.areas[w].sum() == pytest.approx(1.0, abs=1e-12)


def single_pixel_areas(batch, cell_fn) -> np.ndarray:
    parts = []
    for p in range(batch.pixel_count):
        w, a = pixel_slices(batch, p)
        count = len(batch.traced[w])
        parts.append(
            cell_fn(
                batch.traced[w],
                np.array([0, count]),
                batch.aux[a],
                np.array([0, len(batch.aux[a])]),
            ).areas
        )
    return np.concatenate(parts)


def test_batched_areas_equal_single_pixel_areas():
    batch = draw_sppp(np.random.default_rng(12), 64, 40)
    joint = sppp_cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets)
    assert joint.stats.qhull_calls < batch.pixel_count  # several pixels shared Qhull calls
    alone = single_pixel_areas(batch, sppp_cells)
    np.testing.assert_allclose(joint.areas, alone, rtol=RTOL)


@pytest.mark.parametrize("gap", [0.0, -0.6])
def test_exactness_check_catches_interacting_pixels(monkeypatch, gap):
    """With touching (gap 0) or overlapping slots the pixels of a call interact; the
    neighbour-purity check must notice and recompute them, so areas stay exact."""
    batch = draw_sppp(np.random.default_rng(13), 64, 24)
    alone = single_pixel_areas(batch, sppp_cells)
    monkeypatch.setattr(qhull_cells, "SLOT_GAP_FACTOR", gap)
    joint = sppp_cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets)
    assert joint.stats.recomputed_pixels > 0
    np.testing.assert_allclose(joint.areas, alone, rtol=RTOL)
    np.testing.assert_array_equal(joint.bounded, ~np.isnan(alone))


@pytest.mark.parametrize("cell_fn", [clipped_cells, periodic_cells])
def test_partial_ghosts_are_checked_against_full_ghosts(monkeypatch, cell_fn):
    """A too-narrow ghost margin must be caught by the circumdisc check (recomputed with all
    ghosts); a generous one must agree with all ghosts without recomputation."""
    batch = draw_sppp(np.random.default_rng(14), 200, 20)
    monkeypatch.setattr(qhull_cells, "GHOST_MARGIN_SPACINGS", 100.0)  # all ghosts
    full = cell_fn(batch.traced, batch.offsets)
    monkeypatch.setattr(qhull_cells, "GHOST_MARGIN_SPACINGS", 0.7)
    narrow = cell_fn(batch.traced, batch.offsets)
    assert narrow.stats.recomputed_pixels > 0
    np.testing.assert_allclose(narrow.areas, full.areas, rtol=RTOL)
    monkeypatch.setattr(qhull_cells, "GHOST_MARGIN_SPACINGS", 5.0)
    default = cell_fn(batch.traced, batch.offsets)
    np.testing.assert_allclose(default.areas, full.areas, rtol=RTOL)


def test_fvor_box_flags_match_cell_vertices(batch):
    """inside_box is True exactly when every scipy Voronoi vertex of the cell lies in W'."""
    half = 0.5 + batch.eps
    cells = sppp_cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box=half)
    for p in range(batch.pixel_count):
        w, a = pixel_slices(batch, p)
        points = np.concatenate([batch.traced[w], batch.aux[a]])
        vor = Voronoi(points)
        expected = []
        for i in range(len(batch.traced[w])):
            region = vor.regions[vor.point_region[i]]
            bounded = bool(region) and -1 not in region
            expected.append(bounded and bool((np.abs(vor.vertices[region]) <= half).all()))
        np.testing.assert_array_equal(cells.inside_box[w], expected)
