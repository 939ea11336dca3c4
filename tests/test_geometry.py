"""Ray intersection (kernels/geometry.h) against a float64 NumPy reference on random rays."""

import numpy as np
import pytest
from geometry_device import device_intersect

from clrender.scene import load_scene


def reference_intersect(scene, origins, directions):
    """Closest hit in float64: distance (inf on a miss), primitive id, and how clear the hit
    is: its distance from the nearest quad edge or sphere silhouette, 0 when another primitive
    lies at the same distance (coplanar faces, e.g. a box standing on the floor)."""
    count = len(origins)
    hits = []
    best_t = np.full(count, np.inf)
    best_id = np.full(count, -1)
    margin = np.full(count, np.inf)
    for i, quad in enumerate(scene.quads):
        c, e1, e2 = (quad[k].astype(np.float64) for k in ("corner", "edge1", "edge2"))
        n = np.cross(e1, e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c - origins) @ n) / (directions @ n)
        rel = origins + t[:, None] * directions - c
        a = rel @ np.cross(e2, n / (n @ n))
        b = rel @ np.cross(n / (n @ n), e1)
        inside = (t > 0) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        hits.append(np.where(inside, t, np.inf))
        hit = inside & (t < best_t)
        edge = np.minimum.reduce([a, 1 - a, b, 1 - b])
        best_t, best_id = np.where(hit, t, best_t), np.where(hit, i, best_id)
        margin = np.where(hit, edge, margin)
    for s, sphere in enumerate(scene.spheres):
        oc = origins - sphere["center"].astype(np.float64)
        r = float(sphere["radius"])
        b = np.einsum("ij,ij->i", oc, directions)
        disc = b * b - (np.einsum("ij,ij->i", oc, oc) - r * r)
        root = np.sqrt(np.maximum(disc, 0.0))
        t = np.where(-b - root > 0, -b - root, -b + root)
        hits.append(np.where((disc >= 0) & (t > 0), t, np.inf))
        hit = (disc >= 0) & (t > 0) & (t < best_t)
        best_t = np.where(hit, t, best_t)
        best_id = np.where(hit, len(scene.quads) + s, best_id)
        margin = np.where(hit, root / r, margin)
    second = np.sort(np.array(hits), axis=0)[1] if len(hits) > 1 else np.full(count, np.inf)
    with np.errstate(invalid="ignore"):
        tie = np.isfinite(best_t) & (second - best_t <= 1e-5 * np.maximum(best_t, 1e-30))
    return best_t, best_id, np.where(tie, 0.0, margin)


def random_rays(scene, count, seed):
    """Origins spread over (and a little beyond) the scene's bounds, isotropic directions;
    coordinates are rounded to float32 first so both sides trace the same rays."""
    rng = np.random.default_rng(seed)
    low, high = scene.bounds()
    pad = 0.2 * (high - low)
    origins = rng.uniform(low - pad, high + pad, size=(count, 3)).astype(np.float32)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins.astype(np.float64), directions.astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("name", ["cornell-box", "mitsuba-cbox", "furnace"])
def test_intersection_matches_numpy_reference(runtime, name):
    scene = load_scene(name)
    origins, directions = random_rays(scene, 20_000, seed=4)
    t, ids = device_intersect(runtime, scene, origins, directions)
    ref_t, ref_ids, margin = reference_intersect(scene, origins, directions)
    # Rays whose reference hit is within 1e-4 of an edge may legitimately differ in float32
    clear = margin > 1e-4
    assert clear.mean() > 0.95
    np.testing.assert_array_equal(ids[clear], ref_ids[clear])
    hit = clear & (ref_ids >= 0)
    assert hit.mean() > 0.3
    scale = float(np.linalg.norm(np.subtract(*scene.bounds())))
    np.testing.assert_allclose(t[hit], ref_t[hit], rtol=1e-4, atol=1e-5 * scale)
    assert np.all(np.isinf(t[clear & (ref_ids < 0)]))


def test_camera_rays_hit_the_expected_walls(runtime):
    """Rays from the camera of the authors' box through the upper middle of the image hit the
    back wall, and rays through the left and right image edges at mid height hit green
    (x = 555) and red: image right is world -x there."""
    scene = load_scene("cornell-box")
    basis = scene.camera.basis(256, 256)
    origin = basis["origin"].astype(np.float64)
    sxy = [(-0.9, 0.0), (0.0, 0.5), (0.9, 0.0)]
    dirs = np.array([basis["forward"] + sx * basis["right"] + sy * basis["up"] for sx, sy in sxy])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    _, ids = device_intersect(runtime, scene, np.tile(origin, (3, 1)), dirs)
    names = [scene.quad_names[i] for i in ids]
    assert names == ["green wall", "back wall", "red wall"]
