"""The scene as the device reads it: NumPy twins of kernels/scene_types.h and their packing.

This module mirrors kernels/scene_types.h field by field: every dtype below is one struct
there, with its members in the same order and of the same types (only 4-byte members and
``float[3]``, so there is no padding on any device; tests/test_scene.py checks each size against
``sizeof`` on the device). Change both files together.

====================  ===================  ====================================================
dtype                 struct               one record per
====================  ===================  ====================================================
QUAD_DTYPE            Quad                 quad (a box is 6), with its dual vectors
quad_block_dtype      QuadBlock            QUAD_BLOCK_WIDTH quads, structure of arrays
SPHERE_DTYPE          Sphere               sphere
TRIANGLE_DTYPE        Triangle             mesh triangle (vertices, material, normals and
                                           emitter index)
NORMALS_DTYPE         TriangleNormals      mesh triangle with per-vertex shading normals
BVH_NODE_DTYPE        BVHNode              8-wide node of the BVH (bvh.py; few quads stay out)
TRIANGLE_BLOCK_DTYPE  TriangleBlock        8 triangles of a BVH leaf, structure of arrays (in the
                                           leaf records, pack_bvh_leaves, with quad blocks)
MATERIAL_DTYPE        Material             material (MATERIAL_TYPES tags)
EMITTER_DTYPE         Emitter              emitting quad, sphere or mesh triangle, with its
                                           light-selection pdf and cdf
CAMERA_DTYPE          Camera               camera at one image size
====================  ===================  ====================================================

The packing functions take validated plain values (what clrender/scene.py reads from a scene
file) and return these records. Dependencies run one way: scene.py imports this module, this
module imports nothing of clrender's but the BVH builder (clrender/bvh.py) and the errors.
"""

from __future__ import annotations

import math

import numpy as np

from clrender.bvh import BVH_NODE_DTYPE, BVH_WIDTH, build_wide_bvh
from clrender.errors import ClrenderError

# Material type tags: MATERIAL_DIFFUSE, ... in kernels/scene_types.h.
MATERIAL_TYPES = {"diffuse": 0, "dielectric": 1, "roughconductor": 2}
MATERIAL_NONE = -1  # a pure emitter: absorbs everything that reaches it

QUAD_DTYPE = np.dtype(
    [
        ("corner", "<f4", 3),
        ("edge1", "<f4", 3),
        ("edge2", "<f4", 3),
        ("normal", "<f4", 3),
        ("u_dual", "<f4", 3),
        ("v_dual", "<f4", 3),
        ("plane_d", "<f4"),
        ("material", "<i4"),
        ("emitter", "<i4"),
    ]
)
QUAD_BLOCK_WIDTH = 8  # fixed in kernels/scene_types.h


def quad_block_dtype(width: int = QUAD_BLOCK_WIDTH) -> np.dtype:
    """QuadBlock: the quads' intersection data as structure of arrays, `width` quads each."""
    return np.dtype(
        [
            ("corner", "<f4", (3, width)),
            ("normal", "<f4", (3, width)),
            ("u_dual", "<f4", (3, width)),
            ("v_dual", "<f4", (3, width)),
            ("plane_d", "<f4", width),
            ("quad", "<i4", width),
            ("lower", "<f4", 4),
            ("upper", "<f4", 4),
        ]
    )


