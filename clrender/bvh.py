"""Bounding volume hierarchy over a scene's primitives, built on the host for the device.

    nodes, prims = build_bvh(lower, upper)   # primitive bounds, (N, 3) each

Built bottom up by agglomerative clustering in the manner of PLOC (Meister and Bittner 2018,
"Parallel locally-ordered clustering for bounding volume hierarchy construction"): the
primitives are sorted once by the Morton codes of their centroids; then, round after round, each
open cluster finds its nearest among the PLOC_RADIUS clusters before and after it in that order
(nearest: the smallest surface area of the union of the two boxes), mutually nearest clusters
merge into one (in the place of the first), until one cluster is left. The merges are the
binary tree; a bottom-up pass with the surface-area heuristic (SAH) makes a subtree of at most
LEAF_MAX primitives a leaf where that is cheaper. Written in NumPy: each merge round (and each
round of the bottom-up passes, each level of the output) is a handful of whole-array operations,
so the Python loops run per round (about 150 for 1 M triangles) and per level, never per
primitive or node. 1 M triangles build in about 0.9 s of CPU (4 to 5 times faster than the
former top-down binned-SAH build), into trees of an SAH cost 17 % lower that trace 9-20 % faster
(bench/bvh_scaling.py; README).

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
# 2 builds trees 1 % dearer by the SAH on bench/bvh_scaling.py's sphere, 1 the 10 % dearer)
PLOC_RADIUS = 4
LEAF_MAX = 8
# Cost of visiting a node relative to one primitive test (pbrt-v4 takes 1/2; 1 and leaves of
# up to 8 trace 5-10 % faster here: bench/bvh_scaling.py).
TRAVERSAL_COST = 1.0
# Primitive bounds are widened by this fraction of their largest coordinate magnitude: far above
# the rounding of the slab test and of the primitive tests (so a box never rejects a ray that
# hits one of its primitives; flat primitives get boxes of non-zero thickness).
BOUNDS_PADDING = 1e-5


def padded_bounds(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Primitive bounds (N, 3) as float32 structure of arrays (3, N), widened by BOUNDS_PADDING
    of each primitive's magnitude: the padding is far above float32's rounding of the bounds and
    of the padding itself, so each box still holds its primitive."""
    lower = np.asarray(lower).T.astype(np.float32, order="C")
    upper = np.asarray(upper).T.astype(np.float32, order="C")
    magnitude = np.maximum(np.abs(lower).max(axis=0), np.abs(upper).max(axis=0))
    pad = np.float32(BOUNDS_PADDING) * magnitude + np.float32(1e-30)
    return lower - pad, upper + pad


def _half_area(box: np.ndarray) -> np.ndarray:
    """Half the surface area (float64) of boxes stored as rows (lower, -upper) x 6."""
    size = (-box[3:] - box[:3]).astype(np.float64)
    return size[0] * size[1] + size[1] * size[2] + size[2] * size[0]


def _spread_bits(q: np.ndarray) -> np.ndarray:
    """10-bit integers (uint32) with two zero bits put after each bit (bit i moves to 3i)."""
    q = (q | (q << np.uint32(16))) & np.uint32(0x030000FF)
    q = (q | (q << np.uint32(8))) & np.uint32(0x0300F00F)
    q = (q | (q << np.uint32(4))) & np.uint32(0x030C30C3)
    return (q | (q << np.uint32(2))) & np.uint32(0x09249249)


def _morton_keys(centroid: np.ndarray) -> np.ndarray:
    """Unique uint64 sort keys of centroids (3, N): the Morton code of each centroid's cell in
    a grid of 2^MORTON_BITS cells a side over their bounds (bits 32-61, x highest of each
    triple), then the primitive id (bits 0-31: ties broken by id)."""
    low = centroid.min(axis=1)
    extent = centroid.max(axis=1) - low
    cells = 1 << MORTON_BITS
    with np.errstate(divide="ignore"):
        scale = np.where(extent > 0.0, cells / extent, 0.0).astype(np.float32)
    code = np.zeros(centroid.shape[1], np.uint32)
    for axis in range(3):
        cell = ((centroid[axis] - low[axis]) * scale[axis]).astype(np.uint32)
        code |= _spread_bits(np.minimum(cell, np.uint32(cells - 1))) << np.uint32(2 - axis)
    return (code.astype(np.uint64) << np.uint64(32)) | np.arange(len(code), dtype=np.uint64)


