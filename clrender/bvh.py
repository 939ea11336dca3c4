"""Bounding volume hierarchy over a scene's primitives, built on the host for the device.

    nodes, prims = build_bvh(lower, upper)   # primitive bounds, (N, 3) each

Built bottom up by agglomerative clustering in the manner of PLOC (Meister and Bittner 2018,
"Parallel locally-ordered clustering for bounding volume hierarchy construction"): the
primitives are sorted once by the Morton codes of their centroids; then, round after round, each
open cluster finds its nearest among the PLOC_RADIUS clusters before and after it in that order
(nearest: the smallest surface area of the union of the two boxes), mutually nearest clusters
merge into one (in the place of the first), until one cluster is left. The merges are the
binary tree; a bottom-up pass with the surface-area heuristic (SAH) makes a subtree of at most
LEAF_MAX primitives a leaf where that is cheaper; a top-down pass lays the tree out breadth
first, a level at a time. Written in NumPy: each merge round (and each round of the bottom-up
pass, each level of the top-down one) is a handful of whole-array operations, so the Python
loops run per round (about 150 for 1 M triangles) or level, never per primitive or node;
clusters are numbered in Morton order so that each round's gathers stay local. 1 M triangles
build in about 0.4 s of CPU (0.6 s the whole way to the device's 8-wide nodes and leaf records;
the former top-down binned-SAH build took 4-5 s), into trees of an SAH cost 17 % lower that
trace 9-20 % faster (bench/bvh_scaling.py; README).

The result is deterministic (the same bounds give the same tree) and is flattened in the layout
of kernels/scene_types.h's BVHNode, breadth first: an interior node's children are adjacent, a
leaf's primitive ids are a range of `prims`. Depth is capped at BVH_MAX_DEPTH (the device's
traversal stack): a subtree that would reach deeper (a chain of merges, as large boxes among
small ones make) is rebuilt over its primitives as a balanced tree in Morton order, so leaves
keep at most LEAF_MAX primitives (below LEAF_MAX x 2^BVH_MAX_DEPTH primitives).
"""

from __future__ import annotations

import numpy as np

# The binary tree as built (host only): a leaf (count > 0) holds prims[offset .. offset +
# count - 1], an interior node (count = -1 - split axis) has its children at offset, offset + 1.
BINARY_NODE_DTYPE = np.dtype(
    [("lower", "<f4", 3), ("offset", "<i4"), ("upper", "<f4", 3), ("count", "<i4")]
)
BVH_WIDTH = 8  # children per node of the device's tree: fixed in kernels/scene_types.h
# The device's 8-wide nodes (kernels/scene_types.h BVHNode): children's boxes as structure of
# arrays; child lane j is a node (count 0: child = its index), a leaf (count > 0: prims[child ..
# child + count - 1]) or empty (count -1).
BVH_NODE_DTYPE = np.dtype(
    [
        ("lower", "<f4", (3, BVH_WIDTH)),
        ("upper", "<f4", (3, BVH_WIDTH)),
        ("child", "<i4", BVH_WIDTH),
        ("count", "<i4", BVH_WIDTH),
    ]
)
# Depth cap of the binary tree (fixed in kernels/scene_types.h): the device's traversal keeps at
# most BVH_WIDTH - 1 nodes on its stack per level, so BVH_STACK_SIZE = 7 x BVH_MAX_DEPTH.
BVH_MAX_DEPTH = 40
MORTON_BITS = 10  # per axis: Morton codes of 30 bits
# Clusters each one looks among for its nearest, before and after it in Morton order (PLOC's r:
# 2 builds trees 1 % dearer by the SAH on bench/bvh_scaling.py's sphere, 1 the 10 % dearer; 3
# builds 5 % faster, trees 0.8 % cheaper at 1 M triangles but 0.2 % dearer at 10 000, rays/s
# within the noise; with the optimal collapse, trees 0.2 % dearer at 100 000 and 1 M, wide ones
# 0.2-0.4 %, the whole build within the noise: kept at 4)
PLOC_RADIUS = 4
LEAF_MAX = 8
# Cost of visiting a node relative to one primitive test (pbrt-v4 takes 1/2; 1 and leaves of
# up to 8 trace 5-10 % faster here: bench/bvh_scaling.py).
TRAVERSAL_COST = 1.0
# Device costs of the 8-wide tree (collapse_bvh's surface-area heuristic), relative to one
# node's test of its BVH_WIDTH child boxes: a leaf's triangles are tested BVH_BLOCK_WIDTH at a
# time, each block costing about WIDE_BLOCK_COST node tests.
BVH_BLOCK_WIDTH = 8  # triangles a leaf's block holds: fixed in kernels/scene_types.h
WIDE_NODE_COST = 1.0
WIDE_BLOCK_COST = 2.0
WIDE_LEAF_MAX = 8  # primitives of a leaf of the 8-wide tree
# Primitive bounds are widened by this fraction of their largest coordinate magnitude: far above
# the rounding of the slab test and of the primitive tests (so a box never rejects a ray that
# hits one of its primitives; flat primitives get boxes of non-zero thickness).
BOUNDS_PADDING = 1e-5
RECORD_ROWS_CHUNK = 1 << 14  # binary nodes _binary_nodes writes at a time
HALF_AREA_CHUNK = 1 << 14  # boxes _half_area takes at a time (its work rows stay in the caches)