SPHERE_DTYPE = np.dtype(
    [("center", "<f4", 3), ("radius", "<f4"), ("material", "<i4"), ("emitter", "<i4")]
)
TRIANGLE_DTYPE = np.dtype(
    [
        ("p0", "<f4", 3),
        ("p1", "<f4", 3),
        ("p2", "<f4", 3),
        ("material", "<i4"),
        ("normals", "<i4"),
        ("emitter", "<i4"),
    ]
)
NORMALS_DTYPE = np.dtype([("n", "<f4", (3, 3))])
BVH_BLOCK_WIDTH = 8  # lanes of a BVH leaf's blocks: fixed in kernels/scene_types.h
TRIANGLE_BLOCK_DTYPE = np.dtype(
    [
        ("p0", "<f4", (3, BVH_BLOCK_WIDTH)),
        ("p1", "<f4", (3, BVH_BLOCK_WIDTH)),
        ("p2", "<f4", (3, BVH_BLOCK_WIDTH)),
        ("material", "<i4", BVH_BLOCK_WIDTH),
        ("normals", "<i4", BVH_BLOCK_WIDTH),
        ("emitter", "<i4", BVH_BLOCK_WIDTH),
        ("id", "<i4", BVH_BLOCK_WIDTH),
    ]
)
# BVH leaf records (pack_bvh_leaves): a leaf lane's count packs its triangle blocks, quad blocks
# and spheres, as (shift, bits) each (BVH_LEAF_* in kernels/scene_types.h); records start at
# multiples of BVH_LEAF_ALIGN words (32 bytes: a block's rows never straddle a cache line, and
# the 104-word triangle blocks of records of one block follow each other without padding).
BVH_LEAF_FIELDS = ((0, 16), (16, 8), (24, 7))
BVH_LEAF_ALIGN = 8
# Brute force or BVH: brute force tests quads 8 at a time and triangles one at a time, so a
# triangle weighs TRIANGLE_COST quads; a scene whose brute_force_cost is at most
# BRUTE_FORCE_LIMIT is traced by brute force, a larger one through the BVH. Measured by
# bench/bvh_scaling.py (README, "Performance"): brute force wins up to 34 quads, the two are even
# at 66 and 98 quads and with 6 triangles in the Cornell box (cost 114), the BVH wins from 130
# quads (1.2x) and 8 triangles (1.2x).
BRUTE_FORCE_LIMIT = 96
# A scene with a BVH keeps up to this many quads out of it, tested by brute force beside it
# (kernels/scene_types.h, the same)
BVH_MAX_BRUTE_QUADS = 64
TRIANGLE_COST = 16


def brute_force_cost(quad_count: int, sphere_count: int, triangle_count: int) -> int:
    """A scene's cost of brute-force intersection, in quads (see BRUTE_FORCE_LIMIT)."""
    return quad_count + sphere_count + TRIANGLE_COST * triangle_count


MATERIAL_DTYPE = np.dtype(
    [
        ("type", "<i4"),
        ("two_sided", "<i4"),
        ("albedo", "<f4", 3),
        ("eta", "<f4", 3),
        ("k", "<f4", 3),
        ("alpha", "<f4"),
    ]
)
# Emitter shape kinds: EMITTER_QUAD, EMITTER_SPHERE, EMITTER_TRIANGLE in kernels/scene_types.h.
EMITTER_SHAPES = {"quad": 0, "sphere": 1, "triangle": 2}
EMITTER_DTYPE = np.dtype(
    [
        ("shape", "<i4"),
        ("index", "<i4"),
        ("radiance", "<f4", 3),
        ("area", "<f4"),
        ("pick_pdf", "<f4"),
        ("pick_cdf", "<f4"),
    ]
)
CAMERA_DTYPE = np.dtype(
    [("origin", "<f4", 3), ("forward", "<f4", 3), ("right", "<f4", 3), ("up", "<f4", 3)]
)

# Quad blocks' bounding boxes are padded outwards by this fraction of the scene's diagonal (far
# above float rounding in the slab test, so a box never rejects a ray that hits one of its quads).
BLOCK_BOUNDS_PADDING = 1e-4
# A block whose box fills this fraction of the volume of all blocks' boxes is always tested.
BLOCK_BOUNDS_SKIP_FILL = 0.9

QUAD_FRAME = ("corner", "edge1", "edge2")
# Members of a material read from a scene file, besides its type and two_sided.
MATERIAL_VALUES = ("albedo", "eta", "k", "alpha")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def pack_camera(
    look_from, look_at, up, fov: float, width: int, height: int, handedness: str = "right"
) -> np.ndarray:
    """CAMERA_DTYPE record of a pinhole camera (fov: vertical, degrees) for a width x height
    image: origin, unit forward, and right/up scaled so that the ray through normalised image
    coordinates (sx, sy) in [-1, 1]^2 (sx right, sy up) is forward + sx * right + sy * up.
    Image right is cross(forward, up), or its opposite for handedness "left" (pbrt's camera)."""
    origin = np.array(look_from, np.float64)
    forward = _unit(np.array(look_at, np.float64) - origin)
    right = _unit(np.cross(forward, np.array(up, np.float64)))
    true_up = np.cross(right, forward)
    if handedness == "left":
        right = -right
    half_height = math.tan(math.radians(fov) / 2.0)
    record = np.zeros((), CAMERA_DTYPE)
    record["origin"] = origin
    record["forward"] = forward
    record["right"] = right * half_height * (width / height)
    record["up"] = true_up * half_height
    return record


