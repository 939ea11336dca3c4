"""Triangles and the BVH on the device (kernels/geometry.h, clrender/bvh.py): triangle hits
against a float64 NumPy reference, the BVH against brute force on random scenes, watertight
edges, surface records, the BVH's structure, and a mesh rendering like the quad it replaces."""

import json
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from geometry_device import device_intersect, device_occluded, device_surface
from scene_texts import lit_room, mesh_text, random_shapes_text

from clrender import scene_device
from clrender.bvh import (
    BINARY_NODE_DTYPE,
    BOUNDS_PADDING,
    BVH_MAX_DEPTH,
    BVH_NODE_DTYPE,
    BVH_WIDTH,
    KEY_BITS,
    LEAF_MAX,
    NEAREST_ROWS,
    PLOC_RADIUS,
    TRAVERSAL_COST,
    _morton_keys,
    _nearest_clusters,
    build_bvh,
    build_wide_bvh,
    padded_bounds,
    sah_cost,
)
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.scene_device import (
    BOUNDS_CHUNK,
    BVH_BLOCK_WIDTH,
    BVH_LEAF_ALIGN,
    NORMALS_DTYPE,
    RECORD_CHUNK,
    TRIANGLE_BLOCK_DTYPE,
    TRIANGLE_DTYPE,
    pack_bvh_leaves,
    primitive_bounds,
    quad_block_dtype,
)
from clrender.trace import PathTracer
from clrender.wavefront import WavefrontPathTracer

HEADER = lit_room(16)


def random_scene(tmp_path, seed, quads=20, spheres=10, triangles=60, normals=False):
    """Quads, spheres and a mesh of scattered small triangles in [-1, 1]^3 (plus the light)."""
    rng = np.random.default_rng(seed)
    text = HEADER + random_shapes_text(
        rng, quads, spheres, triangles, 0.3, (0.05, 0.2), 0.25, normals
    )
    path = tmp_path / f"random-{seed}.toml"
    path.write_text(text)
    return load_scene(path)


def random_rays(count, seed, spread=1.5):
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-spread, spread, (count, 3))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    return origins, directions