def padded_bounds(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Primitive bounds (N, 3) as float32 structure of arrays (3, N), widened by BOUNDS_PADDING
    of each primitive's magnitude: the padding is far above float32's rounding of the bounds and
    of the padding itself, so each box still holds its primitive."""
    lower = np.asarray(lower).T.astype(np.float32, order="C")
    upper = np.asarray(upper).T.astype(np.float32, order="C")
    pad = np.maximum(np.abs(lower).max(axis=0), np.abs(upper).max(axis=0))
    pad *= np.float32(BOUNDS_PADDING)
    pad += np.float32(1e-30)
    lower -= pad
    upper += pad
    return lower, upper


def _half_area(box: np.ndarray, out: np.ndarray, work: np.ndarray) -> np.ndarray:
    """Half the surface area (float64, into out) of boxes as 6 rows: lower, -upper (from minus
    their float32 extents); HALF_AREA_CHUNK boxes at a time through work (float64, 3 rows of
    at least min(boxes, HALF_AREA_CHUNK))."""
    for start in range(0, box.shape[1], HALF_AREA_CHUNK):
        stop = min(box.shape[1], start + HALF_AREA_CHUNK)
        x, y, z = work[:, : stop - start]
        for axis, extent in enumerate((x, y, z)):
            np.add(box[axis, start:stop], box[3 + axis, start:stop], out=extent, dtype=np.float32)
        area = out[start:stop]
        np.multiply(x, y, out=area)
        area += np.multiply(y, z, out=y)
        area += np.multiply(z, x, out=z)
    return out


def _spread_bits(q: np.ndarray) -> np.ndarray:
    """10-bit integers (uint32) with two zero bits put after each bit (bit i moves to 3i)."""
    q = (q | (q << np.uint32(16))) & np.uint32(0x030000FF)
    q = (q | (q << np.uint32(8))) & np.uint32(0x0300F00F)
    q = (q | (q << np.uint32(4))) & np.uint32(0x030C30C3)
    return (q | (q << np.uint32(2))) & np.uint32(0x09249249)


# Each axis' cell index (0 .. 2^MORTON_BITS - 1) spread to its bits of a Morton sort key:
# bits 32-61, x highest of each triple
MORTON_SPREAD = [
    _spread_bits(np.arange(1 << MORTON_BITS, dtype=np.uint32)).astype(np.uint64)
    << np.uint64(32 + 2 - axis)
    for axis in range(3)
]


def _morton_keys(centroid: np.ndarray) -> np.ndarray:
    """Unique uint64 sort keys of centroids (3, N): the Morton code of each centroid's cell in
    a grid of 2^MORTON_BITS cells a side over their bounds (bits 32-61, x highest of each
    triple), then the primitive id (bits 0-31: ties broken by id)."""
    low = centroid.min(axis=1)
    extent = centroid.max(axis=1) - low
    cells = 1 << MORTON_BITS
    with np.errstate(divide="ignore"):
        scale = np.where(extent > 0.0, cells / extent, 0.0).astype(np.float32)
    keys = np.arange(centroid.shape[1], dtype=np.uint64)
    for axis in range(3):
        cell = np.subtract(centroid[axis], low[axis])
        cell *= scale[axis]
        cell = cell.astype(np.uint32)
        np.minimum(cell, np.uint32(cells - 1), out=cell)
        keys |= np.take(MORTON_SPREAD[axis], cell)
    return keys


# Low bits of an area's float32 bits that _nearest_clusters replaces by the candidate's step
# and side (ties: areas equal to 2^-20 break by distance then side)
KEY_BITS = 4
# The key's low bits hold the step (1 .. PLOC_RADIUS) above one side bit
assert PLOC_RADIUS < 2 ** (KEY_BITS - 1), "PLOC_RADIUS does not fit the merge keys' KEY_BITS"
NEAREST_ROWS = 11  # rows of _nearest_clusters' scratch
# Clusters of each of _nearest_clusters' passes: its 11 rows of scratch (3 MB) stay in the
# caches (twice as fast as whole rows at 1 M clusters)
NEAREST_CHUNK = 1 << 16
# A merge key's last KEY_BITS bits (step, then side: 1 if not the preferred one of an even
# index) to the step from an even index to its nearest
NEAREST_OFFSET = np.array(
    [(code >> 1) * (1 - 2 * (code & 1)) for code in range(1 << KEY_BITS)], np.int32
)
INT32_MAX = np.iinfo(np.int32).max


def _nearest_clusters(
    boxes: np.ndarray,
    index: np.ndarray,
    scratch: np.ndarray,
    result: np.ndarray,
    radius: int = PLOC_RADIUS,
    chunk: int = NEAREST_CHUNK,
) -> tuple:
    """For clusters in Morton order with boxes (6 rows: lower, -upper, float32, in units where
    areas do not overflow), the index of each one's nearest among the `radius` clusters
    before and after it, the one whose union with it has the least surface area, and that
    area (its last KEY_BITS bits zero). Ties (areas equal but for those bits) go to the closer
    in the order, then (same distance) an even index looks forwards and an odd one backwards,
    so equal boxes pair up (2k, 2k + 1). Found `chunk` clusters at a time (with `radius` more
    on either side) so that the scratch stays in the caches: scratch, float32 of at least
    (NEAREST_ROWS, min(clusters, chunk) + 2 radius); result, int32 of at least (2,
    clusters), receives the two results (returned as int32 and float32 views); index: int32
    0, 1, 2, ... (at least as many)."""
    n = boxes.shape[1]
    nearest, area = result[0, :n], result[1, :n]
    for first in range(0, n, chunk):
        end = min(n, first + chunk)
        low, high = max(0, first - radius), min(n, end + radius)
        window = _nearest_in_window(boxes[:, low:high], scratch, index[low:high], radius)
        nearest[first:end] = window[0][first - low : end - low]
        area[first:end] = window[1][first - low : end - low]
    return nearest, area.view(np.float32)


def _nearest_in_window(boxes: np.ndarray, work: np.ndarray, index: np.ndarray, radius) -> tuple:
    """_nearest_clusters over one window of clusters (index: theirs), all at once: the results
    (int32 nearest, area bits) are rows of the scratch `work`."""
    n = boxes.shape[1]
    index = index[:n]
    union, area, product = work[:6], work[6], work[3]
    best, nearest, sign, parity = (work[row, :n].view(np.int32) for row in range(7, 11))
    np.bitwise_and(index, 1, out=parity)
    # One int32 key per candidate, least for the nearest: the area's float32 bits (ordered as
    # integers, areas being >= 0) with the last KEY_BITS bits: the distance, then 0 on the
    # preferred side
    best.fill(INT32_MAX)
    low_bits = (1 << KEY_BITS) - 1
    for step in range(1, min(radius, n - 1) + 1):
        count = n - step
        # Union of cluster i and cluster i + step, and minus its extent
        np.minimum(boxes[:, :count], boxes[:, step:], out=union[:, :count])
        extent = np.add(union[:3, :count], union[3:, :count], out=union[:3, :count])
        np.multiply(extent[0], extent[1], out=area[:count])
        area[:count] += np.multiply(extent[1], extent[2], out=product[:count])
        area[:count] += np.multiply(extent[2], extent[0], out=product[:count])
        key = area[:count].view(np.int32)
        key |= low_bits
        key -= low_bits - (step << 1)
        key |= parity[:count]  # i looks forwards: preferred if even
        np.minimum(best[:count], key, out=best[:count])
        if step % 2 == 0:
            key ^= 1  # i + step looks backwards: preferred if odd
        np.minimum(best[step:], key, out=best[step:])
    # nearest: i + step, or i - step where the key's side is not i's preferred one (a table of
    # the key's last bits, side bit relative to i's parity)
    np.bitwise_and(best, low_bits, out=sign)
    sign ^= parity
    NEAREST_OFFSET.take(sign, out=nearest, mode="clip")
    nearest += index
    return nearest, np.bitwise_and(best, ~low_bits, out=sign)


def _balanced_height(size: np.ndarray) -> np.ndarray:
    """Height of a balanced tree (halves each split) with leaves of at most LEAF_MAX."""
    return np.ceil(np.log2(np.maximum(size / LEAF_MAX, 1.0))).astype(np.int32)


def sah_cost(nodes: np.ndarray) -> float:
    """A binary tree's (BINARY_NODE_DTYPE) surface-area-heuristic cost: interior nodes' areas x
    TRAVERSAL_COST plus leaves' areas x their primitives, over the root's area."""
    if len(nodes) == 0:
        return 0.0
    size = (nodes["upper"] - nodes["lower"]).astype(np.float64)
    area = size[:, 0] * size[:, 1] + size[:, 1] * size[:, 2] + size[:, 2] * size[:, 0]
    weight = np.where(nodes["count"] > 0, nodes["count"], TRAVERSAL_COST)
    return float((area * weight).sum() / area[0])


def build_wide_bvh(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The device's BVH over N primitives with bounds lower[i], upper[i]: (BVH_NODE_DTYPE nodes,
    uint32 primitive ids): build_bvh's binary tree collapsed to BVH_WIDTH children a node by
    the SAH-optimal collapse_bvh."""
    binary, prims = build_bvh(lower, upper)
    return collapse_bvh(binary), prims


def _binary_levels(count: np.ndarray) -> list[tuple[int, int]]:
    """The levels of a binary tree in build_bvh's layout (count: its nodes' counts) as ranges
    (start, end) of node indices from the root's: the split nodes' children, in order, are the
    next level."""
    levels = [(0, min(len(count), 1))]
    while levels[-1][0] < levels[-1][1]:
        start, end = levels[-1]
        levels.append((end, end + 2 * int(np.count_nonzero(count[start:end] < 0))))
    return levels[:-1]


def _node_half_areas(record: np.ndarray, start: int, end: int, work: np.ndarray) -> np.ndarray:
    """Half the surface areas (float64) of binary nodes start .. end - 1 (record: the nodes as
    rows of 8 float32 words), computed in work (float64, 4 rows of at least end - start)."""
    x, y, z, area = work[:, : end - start]
    for axis, extent in enumerate((x, y, z)):
        np.subtract(
            record[start:end, 4 + axis], record[start:end, axis], out=extent, dtype=np.float64
        )
    np.multiply(x, y, out=area)
    area += np.multiply(y, z, out=y)
    area += np.multiply(z, x, out=z)
    return area


def _collapse_costs(binary: np.ndarray) -> tuple:
    """The dynamic programme of an SAH-optimal collapse (Ylitie, Karras and Laine 2017, 3.1) of
    a binary tree in build_bvh's layout, bottom up a level at a time. The least cost of subtree
    n as at most i children of a wide node (area x cost per visit, over all its wide nodes and
    leaves) is row i - 1 of its level's costs (BVH_WIDTH rows; the level's left children's
    columns, then its right children's, so that the level above reads both as slices).
    Returns (as_leaf, split, split_column, first, size): as_leaf[n], n is cheapest as one leaf
    (else as one wide node); split[i - 1, split_column[n]], the k of the best distribution of
    n's subtree into i children, k from its left child's and i - k from its right one's,
    negated where n as one child is cheaper (0 for a binary leaf: split nodes have a column
    each, in order, the leaves share a last one); each subtree's first primitive and size.
    Budgets are rows: every operation is on whole rows."""
    total = len(binary)
    count = np.ascontiguousarray(binary["count"])
    offset = np.ascontiguousarray(binary["offset"])
    record = binary.view(np.float32).reshape(total, 8)
    is_inner = count < 0
    size = np.where(is_inner, 0, count)
    first = np.where(is_inner, 0, offset)
    as_leaf = ~is_inner
    # The k-th split node's children are nodes 2k + 1, 2k + 2: its column of split is k
    parents_total = int(np.count_nonzero(is_inner))
    split_column = offset - 1
    split_column >>= 1
    split_column[~is_inner] = parents_total
    split = np.zeros((BVH_WIDTH, parents_total + 1), np.int8)
    levels = _binary_levels(count)
    widest = max(end - start for start, end in levels)
    area_work = np.empty((4, widest))
    root_area = max(float(_node_half_areas(record, 0, 1, area_work)[0]), 1e-300)
    # Work rows reused by every level: each budget's best distribution, an option, whether it
    # is better and its k where it is (0 elsewhere); the costs of the level below and of this one
    distribute = np.empty((BVH_WIDTH, widest), np.float32)
    option = np.empty(widest, np.float32)
    better = np.empty((BVH_WIDTH, widest), bool)
    better_k = np.empty((BVH_WIDTH, widest), np.int8)
    below, level_cost = np.empty((2, BVH_WIDTH, widest), np.float32)
    parents_after = parents_total
    for start, end in reversed(levels):
        nodes = end - start
        inner = np.flatnonzero(is_inner[start:end])
        parents = len(inner)
        parents_after -= parents
        # The split nodes' sizes and first primitives: their children's (the level below)
        level_size, level_first = size[start:end], first[start:end]
        children = slice(end, end + 2 * parents, 2)
        level_size[inner] = size[children]
        level_size[inner] += size[end + 1 : end + 2 * parents : 2]
        level_first[inner] = first[children]
        # The nodes' areas over the root's (float32 costs: half the traffic)
        area = _node_half_areas(record, start, end, area_work)
        area /= root_area
        area = area.astype(np.float32)
        # Each node as one leaf (at most WIDE_LEAF_MAX primitives unless a binary leaf); this
        # level's costs start as those (left children's columns first; a lone root: its own)
        blocks = -(-level_size // BVH_BLOCK_WIDTH)
        leaf = np.float32(WIDE_BLOCK_COST) * blocks.astype(np.float32)
        leaf *= area
        leaf[inner[level_size[inner] > WIDE_LEAF_MAX]] = np.inf
        half = (nodes + 1) // 2
        costs = level_cost[:, :nodes]
        costs[:, :half] = leaf[0::2]
        costs[:, half:] = leaf[1::2]
        if parents == 0:
            below, level_cost = level_cost, below
            continue
        left, right = below[:, :parents], below[:, parents : 2 * parents]
        spread, scratch = distribute[:, :parents], option[:parents]
        less, gain = better[:, :parents], better_k[:, :parents]
        # Each budget i's best split: k from the left, i - k from the right (the first least:
        # the largest k that beats every smaller one), its k written straight into split
        best_k = split[:, parents_after : parents_after + parents]
        best_k.fill(1)
        spread[0] = np.inf
        for i in range(2, BVH_WIDTH + 1):
            best = spread[i - 1]
            np.add(left[0], right[i - 2], out=best)
            for k in range(2, i):
                np.add(left[k - 1], right[i - k - 1], out=scratch)
                np.less(scratch, best, out=less[0])
                np.multiply(less[0], np.int8(k), out=gain[0])
                np.maximum(best_k[i - 1], gain[0], out=best_k[i - 1])
                np.minimum(best, scratch, out=best)
        # Each split node as one child: a leaf or a wide node, the cheaper; each budget's cost:
        # that or its best distribution, the cheaper (split negated where it is one child)
        node = np.float32(WIDE_NODE_COST) * area[inner]
        node += spread[-1]
        inner_leaf = leaf[inner]
        is_leaf = inner_leaf <= node
        as_leaf[start:end][inner] = is_leaf
        one = np.where(is_leaf, inner_leaf, node)
        np.greater_equal(spread, one, out=less)
        np.multiply(less, best_k, out=gain)
        best_k -= gain
        best_k -= gain
        np.minimum(spread, one, out=spread)
        column = (inner & 1) * half + (inner >> 1)
        for row in range(BVH_WIDTH):
            costs[row][column] = spread[row]
        below, level_cost = level_cost, below
    return as_leaf, split, split_column, first, size


def wide_sah_cost(nodes: np.ndarray) -> float:
    """A wide tree's (BVH_NODE_DTYPE, leaves as prims ranges: collapse_bvh's output) cost by the
    collapse's SAH: each node's visit (WIDE_NODE_COST, the root's at its lanes' union) and each
    leaf's triangle blocks (WIDE_BLOCK_COST each) weighted by their boxes' areas, over the root's
    area."""
    if len(nodes) == 0:
        return 0.0
    count = nodes["count"]
    used = count >= 0
    extent = nodes["upper"].astype(np.float64) - nodes["lower"]  # (nodes, 3, lanes)
    area = extent[:, 0] * extent[:, 1] + extent[:, 1] * extent[:, 2] + extent[:, 2] * extent[:, 0]
    blocks = -(-np.maximum(count, 0) // BVH_BLOCK_WIDTH)
    weight = np.where(count == 0, WIDE_NODE_COST, WIDE_BLOCK_COST * blocks) * used
    root = np.where(used[0], nodes["lower"][0], np.inf).min(axis=1).astype(np.float64)
    x, y, z = np.where(used[0], nodes["upper"][0], -np.inf).max(axis=1) - root
    root_area = x * y + y * z + z * x
    return float(WIDE_NODE_COST + (area * weight).sum() / root_area)


def collapse_bvh(binary: np.ndarray) -> np.ndarray:
    """BVH_NODE_DTYPE nodes of a binary tree (BINARY_NODE_DTYPE in build_bvh's layout: breadth
    first, the k-th split node's children nodes 2k + 1, 2k + 2), collapsed by the
    SAH-optimal dynamic programme (_collapse_costs): each wide node takes the best distribution of
    its binary root's subtree into BVH_WIDTH children, leaves or wide nodes; vectorised over the
    nodes of a level."""
    if len(binary) == 0:
        return np.zeros(0, BVH_NODE_DTYPE)
    as_leaf, split, split_column, first, size = _collapse_costs(binary)
    # The binary nodes as rows of 8 words (box, then child and count: overwritten per lane)
    rows = binary.view(np.float32).reshape(-1, 8)
    offset = binary["offset"]
    empty = len(binary)
    levels = []
    # A binary root's wide node (the whole tree's root: one leaf lane if it is a leaf)
    roots = np.array([0])
    next_index = 1
    while len(roots):
        count = len(roots)
        # Each wide node's children: its root's best distribution into BVH_WIDTH, split down
        owner, node = np.arange(count), roots
        budget = np.full(count, BVH_WIDTH)
        spread = binary["count"][roots] < 0  # (the whole tree's root: a leaf only if binary)
        # (each node's split at its budget: its k, positive where it spreads)
        choice = split[BVH_WIDTH - 1, split_column[node]]
        slot_owner, slot_node = [], []
        while len(node):
            slot_owner.append(owner[~spread])
            slot_node.append(node[~spread])
            owner, node, budget = owner[spread], node[spread], budget[spread]
            k = np.abs(choice[spread].astype(np.int64))
            left = offset[node]
            owner = np.concatenate([owner, owner])
            node = np.concatenate([left, left + 1])
            budget = np.concatenate([k, budget - k])
            choice = split[budget - 1, split_column[node]]
            spread = (budget >= 2) & (choice > 0)
        slot_owner, slot_node = np.concatenate(slot_owner), np.concatenate(slot_node)
        order = np.argsort(slot_owner, kind="stable")
        slot_owner, slot_node = slot_owner[order], slot_node[order]
        per_owner = np.bincount(slot_owner, minlength=count)
        lane = np.arange(len(slot_owner)) - np.repeat(np.cumsum(per_owner) - per_owner, per_owner)
        slots = np.full((count, BVH_WIDTH), empty)
        slots[slot_owner, lane] = slot_node
        # Each lane's node (child and count -1), leaf (its first primitive and size) or empty
        # lane (box 0, -1, -1); then child and count 0 for a node
        is_empty = slots == empty
        slots[is_empty] = 0
        lanes = np.take(rows, slots, axis=0)  # (count, BVH_WIDTH, 8)
        lane_words = lanes.view(np.int32)
        lane_leaf = as_leaf[slots]
        lane_words[:, :, 3] = np.where(lane_leaf, first[slots], -1)
        lane_words[:, :, 7] = np.where(lane_leaf, size[slots], -1)
        lanes[is_empty] = 0.0
        lane_words[is_empty, 3] = lane_words[is_empty, 7] = -1
        is_node = lane_words[:, :, 7] < 0
        is_node &= ~is_empty
        wide = np.empty((count, 8, BVH_WIDTH), np.float32)
        wide[:, 0:3] = lanes[:, :, 0:3].transpose(0, 2, 1)
        wide[:, 3:6] = lanes[:, :, 4:7].transpose(0, 2, 1)
        wide_words = wide.view(np.int32)
        child = lane_words[:, :, 3]
        child[is_node] = next_index + np.arange(np.count_nonzero(is_node))
        wide_words[:, 6] = child
        wide_words[:, 7] = np.where(is_node, 0, lane_words[:, :, 7])
        levels.append(wide.reshape(count, -1))
        roots = slots[is_node]
        next_index += len(roots)
    return _depth_first(levels)


def _depth_first(levels: list[np.ndarray]) -> np.ndarray:
    """Wide nodes (breadth first: levels, each (nodes, words) of BVH_NODE_DTYPE's float32 words)
    put in depth-first order, each node's children after it in lane order: a subtree's nodes
    (and so its leaf records, which pack_bvh_leaves writes in node order) lie together in
    memory, which a ray descending it reads from fewer cache lines. Vectorised over a level."""
    lane_fields = [
        slice(offset // 4, offset // 4 + BVH_WIDTH)
        for offset in (BVH_NODE_DTYPE.fields[name][1] for name in ("child", "count"))
    ]
    child, count = (
        np.concatenate([level.view(np.int32)[:, lanes] for level in levels])
        for lanes in lane_fields
    )
    is_node = count == 0
    child[~is_node] = 0
    ends = np.cumsum([len(level) for level in levels])
    rows_of = [slice(end - len(level), end) for end, level in zip(ends, levels, strict=True)]
    # Bottom up: each subtree's nodes; top down: each node's place, after its parent and its
    # earlier siblings' subtrees
    size = np.ones(len(child), np.int64)
    for rows in reversed(rows_of):
        size[rows] += (size[child[rows]] * is_node[rows]).sum(axis=1)
    place = np.zeros(len(child), np.int64)
    for rows in rows_of:
        lane_size = size[child[rows]] * is_node[rows]
        before = np.cumsum(lane_size, axis=1) - lane_size
        inner = is_node[rows]
        place[child[rows][inner]] = (place[rows][:, None] + 1 + before)[inner]
    # Each level's nodes to their places (as rows of words: a fast copy), node children
    # renumbered
    ordered = np.empty(len(child), BVH_NODE_DTYPE)
    ordered_words = ordered.view(np.int32).reshape(len(child), -1)
    for rows, level in zip(rows_of, levels, strict=True):
        ordered_words[place[rows]] = level.view(np.int32)
    moved = ordered["count"] == 0
    ordered["child"][moved] = place[ordered["child"][moved]]
    return ordered


def build_bvh(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Binary BVH over N primitives with bounds lower[i], upper[i]: (nodes, prims), nodes a
    BINARY_NODE_DTYPE array (the root first, breadth first), prims the uint32 primitive ids the
    leaves point into. Bounds are padded (padded_bounds) in float32."""
    count = len(lower)
    if count == 0:
        return np.zeros(0, BINARY_NODE_DTYPE), np.zeros(0, np.uint32)
    lower32, upper32 = padded_bounds(lower, upper)
    # The primitives in the Morton order of their centroids (their ranks: cluster ids 0 .. N -
    # 1, so that merges gather nearby boxes), then every merge of two (ids N .. 2N - 2), with
    # boxes as 6 rows (lower, -upper): a union is a minimum
    primitive = (np.sort(_morton_keys(0.5 * (lower32 + upper32))) & np.uint64(0xFFFFFFFF)).astype(
        np.int32
    )
    total = 2 * count - 1
    cluster_box = np.empty((6, total), np.float32)
    lower32.take(primitive, axis=1, out=cluster_box[:3, :count])
    upper32.take(primitive, axis=1, out=cluster_box[3:, :count])
    np.negative(cluster_box[3:, :count], out=cluster_box[3:, :count])
    del lower32, upper32
    # The merge rounds' boxes in units of the scene's extent (so that float32 areas neither
    # overflow nor underflow: exact minima of the primitives' scaled boxes)
    low = cluster_box[:, :count].min(axis=1)
    scene_extent = float((-low[3:] - low[:3]).max())
    boxes = np.multiply(cluster_box[:, :count], np.float32(1.0 / max(scene_extent, 1e-30)))
    children, rounds, root = _merge_rounds(boxes, np.arange(count, dtype=np.int32))
    del boxes
    size, height, leaf = _bottom_up(cluster_box, children, rounds)
    # Each primitive's position in the leaves' order (a cluster's primitives follow each other,
    # its left child's first), and the tree's nodes breadth first
    ranks = _leaf_order(children, rounds, root, size)
    cluster, first, length, split = _tree_levels(children, root, size, height, leaf)
    # The nodes' boxes: the clusters', and for a balanced tree's node the union of its range
    # (a rebuilt subtree's primitives sorted by rank, their Morton order)
    box = cluster_box.take(cluster, axis=1)
    ranged = np.flatnonzero(cluster < 0)
    if len(ranged):
        # The rebuilt subtrees' ranges (disjoint), in order, and their primitives' boxes one
        # after another (and a spare column at the end)
        roots = ranged[(cluster[ranged] == REBUILT_ROOT)]
        roots = roots[np.argsort(first[roots], kind="stable")]
        root_first, root_end = first[roots], first[roots] + length[roots]
        ranges = [slice(start, end) for start, end in zip(root_first, root_end, strict=True)]
        for primitives in ranges:
            ranks[primitives].sort()
        rebuilt = np.concatenate([ranks[primitives] for primitives in ranges])
        position_box = np.empty((6, len(rebuilt) + 1), np.float32)
        cluster_box.take(rebuilt, axis=1, out=position_box[:, :-1])
        # Each balanced node's range among those
        root_of = np.searchsorted(root_first, first[ranged], side="right") - 1
        start = (
            first[ranged]
            - root_first[root_of]
            + (np.cumsum(length[roots]) - length[roots])[root_of]
        )
        bounds = np.stack([start, start + length[ranged]], axis=1).reshape(-1)
        box[:, ranged] = np.minimum.reduceat(position_box, bounds, axis=1)[:, ::2]
    prims = primitive.take(ranks).view(np.uint32)
    return _binary_nodes(box, first, length, split), prims


def _merge_rounds(boxes: np.ndarray, active: np.ndarray) -> tuple:
    """PLOC's merge rounds over the clusters `active` (ids, in Morton order; boxes: 6 rows,
    lower then -upper, float32, in units where areas neither overflow nor underflow): mutually
    nearest clusters merge (the merge takes the first one's place and the next cluster id,
    N, N + 1, ...) until one is left. Returns (children, rounds, root): children (2, N - 1),
    each merge's left and right; rounds, (first, end) cluster ids of each round's merges; the
    last cluster. Overwrites boxes and active."""
    count = len(active)
    children = np.empty((2, max(count - 1, 0)), np.int32)
    scratch = np.empty((NEAREST_ROWS, min(count, NEAREST_CHUNK) + 2 * PLOC_RADIUS), np.float32)
    result = np.empty((2, count), np.int32)
    numbers = np.arange(count, dtype=np.int32)
    # Each cluster's partner (itself if it does not merge)
    partner_of = np.empty(count, np.int32)
    kept = np.empty(count, bool)
    rounds = []
    first = count  # the next merge's cluster id
    n = count
    while n > 1:
        index = numbers[:n]
        nearest, area = _nearest_clusters(boxes[:, :n], index, scratch, result)
        lead = np.flatnonzero((nearest.take(nearest) == index) & (nearest > index))
        if len(lead) == 0:  # no mutual pair (ties): the closest pair merges
            closest = int(np.argmin(area))
            lead = np.array([min(closest, nearest[closest])])
            nearest[lead] = max(closest, nearest[closest])
        partner = nearest.take(lead)
        end = first + len(lead)
        active.take(lead, out=children[0, first - count : end - count])
        active.take(partner, out=children[1, first - count : end - count])
        active[lead] = numbers[first - count : end - count] + count
        # The clusters left, in order (a merge in the place of its first): their boxes, the
        # union of their own and their partner's, stored in place a chunk at a time (a kept
        # cluster and its partner sit at or after its new place: no chunk reads what the
        # chunks before it wrote)
        keep = kept[:n]
        keep.fill(True)
        keep[partner] = False
        left = np.flatnonzero(keep)
        m = len(left)
        pairs = partner_of[:n]
        pairs[:] = index
        pairs[lead] = partner
        other = pairs.take(left)
        for start in range(0, m, NEAREST_CHUNK):
            stop = min(m, start + NEAREST_CHUNK)
            these, partners = left[start:stop], other[start:stop]
            united = boxes.take(these, axis=1)
            np.minimum(united, boxes.take(partners, axis=1), out=boxes[:, start:stop])
        active = active.take(left)
        rounds.append((first, end))
        first, n = end, m
    return children, rounds, int(active[0])


def _bottom_up(cluster_box: np.ndarray, children: np.ndarray, rounds: list) -> tuple:
    """Bottom up, a round at a time: the merged clusters' boxes (into cluster_box) and sizes;
    leaves where the SAH finds them cheaper than their subtree, and the subtrees' heights
    (leaves 0). Returns (size, height, leaf) of every cluster."""
    total = cluster_box.shape[1]
    count = total - children.shape[1]
    size = np.empty(total, np.int32)
    size[:count] = 1
    height = np.zeros(total, np.int32)
    leaf = np.ones(total, bool)
    cost = np.empty(total, np.float64)
    work = np.empty((3, min(count, HALF_AREA_CHUNK)))
    merged_area = np.empty(max((end - first for first, end in rounds), default=0))
    _half_area(cluster_box[:, :count], cost[:count], work)  # a leaf of one
    for first, end in rounds:
        below_left, below_right = children[:, first - count : end - count]
        box = cluster_box[:, first:end]
        np.minimum(
            cluster_box.take(below_left, axis=1),
            cluster_box.take(below_right, axis=1),
            out=box,
        )
        merged_size = size[first:end]
        np.add(size.take(below_left), size.take(below_right), out=merged_size)
        area = _half_area(box, merged_area[: end - first], work)
        subtree = TRAVERSAL_COST * area
        subtree += cost.take(below_left)
        subtree += cost.take(below_right)
        as_leaf = np.where(merged_size <= LEAF_MAX, merged_size * area, np.inf)
        is_leaf = leaf[first:end] = as_leaf <= subtree
        np.minimum(as_leaf, subtree, out=cost[first:end])
        higher = np.maximum(height.take(below_left), height.take(below_right)) + 1
        higher[is_leaf] = 0
        height[first:end] = higher
    return size, height, leaf


def _leaf_order(children: np.ndarray, rounds: list, root: int, size: np.ndarray) -> np.ndarray:
    """Top down, a round at a time: each cluster's first position in the leaves' order (its
    left child's first, its right child's after the left's primitives). Returns the
    primitives (cluster ids 0 .. N - 1) in that order."""
    count = len(size) - children.shape[1]
    start = np.empty(len(size), np.int32)
    start[root] = 0
    for first, end in reversed(rounds):
        below_left, below_right = children[:, first - count : end - count]
        merged_start = start[first:end]
        start[below_left] = merged_start
        start[below_right] = merged_start + size.take(below_left)
    ranks = np.empty(count, np.int32)
    ranks[start[:count]] = np.arange(count, dtype=np.int32)
    return ranks


# A node of a balanced tree (_tree_levels' cluster): the root of one, other nodes of one
REBUILT_ROOT, BALANCED_NODE = -1, -2


def _tree_levels(children, root, size, height, leaf) -> tuple:
    """Top down, a level at a time: the tree's nodes breadth first, (cluster, first, length,
    split) each (cluster REBUILT_ROOT or BALANCED_NODE for a balanced tree's; first, length:
    its range of the leaves' order), a level's nodes in order of position, the children of a
    split node next to each other; so the k-th split node's children are nodes 2k + 1, 2k + 2.
    A cluster whose subtree exceeds the depth cap and one of whose children could not be
    fitted either (too deep itself and too large to rebuild) is rebuilt as a balanced tree
    over its primitives, halved until at most LEAF_MAX (or at the cap)."""
    count = len(size) - children.shape[1]
    cluster = np.array([root], np.int32)
    first = np.zeros(1, np.int32)
    length = size[cluster]
    # A node's height is at most its root's less its depth: no subtree can reach below the cap
    # (nor be rebuilt) unless the whole tree does
    capped = height[root] > BVH_MAX_DEPTH
    levels = []
    for depth in range(BVH_MAX_DEPTH + 1):
        room = BVH_MAX_DEPTH - depth
        if capped:
            ranged = cluster < 0
            merged = np.maximum(cluster, 0)  # clusters (primitives are leaves: never split)
            deep = np.flatnonzero((height.take(merged) > room) & ~ranged)
            if len(deep):
                below = children.take(cluster[deep] - count, axis=1)
                fits = np.minimum(height[below], _balanced_height(size[below])) < room
                rebuilt = deep[~fits.all(axis=0)]
                cluster[rebuilt] = REBUILT_ROOT
                ranged[rebuilt] = True
            is_leaf = leaf.take(merged)
            is_leaf[ranged] = length[ranged] <= LEAF_MAX
        else:
            is_leaf = leaf.take(cluster)
        split = ~is_leaf if room > 0 else np.zeros(len(cluster), bool)
        levels.append((cluster, first, length, split))
        parents = np.flatnonzero(split)
        if len(parents) == 0:
            break
        # The next level: each split node's two children (a balanced tree's: the halves of its
        # range, the first taking the odd one), next to each other
        parent_cluster = cluster.take(parents)
        parent_first, parent_length = first.take(parents), length.take(parents)
        below = children.take(np.maximum(parent_cluster - count, 0), axis=1)
        left_length = size.take(below[0])
        if capped:
            halved = np.flatnonzero(parent_cluster < 0)
            below[:, halved] = BALANCED_NODE
            left_length[halved] = (parent_length[halved] + 1) // 2
        cluster = below.T.reshape(-1)
        first = np.stack([parent_first, parent_first + left_length], axis=1).reshape(-1)
        length = np.stack([left_length, parent_length - left_length], axis=1).reshape(-1)
    return tuple(np.concatenate(column) for column in zip(*levels, strict=True))


def _binary_nodes(box, first, length, split) -> np.ndarray:
    """BINARY_NODE_DTYPE nodes, breadth first, from their boxes (6 rows: lower, -upper; made
    lower, upper in place), ranges of `prims` (first, length; overwritten for split nodes) and
    whether they are split (the k-th split node's children being nodes 2k + 1, 2k + 2)."""
    np.negative(box[3:], out=box[3:])
    # A leaf: its range; a split node: its first child, and -1 - the axis of largest extent
    # (informative)
    parents = np.flatnonzero(split)
    x, y, z = (box[3 + axis].take(parents) - box[axis].take(parents) for axis in range(3))
    axes = np.int8(0), np.int8(1), np.int8(2)
    widest = np.where(x >= y, np.where(x >= z, axes[0], axes[2]), np.where(y >= z, *axes[1:]))
    first[parents] = 2 * np.arange(1, len(parents) + 1) - 1
    length[parents] = -1 - widest
    # The records RECORD_ROWS_CHUNK at a time, a column at a time (each chunk in the caches)
    nodes = len(first)
    record = np.empty((nodes, 8), np.float32)
    words = record.view(np.int32)
    for start in range(0, nodes, RECORD_ROWS_CHUNK):
        rows = slice(start, start + RECORD_ROWS_CHUNK)
        for row, column in enumerate((0, 1, 2, 4, 5, 6)):
            record[rows, column] = box[row, rows]
        words[rows, 3] = first[rows]
        words[rows, 7] = length[rows]
    return record.view(BINARY_NODE_DTYPE).reshape(-1)