def _nearest_clusters(boxes: np.ndarray, scale: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """For clusters in Morton order with boxes (6 rows: lower, -upper), the index of each one's
    nearest among the PLOC_RADIUS clusters before and after it, the one whose union with it has
    the least surface area (areas of extents x `scale`: float32 without overflow), and that
    area. Ties go to the closer in the order, then (same distance) an even index looks forwards
    and an odd one backwards, so equal boxes pair up (2k, 2k + 1)."""
    n = boxes.shape[1]
    parity = np.arange(n, dtype=np.int64) & 1
    # One int64 key per candidate, least for the nearest: the area's float32 bits (ordered as
    # integers, areas being >= 0), then the distance, then 0 on the preferred side
    best = np.full(n, np.iinfo(np.int64).max, np.int64)
    for step in range(1, min(PLOC_RADIUS, n - 1) + 1):
        # Union of cluster i and cluster i + step
        union = np.minimum(boxes[:, :-step], boxes[:, step:])
        x, y, z = ((-union[3 + axis] - union[axis]) * scale for axis in range(3))
        area = (x * y + y * z + z * x).view(np.int32).astype(np.int64) << 8 | step << 1
        np.minimum(best[:-step], area | parity[:-step], out=best[:-step])  # i looks forwards
        np.minimum(best[step:], area | (1 - parity[step:]), out=best[step:])  # i + step back
    step = (best >> 1) & 127
    forwards = (best & 1) == parity
    nearest = np.where(forwards, np.arange(n) + step, np.arange(n) - step)
    area = (best >> 8).astype(np.int32).view(np.float32)
    return nearest, area


def _cluster_table(cluster_box, left, right, start, size, height, leaf) -> np.ndarray:
    """One record (48 bytes) per cluster, so that a level's nodes take theirs in one gather:
    box (lower, -upper), left, right, first position in `prims`, size, height, leaf (int32)."""
    table = np.empty((len(left), 12), np.int32)
    table[:, :6] = cluster_box.T.view(np.int32)
    for column, values in enumerate((left, right, start, size, height, leaf), start=6):
        table[:, column] = values
    return table.view(np.dtype((np.void, 48))).reshape(-1)


def _range_children(children, parent_span, parent_is_range, table, position_box) -> tuple:
    """The next level where some nodes are ranges: children (cluster ids, two a split parent;
    a range's are placeholders) become (nodes, span, box (nodes, 6)): a cluster's children
    their merged clusters with their boxes, a range's its two halves with theirs."""
    pairs = children.reshape(-1, 2)
    pairs[parent_is_range] = -1
    span = np.zeros((len(pairs), 2, 2), np.int64)
    low, high = parent_span[parent_is_range, 0], parent_span[parent_is_range, 1]
    middle = low + (high - low + 1) // 2
    span[parent_is_range, 0, 0], span[parent_is_range, 0, 1] = low, middle
    span[parent_is_range, 1, 0], span[parent_is_range, 1, 1] = middle, high
    box = np.take(table, np.maximum(pairs, 0)).view(np.int32).reshape(len(pairs), 2, 12)
    box = box[:, :, :6].view(np.float32).copy()
    if parent_is_range.any():
        left_box, right_box = _range_boxes(position_box, low, middle, high)
        box[parent_is_range, 0], box[parent_is_range, 1] = left_box.T, right_box.T
    return pairs.reshape(-1), span.reshape(-1, 2), box.reshape(-1, 6)


def _balanced_height(size: np.ndarray) -> np.ndarray:
    """Height of a balanced tree (halves each split) with leaves of at most LEAF_MAX."""
    return np.ceil(np.log2(np.maximum(size / LEAF_MAX, 1.0))).astype(np.int64)


def _rebuild_in_morton_order(prims, morton_order, spans, cluster_box, position_box):
    """Sorts each range spans[k] of `prims` (in place) in Morton order, and returns
    position_box (allocated on the first call: (6, N + 1)) with those positions' boxes."""
    count = len(prims)
    if position_box is None:
        position_box = np.zeros((6, count + 1), np.float32)
    rank = np.empty(count, np.int64)
    rank[morton_order] = np.arange(count)
    lengths = spans[:, 1] - spans[:, 0]
    ends = np.cumsum(lengths)
    positions = np.arange(ends[-1]) + np.repeat(spans[:, 0] - (ends - lengths), lengths)
    members = prims[positions]
    order = np.lexsort((rank[members], np.repeat(np.arange(len(spans)), lengths)))
    prims[positions] = members[order]
    position_box[:, positions] = np.take(cluster_box, members[order], axis=1)
    return position_box


def _range_boxes(position_box: np.ndarray, start, middle, end) -> tuple:
    """Boxes (6 rows) of the positions [start, middle) and [middle, end) (disjoint ranges;
    position_box has a spare last column): one reduceat over the ranges in ascending order."""
    order = np.argsort(start, kind="stable")
    bounds = np.stack([start[order], middle[order], end[order]], axis=1).reshape(-1)
    reduced = np.minimum.reduceat(position_box, bounds, axis=1).reshape(6, -1, 3)
    left = np.empty((6, len(start)), np.float32)
    right = np.empty((6, len(start)), np.float32)
    left[:, order], right[:, order] = reduced[:, :, 0], reduced[:, :, 1]
    return left, right


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
    uint32 primitive ids): build_bvh's binary tree collapsed to BVH_WIDTH children a node."""
    binary, prims = build_bvh(lower, upper)
    return collapse_bvh(binary), prims


