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
MORTON_BITS = 10  # per axis: Morton codes of 30 bits
CLUSTER_MAX = 8  # primitives of a Morton cluster (the SAH's unit) at most
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
    lower = np.asarray(lower, np.float32).T
    upper = np.asarray(upper, np.float32).T
    magnitude = np.maximum(np.abs(lower).max(axis=0), np.abs(upper).max(axis=0))
    pad = np.float32(BOUNDS_PADDING) * magnitude + np.float32(1e-30)
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


def _highest_bit(x: np.ndarray) -> np.ndarray:
    """Index of the highest set bit of each (non-zero) uint64, exactly (each half of 32 bits
    is exact in float64)."""
    high = (x >> np.uint64(32)).astype(np.float64)
    low = (x & np.uint64(0xFFFFFFFF)).astype(np.float64)
    return np.where(high > 0.0, 32 + np.frexp(high)[1], np.frexp(low)[1]) - 1


def _boundary_bits(keys: np.ndarray) -> np.ndarray:
    """For sorted unique keys, the highest bit where keys i - 1 and i differ at boundary i
    (1 .. N - 1), stored at CLUSTER_MAX + i of an int8 array padded by CLUSTER_MAX on each
    side with 127 (the boundaries 0 and N, and beyond, differ above every bit)."""
    bits = np.full(len(keys) + 1 + 2 * CLUSTER_MAX, 127, np.int8)
    bits[CLUSTER_MAX + 1 : CLUSTER_MAX + len(keys)] = _highest_bit(keys[1:] ^ keys[:-1])
    return bits


def _morton_clusters(bits: np.ndarray, count: int) -> np.ndarray:
    """Starts (ascending) of the Morton clusters of `count` sorted keys with boundary bits
    `bits` (_boundary_bits): the largest subtrees of the keys' radix tree (Karras 2012) with
    at most CLUSTER_MAX keys. Boundary i splits the radix node reaching from the nearest
    boundary before it with a higher bit to the nearest one after it: a cut between clusters
    where that node holds more than CLUSTER_MAX keys (both found in a window of CLUSTER_MAX)."""
    pad = CLUSTER_MAX
    here = bits[pad + 1 : pad + count]
    before = np.full(count - 1, -pad, np.int64)  # distance to the nearest higher boundary
    after = np.full(count - 1, pad, np.int64)
    for step in range(pad - 1, 0, -1):
        before[bits[pad + 1 - step : pad + count - step] > here] = -step
        after[bits[pad + 1 + step : pad + count + step] > here] = step
    return np.r_[0, 1 + np.flatnonzero(after - before > CLUSTER_MAX)]


def _morton_sweep(windows: np.ndarray, start, end, box, width: int) -> tuple:
    """The SAH's best split of each range [start, end) (2 to `width` primitives) of the Morton
    order into [start, middle) and [middle, end), every middle tried; windows: the sorted
    boxes' windows of CLUSTER_MAX boxes (N, CLUSTER_MAX x 6); box: the ranges' boxes. Returns
    (middle, cost, left boxes, right boxes, axis of the children's centres)."""
    m, size = len(start), end - start
    # Boxes of the first k primitives (head[k - 1]) and of all but the first k (tail[k]), the
    # boxes past the range left out; (window position, row, node) arrays
    window = windows[start, : 6 * width].reshape(m, width, 6).transpose(1, 2, 0)
    head = np.where(np.arange(width)[:, None, None] < size, window, np.float32(np.inf))
    tail = head.copy()
    for k in range(1, width):
        np.minimum(head[k - 1], head[k], out=head[k])
        np.minimum(tail[-k], tail[-k - 1], out=tail[-k - 1])
    # SAH cost of every split (k primitives on the left), areas relative to the node's largest
    # extent (float32 without overflow)
    extent = -box[3:] - box[:3]
    scale = np.float32(1.0) / np.maximum(extent.max(axis=0), np.float32(1e-30))
    k = np.arange(1, width)[:, None]
    with np.errstate(invalid="ignore", over="ignore"):
        node_area = np.maximum(_scaled_half_area(extent, scale), np.float32(1e-30))
        left_area = _scaled_half_area(-head[:-1, 3:] - head[:-1, :3], scale)
        right_area = _scaled_half_area(-tail[1:, 3:] - tail[1:, :3], scale)
        cost = TRAVERSAL_COST + (k * left_area + (size - k) * right_area) / node_area
    cost[k >= size] = np.inf
    best = np.argmin(cost, axis=0)
    rows = np.arange(m)
    left_box, right_box = head[best, :, rows].T, tail[best + 1, :, rows].T
    centre_gap = np.abs((left_box[:3] - left_box[3:]) - (right_box[:3] - right_box[3:]))
    return start + 1 + best, cost[best, rows], left_box, right_box, np.argmax(centre_gap, axis=0)


