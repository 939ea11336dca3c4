"""Voronoi cell areas (clrender.estimators.qhull_cells) against scipy.spatial.Voronoi polygons.

Reference areas: the shoelace formula over scipy.spatial.Voronoi's region vertices, on each
pixel's own point set (W + aux nuclei; originals + all 4 mirrors; originals + all 8 copies).
Tolerance 1e-10 relative: both sides are float64 circumcentre arithmetic on the same points,
which agree to ~1e-13 on these sets; 1e-10 still fails on any wrong triangle or sign.
"""

import numpy as np
import pytest
from exact_cells import exact_cells, torus_copies
from scipy.spatial import Voronoi

from clrender.errors import ClrenderError
from clrender.estimators import qhull_cells
from clrender.estimators.qhull_cells import clipped_cells, periodic_cells, sppp_cells
from clrender.sppp import draw_sppp, sppp_eps

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


# Near-coincident nuclei (issue 12, item 8): a pixel with 41 nuclei within 1e-6 of one spot
# among ordinary SPPP nuclei, in a batch whose pixels share Qhull calls. Qhull alone drops some
# of them as "coplanar" or triangulates them wrongly: cells off by far more than 1 %, sums off
# 1, bounded sets flagged for redraw. References: 60-digit brute-force clipping
# (tests/exact_cells.py) on the positions the cell code uses (nudged inside W for clipped
# cells, wrapped for torus cells), and Qhull on the cluster alone, rescaled to unit size.

CLUSTER_PIXEL = 4
CLUSTER_SCALE = 1e-6
# Inside W; in W's corner (the cluster among its own mirror images and torus copies)
CLUSTER_SPOTS = {"inside": (0.13, -0.21), "corner": (0.5 - 5.1e-7, -0.5 + 5.1e-7)}
REFERENCE_BOX = 8.0  # SPPP reference cells start from [-8, 8]^2: all of these lie inside


def with_cluster(spot: str, scale: float = CLUSTER_SCALE, seed: int = 31):
    """Nine SPPP pixels (n = 64) with 41 nuclei within `scale` of a spot added to one."""
    rng = np.random.default_rng(seed)
    batch = draw_sppp(rng, 64, 9, eps=sppp_eps(64))
    cluster = np.array(CLUSTER_SPOTS[spot]) + scale * (rng.random((41, 2)) - 0.5)
    parts = [batch.traced[batch.offsets[p] : batch.offsets[p + 1]] for p in range(9)]
    parts[CLUSTER_PIXEL] = np.concatenate([parts[CLUSTER_PIXEL], cluster])
    offsets = np.concatenate([[0], np.cumsum([len(part) for part in parts])])
    return np.concatenate(parts), offsets, batch.aux, batch.aux_offsets


@pytest.fixture(scope="module", params=sorted(CLUSTER_SPOTS))
def cluster_case(request):
    """The batch, the cluster pixel's slice, and its reference cells of each kind."""
    traced, offsets, aux, aux_offsets = with_cluster(request.param)
    w = slice(offsets[CLUSTER_PIXEL], offsets[CLUSTER_PIXEL + 1])
    a = slice(aux_offsets[CLUSTER_PIXEL], aux_offsets[CLUSTER_PIXEL + 1])
    nudged = qhull_cells._nudge_inside(traced[w])
    wrapped = qhull_cells._wrap_torus(traced[w])
    none = np.zeros((0, 2))
    sppp, touches = exact_cells(traced[w], aux[a], (-REFERENCE_BOX,) * 2, (REFERENCE_BOX,) * 2)
    assert not touches.any()  # every cell bounded
    reference = {
        "sppp": sppp,
        "clipped": exact_cells(nudged, none, (-0.5, -0.5), (0.5, 0.5))[0],
        "periodic": exact_cells(wrapped, torus_copies(wrapped), wrapped - 0.5, wrapped + 0.5)[0],
    }
    return (traced, offsets, aux, aux_offsets), w, reference


def cells_of(kind: str, traced, offsets, aux, aux_offsets):
    if kind == "sppp":
        return sppp_cells(traced, offsets, aux, aux_offsets)
    return {"clipped": clipped_cells, "periodic": periodic_cells}[kind](traced, offsets)