def pack_materials(materials: list[dict]) -> np.ndarray:
    """MATERIAL_DTYPE records of materials given as dicts: "type" (a MATERIAL_TYPES name),
    "two_sided" (bool) and the MATERIAL_VALUES members their type uses (the rest stay 0)."""
    packed = np.zeros(len(materials), MATERIAL_DTYPE)
    for record, material in zip(packed, materials, strict=True):
        record["type"] = MATERIAL_TYPES[material["type"]]
        record["two_sided"] = int(material["two_sided"])
        for key in MATERIAL_VALUES:
            if key in material:
                record[key] = material[key]
    return packed


def pack_quads(quads: list[dict]) -> np.ndarray:
    """QUAD_DTYPE records (emitter -1: pack_emitters sets it); dual vectors give the
    parallelogram coordinates of a point q: a = dot(q - corner, u_dual),
    b = dot(q - corner, v_dual), inside iff both in [0, 1]."""
    packed = np.zeros(len(quads), QUAD_DTYPE)
    for record, quad in zip(packed, quads, strict=True):
        corner, edge1, edge2 = (np.asarray(quad[k], np.float64) for k in QUAD_FRAME)
        n = np.cross(edge1, edge2)
        w = n / np.dot(n, n)
        normal = _unit(n)
        record["corner"] = corner
        record["edge1"] = edge1
        record["edge2"] = edge2
        record["normal"] = normal
        record["u_dual"] = np.cross(edge2, w)
        record["v_dual"] = np.cross(w, edge1)
        record["plane_d"] = np.dot(normal, corner)
        record["material"] = quad["material"]
        record["emitter"] = -1
    return packed


def pack_spheres(spheres: list[dict]) -> np.ndarray:
    """SPHERE_DTYPE records of spheres given as dicts (center, radius, material; emitter -1:
    pack_emitters sets it)."""
    packed = np.zeros(len(spheres), SPHERE_DTYPE)
    for record, sphere in zip(packed, spheres, strict=True):
        record["center"] = sphere["center"]
        record["radius"] = sphere["radius"]
        record["material"] = sphere["material"]
        record["emitter"] = -1
    return packed


def pack_emitters(
    quads: list[dict],
    packed: np.ndarray,
    spheres: list[dict] = (),
    packed_spheres: np.ndarray | None = None,
    meshes: list[dict] = (),
    packed_triangles: np.ndarray | None = None,
) -> np.ndarray:
    """One EMITTER_DTYPE record per emitting shape (a quad, sphere or mesh dict whose
    "emission" is not None; dicts without the key do not emit), every triangle of an emitting
    mesh an emitter of its own: the quads in order, then the spheres, then the triangles (in
    pack_triangles' order). Selection pdf proportional to power = area * mean radiance (a
    sphere's area is 4 pi r^2); sets the packed quads', spheres' and triangles' emitter index."""
    shapes = [("quad", i, quad, packed) for i, quad in enumerate(quads)]
    shapes += [("sphere", i, sphere, packed_spheres) for i, sphere in enumerate(spheres)]
    emitting = [shape for shape in shapes if shape[2].get("emission") is not None]
    areas = []
    for kind, _, shape, _ in emitting:
        if kind == "quad":
            areas.append(float(np.linalg.norm(np.cross(shape["edge1"], shape["edge2"]))))
        else:
            areas.append(4.0 * math.pi * float(shape["radius"]) ** 2)
    first = 0  # the mesh's first triangle in the packed triangles
    for mesh in meshes:
        count = len(mesh["indices"])
        if mesh.get("emission") is not None:
            positions = np.asarray(mesh["positions"], np.float64)
            p0, p1, p2 = (positions[np.asarray(mesh["indices"])[:, k]] for k in range(3))
            mesh_areas = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
            for k in range(count):
                emitting.append(("triangle", first + k, mesh, packed_triangles))
            areas.extend(mesh_areas.tolist())
        first += count
    emitters = np.zeros(len(emitting), EMITTER_DTYPE)
    if not emitting:
        return emitters
    kinds = np.array([EMITTER_SHAPES[kind] for kind, *_ in emitting])
    indices = np.array([i for _, i, *_ in emitting])
    radiance = np.array([shape["emission"] for _, _, shape, _ in emitting], np.float64)
    emitters["shape"] = kinds
    emitters["index"] = indices
    emitters["radiance"] = radiance
    emitters["area"] = areas
    for kind in EMITTER_SHAPES:
        records = {"quad": packed, "sphere": packed_spheres, "triangle": packed_triangles}[kind]
        mine = kinds == EMITTER_SHAPES[kind]
        if mine.any():
            records["emitter"][indices[mine]] = np.flatnonzero(mine)
    powers = np.array(areas) * np.mean(radiance, axis=1)
    pdf = powers / np.sum(powers)
    emitters["pick_pdf"] = pdf
    cdf = np.cumsum(pdf)
    cdf[-1] = 1.0
    emitters["pick_cdf"] = cdf
    return emitters


