"""The device side of the BVH (kernels/geometry.h BVH_Traverse, scene_device.pack_bvh_leaves):
the 8-lane triangle test decides exactly like the one-triangle test, the leaf records hold every
leaf's primitives once and unchanged, a tree at the depth cap traces like brute force, and
primitives the records cannot hold are refused with a clear error."""

import numpy as np
import pyopencl as cl
import pytest
from geometry_device import assert_bvh_equals_brute_force, device_intersect, device_occluded
from scene_texts import lit_room, mesh_text, random_shapes_text

from clrender.bvh import BVH_MAX_DEPTH, BVH_NODE_DTYPE, build_bvh, build_wide_bvh
from clrender.errors import ClrenderError
from clrender.runtime import padded_global_size
from clrender.scene import load_scene
from clrender.scene_device import (
    BVH_BLOCK_WIDTH,
    BVH_LEAF_ALIGN,
    BVH_LEAF_FIELDS,
    BVH_MAX_BRUTE_QUADS,
    SPHERE_DTYPE,
    TRIANGLE_BLOCK_DTYPE,
    TRIANGLE_DTYPE,
    pack_bvh,
    pack_bvh_leaves,
    primitive_bounds,
    quad_block_dtype,
)

HEADER = lit_room(16)


def mixed_scene(tmp_path, seed, quads=40, spheres=15, triangles=300):
    """Random quads, spheres and small triangles in [-1, 1]^3 (plus the light quad)."""
    rng = np.random.default_rng(seed)
    text = HEADER + random_shapes_text(rng, quads, spheres, triangles, 0.2, (0.03, 0.15), 0.1)
    path = tmp_path / f"mixed-{seed}.toml"
    path.write_text(text)
    return load_scene(path)


def test_triangle_block_struct_matches_the_kernel(runtime):
    sizes = np.zeros(1, np.uint32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=sizes.nbytes)
    runtime.kernel("bvh_test.cl", "struct_sizes")(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, sizes, buf)
    assert sizes[0] == TRIANGLE_BLOCK_DTYPE.itemsize


