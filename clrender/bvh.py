"""Bounding volume hierarchy over a scene's primitives, built on the host for the device.

    nodes, prims = build_bvh(lower, upper)   # primitive bounds, (N, 3) each

A top-down binned surface-area-heuristic build (Wald 2007; pbrt-v4's BVHAggregate with
"sah"): each node's primitives are put in BVH_BINS bins along the axis where their centroids
spread most, every split between bins is costed by the SAH, and the cheapest split is taken
unless a leaf is cheaper (at most LEAF_MAX primitives). Written in NumPy by levels: every node
of one depth is split at once (reductions over node x bin groups, a stable partition by cumulative
sums), so the Python loop runs once per tree level, never per primitive or node; 1 M triangles
build in about a second (bench/bvh_scaling.py).

The result is deterministic (the same bounds give the same tree) and is flattened in the layout
of kernels/scene_types.h's BVHNode, breadth first: an interior node's children are adjacent, a
leaf's primitive ids are a range of `prims`. Depth is capped at BVH_MAX_DEPTH (the device's
traversal stack): nodes that deep become leaves however many primitives they hold.
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
BVH_BINS = 16
LEAF_MAX = 8
# Cost of visiting a node relative to one primitive test (pbrt-v4 takes 1/2; 1 and leaves of
# up to 8 trace 5-10 % faster here: bench/bvh_scaling.py).
TRAVERSAL_COST = 1.0
# Primitive bounds are widened by this fraction of their largest coordinate magnitude: far above
# the rounding of the slab test and of the primitive tests (so a box never rejects a ray that
# hits one of its primitives; flat primitives get boxes of non-zero thickness).
BOUNDS_PADDING = 1e-5


def padded_bounds(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Primitive bounds widened by BOUNDS_PADDING of each primitive's magnitude (float64)."""
    lower = np.asarray(lower, np.float64)
    upper = np.asarray(upper, np.float64)
    magnitude = np.maximum(np.abs(lower).max(axis=1), np.abs(upper).max(axis=1))
    pad = (BOUNDS_PADDING * magnitude + 1e-30)[:, None]
    return lower - pad, upper + pad


def _half_area(box: np.ndarray) -> np.ndarray:
    """Half the surface area (float64) of boxes stored as rows (lower, -upper) x 6."""
    size = (-box[3:] - box[:3]).astype(np.float64)
    return size[0] * size[1] + size[1] * size[2] + size[2] * size[0]


def _segment_prefix_min(values: np.ndarray, segment: np.ndarray, direction: int) -> np.ndarray:
    """Running minimum along the columns of `values` within runs of equal `segment` (runs of at
    most BVH_BINS columns), forwards (direction 1) or backwards (-1): a doubling scan,
    log2(BVH_BINS) vectorised steps."""
    result = values.copy()
    step = 1
    while step < BVH_BINS:
        late, early = (slice(step, None), slice(None, -step))
        target, source = (late, early) if direction > 0 else (early, late)
        # +inf where the neighbour `step` away is in another segment
        barrier = np.where(segment[step:] == segment[:-step], 0.0, np.inf).astype(values.dtype)
        np.minimum(result[:, target], result[:, source] + barrier, out=result[:, target])
        step *= 2
    return result


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
    size = (binary["upper"] - binary["lower"]).astype(np.float64)
    area = size[:, 0] * size[:, 1] + size[:, 1] * size[:, 2] + size[:, 2] * size[:, 0]
    interior = binary["count"] < 0
    levels = []
    roots = np.array([0])  # the binary node each wide node of the level starts from
    next_index = 1
    while len(roots):
        count = len(roots)
        rows = np.arange(count)
        slots = np.full((count, BVH_WIDTH), -1)
        slots[:, 0] = roots
        for _ in range(BVH_WIDTH - 1):
            filled = slots >= 0
            opened = np.maximum(slots, 0)
            score = np.where(filled & interior[opened], area[opened], -1.0)
            widest = np.argmax(score, axis=1)
            empty = np.argmax(~filled, axis=1)
            grow = np.flatnonzero((score[rows, widest] >= 0.0) & (~filled).any(axis=1))
            parent = slots[grow, widest[grow]]
            slots[grow, widest[grow]] = binary["offset"][parent]
            slots[grow, empty[grow]] = binary["offset"][parent] + 1
        filled = slots >= 0
        member = np.maximum(slots, 0)
        is_node = filled & interior[member]
        rank = (np.cumsum(is_node.reshape(-1)) - 1).reshape(slots.shape)
        wide = np.zeros(count, BVH_NODE_DTYPE)
        wide["child"] = np.where(is_node, next_index + rank, binary["offset"][member])
        wide["child"][~filled] = -1
        wide["count"] = np.where(is_node, 0, binary["count"][member])
        wide["count"][~filled] = -1
        wide["lower"] = np.where(filled[:, None, :], binary["lower"][member].transpose(0, 2, 1), 0)
        wide["upper"] = np.where(filled[:, None, :], binary["upper"][member].transpose(0, 2, 1), 0)
        levels.append(wide)
        roots = slots[is_node]
        next_index += len(roots)
    return np.concatenate(levels)