def pack_triangles(meshes: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """TRIANGLE_DTYPE and NORMALS_DTYPE records of meshes given as dicts: "positions" (V, 3),
    "indices" (T, 3), "normals" (V, 3) or None, "material". Triangles of all meshes in order;
    a triangle's normals index is its row in the normals records, or -1 (emitter -1:
    pack_emitters sets it)."""
    triangles = []
    normals = []
    count = 0
    for mesh in meshes:
        positions = np.asarray(mesh["positions"], np.float64)
        indices = np.asarray(mesh["indices"], np.int64)
        packed = np.zeros(len(indices), TRIANGLE_DTYPE)
        packed["p0"], packed["p1"], packed["p2"] = (positions[indices[:, k]] for k in range(3))
        packed["material"] = mesh["material"]
        packed["normals"] = -1
        packed["emitter"] = -1
        if mesh.get("normals") is not None:
            vertex_normals = np.asarray(mesh["normals"], np.float64)
            # Unit normals; a zero one stays zero (the kernel interpolates the corners' normals
            # and shades with the geometric normal where that sum is zero, as pbrt-v4 does)
            length = np.linalg.norm(vertex_normals, axis=1)[:, None]
            vertex_normals = np.divide(
                vertex_normals, length, out=np.zeros_like(vertex_normals), where=length > 0.0
            )
            records = np.zeros(len(indices), NORMALS_DTYPE)
            records["n"] = vertex_normals[indices]
            packed["normals"] = count + np.arange(len(indices))
            normals.append(records)
            count += len(indices)
        triangles.append(packed)
    join = np.concatenate
    return (
        join(triangles) if triangles else np.zeros(0, TRIANGLE_DTYPE),
        join(normals) if normals else np.zeros(0, NORMALS_DTYPE),
    )


BOUNDS_CHUNK = 1 << 14  # triangles primitive_bounds reads at a time


def primitive_bounds(
    quads: np.ndarray, spheres: np.ndarray, triangles: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (lower, upper: (N, 3) float64) of every primitive in id order: quads, spheres,
    triangles. Each is the transpose of a (3, N) array (an axis' bounds contiguous: how
    clrender.bvh.padded_bounds reads them)."""
    c, e1, e2 = (quads[k].astype(np.float64).reshape(-1, 3) for k in QUAD_FRAME)
    quad_points = np.stack([c, c + e1, c + e2, c + e1 + e2])
    centre = spheres["center"].astype(np.float64).reshape(-1, 3)
    radius = spheres["radius"].astype(np.float64).reshape(-1, 1)
    count = len(quads) + len(spheres) + len(triangles)
    lower, upper = np.empty((3, count)), np.empty((3, count))
    first_triangle = len(quads) + len(spheres)
    lower[:, :first_triangle] = np.concatenate([quad_points.min(axis=0), centre - radius]).T
    upper[:, :first_triangle] = np.concatenate([quad_points.max(axis=0), centre + radius]).T
    # Triangles' bounds in their float32 (exact), BOUNDS_CHUNK triangles (in the caches) and an
    # axis at a time
    p0, p1, p2 = (triangles[k].reshape(-1, 3) for k in ("p0", "p1", "p2"))
    for first in range(0, len(triangles), BOUNDS_CHUNK):
        chunk = slice(first, first + BOUNDS_CHUNK)
        for axis in range(3):
            vertex = (p0[chunk, axis], p1[chunk, axis], p2[chunk, axis])
            at = slice(first_triangle + first, first_triangle + first + len(vertex[0]))
            extreme = np.minimum(*vertex[:2])
            lower[axis, at] = np.minimum(extreme, vertex[2], out=extreme)
            extreme = np.maximum(*vertex[:2])
            upper[axis, at] = np.maximum(extreme, vertex[2], out=extreme)
    return lower.T, upper.T


def pack_bvh(
    quads: np.ndarray,
    spheres: np.ndarray,
    triangles: np.ndarray,
    brute_force_limit: int = BRUTE_FORCE_LIMIT,
) -> tuple[np.ndarray, np.ndarray]:
    """(BVH nodes, leaf records) over every primitive but the quads of a scene with at most
    BVH_MAX_BRUTE_QUADS of them (the kernels test those by brute force beside the BVH)
    (clrender/bvh.py; pack_bvh_leaves); or two empty arrays for a scene whose brute_force_cost
    is at most brute_force_limit, or that has nothing but those quads (the kernels then use
    brute force; -1: a BVH wherever there is something to put in it)."""
    none = np.zeros(0, BVH_NODE_DTYPE), np.zeros(0, np.uint32)
    if brute_force_cost(len(quads), len(spheres), len(triangles)) <= brute_force_limit:
        return none
    lower, upper = primitive_bounds(quads, spheres, triangles)
    # At most BVH_MAX_BRUTE_QUADS quads stay out of the tree (brute force beside it)
    first = len(quads) if len(quads) <= BVH_MAX_BRUTE_QUADS else 0
    if first == len(lower):
        return none
    nodes, prims = build_wide_bvh(lower[first:], upper[first:])
    prims += np.uint32(first)
    return pack_bvh_leaves(nodes, prims, quads, len(spheres), triangles)


def _ranks_within(group: np.ndarray, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """For items sorted by group (ids 0 .. groups - 1): each item's rank within its group,
    and each group's item count."""
    per_group = np.bincount(group, minlength=groups)
    first = np.cumsum(per_group) - per_group
    return np.arange(len(group)) - first[group], per_group


# Blocks _write_record_blocks gathers at a time
RECORD_CHUNK = 1 << 13


def _write_record_blocks(words, blocks, first_word, block_words, member_at, rows):
    """One kind's blocks of every record: blocks[r] of block_words words from word
    first_word[r] of record r, in structure of arrays (row k of a block: its BVH_BLOCK_WIDTH
    lanes' k-th words). The members (record, rank among the record's members of the kind:
    member_at) go to lane rank % BVH_BLOCK_WIDTH of block rank // BVH_BLOCK_WIDTH with their
    rows, given as (first row, source, index, unused): member m's rows are the first
    len(unused) words of source[index[m]] (uint32 rows; index None: source[m]), the blocks' other
    lanes get `unused`. The lanes are gathered in block and lane order, RECORD_CHUNK blocks at
    a time, and written transposed: in place when the kind's blocks follow each other in
    `words` (a scene of one kind), else through one array of blocks."""
    record, rank = member_at
    count = int(blocks.sum())
    block_first = np.cumsum(blocks) - blocks
    block_record = np.repeat(np.arange(len(blocks)), blocks)
    base = first_word[block_record] + block_words * (np.arange(count) - block_first[block_record])
    height = sum(len(unused) for _, _, _, unused in rows)
    in_place = count > 0 and base[-1] - base[0] == block_words * (count - 1)
    if in_place:
        span = words[base[0] : base[0] + block_words * count]
        target = span.reshape(count, block_words // BVH_BLOCK_WIDTH, BVH_BLOCK_WIDTH)[:, :height]
    else:
        target = np.empty((count, height, BVH_BLOCK_WIDTH), np.uint32)
    # Each lane's member (-1: unused), lanes in block order
    lane_member = np.full(count * BVH_BLOCK_WIDTH, -1, np.int32)
    lane_member[BVH_BLOCK_WIDTH * block_first[record] + rank] = np.arange(len(record))
    # RECORD_CHUNK blocks at a time (the gathered lanes stay in the caches)
    for first_block in range(0, count, RECORD_CHUNK):
        end_block = min(count, first_block + RECORD_CHUNK)
        members = lane_member[BVH_BLOCK_WIDTH * first_block : BVH_BLOCK_WIDTH * end_block]
        unused_lanes = np.flatnonzero(members < 0)
        for first_row, source, index, unused in rows:
            row_count = len(unused)
            at = members if index is None else index.take(members, mode="clip")
            lanes = source.take(at, axis=0, mode="clip")[:, :row_count]
            lanes[unused_lanes] = unused
            lanes = lanes.reshape(-1, BVH_BLOCK_WIDTH, row_count).transpose(0, 2, 1)
            target[first_block:end_block, first_row : first_row + row_count] = lanes
    if not in_place and count:
        words[base[:, None] + np.arange(target[0].size)] = target.reshape(count, -1)


def _leaf_groups(count: np.ndarray) -> np.ndarray:
    """The record group (0 .. BVH_WIDTH - 1) of each leaf lane of wide nodes (count: their
    lanes' primitive counts), -1 for the other lanes: a node's leaves packed first fit,
    largest first, into groups of at most BVH_BLOCK_WIDTH primitives (a larger leaf alone), so
    that a group's record holds one block of each kind. Vectorised over the nodes."""
    size = np.maximum(count, 0, dtype=np.int32)
    rows = np.arange(len(count))
    order = np.argsort(-size, axis=1, kind="stable")
    fill = np.zeros(count.shape, np.int32)
    group = np.full(count.shape, -1, np.int32)
    for position in range(count.shape[1]):
        lane = order[:, position]
        lane_size = size[rows, lane]
        if not lane_size.any():  # (leaves come first: no node has more)
            break
        # (an empty group takes any leaf: one over BVH_BLOCK_WIDTH goes there alone)
        fits = (fill + lane_size[:, None] <= BVH_BLOCK_WIDTH) | (fill == 0)
        first_fit = np.argmax(fits, axis=1)
        leaf = lane_size > 0
        group[rows[leaf], lane[leaf]] = first_fit[leaf]
        fill[rows[leaf], first_fit[leaf]] += lane_size[leaf]
    return group


# A triangle hit through the BVH is named on the device by quad_count + sphere_count + its
# block's word in the leaf records + its lane (kernels/geometry.h), an int: the records' words
# stay below this.
MAX_HIT_ID = 2**31 - 1 - BVH_BLOCK_WIDTH


def pack_bvh_leaves(
    nodes: np.ndarray,
    prims: np.ndarray,
    quads: np.ndarray,
    sphere_count: int,
    triangles: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The device's nodes and leaf records (kernels/scene_types.h, BVH leaf records) of a wide BVH
    whose leaves hold prims[child .. child + count - 1] (primitive ids: quads, spheres, then
    triangles). A node's leaves are grouped (_leaf_groups: at most BVH_BLOCK_WIDTH primitives a
    group, first fit) and the leaves of a group share a record: their triangles in
    TRIANGLE_BLOCK_DTYPE blocks, their quads in quad_block_dtype() blocks (each in lane and leaf
    order; unused lanes never hit, id -1), then their spheres' ids, as uint32 words, starting at
    a multiple of BVH_LEAF_ALIGN words; records in node and group order; every leaf lane of the
    group gets child = the record's first word and count = the three numbers packed by
    BVH_LEAF_FIELDS. NumPy over all leaves at once."""
    nodes = nodes.copy()
    quad_dtype = quad_block_dtype(BVH_BLOCK_WIDTH)
    first_triangle = len(quads) + sphere_count
    # The leaves in node and lane order (row-major, as boolean masks); a record per group of a
    # node's leaves (_leaf_groups), records in node and group order
    child, count = nodes["child"], nodes["count"]
    is_leaf = count > 0
    group_key = (np.arange(len(nodes))[:, None] * BVH_WIDTH + _leaf_groups(count))[is_leaf]
    used = np.zeros(len(nodes) * BVH_WIDTH + 1, bool)
    used[group_key] = True
    record_of_leaf = (np.cumsum(used) - 1)[group_key]
    records = int(np.count_nonzero(used))
    # Leaves by record, in lane order within it
    by_record = np.argsort(record_of_leaf, kind="stable")
    start = child[is_leaf][by_record].astype(np.int64)
    leaf_count = count[is_leaf][by_record].astype(np.int64)
    # Every record's members, its leaves' primitives in lane and leaf order
    first_member = np.cumsum(leaf_count) - leaf_count
    ids = prims[np.arange(int(leaf_count.sum())) + np.repeat(start - first_member, leaf_count)]
    record_of = np.repeat(record_of_leaf[by_record], leaf_count)
    # Members by kind, each keeping its order within the record
    is_triangle = ids >= first_triangle
    is_quad = ids < len(quads)
    triangle_ids, quad_ids = ids[is_triangle], ids[is_quad]
    sphere_ids = ids[~(is_triangle | is_quad)]
    triangle_rank, triangles_per = _ranks_within(record_of[is_triangle], records)
    quad_rank, quads_per = _ranks_within(record_of[is_quad], records)
    sphere_rank, spheres_per = _ranks_within(record_of[~(is_triangle | is_quad)], records)
    triangle_blocks = -(-triangles_per // BVH_BLOCK_WIDTH)
    quad_blocks = -(-quads_per // BVH_BLOCK_WIDTH)
    packed = (triangle_blocks, quad_blocks, spheres_per)
    fields = np.zeros(records, np.int64)
    for value, (shift, bits) in zip(packed, BVH_LEAF_FIELDS, strict=True):
        if records and value.max() >= 2**bits:
            raise ClrenderError(
                f"BVH: a leaf of {int(leaf_count.max())} primitives in one place, more than the "
                "device's leaf records hold: spread out the coincident shapes"
            )
        fields |= value << shift
    # Each record: triangle blocks, quad blocks, sphere ids (padded to BVH_LEAF_ALIGN)
    triangle_words = TRIANGLE_BLOCK_DTYPE.itemsize // 4
    quad_words = quad_dtype.itemsize // 4
    size = triangle_words * triangle_blocks + quad_words * quad_blocks + spheres_per
    size = -(-size // BVH_LEAF_ALIGN) * BVH_LEAF_ALIGN
    if first_triangle + int(size.sum()) > MAX_HIT_ID:
        raise ClrenderError(
            f"BVH: {len(triangles):,} triangles and {len(quads):,} quads need "
            f"{int(size.sum()):,} words of leaf records, beyond the {MAX_HIT_ID:,} the device's "
            "32-bit hit ids address: use fewer triangles"
        )
    offset = np.cumsum(size) - size
    quads_at = offset + triangle_words * triangle_blocks
    spheres_at = quads_at + quad_words * quad_blocks
    words = np.zeros(int(size.sum()), np.uint32)
    # Triangle blocks: p0, p1, p2, material, normals, emitter (a Triangle's 12 words), id; unused
    # lanes id -1
    minus_one = np.uint32(0xFFFFFFFF)
    triangle_rows = np.ascontiguousarray(triangles, TRIANGLE_DTYPE).view(np.uint32)
    triangle_rows = triangle_rows.reshape(len(triangles), TRIANGLE_DTYPE.itemsize // 4)
    member_at = (record_of[is_triangle], triangle_rank)
    rows = (
        (0, triangle_rows, triangle_ids - first_triangle, np.zeros(12, np.uint32)),
        (12, triangle_ids.astype(np.uint32)[:, None], None, np.array([minus_one])),
    )
    _write_record_blocks(words, triangle_blocks, offset, triangle_words, member_at, rows)
    # Quad blocks: corner, normal, u_dual, v_dual, plane_d, quad id (lower and upper unused);
    # unused lanes id -1, plane_d -1 with a zero normal (t = -inf, never a hit)
    quad_names = ("corner", "normal", "u_dual", "v_dual", "plane_d")
    quad = quads[quad_ids]
    values = np.empty((len(quad_ids), 14), np.uint32)
    values[:, :12] = np.concatenate([quad[name] for name in quad_names[:4]], axis=1).view(np.uint32)
    values[:, 12] = quad["plane_d"].view(np.uint32)
    values[:, 13] = quad_ids
    unused = np.zeros(14, np.uint32)
    unused[12] = np.float32(-1.0).view(np.uint32)
    unused[13] = minus_one
    member_at = (record_of[is_quad], quad_rank)
    rows = ((0, values, None, unused),)
    _write_record_blocks(words, quad_blocks, quads_at, quad_words, member_at, rows)
    # Sphere ids
    words[spheres_at[record_of[~(is_triangle | is_quad)]] + sphere_rank] = sphere_ids
    # Every leaf lane: its record's first word and packed counts
    child[is_leaf] = offset[record_of_leaf]
    count[is_leaf] = fields[record_of_leaf]
    return nodes, words


def scene_bounds(
    quads: np.ndarray, spheres: np.ndarray, triangles: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box (low, high, float64) of packed quads, spheres and triangles; zeros when
    empty."""
    if triangles is not None and len(triangles):
        lower, upper = primitive_bounds(quads, spheres, triangles)
        return lower.min(axis=0), upper.max(axis=0)
    points = []
    for quad in quads:
        c, e1, e2 = (quad[k].astype(np.float64) for k in QUAD_FRAME)
        points += [c, c + e1, c + e2, c + e1 + e2]
    for sphere in spheres:
        r = float(sphere["radius"])
        points += [sphere["center"] - r, sphere["center"] + r]
    if not points:
        return np.zeros(3), np.zeros(3)
    stacked = np.array(points, np.float64)
    return stacked.min(axis=0), stacked.max(axis=0)


# --------------------------------------------------------------------------- quad blocks


def quad_groups(names: list[str]) -> list[int]:
    """Group number of each quad: consecutive quads named "object/part" (a box's faces) share
    one; every other quad is a group of its own."""
    groups: list[int] = []
    previous = None
    for name in names:
        prefix = name.rsplit("/", 1)[0] if "/" in name else None
        if groups and prefix is not None and prefix == previous:
            groups.append(groups[-1])
        else:
            groups.append(groups[-1] + 1 if groups else 0)
        previous = prefix
    return groups


def plan_quad_blocks(groups: list[int], width: int = QUAD_BLOCK_WIDTH) -> list[list[int]]:
    """Quad indices of each block, in scene order: a group that does not fit in the current
    block's free lanes starts a new block (a group wider than a block fills whole blocks)."""
    blocks: list[list[int]] = []
    start = 0
    while start < len(groups):
        end = start
        while end < len(groups) and groups[end] == groups[start]:
            end += 1
        members = list(range(start, end))
        if not blocks or (len(blocks[-1]) + len(members) > width and len(members) <= width):
            blocks.append([])
        for index in members:
            if len(blocks[-1]) == width:
                blocks.append([])
            blocks[-1].append(index)
        start = end
    return blocks


def pack_quad_blocks(
    quads: np.ndarray,
    width: int = QUAD_BLOCK_WIDTH,
    groups: list[int] | None = None,
    padding: float = 0.0,
) -> np.ndarray:
    """The quads in blocks of `width` lanes (structure of arrays), grouped as
    plan_quad_blocks says (default: in order, each quad its own group); unused lanes never
    hit (zero normal, plane_d = -1, so t = -inf; quad -1). Each block carries the bounding box
    of its quads, padded by `padding` and rounded outwards to float32; lower[3] = 1 flags a
    block whose box fills most (BLOCK_BOUNDS_SKIP_FILL) of the volume of all blocks' boxes
    (the enclosing walls): the kernel skips its box test, which nearly every ray passes."""
    if groups is None:
        groups = list(range(len(quads)))
    plan = plan_quad_blocks(groups, width)
    blocks = np.zeros(len(plan), quad_block_dtype(width))
    for block, members in zip(blocks, plan, strict=True):
        block["quad"][:] = -1
        block["plane_d"][len(members) :] = -1.0
        corners = []
        for lane, i in enumerate(members):
            quad = quads[i]
            for key in ("corner", "normal", "u_dual", "v_dual"):
                block[key][:, lane] = quad[key]
            block["plane_d"][lane] = quad["plane_d"]
            block["quad"][lane] = i
            c, e1, e2 = (quad[k].astype(np.float64) for k in QUAD_FRAME)
            corners += [c, c + e1, c + e2, c + e1 + e2]
        stacked = np.array(corners)
        lower = (stacked.min(axis=0) - padding).astype(np.float32)
        upper = (stacked.max(axis=0) + padding).astype(np.float32)
        block["lower"][:3] = np.nextafter(lower, np.float32(-np.inf))
        block["upper"][:3] = np.nextafter(upper, np.float32(np.inf))
    if len(blocks):
        lower = blocks["lower"][:, :3].astype(np.float64)
        upper = blocks["upper"][:, :3].astype(np.float64)
        volumes = np.prod(upper - lower, axis=1)
        whole = np.prod(upper.max(axis=0) - lower.min(axis=0))
        blocks["lower"][:, 3] = volumes >= BLOCK_BOUNDS_SKIP_FILL * whole
    return blocks


def pack_scene_quad_blocks(
    quads: np.ndarray, spheres: np.ndarray, quad_names: list[str], width: int = QUAD_BLOCK_WIDTH
) -> np.ndarray:
    """A scene's QuadBlock array: each box's faces in one block (quad_groups of the names),
    boxes padded by BLOCK_BOUNDS_PADDING of the scene's diagonal."""
    low, high = scene_bounds(quads, spheres)
    padding = BLOCK_BOUNDS_PADDING * max(float(np.linalg.norm(high - low)), 1e-30)
    return pack_quad_blocks(quads, width, quad_groups(quad_names), padding)