def block_hits(runtime, triangles, origins, directions, tmax):
    """(t_block, t_scalar) of kernels/bvh_test.cl: rays x triangles, inf where no hit."""
    count = len(triangles)
    lanes = -(-count // BVH_BLOCK_WIDTH) * BVH_BLOCK_WIDTH
    padded = np.zeros(lanes, TRIANGLE_DTYPE)
    padded[:count] = triangles
    blocks = np.zeros(lanes // BVH_BLOCK_WIDTH, TRIANGLE_BLOCK_DTYPE)
    for key in ("p0", "p1", "p2"):
        blocks[key] = padded[key].reshape(-1, BVH_BLOCK_WIDTH, 3).transpose(0, 2, 1)
    blocks["id"] = np.arange(lanes).reshape(-1, BVH_BLOCK_WIDTH)
    n = len(origins)
    out = [cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=4 * n * lanes) for _ in "ab"]
    runtime.kernel("bvh_test.cl", "triangle_block_hits")(
        runtime.queue,
        (padded_global_size(n),),
        (runtime.local_size,),
        np.uint32(n),
        runtime.upload(origins.astype(np.float32)),
        runtime.upload(directions.astype(np.float32)),
        runtime.upload(tmax.astype(np.float32)),
        runtime.upload(blocks),
        runtime.upload(padded),
        np.uint32(len(blocks)),
        *out,
    )
    result = []
    for buf in out:
        host = np.empty((n, lanes), np.float32)
        cl.enqueue_copy(runtime.queue, host, buf)
        result.append(host[:, :count])
    return result


def test_triangle_block_decides_like_the_one_triangle_test(runtime):
    """Random triangles, a triangulated grid whose shared vertices and edges rays aim at exactly
    (some along the axes), degenerate and far-away triangles: the block test reports the same
    hits at bit-identical distances as Triangle_Hit (the watertight test it vectorises)."""
    rng = np.random.default_rng(21)
    n = 6
    grid = np.stack(np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"), -1)
    points = np.concatenate([grid.reshape(-1, 2) / n - 0.5, np.zeros(((n + 1) ** 2, 1))], 1)
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).reshape(-1)
    faces = np.concatenate(
        [
            np.stack([corner, corner + n + 1, corner + n + 2], 1),
            np.stack([corner, corner + n + 2, corner + 1], 1),
        ]
    )
    vertices = [points[faces]]
    vertices.append(rng.uniform(-1, 1, (1, 1, 3)) + rng.normal(size=(60, 3, 3)) * 0.3)
    flat = rng.normal(size=(8, 3, 3))
    flat[:, 2] = flat[:, 0] + 0.5 * (flat[:, 1] - flat[:, 0])  # collinear: zero area
    flat[:4, 1] = flat[:4, 0]  # two equal vertices
    vertices.append(flat)
    vertices.append(rng.normal(size=(8, 3, 3)) * 1e4 + 3e4)
    vertices = np.concatenate(vertices).astype(np.float32)
    triangles = np.zeros(len(vertices), TRIANGLE_DTYPE)
    triangles["p0"], triangles["p1"], triangles["p2"] = vertices.transpose(1, 0, 2)
    # Rays at the grid's vertices and edge midpoints (axis-aligned and oblique), random rays,
    # and rays towards the far triangles
    ticks = np.arange(1, 2 * n) / (2 * n) - 0.5  # the interior vertices and edges
    targets = np.stack(np.meshgrid(ticks, ticks), -1).reshape(-1, 2)
    targets = np.concatenate([targets, np.zeros((len(targets), 1))], 1)
    straight = targets + [0.0, 0.0, 2.0]
    oblique = targets + rng.uniform(-1, 1, targets.shape) * [1, 1, 0] + [0, 0, 1.5]
    origins = [straight, oblique, rng.uniform(-1.5, 1.5, (3000, 3))]
    directions = [targets - straight, targets - oblique, rng.normal(size=(3000, 3))]
    far = rng.normal(size=(500, 3))
    origins.append(far)
    directions.append(vertices[-8:].mean(axis=1)[rng.integers(0, 8, 500)] - far)
    origins, directions = np.concatenate(origins), np.concatenate(directions)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    tmax = np.where(rng.uniform(size=len(origins)) < 0.5, np.inf, rng.uniform(0, 3, len(origins)))
    grid_rays = 2 * len(targets)
    tmax[:grid_rays] = np.inf
    t_block, t_scalar = block_hits(runtime, triangles, origins, directions, tmax)
    hits = np.isfinite(t_scalar)
    assert hits[:grid_rays].any(axis=1).all()  # every ray at the grid hits it (watertight)
    assert hits[grid_rays:].sum() > 500 and hits[-500:, -8:].sum() > 100
    np.testing.assert_array_equal(t_block.view(np.uint32), t_scalar.view(np.uint32))


def decode_records(nodes, words, scene):
    """Per (node, record start) of the node's leaf lanes: the primitive ids the record holds,
    checking each block's contents against the scene's primitives on the way."""
    held = {}
    for index, node in enumerate(nodes):
        leaf = node["count"] > 0
        for start in sorted(set(node["child"][leaf].tolist())):
            # The lanes of a group share their record and its counts
            group = leaf & (node["child"] == start)
            assert len(set(node["count"][group])) == 1
            held[index, start] = decode_record(words, start, node["count"][group][0], scene)
    # Each record belongs to one group
    starts = [start for _, start in held]
    assert len(starts) == len(set(starts))
    return held


def decode_record(words, start, count, scene):
    """The primitive ids of the record at word `start` (its lanes' packed `count`)."""
    quad_dtype = quad_block_dtype(BVH_BLOCK_WIDTH)
    first_triangle = len(scene.quads) + len(scene.spheres)
    start, count = int(start), int(count)
    assert start % BVH_LEAF_ALIGN == 0
    (tri_shift, tri_bits), (quad_shift, quad_bits), (sphere_shift, sphere_bits) = BVH_LEAF_FIELDS
    tri_blocks = count >> tri_shift & (2**tri_bits - 1)
    quad_blocks = count >> quad_shift & (2**quad_bits - 1)
    sphere_count = count >> sphere_shift & (2**sphere_bits - 1)
    at = start
    tri = words[at : at + tri_blocks * TRIANGLE_BLOCK_DTYPE.itemsize // 4]
    tri = tri.view(TRIANGLE_BLOCK_DTYPE)
    at += tri.nbytes // 4
    quads = words[at : at + quad_blocks * quad_dtype.itemsize // 4].view(quad_dtype)
    at += quads.nbytes // 4
    spheres = words[at : at + sphere_count].astype(np.int64)
    ids = []
    for block in tri:
        used = block["id"] >= 0
        assert np.all(block["p0"][:, ~used] == 0) and np.all(block["p2"][:, ~used] == 0)
        # Unused lanes come last
        assert np.all(used[: used.sum()])
        for lane in np.flatnonzero(used):
            original = scene.triangles[block["id"][lane] - first_triangle]
            for key in ("p0", "p1", "p2", "material", "normals", "emitter"):
                np.testing.assert_array_equal(block[key][..., lane], original[key])
        ids += block["id"][used].tolist()
    for block in quads:
        used = block["quad"] >= 0
        assert np.all(block["plane_d"][~used] == -1) and np.all(block["normal"][:, ~used] == 0)
        for lane in np.flatnonzero(used):
            original = scene.quads[block["quad"][lane]]
            for key in ("corner", "normal", "u_dual", "v_dual"):
                np.testing.assert_array_equal(block[key][:, lane], original[key])
            assert block["plane_d"][lane] == original["plane_d"]
        ids += block["quad"][used].tolist()
    assert np.all((spheres >= len(scene.quads)) & (spheres < first_triangle))
    ids += spheres.tolist()
    return ids


def test_leaf_records_hold_every_leaf_primitive_once(tmp_path):
    scene = mixed_scene(tmp_path, 31)
    tree, prims = build_wide_bvh(*primitive_bounds(scene.quads, scene.spheres, scene.triangles))
    nodes, words = pack_bvh_leaves(tree, prims, scene.quads, len(scene.spheres), scene.triangles)
    # Only the leaf lanes' child and count change
    for key in ("lower", "upper"):
        np.testing.assert_array_equal(nodes[key], tree[key])
    inner = tree["count"] <= 0
    np.testing.assert_array_equal(nodes["child"][inner], tree["child"][inner])
    np.testing.assert_array_equal(nodes["count"][inner], tree["count"][inner])
    held = decode_records(nodes, words, scene)
    for (index, start), ids in held.items():
        lanes = np.flatnonzero((nodes["count"][index] > 0) & (nodes["child"][index] == start))
        child, count = tree["child"][index], tree["count"][index]
        expected = np.concatenate([prims[child[j] : child[j] + count[j]] for j in lanes])
        assert sorted(ids) == sorted(expected.tolist())
        # A group fills at most one block of its primitives
        assert count[lanes].sum() <= BVH_BLOCK_WIDTH or len(lanes) == 1
    every = np.concatenate([np.asarray(ids) for ids in held.values()])
    np.testing.assert_array_equal(np.sort(every), np.arange(scene.primitive_count))
    # The renderer's packing is this one, over the primitives but its few quads (brute force)
    assert len(scene.quads) <= BVH_MAX_BRUTE_QUADS
    lower, upper = primitive_bounds(scene.quads, scene.spheres, scene.triangles)
    first = len(scene.quads)
    tree, prims = build_wide_bvh(lower[first:], upper[first:])
    expected = pack_bvh_leaves(
        tree, prims + np.uint32(first), scene.quads, len(scene.spheres), scene.triangles
    )
    packed_nodes, packed_words = pack_bvh(scene.quads, scene.spheres, scene.triangles, -1)
    assert packed_nodes.tobytes() == expected[0].tobytes()
    np.testing.assert_array_equal(packed_words, expected[1])


def test_leaf_records_beyond_the_hit_ids_are_refused(tmp_path, monkeypatch):
    # A triangle hit is named by an int (quad_count + sphere_count + word + lane): records the
    # device could not address are refused in one line, not wrapped into negative ids (holes)
    from clrender import scene_device

    scene = mixed_scene(tmp_path, 31)
    tree, prims = build_wide_bvh(*primitive_bounds(scene.quads, scene.spheres, scene.triangles))
    args = (tree, prims, scene.quads, len(scene.spheres), scene.triangles)
    _, words = pack_bvh_leaves(*args)
    first_triangle = len(scene.quads) + len(scene.spheres)
    monkeypatch.setattr(scene_device, "MAX_HIT_ID", first_triangle + len(words))
    pack_bvh_leaves(*args)  # the last word addressable: accepted
    monkeypatch.setattr(scene_device, "MAX_HIT_ID", first_triangle + len(words) - 1)
    with pytest.raises(ClrenderError, match="32-bit hit ids") as error:
        pack_bvh_leaves(*args)
    assert "\n" not in str(error.value)


def clear_triangle_hits(scene, origins, directions, t, prim):
    """Where a hit on a triangle is one the geometry bears out: Moller-Trumbore in float64 puts
    the ray inside the triangle, away from its edges, at the same distance. (Triangles far below
    the float rounding of the ray's origin round to chance hits; the BVH's boxes cull those.)"""
    first = len(scene.quads) + len(scene.spheres)
    on_triangle = prim >= first
    tri = scene.triangles[np.where(on_triangle, prim - first, 0)]
    p0, p1, p2 = (tri[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    e1, e2 = p1 - p0, p2 - p0
    pvec = np.cross(directions, e2)
    inv = 1.0 / np.einsum("ij,ij->i", pvec, e1)
    tvec = origins - p0
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = np.einsum("ij,ij->i", directions, qvec) * inv
    t_ref = np.einsum("ij,ij->i", e2, qvec) * inv
    inside = np.minimum.reduce([u, v, 1 - u - v]) > 1e-3
    return on_triangle & inside & (np.abs(t_ref - t) <= 1e-4 * t_ref)


def test_bvh_at_the_depth_cap_traces_like_brute_force(runtime, tmp_path):
    """Triangles at doubling distances along x, 2^-59 to 2^59 (the binned SAH splits off about
    one a level, so the binary tree reaches BVH_MAX_DEPTH): closest hits equal brute force's
    wherever brute force's hit is geometrically clear, and any hit agrees with them."""
    x = 2.0 ** np.arange(-59, 60)
    count = len(x)
    s = 0.4 * x
    positions = np.stack(
        [
            np.stack([x, -s, -s], 1),
            np.stack([x, s, -s], 1),
            np.stack([x, np.zeros(count), s], 1),
        ],
        1,
    )
    path = tmp_path / "chain.toml"
    path.write_text(
        HEADER + mesh_text(positions.reshape(-1, 3), np.arange(3 * count).reshape(-1, 3))
    )
    scene = load_scene(path)
    binary, _ = build_bvh(*primitive_bounds(scene.quads, scene.spheres, scene.triangles))
    depth = np.zeros(len(binary), int)
    for index, node in enumerate(binary):
        if node["count"] < 0:
            depth[node["offset"] : node["offset"] + 2] = depth[index] + 1
    assert depth.max() == BVH_MAX_DEPTH
    rng = np.random.default_rng(41)
    # From near the axis among the triangles, along +x and -x within a wide cone
    start = rng.choice(x[10:110], 4000)[:, None]
    origins = start * ([1, 0, 0] + rng.uniform(-0.2, 0.2, (4000, 3)))
    directions = rng.normal(size=(4000, 3)) * [0.2, 1, 1] + [1, 0, 0]
    directions[::2, 0] *= -1
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    t_bvh, prim_bvh = device_intersect(runtime, scene, origins, directions, True)
    clear = clear_triangle_hits(scene, origins, directions, t_brute, prim_brute)
    assert clear.sum() > 1000 and (clear | (prim_brute < 0)).mean() > 0.95
    np.testing.assert_array_equal(prim_bvh[clear], prim_brute[clear])
    np.testing.assert_array_equal(t_bvh[clear], t_brute[clear])
    # The BVH tests a subset of brute force's triangles: no hit where brute force has none
    assert np.all(prim_bvh[prim_brute < 0] < 0)
    tmax = rng.uniform(0, 1, len(origins)) * start[:, 0]
    blocked = device_occluded(runtime, scene, origins, directions, tmax, True)
    known = clear | (prim_brute < 0)
    np.testing.assert_array_equal(blocked[known], (t_brute < tmax)[known])
    assert 0.1 < blocked[known].mean() < 0.9


@pytest.mark.parametrize("shape", ["sphere", "quad"])
def test_too_many_coincident_primitives_are_refused(shape):
    """A leaf of more primitives than a leaf record's count fields hold is a one-line error,
    not a wrong picture. The builder splits even coincident primitives into leaves of at most
    LEAF_MAX (so such coincident scenes pack), so the refusal is met with a hand-made node."""
    quads = np.zeros(0, load_scene("mitsuba-cbox").quads.dtype)
    sphere_count = 0
    if shape == "sphere":
        sphere_count = 2 ** BVH_LEAF_FIELDS[2][1]
        spheres = np.zeros(sphere_count, SPHERE_DTYPE)
        spheres["radius"] = 1.0
    else:
        quads = np.zeros(8 * 2 ** BVH_LEAF_FIELDS[1][1], quads.dtype)
        quads["edge1"] = [1, 0, 0]
        quads["edge2"] = [0, 1, 0]
        spheres = np.zeros(0, SPHERE_DTYPE)
    triangles = np.zeros(0, TRIANGLE_DTYPE)
    count = len(quads) + sphere_count
    nodes, _ = pack_bvh(quads, spheres, triangles, -1)
    assert nodes["count"][nodes["count"] > 0].size >= count // 8  # split, not one leaf
    node = np.zeros(1, BVH_NODE_DTYPE)
    node["count"] = -1
    node["count"][0, 0], node["child"][0, 0] = count, 0
    prims = np.arange(count, dtype=np.uint32)
    with pytest.raises(ClrenderError, match="in one place") as error:
        pack_bvh_leaves(node, prims, quads, sphere_count, triangles)
    assert "\n" not in str(error.value)
    # One fewer fits
    fewer = 8 if shape == "quad" else 1
    node["count"][0, 0] = count - fewer
    pack_bvh_leaves(
        node,
        prims[fewer:] - fewer,
        quads[fewer:] if fewer == 8 else quads,
        sphere_count - (fewer if shape == "sphere" else 0),
        triangles,
    )


def test_bvh_equals_brute_force_with_every_kind_in_the_leaves(runtime, tmp_path):
    """Quads, spheres and triangles mixed in the nodes' records: ids and distances of the
    closest hits equal brute force's, and so do shadow rays' answers."""
    scene = mixed_scene(tmp_path, 32, quads=120, spheres=60, triangles=2000)
    nodes, _ = scene.bvh(brute_force_limit=-1)
    leaf = nodes["count"] > 0
    counts = nodes["count"][leaf]
    (_, tri_bits), (quad_shift, quad_bits), (sphere_shift, _) = BVH_LEAF_FIELDS
    assert (
        (counts & (2**tri_bits - 1) > 0) & (counts >> quad_shift & (2**quad_bits - 1) > 0)
    ).any()
    assert (counts >> sphere_shift > 0).any()
    rng = np.random.default_rng(33)
    prim_brute = assert_bvh_equals_brute_force(runtime, scene, rng)
    assert (prim_brute >= 0).mean() > 0.5


def test_bvh_through_stacked_sheets_equals_brute_force(runtime, tmp_path):
    """Sheets of small triangles stacked along z (a ray's nearer sheet hides the farther ones:
    after a hit, the traversal culls their subtrees) and large triangles across the whole scene
    (leaves of the root, whose children are tested before the traversal's call): closest hits
    and shadow rays through the BVH equal brute force's, for rays from outside the tree's box and
    from inside it, oblique and along the axes (zero direction components), and shadow rays
    ending before the tree's box, between sheets and beyond them."""
    rng = np.random.default_rng(51)
    cells = 10
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, cells + 1), np.linspace(-1, 1, cells + 1)), -1)
    corner = (np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]).reshape(-1)
    faces = np.concatenate(
        [
            np.stack([corner, corner + cells + 1, corner + cells + 2], 1),
            np.stack([corner, corner + cells + 2, corner + 1], 1),
        ]
    )
    sheets = []
    for z in np.linspace(-0.8, 0.8, 6):
        points = np.concatenate([grid.reshape(-1, 2), np.full(((cells + 1) ** 2, 1), z)], 1)
        points[:, 2] += rng.normal(size=len(points)) * 0.02  # uneven: sheets' boxes overlap a bit
        sheets.append(points[faces])
    large = rng.uniform(-1.5, 1.5, (4, 3, 3))
    vertices = np.concatenate([*sheets, large]).reshape(-1, 3)
    path = tmp_path / "sheets.toml"
    path.write_text(HEADER + mesh_text(vertices, np.arange(len(vertices)).reshape(-1, 3)))
    scene = load_scene(path)
    nodes, _ = scene.bvh(brute_force_limit=-1)
    root = nodes[0]
    assert (root["count"] > 0).any() and (root["count"] == 0).any()  # leaves and nodes
    rays = 6000
    # From outside (above and below the sheets, towards them), from inside, and along the axes
    target = rng.uniform(-1, 1, (rays, 3))
    origins = target + rng.choice([-1, 1], (rays, 1)) * [0, 0, 3] + rng.normal(size=(rays, 3))
    origins[: rays // 3] = rng.uniform(-1.2, 1.2, (rays // 3, 3))
    directions = target - origins
    axis = np.eye(3)[rng.integers(0, 3, rays // 3)] * rng.choice([-1, 1], (rays // 3, 1))
    directions[-(rays // 3) :] = axis
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    t_bvh, prim_bvh = device_intersect(runtime, scene, origins, directions, True)
    np.testing.assert_array_equal(prim_bvh, prim_brute)
    np.testing.assert_array_equal(t_bvh, t_brute)
    first_large = len(scene.quads) + len(scene.spheres) + len(vertices) // 3 - len(large)
    assert ((prim_brute >= 0) & (prim_brute < first_large)).mean() > 0.5
    assert (prim_brute >= first_large).sum() > 100
    # Shadow rays: to just before the closest hit, just beyond it, and to a tenth of the way
    reach = np.where(np.isfinite(t_brute), t_brute, 3.0)
    for tmax in (reach * 0.999, reach * 1.001 + 1e-3, reach * 0.1):
        blocked = device_occluded(runtime, scene, origins, directions, tmax, True)
        np.testing.assert_array_equal(blocked, t_brute < tmax)