def reference_triangle_hits(scene, origins, directions):
    """Closest triangle hit in float64 (Moller-Trumbore): t (inf on a miss), triangle index,
    and how clear the answer is: the smallest distance, in barycentric coordinates, of the ray
    from any triangle's boundary (0 when another triangle lies within 1e-5 of the same
    distance)."""
    count = len(origins)
    p0, p1, p2 = (scene.triangles[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    e1, e2 = p1 - p0, p2 - p0
    # rays x triangles
    pvec = np.cross(directions[:, None, :], e2[None, :, :])
    det = np.einsum("rtk,tk->rt", pvec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tvec = origins[:, None, :] - p0[None, :, :]
        u = np.einsum("rtk,rtk->rt", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None, :, :])
        v = np.einsum("rk,rtk->rt", directions, qvec) * inv
        t = np.einsum("tk,rtk->rt", e2, qvec) * inv
    hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(hit, t, np.inf)
    best = np.argmin(t, axis=1)
    best_t = t[np.arange(count), best]
    # How far every triangle ahead is from having the ray on its boundary
    with np.errstate(invalid="ignore"):
        edge = np.abs(np.minimum.reduce([u, v, 1 - u - v]))
        margin = np.where((det != 0) & (np.abs(t) > 0), edge, np.inf).min(axis=1)
    second = np.sort(t, axis=1)[:, 1]
    with np.errstate(invalid="ignore"):
        tie = np.isfinite(best_t) & (second - best_t <= 1e-5 * best_t)
    return best_t, np.where(np.isfinite(best_t), best, -1), np.where(tie, 0.0, margin)


@pytest.mark.parametrize("use_bvh", [False, True])
def test_triangle_hits_match_the_numpy_reference(runtime, tmp_path, use_bvh):
    scene = random_scene(tmp_path, 1, quads=0, spheres=0, triangles=200)
    origins, directions = random_rays(4000, 2)
    t, prim = device_intersect(runtime, scene, origins, directions, use_bvh)
    ref_t, ref_tri, margin = reference_triangle_hits(scene, origins, directions)
    first = len(scene.quads) + len(scene.spheres)
    ref_prim = np.where(ref_tri >= 0, ref_tri + first, -1)
    # The light quad (id 0) can be hit first: compare the other rays
    clear = (margin > 1e-4) & (prim != 0)
    assert clear.sum() > 3000 and (ref_prim[clear] >= 0).sum() > 300
    np.testing.assert_array_equal(prim[clear], ref_prim[clear])
    hit = clear & (ref_prim >= 0)
    np.testing.assert_allclose(t[hit], ref_t[hit], rtol=2e-5, atol=1e-6)
    assert np.all(np.isinf(t[clear & (ref_prim < 0)]))


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_bvh_closest_and_any_hit_equal_brute_force(runtime, tmp_path, seed):
    scene = random_scene(tmp_path, seed, quads=80, spheres=30, triangles=400)
    assert len(scene.quads) and len(scene.spheres) and len(scene.triangles)
    origins, directions = random_rays(20000, seed + 100)
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    t_bvh, prim_bvh = device_intersect(runtime, scene, origins, directions, True)
    assert (prim_brute >= 0).mean() > 0.4
    np.testing.assert_array_equal(prim_bvh, prim_brute)
    np.testing.assert_array_equal(t_bvh, t_brute)
    # Any hit: shadow rays to random distances, about half of them blocked
    tmax = np.random.default_rng(seed).uniform(0.0, 2.0, len(origins))
    blocked_brute = device_occluded(runtime, scene, origins, directions, tmax, False)
    blocked_bvh = device_occluded(runtime, scene, origins, directions, tmax, True)
    np.testing.assert_array_equal(blocked_bvh, blocked_brute)
    np.testing.assert_array_equal(blocked_bvh, t_brute < tmax)
    assert 0.1 < blocked_bvh.mean() < 0.9


def test_triangle_grid_is_watertight(runtime, tmp_path):
    """Rays aimed exactly at the shared vertices and edges of a triangulated grid all hit it
    (the edge functions of neighbours are exact opposites)."""
    n = 8
    grid = np.stack(np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"), -1)
    positions = np.concatenate([grid.reshape(-1, 2) / n - 0.5, np.zeros(((n + 1) ** 2, 1))], 1)
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).reshape(-1)
    indices = np.concatenate(
        [
            np.stack([corner, corner + n + 1, corner + n + 2], 1),
            np.stack([corner, corner + n + 2, corner + 1], 1),
        ]
    )
    path = tmp_path / "grid.toml"
    path.write_text(HEADER + mesh_text(positions, indices))
    scene = load_scene(path)
    # Targets: interior vertices and edge midpoints, from random origins above
    ticks = np.arange(1, 2 * n) / (2 * n) - 0.5
    targets = np.stack(np.meshgrid(ticks, ticks), -1).reshape(-1, 2)
    targets = np.concatenate([targets, np.zeros((len(targets), 1))], 1)
    rng = np.random.default_rng(9)
    origins = targets + rng.uniform(-1, 1, targets.shape) * [1, 1, 0] + [0, 0, 1.5]
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    for use_bvh in (False, True):
        t, prim = device_intersect(runtime, scene, origins, directions, use_bvh)
        assert np.all(prim >= 1), f"{np.sum(prim < 1)} rays leaked (bvh {use_bvh})"


def scattered_mesh_text(rng, triangles, material, normals=False, emission=None):
    """A mesh of scattered small triangles in [-1, 1]^3 (random vertex normals if `normals`),
    emitting `emission` if given."""
    centres = rng.uniform(-1, 1, (triangles, 1, 3))
    positions = (centres + rng.normal(size=(triangles, 3, 3)) * 0.2).reshape(-1, 3)
    indices = [(3 * k, 3 * k + 1, 3 * k + 2) for k in range(triangles)]
    vertex_normals = rng.normal(size=positions.shape) if normals else None
    text = mesh_text(positions, indices, vertex_normals, material)
    return text + (f"emission = {emission}\n" if emission else "")


def test_surface_through_the_bvh_equals_brute_force(runtime, tmp_path):
    """Scene_Surface of a triangle hit through the BVH reads its leaf block (vertices, material,
    normals, emitter), by brute force the Triangle: the same records bit for bit, on meshes of
    two materials, with and without vertex normals, one emitting."""
    rng = np.random.default_rng(12)
    text = HEADER + '\n[materials.grey]\ntype = "diffuse"\nalbedo = [0.2, 0.2, 0.2]\n'
    text += random_shapes_text(rng, 8, 4, 150, 0.3, (0.05, 0.2), 0.2)
    text += scattered_mesh_text(rng, 150, "grey", normals=True)
    text += scattered_mesh_text(rng, 100, "white", emission=[2.0, 1.0, 0.5])
    path = tmp_path / "meshes.toml"
    path.write_text(text)
    scene = load_scene(path)
    origins, directions = random_rays(6000, 13)
    t, prim = device_intersect(runtime, scene, origins, directions, True)
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    np.testing.assert_array_equal(prim, prim_brute)
    np.testing.assert_array_equal(t, t_brute)
    through_bvh = device_surface(runtime, scene, origins, directions, True)
    brute = device_surface(runtime, scene, origins, directions, False)
    hit = brute[3] >= 0
    triangle = prim >= len(scene.quads) + len(scene.spheres)
    hit_triangles = scene.triangles[prim[triangle] - len(scene.quads) - len(scene.spheres)]
    # Every kind of triangle is hit: both materials, with normals, emitting
    assert len(set(hit_triangles["material"])) == 2
    assert np.any(hit_triangles["normals"] >= 0) and np.any(hit_triangles["emitter"] >= 0)
    assert np.any(hit & ~triangle)
    for bvh_values, brute_values in zip(through_bvh, brute, strict=True):
        np.testing.assert_array_equal(bvh_values[hit], brute_values[hit])
    np.testing.assert_array_equal(brute[4][triangle], hit_triangles["material"])
    np.testing.assert_array_equal(brute[5][triangle], hit_triangles["emitter"])


def test_triangle_surface_record(runtime, tmp_path):
    scene = random_scene(tmp_path, 6, quads=0, spheres=0, triangles=100, normals=True)
    origins, directions = random_rays(3000, 7)
    t, prim = device_intersect(runtime, scene, origins, directions, True)
    p, ng, ns, error, _, _ = device_surface(runtime, scene, origins, directions, True)
    hit = prim >= 1
    assert hit.sum() > 300
    tri = scene.triangles[prim[hit] - 1]
    p0, p1, p2 = (tri[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    # Position: on the ray and on the triangle's plane, within the error bound
    on_ray = origins[hit] + t[hit, None].astype(np.float64) * directions[hit]
    assert np.all(np.abs(p[hit] - on_ray).max(axis=1) < 4 * error[hit] + 1e-6)
    normal = np.cross(p1 - p0, p2 - p0)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    plane = np.abs(np.einsum("ij,ij->i", p[hit] - p0, normal))
    assert np.all(plane <= error[hit])
    assert np.all(error[hit] < 1e-4)
    # Geometric normal: counter-clockwise front side
    np.testing.assert_allclose(ng[hit], normal, atol=2e-6)
    # Shading normal: the interpolated vertex normals, turned to the geometric normal's side
    vn = scene.triangle_normals["n"][tri["normals"]].astype(np.float64)
    e1, e2, rel = p1 - p0, p2 - p0, p[hit] - p0
    d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", rel, e1), np.einsum("ij,ij->i", rel, e2)
    den = d11 * d22 - d12 * d12
    b1, b2 = (d22 * r1 - d12 * r2) / den, (d11 * r2 - d12 * r1) / den
    bary = np.stack([1 - b1 - b2, b1, b2], 1)
    expected = np.einsum("ik,ikj->ij", bary, vn)
    expected /= np.linalg.norm(expected, axis=1)[:, None]
    expected *= np.sign(np.einsum("ij,ij->i", expected, normal))[:, None]
    np.testing.assert_allclose(ns[hit], expected, atol=1e-4)


def test_bvh_structure_covers_every_primitive_once():
    rng = np.random.default_rng(11)
    lower = rng.uniform(-1, 1, (5000, 3))
    upper = lower + rng.uniform(0, 0.05, (5000, 3))
    nodes, prims = build_bvh(lower, upper)
    assert nodes.dtype == BINARY_NODE_DTYPE
    np.testing.assert_array_equal(np.sort(prims), np.arange(5000))
    leaves = nodes[nodes["count"] > 0]
    covered = np.zeros(5000, int)
    for offset, count in zip(leaves["offset"], leaves["count"], strict=True):
        covered[offset : offset + count] += 1
    assert np.all(covered == 1)
    # Every leaf's box holds its primitives; every interior box holds its children's
    for node in leaves:
        members = prims[node["offset"] : node["offset"] + node["count"]]
        assert np.all(lower[members] >= node["lower"]) and np.all(upper[members] <= node["upper"])
    depth = np.zeros(len(nodes), int)
    for index, node in enumerate(nodes):
        if node["count"] < 0:
            for child in (node["offset"], node["offset"] + 1):
                assert child > index
                assert np.all(nodes[child]["lower"] >= node["lower"])
                assert np.all(nodes[child]["upper"] <= node["upper"])
                depth[child] = depth[index] + 1
    assert depth.max() <= BVH_MAX_DEPTH
    # Deterministic: the same bounds give the same tree
    again_nodes, again_prims = build_bvh(lower, upper)
    assert again_nodes.tobytes() == nodes.tobytes() and np.array_equal(again_prims, prims)


def test_wide_bvh_reaches_every_primitive_once_inside_its_boxes():
    rng = np.random.default_rng(12)
    lower = rng.uniform(-1, 1, (3000, 3))
    upper = lower + rng.uniform(0, 0.05, (3000, 3))
    nodes, prims = build_wide_bvh(lower, upper)
    assert nodes.dtype == BVH_NODE_DTYPE
    reached = np.zeros(3000, int)
    seen_nodes = np.zeros(len(nodes), int)
    seen_nodes[0] = 1
    for index, node in enumerate(nodes):
        for lane in range(BVH_WIDTH):
            count, child = node["count"][lane], node["child"][lane]
            box_low, box_high = node["lower"][:, lane], node["upper"][:, lane]
            if count == 0:
                assert child > index
                seen_nodes[child] += 1
                # The child's own children lie inside this box
                inner = nodes[child]
                used = inner["count"] >= 0
                assert np.all(inner["lower"][:, used] >= box_low[:, None])
                assert np.all(inner["upper"][:, used] <= box_high[:, None])
            elif count > 0:
                members = prims[child : child + count]
                reached[members] += 1
                assert np.all(lower[members] >= box_low) and np.all(upper[members] <= box_high)
    assert np.all(reached == 1) and np.all(seen_nodes == 1)
    # Nodes are well filled (a binary tree would use 2 lanes; tests/test_bvh_collapse.py)
    assert (nodes["count"] >= 0).sum(axis=1).mean() > 4.0


def test_bvh_depth_is_capped_for_a_pathological_scene():
    # Boxes at exponentially growing positions: SAH splits off one primitive per level
    x = 2.0 ** np.arange(100)
    lower = np.stack([x, np.zeros(100), np.zeros(100)], 1)
    nodes, prims = build_bvh(lower, lower + 0.5)
    np.testing.assert_array_equal(np.sort(prims), np.arange(100))
    depth = np.zeros(len(nodes), int)
    for index, node in enumerate(nodes):
        if node["count"] < 0:
            depth[node["offset"] : node["offset"] + 2] = depth[index] + 1
    assert depth.max() <= BVH_MAX_DEPTH


def assert_valid_bvh(lower, upper, nodes, prims):
    """Every invariant of build_bvh's output, vectorised: each primitive in exactly one leaf
    and inside its box, children after their parent and inside its box, each node (but the
    root) some node's child exactly once, breadth first (depth never falls with the index),
    depth at most BVH_MAX_DEPTH, leaves of at most LEAF_MAX primitives but at the depth cap.
    Returns each node's depth."""
    count = len(lower)
    assert nodes.dtype == BINARY_NODE_DTYPE and prims.dtype == np.uint32
    np.testing.assert_array_equal(np.sort(prims), np.arange(count))
    leaf = nodes["count"] > 0
    interior = np.flatnonzero(~leaf)
    assert np.all(nodes["count"][~leaf] <= -1) and np.all(nodes["count"][~leaf] >= -3)
    # Leaves tile prims: sorted by offset, each starts where the one before ends
    by_offset = np.argsort(nodes["offset"][leaf], kind="stable")
    offsets = nodes["offset"][leaf][by_offset]
    counts = nodes["count"][leaf][by_offset]
    assert offsets[0] == 0 and offsets[-1] + counts[-1] == count
    np.testing.assert_array_equal(offsets[1:], offsets[:-1] + counts[:-1])
    owner = np.repeat(np.flatnonzero(leaf)[by_offset], counts)  # the leaf of each position
    assert np.all(lower[prims] >= nodes["lower"][owner])
    assert np.all(upper[prims] <= nodes["upper"][owner])
    # Children: the k-th split node's are nodes 2k + 1, 2k + 2 (the layout collapse_bvh reads
    # level by level), each node but the root reached once, inside the parent's box
    np.testing.assert_array_equal(nodes["offset"][interior], 2 * np.arange(len(interior)) + 1)
    children = np.concatenate([nodes["offset"][interior], nodes["offset"][interior] + 1])
    parents = np.concatenate([interior, interior])
    assert np.all(children > parents) and np.all(children < len(nodes))
    np.testing.assert_array_equal(np.bincount(children, minlength=len(nodes))[1:], 1)
    assert np.all(nodes["lower"][children] >= nodes["lower"][parents])
    assert np.all(nodes["upper"][children] <= nodes["upper"][parents])
    depth = np.zeros(len(nodes), int)
    order = np.argsort(children)
    for child, parent in zip(children[order], parents[order], strict=True):
        depth[child] = depth[parent] + 1  # parents come first: children[order] ascends
    assert np.all(np.diff(depth) >= 0) and depth.max() <= BVH_MAX_DEPTH
    assert np.all(nodes["count"][leaf & (depth < BVH_MAX_DEPTH)] <= LEAF_MAX)
    return depth


def test_bvh_invariants_on_100k_random_boxes():
    rng = np.random.default_rng(21)
    lower = rng.uniform(-1, 1, (100_000, 3))
    upper = lower + rng.exponential(0.01, (100_000, 3))
    nodes, prims = build_bvh(lower, upper)
    depth = assert_valid_bvh(lower, upper, nodes, prims)
    assert depth.max() < BVH_MAX_DEPTH  # no leaf forced by the cap
    assert 1.0 < nodes["count"][nodes["count"] > 0].mean() <= LEAF_MAX


def test_bvh_of_identical_boxes_splits_to_small_leaves_within_the_depth_cap():
    """10^4 equal boxes: every union is as large, ties pair neighbours (2k, 2k + 1), so the
    tree is balanced; the SAH keeps leaves of LEAF_MAX."""
    lower = np.zeros((10_000, 3))
    nodes, prims = build_bvh(lower, lower + 1.0)
    depth = assert_valid_bvh(lower, lower + 1.0, nodes, prims)
    assert depth.max() <= 12  # log2(10^4 / 8) + 2
    np.testing.assert_array_equal(np.unique(nodes["count"][nodes["count"] > 0]), [LEAF_MAX])


def test_bvh_of_a_chain_is_rebuilt_within_the_depth_cap():
    """Boxes at exponentially growing positions: each merges with the whole chain before it, a
    tree 99 deep; its part below the cap is rebuilt balanced, in leaves of at most LEAF_MAX."""
    x = 2.0 ** np.arange(100)
    lower = np.stack([x, np.zeros(100), np.zeros(100)], 1)
    nodes, prims = build_bvh(lower, lower + 0.5)
    depth = assert_valid_bvh(lower, lower + 0.5, nodes, prims)
    assert depth.max() <= BVH_MAX_DEPTH and nodes["count"].max() <= LEAF_MAX


def test_bvh_of_heavy_tailed_boxes_keeps_small_leaves_within_the_depth_cap():
    """Box sizes of a Pareto law (alpha 1): the large boxes merge with cluster after cluster,
    chains deeper than the cap; rebuilt below it, no leaf holds more than LEAF_MAX."""
    rng = np.random.default_rng(27)
    lower = rng.uniform(-1, 1, (200_000, 3))
    upper = lower + rng.pareto(1.0, (200_000, 1)) * 1e-3
    nodes, prims = build_bvh(lower, upper)
    assert_valid_bvh(lower, upper, nodes, prims)
    assert nodes["count"].max() <= LEAF_MAX


def degenerate_bounds(shape):
    """Bounds (lower, upper) of inputs that strain the build: one primitive, two, coincident
    points (boxes of zero size), boxes along a line, a flat grid of equal boxes."""
    if shape == "one":
        return np.zeros((1, 3)), np.ones((1, 3))
    if shape == "two":
        return np.array([[0.0, 0, 0], [2, 0, 0]]), np.array([[1.0, 1, 1], [3, 1, 1]])
    if shape == "coincident points":
        point = np.full((3000, 3), 0.25)
        return point, point
    if shape == "a line":
        t = np.linspace(-1.0, 1.0, 5000)[:, None] * np.array([[1.0, 0.5, 0.25]])
        return t, t + 1e-4
    x, y = np.meshgrid(np.arange(100.0), np.arange(60.0), indexing="ij")
    lower = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return lower, lower + [1.0, 1.0, 0.0]


@pytest.mark.parametrize("shape", ["one", "two", "coincident points", "a line", "a flat grid"])
def test_bvh_of_degenerate_inputs_keeps_every_invariant(shape):
    """Each primitive exactly once, boxes holding their children, leaves of at most LEAF_MAX,
    depth within the cap; and the 8-wide tree reaches each primitive once."""
    lower, upper = degenerate_bounds(shape)
    nodes, prims = build_bvh(lower, upper)
    assert_valid_bvh(lower, upper, nodes, prims)
    assert nodes["count"].max() <= LEAF_MAX
    wide, wide_prims = build_wide_bvh(lower, upper)
    np.testing.assert_array_equal(wide_prims, prims)
    leaf = wide["count"] > 0
    reached = np.concatenate(
        [prims[c : c + n] for c, n in zip(wide["child"][leaf], wide["count"][leaf], strict=True)]
    )
    np.testing.assert_array_equal(np.sort(reached), np.arange(len(lower)))


def reference_leaf_records(nodes, prims, quads, sphere_count, triangles):
    """pack_bvh_leaves one node and group at a time, through the block dtypes' fields: a
    node's leaf lanes, largest first, each in the first group it fits in (at most
    BVH_BLOCK_WIDTH primitives), a record per group in group order."""
    nodes = nodes.copy()
    words = []
    for node in nodes:
        sizes = node["count"].copy()
        fill, groups = [], []
        for lane in sorted(np.flatnonzero(sizes > 0), key=lambda j: (-sizes[j], j)):
            fits = [g for g, f in enumerate(fill) if f + sizes[lane] <= BVH_BLOCK_WIDTH]
            if not fits:
                fill.append(0)
                groups.append([])
            group = fits[0] if fits else len(fill) - 1
            fill[group] += sizes[lane]
            groups[group].append(lane)
        for lanes in groups:
            record = reference_record(
                node, sorted(lanes), prims, quads, sphere_count, triangles, words
            )
            words.append(record)
    return nodes, np.concatenate(words)


def reference_record(node, lanes, prims, quads, sphere_count, triangles, words):
    """One group's record (its lanes' child and count set in `node`)."""
    first_triangle = len(quads) + sphere_count
    quad_block = quad_block_dtype(BVH_BLOCK_WIDTH)
    members = np.concatenate(
        [prims[c : c + n] for c, n in zip(node["child"][lanes], node["count"][lanes], strict=True)]
    )
    kinds = (
        [m for m in members if m >= first_triangle],
        [m for m in members if m < len(quads)],
        [m for m in members if len(quads) <= m < first_triangle],
    )
    triangle_blocks = np.zeros(-(-len(kinds[0]) // BVH_BLOCK_WIDTH), TRIANGLE_BLOCK_DTYPE)
    triangle_blocks["id"] = -1
    for k, member in enumerate(kinds[0]):
        block, lane = triangle_blocks[k // BVH_BLOCK_WIDTH], k % BVH_BLOCK_WIDTH
        for name in ("p0", "p1", "p2", "material", "normals", "emitter"):
            block[name][..., lane] = triangles[member - first_triangle][name]
        block["id"][lane] = member
    quad_blocks = np.zeros(-(-len(kinds[1]) // BVH_BLOCK_WIDTH), quad_block)
    quad_blocks["quad"], quad_blocks["plane_d"] = -1, -1.0
    for k, member in enumerate(kinds[1]):
        block, lane = quad_blocks[k // BVH_BLOCK_WIDTH], k % BVH_BLOCK_WIDTH
        for name in ("corner", "normal", "u_dual", "v_dual"):
            block[name][:, lane] = quads[member][name]
        block["plane_d"][lane], block["quad"][lane] = quads[member]["plane_d"], member
    record = np.concatenate(
        [
            triangle_blocks.view(np.uint32),
            quad_blocks.view(np.uint32),
            np.array(kinds[2], np.uint32),
        ]
    )
    record = np.concatenate([record, np.zeros(-len(record) % BVH_LEAF_ALIGN, np.uint32)])
    node["child"][lanes] = sum(len(r) for r in words)
    node["count"][lanes] = len(triangle_blocks) | len(quad_blocks) << 16 | len(kinds[2]) << 24
    return record


# Mixed records (blocks of a kind apart: written through one array), and records of one kind
# (blocks that follow each other: written in place); blocks gathered a few at a time or all at
# once
@pytest.mark.parametrize(
    "quads, spheres, triangles", [(150, 80, 1500), (0, 0, 1500), (300, 0, 0), (0, 200, 0)]
)
@pytest.mark.parametrize("record_chunk", [7, RECORD_CHUNK])
def test_leaf_records_equal_a_node_by_node_reference(
    tmp_path, monkeypatch, quads, spheres, triangles, record_chunk
):
    monkeypatch.setattr(scene_device, "RECORD_CHUNK", record_chunk)
    scene = random_scene(tmp_path, 33, quads=quads, spheres=spheres, triangles=max(triangles, 1))
    # (the scene has a light quad and a mesh: only the kinds asked for are kept)
    kinds = (scene.quads[: quads and None], scene.spheres, scene.triangles[:triangles])
    wide, prims = build_wide_bvh(*primitive_bounds(*kinds))
    args = (wide, prims, kinds[0], len(kinds[1]), kinds[2])
    nodes, words = pack_bvh_leaves(*args)
    reference_nodes, reference_words = reference_leaf_records(*args)
    assert nodes.tobytes() == reference_nodes.tobytes()
    np.testing.assert_array_equal(words, reference_words)
    counts = nodes["count"][nodes["count"] > 0]
    if quads and spheres and triangles:  # every kind shares some record with another kind
        assert np.any((counts & 0xFFFF) * ((counts >> 16) & 0xFF)) and np.any(counts >> 24)


def test_sah_cost_of_a_hand_built_tree():
    """Root [0, 2] x [0, 1] x [0, 1] (half area 5) over leaves [0, 1]^3 (3 primitives) and
    [1, 2] x [0, 1] x [0, 1] (1): (5 x TRAVERSAL_COST + 3 x 3 + 3 x 1) / 5."""
    nodes = np.zeros(3, BINARY_NODE_DTYPE)
    nodes["lower"] = [[0, 0, 0], [0, 0, 0], [1, 0, 0]]
    nodes["upper"] = [[2, 1, 1], [1, 1, 1], [2, 1, 1]]
    nodes["offset"] = [1, 0, 3]
    nodes["count"] = [-1, 3, 1]
    assert sah_cost(nodes) == pytest.approx((5 * TRAVERSAL_COST + 9 + 3) / 5)


def half_area(low, high):
    d = high - low
    return d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]


def full_sweep_sah_cost(lower, upper):
    """SAH cost (as sah_cost) of a reference top-down build in float64: every split between
    centroids sorted along each axis is costed, the cheapest taken unless a leaf of at most
    LEAF_MAX is cheaper (pbrt-v4's full-sweep SAH); one node at a time."""
    centroid = 0.5 * (lower + upper)
    total, root_area = 0.0, None
    stack = [np.arange(len(lower))]
    while stack:
        ids = stack.pop()
        n = len(ids)
        area = half_area(lower[ids].min(axis=0), upper[ids].max(axis=0))
        root_area = area if root_area is None else root_area
        best_cost, best_split = np.inf, None
        for axis in range(3):
            order = ids[np.argsort(centroid[ids, axis], kind="stable")]
            low, high = lower[order], upper[order]
            head = half_area(np.minimum.accumulate(low), np.maximum.accumulate(high))
            tail = half_area(np.minimum.accumulate(low[::-1]), np.maximum.accumulate(high[::-1]))[
                ::-1
            ]
            k = np.arange(1, n)
            cost = TRAVERSAL_COST + (k * head[:-1] + (n - k) * tail[1:]) / area
            if n > 1 and cost.min() < best_cost:
                best_cost, cut = cost.min(), np.argmin(cost) + 1
                best_split = (order[:cut], order[cut:])
        if n == 1 or (n <= LEAF_MAX and n <= best_cost):
            total += n * area
        else:
            total += TRAVERSAL_COST * area
            stack += list(best_split)
    return total / root_area


def sphere_triangle_bounds(rings, segments):
    """Bounds of a latitude/longitude unit sphere's triangles (two a cell)."""
    theta = np.linspace(0.0, np.pi, rings + 1)[:, None]
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[None, :]
    grid = np.stack(
        [np.sin(theta) * np.cos(phi), np.cos(theta) + 0 * phi, np.sin(theta) * np.sin(phi)], -1
    )
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    corners = np.concatenate([np.stack([a, b, d], -2), np.stack([a, d, c], -2)]).reshape(-1, 3, 3)
    return corners.min(axis=1), corners.max(axis=1)


def random_triangle_bounds(rng, count, spread):
    points = rng.uniform(-1, 1, (count, 1, 3)) + rng.normal(size=(count, 3, 3)) * spread
    return points.min(axis=1), points.max(axis=1)


def test_bvh_sah_cost_is_near_a_full_sweep_build():
    """The agglomerative tree against a float64 full-sweep SAH build of the same (padded)
    boxes: measured 0.5 % to 8 % dearer on these inputs (the greedy merges' price on small
    uniform inputs; on bench/bvh_scaling.py's scenes it is cheaper than the former binned
    build): allowed 12 %."""
    rng = np.random.default_rng(22)
    low = rng.uniform(-1, 1, (3000, 3))
    inputs = [
        random_triangle_bounds(rng, 2000, 0.05),
        random_triangle_bounds(rng, 2000, 0.3),
        sphere_triangle_bounds(22, 45),
        (low, low + rng.uniform(0, 0.1, (3000, 3))),
    ]
    for lower, upper in inputs:
        padded = [bound.T.astype(np.float64) for bound in padded_bounds(lower, upper)]
        reference = full_sweep_sah_cost(*padded)
        assert sah_cost(build_bvh(lower, upper)[0]) <= 1.12 * reference


def test_nearest_clusters_match_a_pairwise_search():
    """_nearest_clusters against every pair within PLOC_RADIUS, one cluster at a time, with
    the same float32 areas (their last KEY_BITS bits cleared); repeated boxes make ties (closer
    first, then even forwards)."""
    rng = np.random.default_rng(23)
    low = rng.uniform(-1, 1, (120, 3)).astype(np.float32)
    high = low + rng.uniform(0, 0.3, (120, 3)).astype(np.float32)
    repeat = rng.integers(0, 120, 60)
    low[repeat[:30]], high[repeat[:30]] = low[repeat[30:]], high[repeat[30:]]
    low[40:60], high[40:60] = low[40], high[40]  # a run of equal boxes
    boxes = np.concatenate([low.T, -high.T])
    scratch = np.empty((NEAREST_ROWS, 120 + 2 * PLOC_RADIUS), np.float32)
    result = np.empty((2, 120), np.int32)
    nearest, area = _nearest_clusters(boxes, np.arange(120, dtype=np.int32), scratch, result)
    for i in range(120):
        candidates = []
        for j in range(max(0, i - PLOC_RADIUS), min(120, i + PLOC_RADIUS + 1)):
            if j != i:
                x, y, z = (
                    np.maximum(high[i, a], high[j, a]) - np.minimum(low[i, a], low[j, a])
                    for a in range(3)
                )
                bits = np.float32(x * y + y * z + z * x).view(np.int32)
                rounded = (bits & ~np.int32(2**KEY_BITS - 1)).view(np.float32)
                preferred = (j > i) == (i % 2 == 0)
                candidates.append((rounded, abs(j - i), not preferred, j))
        best = min(candidates)
        assert nearest[i] == best[3] and area[i] == best[0]
    np.testing.assert_array_equal(nearest[40:60], np.arange(40, 60) ^ 1)


def test_morton_keys_interleave_the_cell_bits_then_the_id():
    rng = np.random.default_rng(24)
    cells = rng.integers(0, 1024, (500, 3))
    cells[:3] = [[0, 0, 0], [1023, 1023, 1023], [1023, 0, 5]]  # the grid's extent: 0 to 1023
    keys = _morton_keys(cells.T.astype(np.float32))
    for index, (x, y, z) in enumerate(cells.tolist()):
        code = 0
        for bit in range(10):
            code |= ((x >> bit) & 1) << (3 * bit + 2)
            code |= ((y >> bit) & 1) << (3 * bit + 1)
            code |= ((z >> bit) & 1) << (3 * bit)
        assert int(keys[index]) == (code << 32) | index


def test_padded_bounds_hold_the_float64_bounds():
    rng = np.random.default_rng(25)
    magnitude = 10.0 ** rng.uniform(-20, 20, (2000, 1))
    lower = rng.normal(size=(2000, 3)) * magnitude
    upper = lower + rng.uniform(0, 1, (2000, 3)) * magnitude
    lower[0], upper[0] = 0.0, 0.0  # a point at the origin
    low, high = padded_bounds(lower, upper)
    assert low.dtype == np.float32 and low.shape == (3, 2000)
    assert np.all(lower > low.T) and np.all(upper < high.T)
    largest = np.maximum(np.abs(lower), np.abs(upper)).max(axis=1)
    assert np.all(lower - low.T <= 2 * BOUNDS_PADDING * largest[:, None] + 1e-29)
    assert np.all(high.T - upper <= 2 * BOUNDS_PADDING * largest[:, None] + 1e-29)


@pytest.mark.parametrize("bounds_chunk", [7, BOUNDS_CHUNK])  # triangles a few at a time or all
def test_primitive_bounds_are_the_float64_extremes_of_every_primitive(
    tmp_path, monkeypatch, bounds_chunk
):
    monkeypatch.setattr(scene_device, "BOUNDS_CHUNK", bounds_chunk)
    scene = random_scene(tmp_path, 26, quads=10, spheres=5, triangles=40)
    lower, upper = primitive_bounds(scene.quads, scene.spheres, scene.triangles)
    assert lower.dtype == np.float64
    assert len(lower) == len(scene.quads) + len(scene.spheres) + len(scene.triangles)
    corner, e1, e2 = (scene.quads[k].astype(np.float64) for k in ("corner", "edge1", "edge2"))
    quad_points = np.stack([corner, corner + e1, corner + e2, corner + e1 + e2])
    points = np.stack([scene.triangles[k].astype(np.float64) for k in ("p0", "p1", "p2")])
    centre = scene.spheres["center"].astype(np.float64)
    radius = scene.spheres["radius"].astype(np.float64)[:, None]
    np.testing.assert_array_equal(
        lower, np.concatenate([quad_points.min(axis=0), centre - radius, points.min(axis=0)])
    )
    np.testing.assert_array_equal(
        upper, np.concatenate([quad_points.max(axis=0), centre + radius, points.max(axis=0)])
    )


def test_struct_layouts_match_the_kernel(runtime):
    sizes = np.zeros(3, np.uint32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=sizes.nbytes)
    runtime.kernel("geometry_test.cl", "struct_sizes")(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, sizes, buf)
    assert list(sizes) == [TRIANGLE_DTYPE.itemsize, NORMALS_DTYPE.itemsize, BVH_NODE_DTYPE.itemsize]


def quads_as_meshes(text: str) -> str:
    """A scene text whose non-emitting 4-vertex quads become meshes of 2 triangles."""
    out = []
    for block in text.split("[[shapes]]"):
        if 'type = "quad"' in block and "emission" not in block and "vertices" in block:
            block = block.replace('type = "quad"', 'type = "mesh"')
            block = block.replace("vertices = [", "indices = [[0, 1, 2], [0, 2, 3]]\npositions = [")
        out.append(block)
    return "[[shapes]]".join(out)


def render_mean(runtime, scene, size=16, spp=64):
    tracer = PathTracer(runtime, scene, max_depth=4)
    pixels = rectangle_pixels(size, 0, 0, size, size)
    sets = generate_sample_sets(runtime, make_sampler("independent", spp), 5, pixels)
    radiance = tracer.trace(sets, 5, size, size).to_host()
    return radiance.reshape(size, size, spp, 3).mean(axis=2)


def test_two_triangle_meshes_render_like_their_quads(runtime, tmp_path):
    """mitsuba-cbox with every wall a mesh of 2 triangles: the same random numbers give the
    same paths but for float rounding, so the images agree far inside their noise."""
    base = load_scene("mitsuba-cbox")
    path = tmp_path / "mesh-cbox.toml"
    path.write_text(quads_as_meshes(base.path.read_text()))
    meshed = load_scene(path)
    assert len(meshed.triangles) >= 10 and len(meshed.quads) < len(base.quads)
    quad_image = render_mean(runtime, base)
    mesh_image = render_mean(runtime, meshed)
    assert quad_image.mean() > 0.05
    # Noise of the image mean (64 paths per pixel, 256 pixels) is about 2 %: demand 0.5 %
    assert mesh_image.mean() == pytest.approx(quad_image.mean(), rel=0.005)
    assert np.abs(mesh_image - quad_image).mean() < 0.02 * quad_image.mean()


def test_bvh_scaling_bench_runs_and_reports_every_figure(runtime, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "bench"))
    import bvh_scaling

    output = tmp_path / "bvh.json"
    bvh_scaling.main(
        ["--triangles", "20", "2000", "--quads", "66", "--compare-triangles", "20"]
        + ["--size", "8", "--spp", "2"]
        + ["--repeats", "1", "--paired-rounds", "2", "--output", str(output)]
    )
    data = json.loads(output.read_text())
    # Paired rounds: each mesh against each box within a round, median inside its range
    assert [row["triangles"] for row in data["paired"]] == [
        row["triangles"] for row in data["triangles"]
    ]
    for row in data["paired"]:
        for box in ("mitsuba-cbox", "cornell-box"):
            low, high = row[f"against_{box}_range"]
            assert 0 < low <= row[f"against_{box}"] <= high and row[f"{box}_rays_per_s"] > 0
    assert data["machine_before"]["cpus"] > 0 and "load_1_5_15" in data["machine_after"]
    counts = [row["triangles"] for row in data["triangles"]]
    assert counts[0] == 20 and abs(counts[1] - 2000) < 50
    assert all(row["rays_per_s"] > 0 and row["build_wall_s"] > 0 for row in data["triangles"])
    for row in data["triangles"]:
        assert row["total_build_cpu_s"] >= row["build_cpu_s"] and row["sah_cost"] > 1.0
    assert [row["scene"] for row in data["cornell"]][0] == "cornell-box"
    row = data["quads"][0]
    assert row["primitives"] == 66 and not row["default_uses_bvh"]
    assert data["meshes"][0]["default_uses_bvh"]  # 20 triangles
    assert row["brute_rays_per_s"] > 0 and row["bvh_rays_per_s"] > 0


def test_wavefront_equals_the_megakernel_on_a_mesh_scene(runtime, tmp_path):
    """The wavefront stages call geometry.h too: bit-identical radiance on meshes through the
    BVH, shading normals included."""
    base = load_scene("mitsuba-cbox")
    text = quads_as_meshes(base.path.read_text())
    rng = np.random.default_rng(13)
    positions = rng.uniform(-0.5, 0.5, (30, 3))
    text += mesh_text(positions, np.arange(30).reshape(-1, 3), rng.normal(size=(30, 3)))
    path = tmp_path / "mesh-cbox.toml"
    path.write_text(text)
    scene = load_scene(path)
    mega = PathTracer(runtime, scene)
    assert len(mega.bvh_nodes) > 0 and np.any(scene.triangles["normals"] >= 0)
    wave = WavefrontPathTracer(runtime, scene, wave_paths=1500)
    pixels = rectangle_pixels(16, 0, 0, 16, 16)
    sets = generate_sample_sets(runtime, make_sampler("independent", 16), 3, pixels)
    a, b = mega.trace(sets, 3, 16, 16), wave.trace(sets, 3, 16, 16)
    radiance = a.to_host()
    np.testing.assert_array_equal(b.to_host(), radiance)
    assert a.rays == b.rays and np.count_nonzero(radiance.sum(axis=1)) > len(radiance) // 2


# --------------------------------------------------------------------------- the build, cluster
# by cluster (bvh-build-3: build_bvh's passes against a plain one-cluster-at-a-time reference)


def reference_nearest(scaled, radius):
    """Each cluster's nearest among `radius` before and after it (boxes as (lower, -upper)
    float32 rows of 6), one pair at a time: the least float32 area of the union (its last
    KEY_BITS bits cleared), then the closer, then forwards from an even index."""
    nearest, areas = [], []
    for i in range(len(scaled)):
        candidates = []
        for j in range(max(0, i - radius), min(len(scaled), i + radius + 1)):
            if j != i:
                union = np.minimum(scaled[i], scaled[j])
                e = union[:3] + union[3:]
                area = e[0] * e[1]
                area += e[1] * e[2]
                area += e[2] * e[0]
                bits = np.float32(area).view(np.int32) & ~np.int32(2**KEY_BITS - 1)
                preferred = (j > i) == (i % 2 == 0)
                candidates.append((int(bits), abs(j - i), not preferred, j))
        best = min(candidates)
        nearest.append(best[3])
        areas.append(best[0])
    return nearest, areas


def reference_build(lower, upper):
    """build_bvh one cluster at a time in plain Python: PLOC merge rounds over the Morton order,
    the SAH's leaves bottom up (float64 half areas of the float32 extents), the depth cap's
    balanced rebuilds and the breadth-first layout top down, one node at a time."""
    low, high = padded_bounds(lower, upper)
    count = low.shape[1]
    ranked = np.argsort(_morton_keys(0.5 * (low + high)))
    box = [np.concatenate([low[:, p], -high[:, p]]) for p in ranked]  # by rank
    extent = float((high.max(axis=1) - low.min(axis=1)).max())
    scale = np.float32(1.0 / max(extent, 1e-30))
    # Merge rounds: (cluster id, scaled box) in order; merges get ids count, count + 1, ...
    active = [(rank, box[rank] * scale) for rank in range(count)]
    children = {}
    while len(active) > 1:
        nearest, areas = reference_nearest([b for _, b in active], PLOC_RADIUS)
        leads = [i for i, j in enumerate(nearest) if nearest[j] == i and j > i]
        if not leads:
            closest = int(np.argmin(areas))
            leads = [min(closest, nearest[closest])]
            nearest[leads[0]] = max(closest, nearest[closest])
        partners = {nearest[i]: i for i in leads}
        merged = []
        for i, (ident, scaled) in enumerate(active):
            if i in partners:
                continue
            if i in leads:
                other_id, other_box = active[nearest[i]]
                children[count + len(children)] = (ident, other_id)
                merged.append((count + len(children) - 1, np.minimum(scaled, other_box)))
            else:
                merged.append((ident, scaled))
        active = merged
    root = active[0][0]
    # Bottom up: boxes, sizes, SAH costs, leaves, heights
    size, cost, leaf, height = [1] * count, [], [True] * count, [0] * count
    for b in box:
        x, y, z = (float(b[a] + b[3 + a]) for a in range(3))
        cost.append(x * y + y * z + z * x)
    for ident in range(count, count + len(children)):
        left, right = children[ident]
        box.append(np.minimum(box[left], box[right]))
        size.append(size[left] + size[right])
        x, y, z = (float(box[ident][a] + box[ident][3 + a]) for a in range(3))
        area = x * y + y * z + z * x
        subtree = TRAVERSAL_COST * area + cost[left] + cost[right]
        as_leaf = size[ident] * area if size[ident] <= LEAF_MAX else np.inf
        leaf.append(as_leaf <= subtree)
        cost.append(min(as_leaf, subtree))
        height.append(0 if leaf[ident] else 1 + max(height[left], height[right]))

    def ranks_of(ident):
        if ident < count:
            return [ident]
        return ranks_of(children[ident][0]) + ranks_of(children[ident][1])

    def balanced(size):
        return int(np.ceil(np.log2(max(size / LEAF_MAX, 1.0))))

    # Top down, breadth first: a node is (cluster id or None for a balanced tree's, ranks,
    # first position in the leaves' order: a cluster's left child's first)
    nodes, level, depth = [], [(root, ranks_of(root), 0)], 0
    while level:
        room, below = BVH_MAX_DEPTH - depth, []
        for ident, ranks, first in level:
            if ident is not None and ident >= count and height[ident] > room:
                fits = [
                    min(height[child], balanced(size[child])) < room for child in children[ident]
                ]
                if not all(fits):
                    ident, ranks = None, sorted(ranks)
            if ident is None:
                split = len(ranks) > LEAF_MAX and room > 0
                half = (len(ranks) + 1) // 2
                pairs = [(None, ranks[:half], first), (None, ranks[half:], first + half)]
            else:
                split = not leaf[ident] and room > 0
                pairs = [
                    (child, ranks_of(child), first + (k and size[children[ident][0]]))
                    for k, child in enumerate(children.get(ident, ()))
                ]
            nodes.append((ranks, split, first))
            below += pairs if split else []
        level, depth = below, depth + 1
    # Records: leaves' ranges of the leaves' order, split nodes' first children 2k + 1
    order = np.full(count, -1)
    for ranks, split, first in nodes:
        if not split:
            order[first : first + len(ranks)] = ranks
    records = np.zeros(len(nodes), BINARY_NODE_DTYPE)
    split_count = 0
    for k, (ranks, split, first) in enumerate(nodes):
        union = np.min([box[r] for r in ranks], axis=0)
        records[k]["lower"], records[k]["upper"] = union[:3], -union[3:]
        if split:
            split_count += 1
            x, y, z = records[k]["upper"] - records[k]["lower"]
            widest = (0 if x >= z else 2) if x >= y else (1 if y >= z else 2)
            records[k]["offset"], records[k]["count"] = 2 * split_count - 1, -1 - widest
        else:
            records[k]["offset"], records[k]["count"] = first, len(ranks)
    return records, ranked[order].astype(np.uint32)


@pytest.mark.parametrize(
    "shape", ["random", "overlapping", "identical", "coincident points", "a chain", "two"]
)
def test_build_equals_the_cluster_by_cluster_reference(shape):
    """build_bvh's whole-array passes (merge rounds, SAH leaves, levels top down) against
    reference_build, bit for bit: random small boxes, large overlapping ones, identical
    boxes (ties), coincident points, an exponential chain (rebuilt below the depth cap: 23
    primitives halved into 12 and 11)."""
    rng = np.random.default_rng(31)
    if shape == "random":
        lower = rng.uniform(-1, 1, (400, 3))
        upper = lower + rng.exponential(0.03, (400, 3))
    elif shape == "overlapping":
        lower, upper = random_triangle_bounds(rng, 300, 0.4)
    elif shape == "identical":
        lower = np.zeros((100, 3))
        upper = lower + 1.0
    elif shape == "coincident points":
        lower = upper = np.full((60, 3), 0.25)
    elif shape == "a chain":
        lower = np.stack([2.0 ** np.arange(100), np.zeros(100), np.zeros(100)], 1)
        upper = lower + 0.5
    else:
        lower, upper = degenerate_bounds("two")
    nodes, prims = build_bvh(lower, upper)
    reference_nodes, reference_prims = reference_build(lower, upper)
    np.testing.assert_array_equal(prims, reference_prims)
    assert nodes.tobytes() == reference_nodes.tobytes()


@pytest.mark.parametrize("radius", range(1, PLOC_RADIUS + 1))
@pytest.mark.parametrize("chunk", [1, 7, 90])
def test_nearest_clusters_match_the_reference_at_every_radius(radius, chunk):
    """_nearest_clusters at each search radius against reference_nearest, in chunks of 1, 7
    and all 90 clusters, twice through the same scratch."""
    rng = np.random.default_rng(32)
    low = rng.uniform(-1, 1, (90, 3)).astype(np.float32)
    high = low + rng.uniform(0, 0.3, (90, 3)).astype(np.float32)
    low[30:45], high[30:45] = low[30], high[30]  # ties
    boxes = np.concatenate([low.T, -high.T])
    scratch = np.empty((NEAREST_ROWS, chunk + 2 * radius), np.float32)
    result = np.empty((2, 100), np.int32)
    expected, areas = reference_nearest(list(boxes.T), radius)
    for _ in range(2):
        index = np.arange(100, dtype=np.int32)
        nearest, area = _nearest_clusters(boxes, index, scratch, result, radius, chunk)
        np.testing.assert_array_equal(nearest, expected)
        np.testing.assert_array_equal(area.view(np.int32), areas)


def test_bvh_scaling_build_times_report_each_stage_with_its_page_faults(monkeypatch):
    """bench/bvh_scaling.py's build section: CPU, wall time and minor page faults of each
    stage of the whole way, and totals that cover the stages."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "bench"))
    import bvh_scaling

    row = bvh_scaling.build_times(bvh_scaling.scene_with_sphere_mesh(2000), 2)
    for stage in ("bounds", "build", "collapse", "leaves", "total_build"):
        assert row[f"{stage}_cpu_s"] >= 0.0 and row[f"{stage}_wall_s"] > 0.0
        assert row[f"{stage}_page_faults"] >= 0
    stages = ("bounds", "build", "collapse", "leaves")
    assert row["total_build_wall_s"] >= 0.99 * max(row[f"{stage}_wall_s"] for stage in stages)
    assert row["sah_cost"] > 1.0 and row["nodes"] > 1