def _scaled_half_area(extent: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes of extents (..., 3, nodes) scaled by `scale` (nodes)."""
    x, y, z = (extent[..., axis, :] * scale for axis in range(3))
    return x * y + y * z + z * x


def _expand_ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The integers of the ranges [starts[k], starts[k] + lengths[k]), one range after another."""
    ends = np.cumsum(lengths)
    return np.arange(ends[-1]) + np.repeat(starts - (ends - lengths), lengths)


def _binned_sah(work_c, work_boxes, work_w, first, size, box) -> tuple:
    """The best binned-SAH split of each node of items first[k] .. first[k] + size[k] - 1 (at
    least 2) of the working set (centroids work_c, boxes work_boxes, primitive counts work_w);
    box: the nodes' boxes. Returns (goes_right per item, axis, cost, left items, left
    primitives, child boxes (6, nodes, 2)); cost inf where no split separates the items."""
    m, total = len(size), len(work_w)
    if m == 0:
        empty = np.zeros(0, np.int64)
        return np.zeros(0, bool), empty, np.zeros(0), empty, empty, np.zeros((6, 0, 2), np.float32)
    node_of = np.repeat(np.arange(m), size)
    # Split axis: the longest extent of the node's centroids
    cmin = np.minimum.reduceat(work_c, first, axis=1)
    cmax = np.maximum.reduceat(work_c, first, axis=1)
    axis = np.argmax(cmax - cmin, axis=0)
    extent = (cmax - cmin)[axis, np.arange(m)]
    low = cmin[axis, np.arange(m)]
    # Bin every item by its centroid: min(BVH_BINS, size) bins per node, so the level's bins
    # never outnumber its items; bins of node k are groups bin_first[k] .. + node_bins[k] - 1
    # (2 bins where the centroids coincide: rank halves)
    node_bins = np.where(extent > 0.0, np.minimum(size, BVH_BINS), 2)
    bin_first = np.cumsum(node_bins) - node_bins
    group_count = int(node_bins.sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(extent > 0.0, node_bins / extent, 0.0).astype(np.float32)
    along = work_c.reshape(-1)[axis[node_of] * total + np.arange(total)]
    bins = ((along - low[node_of]) * scale[node_of]).astype(np.int64)
    bins = np.minimum(bins, node_bins[node_of] - 1)
    if not np.all(extent > 0.0):
        # Items whose centroids coincide are binned by their rank in the node
        flat = (extent <= 0.0)[node_of]
        rank = np.arange(total) - first[node_of]
        bins[flat] = (rank * node_bins[node_of] // size[node_of])[flat]
    group = bin_first[node_of] + bins
    # Bounds and counts of each group
    bin_boxes = np.full((6, group_count), np.inf, np.float32)
    for row in range(6):
        np.minimum.at(bin_boxes[row], group, work_boxes[row])
    bin_items = np.bincount(group, minlength=group_count)
    bin_prims = np.bincount(group, weights=work_w, minlength=group_count).astype(np.int64)
    # SAH cost of the split after each bin j (left: the node's bins up to j, the rest right)
    group_node = np.repeat(np.arange(m), node_bins)
    left_boxes = _segment_prefix_min(bin_boxes, group_node, 1)
    right_boxes = _segment_prefix_min(bin_boxes, group_node, -1)
    right_boxes = np.concatenate([right_boxes[:, 1:], np.full((6, 1), np.inf, np.float32)], axis=1)
    left_items = _segment_cumsum(bin_items, bin_first, node_bins)
    left_prims = _segment_cumsum(bin_prims, bin_first, node_bins)
    right_prims = np.repeat(np.add.reduceat(bin_prims, bin_first), node_bins) - left_prims
    node_area = np.maximum(_half_area(box), 1e-300)
    with np.errstate(invalid="ignore", over="ignore"):
        cost = (
            TRAVERSAL_COST
            + (left_prims * _half_area(left_boxes) + right_prims * _half_area(right_boxes))
            / node_area[group_node]
        )
    cost[(left_items == 0) | (left_items == size[group_node])] = np.inf
    # The cheapest split of each node (the first bin of the lowest cost)
    best_cost = np.minimum.reduceat(cost, bin_first)
    candidates = np.flatnonzero(cost == best_cost[group_node])
    first_candidate = np.r_[True, group_node[candidates][1:] != group_node[candidates][:-1]]
    best_group = np.zeros(m, np.int64)
    best_group[group_node[candidates[first_candidate]]] = candidates[first_candidate]
    goes_right = bins > (best_group - bin_first)[node_of]
    child_boxes = np.stack([left_boxes[:, best_group], right_boxes[:, best_group]], axis=2)
    return (
        goes_right,
        axis,
        best_cost,
        left_items[best_group],
        left_prims[best_group],
        child_boxes,
    )


def _segment_cumsum(values: np.ndarray, first: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Inclusive running sums of values within the segments first[k] .. first[k] + size[k] - 1."""
    total = np.cumsum(values)
    return total - np.repeat(total[first] - values[first], size)


def _partition(work: tuple, moving, goes_right, first, size, left_items, split) -> tuple:
    """The working arrays (last axis: items) of the split nodes' items, each node's left items
    first then its right ones, in order (a stable partition by cumulative sums); and the item
    counts (split nodes, 2) of the children."""
    total = len(moving)
    node_of = np.repeat(np.arange(len(size)), size)
    moved_size = np.where(split, size, 0)
    next_first = np.cumsum(moved_size) - moved_size
    # Rank of each moving item among its node's items going the same way
    right = goes_right & moving
    right_before = np.cumsum(right) - right
    right_before -= np.repeat(right_before[first], size)
    left_before = np.arange(total) - first[node_of] - right_before
    side_rank = np.where(goes_right, left_items[node_of] + right_before, left_before)
    destination = (next_first[node_of] + side_rank)[moving]
    source = np.empty(len(destination), np.int64)
    source[destination] = np.flatnonzero(moving)
    moved = tuple(np.take(array, source, axis=-1) for array in work)
    children = np.stack([left_items[split], size[split] - left_items[split]], axis=1)
    return (*moved, children)


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
    BINARY_NODE_DTYPE array (the root first, breadth first), prims the uint32 primitive ids the
    leaves point into. Bounds are padded (padded_bounds) in float32."""
    count = len(lower)
    if count == 0:
        return np.zeros(0, BINARY_NODE_DTYPE), np.zeros(0, np.uint32)
    lower32, upper32 = padded_bounds(lower, upper)
    # Sort the primitives once along the Morton curve of their centroids
    keys = np.sort(_morton_keys(0.5 * (lower32 + upper32)))
    order = (keys & np.uint64(0xFFFFFFFF)).astype(np.intp)
    # Boxes in that order (lower, -upper: a union is a minimum), then CLUSTER_MAX empty ones,
    # so that every primitive starts a window of CLUSTER_MAX boxes
    sorted_boxes = np.full((count + CLUSTER_MAX, 6), np.inf, np.float32)
    for row in range(3):
        sorted_boxes[:count, row] = np.take(lower32[row], order)
        sorted_boxes[:count, 3 + row] = -np.take(upper32[row], order)
    windows = np.lib.stride_tricks.as_strided(
        sorted_boxes, shape=(count, 6 * CLUSTER_MAX), strides=sorted_boxes.strides, writeable=False
    )
    # The SAH's units: Morton clusters of at most CLUSTER_MAX primitives
    cluster_start = _morton_clusters(_boundary_bits(keys), count)
    cluster_end = np.r_[cluster_start[1:], count]
    cluster_boxes = np.minimum.reduceat(sorted_boxes[:count], cluster_start, axis=0).T
    clusters = len(cluster_start)
    # The level's nodes, in index order: box, first position in `prims`, primitives, and
    # either clusters (an SAH node, items > 0) or a range of the sorted order (a Morton node,
    # items 0: a single cluster or part of one)
    box = sorted_boxes[:count].min(axis=0)[:, None]
    first = np.array([0])
    prims = np.array([count])
    items = np.array([clusters if clusters > 1 else 0])
    span = np.array([[0, count]])
    # The working set: the clusters of the level's SAH nodes, node by node
    work_ids = np.arange(clusters)
    work_c = 0.5 * (cluster_boxes[:3] - cluster_boxes[3:])
    work_boxes = cluster_boxes
    work_w = cluster_end - cluster_start
    if clusters == 1:
        work_ids, work_c, work_boxes, work_w = (
            work_ids[:0],
            work_c[:, :0],
            work_boxes[:, :0],
            work_w[:0],
        )
    levels = []  # per depth: (box, offset, count) of its nodes, in index order
    leaf_ranges = []  # (source start in the sorted order, length, first position in prims)
    next_index = 1
    depth = 0
    while len(prims):
        m = len(prims)
        sah = np.flatnonzero(items > 0)
        morton = np.flatnonzero(items == 0)
        child_box = np.zeros((6, m, 2), np.float32)
        left_prims = np.zeros(m, np.int64)
        cost = np.full(m, np.inf)
        axis = np.zeros(m, np.int64)
        # SAH nodes: the best binned split of their clusters
        item_first = np.cumsum(items[sah]) - items[sah]
        sah_split = _binned_sah(work_c, work_boxes, work_w, item_first, items[sah], box[:, sah])
        goes_right, sah_axis, cost[sah], left_items, left_prims[sah], boxes_lr = sah_split
        axis[sah] = sah_axis
        child_box[:, sah] = boxes_lr
        # Morton nodes: the best split of their range of the Morton order
        middle = np.zeros(m, np.int64)
        several = morton[prims[morton] > 1]
        for low, width in ((1, 2), (2, 4), (4, CLUSTER_MAX)):
            sweep = several[(prims[several] > low) & (prims[several] <= width)]
            if len(sweep):
                start, end = span[sweep, 0], span[sweep, 1]
                result = _morton_sweep(windows, start, end, box[:, sweep], width)
                middle[sweep], cost[sweep], left_box, right_box, axis[sweep] = result
                child_box[:, sweep, 0], child_box[:, sweep, 1] = left_box, right_box
                left_prims[sweep] = middle[sweep] - start
        # Leaf or split: SAH decides for small nodes
        splittable = np.isfinite(cost) & (depth < BVH_MAX_DEPTH)
        split = splittable & ~((prims <= LEAF_MAX) & (prims <= cost))
        offset = np.where(split, next_index + 2 * (np.cumsum(split) - 1), first)
        levels.append((box, offset, np.where(split, -1 - axis, prims)))
        # Leaves take their primitives: a Morton leaf one range of the sorted order, an SAH
        # leaf its clusters' ranges one after another
        morton_leaves = morton[~split[morton]]
        leaf_ranges.append((span[morton_leaves, 0], prims[morton_leaves], first[morton_leaves]))
        item_node = np.repeat(sah, items[sah])
        leaf_items = np.flatnonzero(~split[item_node])
        if len(leaf_items):
            sizes = work_w[leaf_items]
            node = item_node[leaf_items]
            ends = np.cumsum(sizes)
            node_begins = np.r_[True, node[1:] != node[:-1]]
            within = ends - sizes
            within -= np.maximum.accumulate(np.where(node_begins, within, 0))
            leaf_ranges.append((cluster_start[work_ids[leaf_items]], sizes, first[node] + within))
        # Split SAH nodes' clusters move on, each node's left side first (a stable partition)
        moving = split[item_node]
        work_ids, work_c, work_boxes, work_w, child_items = _partition(
            (work_ids, work_c, work_boxes, work_w),
            moving,
            goes_right,
            item_first,
            items[sah],
            left_items,
            split[sah],
        )
        # The next level: both children of every split node
        parents = np.flatnonzero(split)
        child_items_all = np.zeros((m, 2), np.int64)
        child_items_all[sah[split[sah]]] = child_items
        child_span = np.zeros((m, 2, 2), np.int64)
        child_span[several, 0, 0] = span[several, 0]
        child_span[several, 0, 1] = middle[several]
        child_span[several, 1, 0] = middle[several]
        child_span[several, 1, 1] = span[several, 1]
        items = child_items_all[parents].reshape(-1)
        span = child_span[parents].reshape(-1, 2)
        # An SAH child of one cluster becomes a Morton node over that cluster
        item_child = np.repeat(np.flatnonzero(items > 0), items[items > 0])
        single = items[item_child] == 1
        span[item_child[single], 0] = cluster_start[work_ids[single]]
        span[item_child[single], 1] = cluster_end[work_ids[single]]
        items[items == 1] = 0
        keep = ~single
        work_ids, work_c, work_boxes, work_w = (
            work_ids[keep],
            work_c[:, keep],
            work_boxes[:, keep],
            work_w[keep],
        )
        n_left = left_prims[parents]
        first = np.stack([first[parents], first[parents] + n_left], axis=1).reshape(-1)
        prims = np.stack([n_left, prims[parents] - n_left], axis=1).reshape(-1)
        box = child_box[:, parents].reshape(6, -1)
        next_index += 2 * len(parents)
        depth += 1
    source, length, destination = (
        np.concatenate(column) for column in zip(*leaf_ranges, strict=True)
    )
    perm = np.empty(count, np.uint32)
    perm[_expand_ranges(destination, length)] = order[_expand_ranges(source, length)]
    return _flatten(levels), perm


def _flatten(levels: list) -> np.ndarray:
    """BVH_NODE_DTYPE records of every level's nodes."""
    box = np.concatenate([level[0] for level in levels], axis=1).T
    nodes = np.zeros(len(box), BINARY_NODE_DTYPE)
    nodes["lower"] = box[:, :3]
    nodes["upper"] = -box[:, 3:]
    nodes["offset"] = np.concatenate([level[1] for level in levels])
    nodes["count"] = np.concatenate([level[2] for level in levels])
    return nodes