@pytest.mark.parametrize("kind", ["sppp", "clipped", "periodic"])
def test_cluster_cells_match_exact_reference(cluster_case, kind):
    """Every cell of the cluster pixel within 1e-9 (relative) of the exact cells, the pixel
    settled by clipping, all its SPPP cells bounded (no redraw), its clipped and torus areas
    summing to 1."""
    batch, w, reference = cluster_case
    cells = cells_of(kind, *batch)
    assert cells.bounded[w].all()
    np.testing.assert_allclose(cells.areas[w], reference[kind], rtol=1e-9)
    assert cells.stats.settled_pixels == 1
    if kind != "sppp":
        assert cells.areas[w].sum() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("kind", ["sppp", "clipped", "periodic"])
def test_cluster_cells_match_qhull_at_both_scales(kind):
    """Two truths from Qhull, each at a scale it resolves. Inside the cluster: cells that no
    other nucleus is near enough to cut are those of the cluster alone, which Qhull resolves
    once the cluster is recentred and scaled by 1 / CLUSTER_SCALE. From afar the cluster is one
    nucleus: its cells together, and every other cell, are within O(1e-6) of the cells with the
    cluster replaced by its spot (relative bound 1e-4: the perimeter times 1e-6 over the area).
    Only the first fails without the settling (Qhull's errors stay inside the cluster)."""
    traced, offsets, aux, aux_offsets = with_cluster("inside")
    w = slice(offsets[CLUSTER_PIXEL], offsets[CLUSTER_PIXEL + 1])
    a = slice(aux_offsets[CLUSTER_PIXEL], aux_offsets[CLUSTER_PIXEL + 1])
    areas = cells_of(kind, traced, offsets, aux, aux_offsets).areas[w]
    spot = np.array(CLUSTER_SPOTS["inside"])
    cluster, others = traced[w][-41:], traced[w][:-41]

    vor = Voronoi((cluster - spot) / CLUSTER_SCALE)
    nearest_other = np.hypot(*(others - spot).T).min() / CLUSTER_SCALE
    checked = 0
    for i in range(41):
        region = vor.regions[vor.point_region[i]]
        if not region or -1 in region:
            continue
        vertices = vor.vertices[region]
        # No other nucleus can cut a cell whose vertices are nearer than half its distance
        if 2 * np.hypot(*vertices.T).max() + 1.0 < nearest_other:
            expected = shoelace(vertices) * CLUSTER_SCALE**2
            assert areas[-41 + i] == pytest.approx(expected, rel=1e-9), i
            checked += 1
    assert checked >= 10

    one = np.concatenate([others, [spot]])
    points = {"sppp": np.concatenate([one, aux[a]]), "clipped": mirrored(one)}
    expected = scipy_areas(points.get(kind, periodic_copies(one)), len(one))
    np.testing.assert_allclose(areas[:-41], expected[:-1], rtol=1e-4)
    assert areas[-41:].sum() == pytest.approx(expected[-1], rel=1e-4)


@pytest.mark.parametrize("kind", ["clipped", "periodic"])
def test_area_check_settles_what_detection_misses(monkeypatch, kind):
    """With the near-coincidence flags off, the corner cluster's pixel still comes out exact:
    Qhull leaves it with unbounded cells or areas not summing to 1, and it is settled."""
    monkeypatch.setattr(qhull_cells, "NEAR_COINCIDENT", 0.0)
    traced, offsets, aux, aux_offsets = with_cluster("corner")
    cells = cells_of(kind, traced, offsets, aux, aux_offsets)
    assert cells.stats.settled_pixels == 1
    sums = np.add.reduceat(cells.areas, offsets[:-1])
    np.testing.assert_allclose(sums, 1.0, atol=1e-12)


def test_area_check_raises_when_settling_fails(monkeypatch):
    monkeypatch.setattr(qhull_cells, "clipped_cell_areas", lambda nuclei: np.zeros(len(nuclei)))
    traced, offsets, aux, aux_offsets = with_cluster("inside")
    with pytest.raises(ClrenderError, match="internal error"):
        clipped_cells(traced, offsets)
