// Scene records shared with the host: clrender/scene_device.py mirrors each struct field by field
// as a NumPy dtype and packs the records. Change both files together.
// Only 4-byte members and float[3] (never float3, which takes 16 bytes): the layout is the same
// on the host and on every device. Read vectors with Load3(record->member) (kernels/vecmath.h).
#ifndef CLRENDER_SCENE_TYPES_H
#define CLRENDER_SCENE_TYPES_H

// Material type tags (scene_device.MATERIAL_TYPES); MATERIAL_NONE marks a pure emitter.
#define MATERIAL_NONE -1
#define MATERIAL_DIFFUSE 0
#define MATERIAL_DIELECTRIC 1
#define MATERIAL_ROUGHCONDUCTOR 2

// A parallelogram corner + a edge1 + b edge2, (a, b) in [0, 1]^2. The unit normal is along
// cross(edge1, edge2) (the front side); for a point q, a = dot(q - corner, u_dual) and
// b = dot(q - corner, v_dual); plane_d = dot(normal, corner).
typedef struct {
    float corner[3];
    float edge1[3];
    float edge2[3];
    float normal[3];
    float u_dual[3];
    float v_dual[3];
    float plane_d;
    int material; // index into the materials, or MATERIAL_NONE
    int emitter;  // index into the emitters, or -1
} Quad;

// The same quads for intersection, QUAD_BLOCK_WIDTH at a time (structure of arrays, so one
// ray is tested against a whole block with vector instructions). Unused lanes at the end have
// a zero normal and plane_d = -1: t = -inf, never a hit. Lane j of the block is scene quad
// quad[j] (-1 for unused lanes); the faces of one object (a box) share a block, so a ray that
// misses the block's bounding box (lower, upper: padded outwards) skips them all; lower[3] = 1
// flags a block whose box holds the whole scene (the room's walls): no box test.
// (Width 16 crashes the LLVM 14 of pip's PoCL 3.0: "Cannot emit physreg copy instruction".)
#define QUAD_BLOCK_WIDTH 8
typedef struct {
    float corner[3][QUAD_BLOCK_WIDTH];
    float normal[3][QUAD_BLOCK_WIDTH];
    float u_dual[3][QUAD_BLOCK_WIDTH];
    float v_dual[3][QUAD_BLOCK_WIDTH];
    float plane_d[QUAD_BLOCK_WIDTH];
    int quad[QUAD_BLOCK_WIDTH];
    float lower[4];
    float upper[4];
} QuadBlock;

typedef struct {
    float center[3];
    float radius;
    int material;
    int emitter; // index into the emitters, or -1
} Sphere;

// A triangle p0, p1, p2; its front side is counter-clockwise: geometric normal along
// cross(p1 - p0, p2 - p0) (pbrt's convention). normals indexes its three per-vertex shading
// normals in the TriangleNormals array, or is -1 (shading normal = geometric normal).
typedef struct {
    float p0[3];
    float p1[3];
    float p2[3];
    int material; // index into the materials, or MATERIAL_NONE
    int normals;  // index into the triangle normals, or -1
    int emitter;  // index into the emitters, or -1
} Triangle;

// Unit shading normals at a triangle's p0, p1, p2.
typedef struct {
    float n[3][3];
} TriangleNormals;

// A node of the bounding volume hierarchy (clrender/bvh.py: over the primitives but up to
// BVH_MAX_BRUTE_QUADS quads, which are tested beside it; a binary SAH
// tree collapsed to BVH_WIDTH children a node), the root first. Its children's boxes are stored
// as structure of arrays (one vector slab test for all of them), rounded outwards to float.
// Child lane j: count[j] = 0, an interior node at child[j]; count[j] > 0, a leaf, whose
// primitives are in the record of its group of leaves at word child[j] of bvh_prims (leaf
// records below; the leaf lanes of a group have the same child and count); count[j] = -1, no
// child. Nodes are in depth-first order.
// Traversal keeps a private stack of at most BVH_STACK_SIZE nodes: BVH_WIDTH - 1 per level of
// a tree the builder never makes deeper than BVH_MAX_DEPTH.
#define BVH_WIDTH 8
// A scene with a BVH keeps its quads out of it, tested by brute force beside it (its quad
// blocks, as without a BVH), while it has at most this many (kernels/geometry.h).
#define BVH_MAX_BRUTE_QUADS 64
#define BVH_MAX_DEPTH 40
#define BVH_STACK_SIZE ((BVH_WIDTH - 1) * BVH_MAX_DEPTH)
typedef struct {
    float lower[3][BVH_WIDTH];
    float upper[3][BVH_WIDTH];
    int child[BVH_WIDTH];
    int count[BVH_WIDTH];
} BVHNode;

