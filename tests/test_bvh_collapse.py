"""The 8-wide tree (clrender/bvh.py collapse_bvh) and its leaf records' groups
(scene_device._leaf_groups): the collapse reaches the optimum of its surface-area heuristic (a
recursive reference), never dearer than the greedy collapse it replaced; every structure
invariant on random and degenerate inputs; groups of at most one block; quads beside the BVH
trace like brute force."""

import functools
import re
from pathlib import Path

import numpy as np
import pytest
from geometry_device import assert_bvh_equals_brute_force
from scene_texts import lit_room, random_shapes_text

from clrender.bvh import (
    BVH_BLOCK_WIDTH,
    BVH_MAX_DEPTH,
    BVH_NODE_DTYPE,
    BVH_WIDTH,
    LEAF_MAX,
    WIDE_BLOCK_COST,
    WIDE_LEAF_MAX,
    WIDE_NODE_COST,
    build_bvh,
    collapse_bvh,
    wide_sah_cost,
)
from clrender.scene import load_scene
from clrender.scene_device import BVH_MAX_BRUTE_QUADS, _leaf_groups, pack_bvh

KERNELS = Path(__file__).resolve().parent.parent / "kernels"


def degenerate_bounds(shape):
    """Bounds (lower, upper) of inputs that strain the build: one primitive, two, coincident
    points, boxes along a line, a flat grid of equal boxes, random boxes."""
    if shape == "one":
        return np.zeros((1, 3)), np.ones((1, 3))
    if shape == "two":
        return np.array([[0.0, 0, 0], [2, 0, 0]]), np.array([[1.0, 1, 1], [3, 1, 1]])
    if shape == "coincident points":
        point = np.full((600, 3), 0.25)
        return point, point
    if shape == "a line":
        t = np.linspace(-1.0, 1.0, 700)[:, None] * np.array([[1.0, 0.5, 0.25]])
        return t, t + 1e-4
    if shape == "a flat grid":
        x, y = np.meshgrid(np.arange(30.0), np.arange(20.0), indexing="ij")
        lower = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
        return lower, lower + [1.0, 1.0, 0.0]
    rng = np.random.default_rng(41)
    lower = rng.uniform(-1, 1, (800, 3))
    return lower, lower + rng.exponential(0.03, (800, 3))


SHAPES = ["one", "two", "coincident points", "a line", "a flat grid", "random"]


def half_area(lower, upper):
    x, y, z = (np.asarray(upper, np.float64) - np.asarray(lower, np.float64)).T
    return x * y + y * z + z * x