def collapse_bvh(binary: np.ndarray) -> np.ndarray:
    """BVH_NODE_DTYPE nodes of a binary tree (BINARY_NODE_DTYPE, breadth first): each wide node
    starts as one binary node and repeatedly opens the interior child of largest surface area
    until it has BVH_WIDTH children (Wald et al. 2008); vectorised over the nodes of a level."""
    if len(binary) == 0:
        return np.zeros(0, BVH_NODE_DTYPE)
    # The binary nodes as rows of 8 words, and a last row for an empty lane (box 0, -1, -1)
    rows = np.empty((len(binary) + 1, 8), np.float32)
    rows[:-1] = binary.view(np.float32).reshape(-1, 8)
    rows[-1] = 0.0
    row_words = rows.view(np.int32)
    row_words[-1, 3] = row_words[-1, 7] = -1
    offset = row_words[:, 3]
    x, y, z = ((rows[:, 4 + axis] - rows[:, axis]).astype(np.float64) for axis in range(3))
    area = x * y + y * z + z * x
    # The area of an interior node (the one to open), -1 for a leaf or an empty lane
    opening = np.where(row_words[:, 7] < 0, area, -1.0)
    opening[-1] = -1.0
    empty = len(binary)
    levels = []
    roots = np.array([0])  # the binary node each wide node of the level starts from
    next_index = 1
    while len(roots):
        count = len(roots)
        slots = np.full((count, BVH_WIDTH), empty)
        slots[:, 0] = roots
        # Lanes 0 .. filled - 1 are full while a node grows; it stops growing for good when
        # none of them is interior (score < 0)
        score = np.full((count, BVH_WIDTH), -1.0)
        score[:, 0] = opening[roots]
        flat_slots, flat_score = slots.reshape(-1), score.reshape(-1)
        for filled in range(1, BVH_WIDTH):
            widest = np.argmax(score, axis=1)
            widest += np.arange(0, count * BVH_WIDTH, BVH_WIDTH)
            widest = widest[flat_score[widest] >= 0.0]
            if len(widest) == 0:
                break
            first_child = offset[flat_slots[widest]]
            second = widest - widest % BVH_WIDTH + filled
            flat_slots[widest], flat_slots[second] = first_child, first_child + 1
            flat_score[widest], flat_score[second] = opening[first_child], opening[first_child + 1]
        # Each lane's node, leaf or empty lane: box, child, count (0 for a node)
        lanes = np.take(rows, slots, axis=0)  # (count, BVH_WIDTH, 8)
        lane_words = lanes.view(np.int32)
        is_node = lane_words[:, :, 7] < 0
        is_node &= slots != empty
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
    return np.concatenate(levels).view(BVH_NODE_DTYPE).reshape(-1)