// Up to BVH_BLOCK_WIDTH triangles of a BVH leaf as structure of arrays (one vector watertight
// test for all of them): vertex coordinates p0[axis][lane], ..., then what the hit's surface
// needs besides them (the Triangle's material, normals and emitter: Scene_Surface reads the
// block the traversal has just tested, not the Triangle), and the scene primitive id of each
// lane (-1: an unused lane, all vertices 0, never a hit). 104 words: blocks start at multiples
// of 8 words (as records), so a lane's hit id is its block's word + the lane.
#define BVH_BLOCK_WIDTH 8
typedef struct {
    float p0[3][BVH_BLOCK_WIDTH];
    float p1[3][BVH_BLOCK_WIDTH];
    float p2[3][BVH_BLOCK_WIDTH];
    int material[BVH_BLOCK_WIDTH];
    int normals[BVH_BLOCK_WIDTH];
    int emitter[BVH_BLOCK_WIDTH];
    int id[BVH_BLOCK_WIDTH];
} TriangleBlock;

// The record of a group of a node's leaves in bvh_prims (32-bit words; clrender/scene_device.py
// pack_bvh_leaves groups a node's leaves into records of at most BVH_BLOCK_WIDTH primitives,
// first fit), at word child[j] (a multiple of 8: 32 bytes) of the group's leaf lanes: their
// triangles in TriangleBlocks, their quads in QuadBlocks (unused lanes as in brute force's;
// bounds unused), then their spheres' primitive ids; floats stored as their bits. The lanes'
// count[j] packs the three numbers. Lanes with the same child share the record.
#define BVH_LEAF_TRIANGLE_BLOCKS(count) ((count) & 0xffff)
#define BVH_LEAF_QUAD_BLOCKS(count) (((count) >> 16) & 0xff)
#define BVH_LEAF_SPHERES(count) ((count) >> 24)

// One record for every material type; each type reads its own members.
typedef struct {
    int type;
    int two_sided;   // diffuse, roughconductor: 0 = a back-side hit is black
    float albedo[3]; // diffuse reflectance
    float eta[3];    // dielectric: interior ior (all three equal); conductor: real ior
    float k[3];      // conductor: imaginary ior
    float alpha;     // roughconductor: GGX alpha (the microfacet alpha itself)
} Material;

// Emitter shape kinds (scene_device.EMITTER_SHAPES).
#define EMITTER_QUAD 0
#define EMITTER_SPHERE 1
#define EMITTER_TRIANGLE 2

// An emitting quad, sphere or mesh triangle; area is its surface area (a sphere's 4 pi r^2),
// pick_pdf its selection probability (proportional to power: area x mean radiance) and pick_cdf
// the upper end of its interval in the selection CDF (non-decreasing, the last one 1).
typedef struct {
    int shape; // EMITTER_QUAD, EMITTER_SPHERE or EMITTER_TRIANGLE
    int index; // the emitting quad's, sphere's or triangle's index
    float radiance[3];
    float area;
    float pick_pdf;
    float pick_cdf;
} Emitter;

// Pinhole camera: the ray through normalised image coordinates (sx, sy) in [-1, 1]^2, sx to
// the right and sy up, has direction forward + sx right + sy up (right and up are scaled).
typedef struct {
    float origin[3];
    float forward[3];
    float right[3];
    float up[3];
} Camera;

// The scene as the device functions see it (private; built in the kernel from its arguments).
// Primitive ids: quads 0 .. quad_count - 1, then spheres, then triangles.
typedef struct {
    __global const Quad *quads;
    __global const QuadBlock *quad_blocks;
    __global const Sphere *spheres;
    __global const Material *materials;
    __global const Emitter *emitters;
    __global const Triangle *triangles;
    __global const TriangleNormals *triangle_normals;
    __global const BVHNode *bvh_nodes;
    __global const uint *bvh_prims; // the BVH leaves' records
    uint quad_count;
    uint quad_block_count;
    uint sphere_count;
    uint emitter_count;
    uint triangle_count;
    uint bvh_node_count; // 0: brute force over every primitive (small scenes)
} SceneData;

// The SceneData of a kernel whose arguments carry the scene under these names (the path
// tracer's kernels: integrator.cl, wavefront.cl; the host passes them in
// PathTracer.scene_arguments' order).
#define SCENE_DATA_OF_ARGUMENTS                                                                \
    {.quads = quads, .quad_blocks = quad_blocks, .spheres = spheres, .materials = materials,  \
     .emitters = emitters, .triangles = triangles, .triangle_normals = triangle_normals,       \
     .bvh_nodes = bvh_nodes, .bvh_prims = bvh_prims, .quad_count = quad_count,                \
     .quad_block_count = quad_block_count, .sphere_count = sphere_count,                      \
     .emitter_count = emitter_count, .triangle_count = triangle_count,                        \
     .bvh_node_count = bvh_node_count}

#endif