def build_bvh(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Binary BVH over N primitives with bounds lower[i], upper[i]: (nodes, prims), nodes a
    BINARY_NODE_DTYPE array (the root first), prims the uint32 primitive ids the leaves point
    into. Bounds are padded (padded_bounds) and rounded outwards to float32."""
    lower, upper = padded_bounds(lower, upper)
    count = len(lower)
    if count == 0:
        return np.zeros(0, BINARY_NODE_DTYPE), np.zeros(0, np.uint32)
    # Structure of arrays (one row per coordinate): gathers and reductions run along rows
    # (float32, rounded outwards: half the memory traffic of float64)
    lower32 = np.nextafter(lower.astype(np.float32), np.float32(-np.inf))
    upper32 = np.nextafter(upper.astype(np.float32), np.float32(np.inf))
    centroid = np.ascontiguousarray((0.5 * (lower32 + upper32)).T)
    boxes = np.ascontiguousarray(np.concatenate([lower32, -upper32], axis=1).T)  # min: union
    perm = np.zeros(count, np.int64)  # position -> primitive; a leaf owns a range of them
    # The working set: primitives of the current level's nodes, node by node, in their
    # current order (kept in that order, so gathers and scatters stay local)
    work_ids = np.arange(count)
    work_c = centroid
    work_boxes = boxes
    levels = []  # per depth: (lower, upper, offset, count) of its nodes, in index order
    start = np.array([0])
    size = np.array([count])
    box = boxes.min(axis=1)[:, None]
    next_index = 1
    depth = 0
    while len(start):
        m = len(start)
        # The level's primitives, node by node
        first = np.concatenate([[0], np.cumsum(size)[:-1]])
        total = int(size.sum())
        node_of = np.repeat(np.arange(m), size)
        c = work_c
        # Split axis: the longest extent of the node's centroids
        cmin = np.minimum.reduceat(c, first, axis=1)
        cmax = np.maximum.reduceat(c, first, axis=1)
        axis = np.argmax(cmax - cmin, axis=0)
        extent = (cmax - cmin)[axis, np.arange(m)]
        low = cmin[axis, np.arange(m)]
        # Bin every primitive by its centroid: min(BVH_BINS, size) bins per node, so the
        # level's bins never outnumber its primitives; bins of node k are groups
        # bin_first[k] .. bin_first[k] + node_bins[k] - 1
        node_bins = np.minimum(size, BVH_BINS)
        bin_first = np.concatenate([[0], np.cumsum(node_bins)[:-1]])
        group_count = int(node_bins.sum())
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(extent > 0.0, node_bins / extent, 0.0)
        along = c.reshape(-1)[axis[node_of] * total + np.arange(total)]
        bins = ((along - low[node_of]) * scale[node_of]).astype(np.int64)
        bins = np.clip(bins, 0, node_bins[node_of] - 1)
        group = bin_first[node_of] + bins
        # Bounds and counts of each group: sort by bin (stable, so nodes stay in order within
        # a bin: each (bin, node) group is then contiguous) and reduce
        order = np.argsort(bins.astype(np.uint8), kind="stable")
        sorted_group = group[order]
        run_start = np.flatnonzero(np.r_[True, sorted_group[1:] != sorted_group[:-1]])
        bin_boxes = np.full((6, group_count), np.inf, np.float32)
        bin_boxes[:, sorted_group[run_start]] = np.minimum.reduceat(
            np.take(work_boxes, order, axis=1), run_start, axis=1
        )
        bin_counts = np.bincount(group, minlength=group_count)
        # SAH cost of the split after each bin j (left: the node's bins up to j, the rest right)
        group_node = np.repeat(np.arange(m), node_bins)
        left_boxes = _segment_prefix_min(bin_boxes, group_node, 1)
        right_boxes = _segment_prefix_min(bin_boxes, group_node, -1)
        right_boxes = np.concatenate(
            [right_boxes[:, 1:], np.full((6, 1), np.inf, np.float32)], axis=1
        )
        left_counts = np.cumsum(bin_counts) - np.repeat(
            np.cumsum(bin_counts)[bin_first] - bin_counts[bin_first], node_bins
        )
        right_counts = size[group_node] - left_counts
        node_area = np.maximum(_half_area(box), 1e-300)
        with np.errstate(invalid="ignore", over="ignore"):
            cost = (
                TRAVERSAL_COST
                + (left_counts * _half_area(left_boxes) + right_counts * _half_area(right_boxes))
                / node_area[group_node]
            )
        cost[(left_counts == 0) | (right_counts == 0)] = np.inf
        # The cheapest split of each node (the first bin of the lowest cost)
        best_cost = np.minimum.reduceat(cost, bin_first)
        candidates = np.flatnonzero(cost == best_cost[group_node])
        first_candidate = np.r_[True, group_node[candidates][1:] != group_node[candidates][:-1]]
        best_group = np.zeros(m, np.int64)
        best_group[group_node[candidates[first_candidate]]] = candidates[first_candidate]
        best = best_group - bin_first
        # Leaf or split: SAH decides for small nodes; unsplittable nodes are leaves
        splittable = (extent > 0.0) & (size > 1) & (depth < BVH_MAX_DEPTH) & np.isfinite(best_cost)
        split = splittable & ~((size <= LEAF_MAX) & (size <= best_cost))
        child = next_index + 2 * (np.cumsum(split) - 1)
        offset = np.where(split, child, start)
        levels.append((box, offset, np.where(split, -1 - axis, size)))
        # Leaves take their primitives; the split nodes' primitives move on, each node's
        # left side first (a stable partition)
        moving = split[node_of]
        leaf_prims = ~moving
        perm[start[node_of[leaf_prims]] + (np.arange(total) - first[node_of])[leaf_prims]] = (
            work_ids[leaf_prims]
        )
        goes_right = bins > best[node_of]
        n_left = left_counts[best_group]
        next_first = np.cumsum(np.where(split, size, 0)) - np.where(split, size, 0)
        # Rank of each moving primitive among its node's primitives going the same way
        right = goes_right & moving
        right_before = np.cumsum(right) - right
        right_before -= right_before[first][node_of]
        left_before = np.arange(total) - first[node_of] - right_before
        side_rank = np.where(goes_right, n_left[node_of] + right_before, left_before)
        dest = (next_first[node_of] + side_rank)[moving]
        source = np.empty(len(dest), np.int64)
        source[dest] = np.flatnonzero(moving)
        work_ids_next = work_ids[source]
        work_c_next = np.take(work_c, source, axis=1)
        work_boxes_next = np.take(work_boxes, source, axis=1)
        work_ids, work_c, work_boxes = work_ids_next, work_c_next, work_boxes_next
        # The next level: both children of every split node, bounds from the bin sweep
        parents = np.flatnonzero(split)
        left_box = left_boxes[:, best_group[parents]]
        right_box = right_boxes[:, best_group[parents]]
        start = np.stack([start[parents], start[parents] + n_left[parents]], axis=1).reshape(-1)
        size = np.stack([n_left[parents], size[parents] - n_left[parents]], axis=1).reshape(-1)
        box = np.stack([left_box, right_box], axis=2).reshape(6, -1)
        next_index += 2 * len(parents)
        depth += 1
    return _flatten(levels), perm.astype(np.uint32)


def _flatten(levels: list) -> np.ndarray:
    """BVH_NODE_DTYPE records of every level's nodes."""
    box = np.concatenate([level[0] for level in levels], axis=1).T
    nodes = np.zeros(len(box), BINARY_NODE_DTYPE)
    nodes["lower"] = box[:, :3]
    nodes["upper"] = -box[:, 3:]
    nodes["offset"] = np.concatenate([level[1] for level in levels])
    nodes["count"] = np.concatenate([level[2] for level in levels])
    return nodes