def build_bvh(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Binary BVH over N primitives with bounds lower[i], upper[i]: (nodes, prims), nodes a
    BINARY_NODE_DTYPE array (the root first, breadth first), prims the uint32 primitive ids the
    leaves point into. Bounds are padded (padded_bounds) in float32."""
    count = len(lower)
    if count == 0:
        return np.zeros(0, BINARY_NODE_DTYPE), np.zeros(0, np.uint32)
    lower32, upper32 = padded_bounds(lower, upper)
    # Clusters: every primitive (ids 0 .. N - 1), then every merge of two (ids N .. 2N - 2),
    # with boxes as rows (lower, -upper): a union is a minimum
    total = 2 * count - 1
    cluster_box = np.empty((6, total), np.float32)
    cluster_box[:3, :count] = lower32
    np.negative(upper32, out=cluster_box[3:, :count])
    left = np.full(total, -1, np.int64)
    right = np.full(total, -1, np.int64)
    size = np.ones(total, np.int64)
    # The clusters still open, in the Morton order of the primitives' centroids
    keys = np.sort(_morton_keys(0.5 * (lower32 + upper32)))
    morton_order = (keys & np.uint64(0xFFFFFFFF)).astype(np.int64)
    active = morton_order.copy()
    boxes = np.take(cluster_box[:, :count], active, axis=1)
    scene_extent = float((-boxes[3:].min(axis=1) - boxes[:3].min(axis=1)).max())
    scale = np.float32(1.0 / max(scene_extent, 1e-30))
    # Merge rounds: mutual nearest clusters merge (the merge takes the first one's place)
    round_first = [count]  # first cluster id of each round's merges, then the next id
    while len(active) > 1:
        nearest, area = _nearest_clusters(boxes, scale)
        index = np.arange(len(active))
        lead = np.flatnonzero((nearest[nearest] == index) & (nearest > index))
        if len(lead) == 0:  # no mutual pair (ties): the closest pair merges
            closest = int(np.argmin(area))
            lead = np.array([min(closest, nearest[closest])])
            nearest[lead] = max(closest, nearest[closest])
        partner = nearest[lead]
        merged = slice(round_first[-1], round_first[-1] + len(lead))
        left[merged], right[merged] = active[lead], active[partner]
        size[merged] = size[left[merged]] + size[right[merged]]
        np.minimum(
            np.take(boxes, lead, axis=1),
            np.take(boxes, partner, axis=1),
            out=cluster_box[:, merged],
        )
        active[lead] = np.arange(merged.start, merged.stop)
        boxes[:, lead] = cluster_box[:, merged]
        keep = np.ones(len(active), bool)
        keep[partner] = False
        active, boxes = active[keep], np.compress(keep, boxes, axis=1)
        round_first.append(round_first[-1] + len(lead))
    rounds = list(zip(round_first[:-1], round_first[1:], strict=True))
    # Leaves where the SAH finds them cheaper than their subtree, and the subtrees' heights
    # (leaves 0): bottom up, a round at a time
    area = _half_area(cluster_box)
    cost = area.copy()  # a primitive: a leaf of one
    leaf = np.ones(total, bool)
    height = np.zeros(total, np.int64)
    for first, end in rounds:
        merged = slice(first, end)
        below_left, below_right = left[merged], right[merged]
        subtree = TRAVERSAL_COST * area[merged] + cost[below_left] + cost[below_right]
        as_leaf = np.where(size[merged] <= LEAF_MAX, size[merged] * area[merged], np.inf)
        leaf[merged] = as_leaf <= subtree
        cost[merged] = np.minimum(as_leaf, subtree)
        below = np.maximum(height[below_left], height[below_right])
        height[merged] = np.where(leaf[merged], 0, 1 + below)
    # Each cluster's primitives are a range of `prims`, its left child's first (top down)
    start = np.zeros(total, np.int64)
    for first, end in reversed(rounds):
        merged = slice(first, end)
        start[left[merged]] = start[merged]
        start[right[merged]] = start[merged] + size[left[merged]]
    prims = np.empty(count, np.uint32)
    prims[start[:count]] = np.arange(count, dtype=np.uint32)
    # The nodes, breadth first: a level's split nodes' children make the next level. A node is
    # a cluster, or a range of `prims` (a subtree too deep for the cap, rebuilt as a balanced
    # tree over its primitives in Morton order: node -1, span[k] its range)
    table = _cluster_table(cluster_box, left, right, start, size, height, leaf)
    levels = []  # per depth: the nodes' records, (nodes, 8) words of BINARY_NODE_DTYPE
    nodes = active
    span = None  # (nodes, 2) once some node is a range
    box = None  # (nodes, 6) boxes, carried from the level before once some node is a range
    position_box = None  # boxes of the rebuilt primitives by position in `prims`
    next_index = 1
    for depth in range(BVH_MAX_DEPTH + 1):
        room = BVH_MAX_DEPTH - depth
        fields = np.take(table, np.maximum(nodes, 0)).view(np.int32).reshape(-1, 12)
        left_of, right_of, first_prim, size_of, height_of, leaf_of = fields[:, 6:].T
        box = fields[:, :6].view(np.float32) if span is None else box
        # Too deep: a cluster whose subtree exceeds the cap and one of whose children could
        # not be fitted either (too deep itself and too large to rebuild) becomes a range
        convert = (height_of > room) & (nodes >= 0)
        deep = np.flatnonzero(convert)
        if len(deep):
            child_fits = [
                np.minimum(height[child], _balanced_height(size[child])) < room
                for child in (left_of[deep], right_of[deep])
            ]
            convert[deep[child_fits[0] & child_fits[1]]] = False
        if convert.any():
            span = np.zeros((len(nodes), 2), np.int64) if span is None else span
            span[convert, 0], span[convert, 1] = (
                first_prim[convert],
                first_prim[convert] + size_of[convert],
            )
            position_box = _rebuild_in_morton_order(
                prims, morton_order, span[convert], cluster_box, position_box
            )
            nodes = np.where(convert, -1, nodes)
        is_range = nodes < 0
        length = size_of if span is None else np.where(is_range, span[:, 1] - span[:, 0], size_of)
        if span is not None:
            first_prim = np.where(is_range, span[:, 0], first_prim)
        split = np.where(is_range, length > LEAF_MAX, leaf_of == 0) & (depth < BVH_MAX_DEPTH)
        # The level's records: box, first child or primitive, count or -1 - split axis
        record = np.empty((len(nodes), 8), np.float32)
        record[:, 0:3] = box[:, 0:3]
        np.negative(box[:, 3:6], out=record[:, 4:7])
        widest = np.argmax(record[:, 4:7] - record[:, 0:3], axis=1)  # informative only
        words = record.view(np.int32)
        words[:, 3] = np.where(split, next_index + 2 * (np.cumsum(split) - 1), first_prim)
        words[:, 7] = np.where(split, -1 - widest, length)
        levels.append(record)
        # Children: a cluster's two merged clusters, a range's two halves
        parents = np.flatnonzero(split)
        nodes = np.stack([left_of[parents], right_of[parents]], axis=1).reshape(-1)
        if span is not None:
            nodes, span, box = _range_children(
                nodes, span[parents], is_range[parents], table, position_box
            )
        next_index += len(nodes)
        if len(nodes) == 0:
            break
    return np.concatenate(levels).view(BINARY_NODE_DTYPE).reshape(-1), prims