def reference_optimum(binary):
    """The least cost of any collapse of the binary tree by the collapse's heuristic, one node
    at a time by recursion: a subtree as i children is either one child (a leaf of at most
    WIDE_LEAF_MAX primitives, or of a binary leaf; or a wide node over the best distribution of
    its subtree into BVH_WIDTH) or k children from its left subtree and i - k from its right."""
    area = half_area(binary["lower"], binary["upper"])
    count, offset = binary["count"], binary["offset"]

    @functools.cache
    def size(n):
        return int(count[n]) if count[n] > 0 else size(offset[n]) + size(offset[n] + 1)

    def as_leaf(n):
        if count[n] < 0 and size(n) > WIDE_LEAF_MAX:
            return np.inf
        return WIDE_BLOCK_COST * -(-size(n) // BVH_BLOCK_WIDTH) * area[n]

    @functools.cache
    def spread(n, i):
        if count[n] > 0 or i < 2:
            return np.inf
        left = offset[n]
        return min(best(left, k) + best(left + 1, i - k) for k in range(1, i))

    @functools.cache
    def best(n, i):
        one = min(as_leaf(n), WIDE_NODE_COST * area[n] + spread(n, BVH_WIDTH))
        return min(one, spread(n, i))

    root = spread(0, BVH_WIDTH) if count[0] < 0 else as_leaf(0)
    return (WIDE_NODE_COST * area[0] + root) / area[0]


def reference_greedy_collapse(binary):
    """The collapse this one replaced (Wald et al. 2008), one node at a time: from a binary
    node, open the interior child of largest area until BVH_WIDTH lanes or no interior lane."""
    area = half_area(binary["lower"], binary["upper"])
    wide, queue = [], [0]
    while len(wide) < len(queue):
        lanes = [queue[len(wide)]]
        while len(lanes) < BVH_WIDTH:
            interior = [k for k, node in enumerate(lanes) if binary["count"][node] < 0]
            if not interior:
                break
            opened = max(interior, key=lambda k: (area[lanes[k]], -k))
            first = int(binary["offset"][lanes[opened]])
            lanes[opened] = first
            lanes.append(first + 1)
        node = np.zeros((), BVH_NODE_DTYPE)
        node["child"], node["count"] = -1, -1
        for lane, index in enumerate(lanes):
            node["lower"][:, lane] = binary["lower"][index]
            node["upper"][:, lane] = binary["upper"][index]
            if binary["count"][index] < 0:
                node["child"][lane], node["count"][lane] = len(queue), 0
                queue.append(index)
            else:
                node["child"][lane] = binary["offset"][index]
                node["count"][lane] = binary["count"][index]
        wide.append(node)
    return np.array(wide, BVH_NODE_DTYPE)


@pytest.mark.parametrize("shape", SHAPES)
def test_collapse_reaches_the_optimum_of_its_heuristic(shape):
    binary, _ = build_bvh(*degenerate_bounds(shape))
    wide = collapse_bvh(binary)
    optimum = reference_optimum(binary)
    assert wide_sah_cost(wide) == pytest.approx(optimum, rel=1e-5)  # (float32 costs)
    greedy = wide_sah_cost(reference_greedy_collapse(binary))
    assert wide_sah_cost(wide) <= greedy * (1 + 1e-5)
    if shape == "random":  # the greedy collapse is not optimal here
        assert wide_sah_cost(wide) < 0.99 * greedy


def test_wide_sah_cost_of_a_hand_built_tree():
    """A root with a leaf of 9 primitives in [0, 1]^3 (half area 3, two blocks) and a node in
    [1, 2] x [0, 1] x [0, 0.5] (half area 2) holding a leaf of 3 in [1, 2] x [0, 1] x [0, 0]
    (half area 1): the root's union [0, 2] x [0, 1]^2 has half area 5."""
    nodes = np.zeros(2, BVH_NODE_DTYPE)
    nodes["count"] = -1
    nodes[0]["lower"][:, 0], nodes[0]["upper"][:, 0] = (0, 0, 0), (1, 1, 1)
    nodes[0]["count"][0] = 9
    nodes[0]["lower"][:, 1], nodes[0]["upper"][:, 1] = (1, 0, 0), (2, 1, 0.5)
    nodes[0]["count"][1], nodes[0]["child"][1] = 0, 1
    nodes[1]["lower"][:, 0], nodes[1]["upper"][:, 0] = (1, 0, 0), (2, 1, 0)
    nodes[1]["count"][0] = 3
    expected = (
        WIDE_NODE_COST * 5 + 2 * WIDE_BLOCK_COST * 3 + WIDE_NODE_COST * 2 + WIDE_BLOCK_COST * 1
    ) / 5
    assert wide_sah_cost(nodes) == pytest.approx(expected)


@pytest.mark.parametrize("shape", SHAPES)
def test_collapse_keeps_every_invariant(shape):
    """Each primitive in exactly one leaf lane, inside its box; each node but the root some
    lane's child exactly once, its lanes inside that lane's box; depth first (a node's children
    after it, each subtree a contiguous range); leaves of at most WIDE_LEAF_MAX primitives but
    the binary tree's own leaves (at most LEAF_MAX); depth within BVH_MAX_DEPTH."""
    lower, upper = degenerate_bounds(shape)
    binary, prims = build_bvh(lower, upper)
    nodes = collapse_bvh(binary)
    assert nodes.dtype == BVH_NODE_DTYPE
    count, child = nodes["count"], nodes["child"]
    leaf = count > 0
    reached = np.concatenate(
        [prims[c : c + n] for c, n in zip(child[leaf], count[leaf], strict=True)]
    )
    np.testing.assert_array_equal(np.sort(reached), np.arange(len(lower)))
    binary_leaf_sizes = set(binary["count"][binary["count"] > 0].tolist())
    for size in count[leaf]:
        assert size <= WIDE_LEAF_MAX or size in binary_leaf_sizes
    assert count[leaf].max() <= max(WIDE_LEAF_MAX, LEAF_MAX)
    parent = np.full(len(nodes), -1)
    depth = np.zeros(len(nodes), int)
    end = np.zeros(len(nodes), int)  # one past the last node of each subtree
    for index in range(len(nodes) - 1, -1, -1):
        inner = np.flatnonzero(count[index] == 0)
        end[index] = max([index + 1] + [end[child[index, j]] for j in inner])
    for index, node in enumerate(nodes):
        # Leaves' primitives inside their boxes
        for lane in np.flatnonzero(leaf[index]):
            members = prims[child[index, lane] : child[index, lane] + count[index, lane]]
            assert np.all(lower[members] >= node["lower"][:, lane])
            assert np.all(upper[members] <= node["upper"][:, lane])
        # Child nodes: after it, in depth-first order, reached once, inside the lane's box
        following = index + 1
        for lane in np.flatnonzero(count[index] == 0):
            below = child[index, lane]
            assert below == following and parent[below] == -1
            following = end[below]
            parent[below], depth[below] = index, depth[index] + 1
            used = nodes[below]["count"] >= 0
            assert np.all(nodes[below]["lower"][:, used] >= node["lower"][:, lane, None])
            assert np.all(nodes[below]["upper"][:, used] <= node["upper"][:, lane, None])
        assert following == end[index]
    assert np.all(parent[1:] >= 0) and depth.max() <= BVH_MAX_DEPTH
    assert np.all(count >= -1)


def test_collapse_fills_its_nodes():
    """Random small boxes: the wide nodes use most of their lanes, fewer than half as many nodes
    as the greedy collapse makes (which fills lanes only while it finds interior nodes)."""
    rng = np.random.default_rng(5)
    centre = rng.normal(size=(20000, 3))
    centre /= np.linalg.norm(centre, axis=1)[:, None]
    binary, _ = build_bvh(centre - 0.01, centre + 0.01)
    nodes = collapse_bvh(binary)
    assert (nodes["count"] >= 0).sum(axis=1).mean() > 6.0
    assert len(nodes) < 0.5 * len(reference_greedy_collapse(binary))


@pytest.mark.parametrize(
    "sizes, groups",
    [
        ([3, 5, -1, 2, 0, 6, 1, -1], [1, 1, -1, 0, -1, 0, 2, -1]),
        ([8, 8, 1, 1, 1, 1, 1, 1], [0, 1, 2, 2, 2, 2, 2, 2]),
        ([12, 4, 4, 0, -1, -1, -1, -1], [0, 1, 1, -1, -1, -1, -1, -1]),
        ([-1] * 8, [-1] * 8),
    ],
)
def test_leaf_groups_pack_first_fit_largest_first(sizes, groups):
    """Lanes by size (ties in lane order), each in the first group it fits in (at most
    BVH_BLOCK_WIDTH primitives; a larger leaf alone)."""
    count = np.array([sizes], np.int32)
    np.testing.assert_array_equal(_leaf_groups(count), [groups])


def test_leaf_groups_match_a_one_node_reference():
    rng = np.random.default_rng(8)
    # (leaves up to 12 primitives: the collapse makes none over 8, but a larger one goes alone)
    count = rng.integers(-1, 13, (500, BVH_WIDTH)).astype(np.int32)
    groups = _leaf_groups(count)
    for row, expected_row in zip(count, groups, strict=True):
        fill, expected = [], [-1] * BVH_WIDTH
        for lane in sorted(range(BVH_WIDTH), key=lambda j: (-max(row[j], 0), j)):
            if row[lane] <= 0:
                continue
            fits = [g for g, f in enumerate(fill) if f + row[lane] <= BVH_BLOCK_WIDTH]
            group = fits[0] if fits else len(fill)
            if group == len(fill):
                fill.append(0)
            fill[group] += row[lane]
            expected[lane] = group
        assert expected_row.tolist() == expected


def test_brute_force_quad_limit_matches_the_kernel():
    header = (KERNELS / "scene_types.h").read_text()
    match = re.search(r"#define BVH_MAX_BRUTE_QUADS (\d+)", header)
    assert match and int(match.group(1)) == BVH_MAX_BRUTE_QUADS


@pytest.mark.parametrize("quads", [BVH_MAX_BRUTE_QUADS - 1, BVH_MAX_BRUTE_QUADS + 10])
def test_quads_beside_or_inside_the_bvh_trace_like_brute_force(runtime, tmp_path, quads):
    """Up to BVH_MAX_BRUTE_QUADS quads stay out of the tree (tested by brute force beside it),
    more go in: either way closest hits (ids and distances) and shadow rays equal brute force's."""
    rng = np.random.default_rng(quads)
    # (the light quad is one of the quads)
    text = lit_room(16) + random_shapes_text(rng, quads - 1, 20, 1500, 0.2, (0.03, 0.3), 0.1)
    path = tmp_path / "scene.toml"
    path.write_text(text)
    scene = load_scene(path)
    assert len(scene.quads) == quads
    nodes, words = pack_bvh(scene.quads, scene.spheres, scene.triangles, -1)
    quad_blocks = nodes["count"][nodes["count"] > 0] >> 16 & 0xFF
    assert (quad_blocks.sum() > 0) == (quads > BVH_MAX_BRUTE_QUADS)
    prim_brute = assert_bvh_equals_brute_force(runtime, scene, rng)
    on_quads = (prim_brute >= 0) & (prim_brute < quads)
    assert on_quads.mean() > 0.05 and (prim_brute >= quads).mean() > 0.2
