// Ray-primitive intersection. Small scenes: every block of quads (one vector test per block)
// whose bounding box the ray meets, then every sphere, then every triangle. Larger scenes
// (bvh_node_count > 0): a bounding volume hierarchy (clrender/bvh.py) over the spheres, the
// triangles and the quads unless there are at most BVH_MAX_BRUTE_QUADS (those are tested by
// brute force beside it), traversed with a private stack after a test of the root's children
// (most rays around a mesh reach none); a node's leaves the ray reaches are tested nearest first
// (shadow rays: in lane order), each group of leaves' record once (triangles and quads 8 at a
// time).
// Primitive ids: quads are 0 .. quad_count-1, sphere s is quad_count + s, triangle k is
// quad_count + sphere_count + k. Hit ids (Scene_Intersect's): -1 is a miss; primitive ids, but
// for a triangle found through the BVH: quad_count + sphere_count + the word of its leaf block
// in bvh_prims + its lane (Scene_Surface reads the block, Scene_HitPrimitive its primitive id).
// With a BVH nothing here reads scene->triangles (a scene without emitting triangles gets
// none: clrender/trace.py device_triangles); lights.h reads the emitting ones.
#ifndef CLRENDER_GEOMETRY_H
#define CLRENDER_GEOMETRY_H

#include "scene_types.h"
#include "vecmath.h"

// A surface point found by a ray: position, geometric normal (the quad's and the triangle's
// front side, the sphere's outside), shading normal (the triangle's interpolated vertex normal
// turned to the side of ng; ng elsewhere), material and emitter, and a bound on p's distance
// from the true surface (float rounding), which is how far rays leaving it start off the surface.
typedef struct {
    float3 p;
    float3 ng;
    float3 ns;
    int material;
    int emitter;
    float error;
} Surface;

// Float rounding of a computed surface point, per unit of the magnitudes that enter it (the
// ray origin, the distance travelled, the primitive's position and size): a few dozen float
// epsilons (pbrt-v4 bounds the same error operation by operation). It follows the point's own
// magnitude, never the scene's extent: far-away objects do not push every ray off its surface.
#define SURFACE_ERROR_SCALE (32.0f * FLT_EPSILON)

CL_INLINE float MaxAbs3(float3 v)
{
    return Fmax(Fabs(v.x), Fmax(Fabs(v.y), Fabs(v.z)));
}

// Bit j set where lane j of the mask is set (-1): one instruction with AVX (the sign bits),
// else a reduction.
CL_INLINE uint Lanes_Bits(int8 mask)
{
#if defined(__AVX__)
    return (uint)__builtin_ia32_movmskps256(as_float8(mask));
#else
    int8 bits = mask & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    int4 b4 = bits.lo | bits.hi;
    int2 b2 = b4.lo | b4.hi;
    return (uint)(b2.x | b2.y);
#endif
}

// 8 ints from a 4-byte aligned address.
typedef int Int8Unaligned __attribute__((ext_vector_type(8), aligned(4)));

CL_INLINE int8 Load8Int(__global const int *p)
{
    return *(__global const Int8Unaligned *)p;
}

// Whether the ray o + t d (inv_d = 1 / d) can meet the box [lower, upper] for some t in
// [0, tmax] (slab test). A NaN (zero direction on a slab's plane) never rejects.
CL_INLINE bool Bounds_Hit(__global const float *lower, __global const float *upper, float3 o,
                          float3 inv_d, float tmax)
{
    float3 t0 = (Load3(lower) - o) * inv_d;
    float3 t1 = (Load3(upper) - o) * inv_d;
    float3 t_near = t0 < t1 ? t0 : t1;
    float3 t_far = t0 < t1 ? t1 : t0;
    float t_enter = t_near.x > t_near.y ? t_near.x : t_near.y;
    t_enter = t_enter > t_near.z ? t_enter : t_near.z;
    float t_exit = t_far.x < t_far.y ? t_far.x : t_far.y;
    t_exit = t_exit < t_far.z ? t_exit : t_far.z;
    return !(t_enter > t_exit || t_exit < 0.0f || t_enter > tmax);
}

// Whether the ray can meet the block's bounding box before tmax. Always true for a block
// flagged as enclosing the scene (lower[3] = 1: every ray meets it).
CL_INLINE bool QuadBlock_BoundsHit(__global const QuadBlock *block, float3 o, float3 inv_d,
                                   float tmax)
{
    if (block->lower[3] != 0.0f)
        return true;
    return Bounds_Hit(block->lower, block->upper, o, inv_d, tmax);
}

// Hit mask of a block's quads along the ray before tmax (-1 where hit), and distances in *t.
CL_INLINE int8 QuadBlock_Hits(__global const QuadBlock *block, float3 o, float3 d, float tmax,
                              float8 *t_out)
{
    float8 nx = Load8(block->normal[0]);
    float8 ny = Load8(block->normal[1]);
    float8 nz = Load8(block->normal[2]);
    float8 t = (Load8(block->plane_d) - (nx * o.x + ny * o.y + nz * o.z)) /
               (nx * d.x + ny * d.y + nz * d.z);
    float8 rx = o.x + t * d.x - Load8(block->corner[0]);
    float8 ry = o.y + t * d.y - Load8(block->corner[1]);
    float8 rz = o.z + t * d.z - Load8(block->corner[2]);
    float8 a = rx * Load8(block->u_dual[0]) + ry * Load8(block->u_dual[1]) +
               rz * Load8(block->u_dual[2]);
    float8 b = rx * Load8(block->v_dual[0]) + ry * Load8(block->v_dual[1]) +
               rz * Load8(block->v_dual[2]);
    *t_out = t;
    return (t > 0.0f) & (t < tmax) & (a >= 0.0f) & (a <= 1.0f) & (b >= 0.0f) & (b <= 1.0f);
}

// The nearest quad of a block hit before tmax: its distance (tmax if none) and lane in *lane.
CL_INLINE float QuadBlock_Intersect(__global const QuadBlock *block, float3 o, float3 d,
                                    float tmax, int *lane)
{
    float8 t;
    int8 hit = QuadBlock_Hits(block, o, d, tmax, &t);
    float8 t_hit = hit ? t : (float8)(INFINITY);
    float t_min = Lanes_Min(t_hit);
    *lane = Ctz(Lanes_Bits(t_hit == t_min) | (1u << QUAD_BLOCK_WIDTH));
    return t_min < tmax ? t_min : tmax;
}

// Whether any quad of a block lies along the ray before tmax.
CL_INLINE bool QuadBlock_Occluded(__global const QuadBlock *block, float3 o, float3 d,
                                  float tmax)
{
    float8 t;
    return Lanes_Bits(QuadBlock_Hits(block, o, d, tmax, &t)) != 0u;
}

// Distance along d (unit) to the nearest sphere crossing ahead, or tmax.
// (Ray Tracing Gems, ch. 7: discriminant from the closest-approach vector, stable roots.)
CL_INLINE float Sphere_Intersect(__global const Sphere *s, float3 o, float3 d, float tmax)
{
    float3 oc = o - Load3(s->center);
    float r = s->radius;
    float b = Dot3(oc, d);
    float3 f = oc - b * d;
    float disc = r * r - Dot3(f, f);
    if (disc < 0.0f)
        return tmax;
    float c = Dot3(oc, oc) - r * r;
    float q = -b - Copysign(Sqrt(disc), b);
    float t0 = c / q;
    float t1 = q;
    float tnear = Fmin(t0, t1);
    float tfar = Fmax(t0, t1);
    float t = tnear > 0.0f ? tnear : tfar;
    return (t > 0.0f && t < tmax) ? t : tmax;
}

// A ray prepared for watertight triangle tests (Woop, Benthin and Wald 2013, as pbrt-v4):
// its origin, the axis permutation that makes the largest direction component z, and the
// shear taking the direction to +z.
typedef struct {
    float3 o;
    uint kz;      // the permuted z axis; x and y follow it cyclically
    float3 shear;      // (-dx / dz, -dy / dz, 1 / dz) after permutation
    float3 o_permuted; // o with its axes permuted (TriangleBlock_Hits subtracts it by axis)
} TriangleRay;

// v with its axes permuted so that axis kz comes last (kx = kz + 1, ky = kz + 2, cyclically):
// swizzles and selects, no shuffle() (a builtin PoCL does not inline: see vecmath.h).
CL_INLINE float3 TriangleRay_Permute(float3 v, uint kz)
{
    return kz == 0u ? v.yzx : (kz == 1u ? v.zxy : v);
}

CL_INLINE TriangleRay TriangleRay_Make(float3 o, float3 d)
{
    TriangleRay r;
    // z: the axis of the largest direction component; x and y follow it cyclically
    float ax = Fabs(d.x);
    float ay = Fabs(d.y);
    float az = Fabs(d.z);
    uint kz = ax > ay ? (ax > az ? 0u : 2u) : (ay > az ? 1u : 2u);
    float3 dp = TriangleRay_Permute(d, kz);
    r.o = o;
    r.kz = kz;
    r.shear = (float3)(-dp.x / dp.z, -dp.y / dp.z, 1.0f / dp.z);
    r.o_permuted = TriangleRay_Permute(o, kz);
    return r;
}

// A triangle vertex in the ray's frame: translated to the origin, permuted, sheared (x, y);
// z is left unscaled.
CL_INLINE float3 TriangleRay_Vertex(const TriangleRay *r, float3 p)
{
    float3 v = TriangleRay_Permute(p - r->o, r->kz);
    return (float3)(v.x + r->shear.x * v.z, v.y + r->shear.y * v.z, v.z);
}

// Edge function of the ray's origin against the edge a -> b: the two products rounded apart,
// so that the neighbour across a shared edge gets exactly the opposite value (watertight).
CL_INLINE float Triangle_Edge(float3 a, float3 b)
{
    float p = a.x * b.y;
    float q = a.y * b.x;
    return p - q;
}

// Whether the ray meets the triangle (v0, v1, v2) at a distance in (0, tmax): the distance in
// *t and the barycentric coordinates of v0, v1, v2 in *b.
CL_INLINE bool Triangle_HitVertices(float3 v0, float3 v1, float3 v2, const TriangleRay *r,
                                    float tmax, float *t, float3 *b)
{
    float3 p0 = TriangleRay_Vertex(r, v0);
    float3 p1 = TriangleRay_Vertex(r, v1);
    float3 p2 = TriangleRay_Vertex(r, v2);
    // Edge functions: the origin is inside when all three share a sign
    float e0 = Triangle_Edge(p1, p2);
    float e1 = Triangle_Edge(p2, p0);
    float e2 = Triangle_Edge(p0, p1);
    if ((e0 < 0.0f || e1 < 0.0f || e2 < 0.0f) && (e0 > 0.0f || e1 > 0.0f || e2 > 0.0f))
        return false;
    float det = e0 + e1 + e2;
    if (det == 0.0f)
        return false;
    // Scaled distance, compared with the range before dividing by det
    float t_scaled = r->shear.z * (e0 * p0.z + e1 * p1.z + e2 * p2.z);
    if (det < 0.0f ? (t_scaled >= 0.0f || t_scaled < tmax * det)
                   : (t_scaled <= 0.0f || t_scaled > tmax * det))
        return false;
    float inv_det = 1.0f / det;
    *t = t_scaled * inv_det;
    *b = (float3)(e0, e1, e2) * inv_det;
    return *t > 0.0f && *t < tmax;
}

// Triangle_HitVertices of a Triangle record.
CL_INLINE bool Triangle_Hit(__global const Triangle *tri, const TriangleRay *r, float tmax,
                            float *t, float3 *b)
{
    return Triangle_HitVertices(Load3(tri->p0), Load3(tri->p1), Load3(tri->p2), r, tmax, t, b);
}

// Distance to the triangle along the ray if hit before tmax, else tmax.
CL_INLINE float Triangle_Intersect(__global const Triangle *tri, const TriangleRay *r,
                                   float tmax)
{
    float t;
    float3 b;
    return Triangle_Hit(tri, r, tmax, &t, &b) ? t : tmax;
}

// One vertex row of a TriangleBlock in the ray's frame (TriangleRay_Vertex on 8 lanes, operation
// for operation): x and y sheared, z translated only.
CL_INLINE void TriangleBlock_Vertices(__global const float (*p)[BVH_BLOCK_WIDTH],
                                      const TriangleRay *r, float8 *x, float8 *y, float8 *z)
{
    uint kx = r->kz == 2u ? 0u : r->kz + 1u;
    uint ky = kx == 2u ? 0u : kx + 1u;
    float8 vx = Load8(p[kx]) - r->o_permuted.x;
    float8 vy = Load8(p[ky]) - r->o_permuted.y;
    float8 vz = Load8(p[r->kz]) - r->o_permuted.z;
    *x = vx + r->shear.x * vz;
    *y = vy + r->shear.y * vz;
    *z = vz;
}

// Edge functions of the 8 lanes (Triangle_Edge: the two products rounded apart).
CL_INLINE float8 TriangleBlock_Edge(float8 ax, float8 ay, float8 bx, float8 by)
{
    float8 p = ax * by;
    float8 q = ay * bx;
    return p - q;
}

// Hit mask of a block's triangles along the ray in (0, tmax) (-1 where hit), distances in *t:
// Triangle_Hit's watertight test on 8 lanes with the same operations, so the same decisions.
CL_INLINE int8 TriangleBlock_Hits(__global const TriangleBlock *block, const TriangleRay *r,
                                  float tmax, float8 *t_out)
{
    float8 x0, y0, z0, x1, y1, z1, x2, y2, z2;
    TriangleBlock_Vertices(block->p0, r, &x0, &y0, &z0);
    TriangleBlock_Vertices(block->p1, r, &x1, &y1, &z1);
    TriangleBlock_Vertices(block->p2, r, &x2, &y2, &z2);
    // Edge functions: the origin is inside when all three share a sign
    float8 e0 = TriangleBlock_Edge(x1, y1, x2, y2);
    float8 e1 = TriangleBlock_Edge(x2, y2, x0, y0);
    float8 e2 = TriangleBlock_Edge(x0, y0, x1, y1);
    int8 negative = (e0 < 0.0f) | (e1 < 0.0f) | (e2 < 0.0f);
    int8 positive = (e0 > 0.0f) | (e1 > 0.0f) | (e2 > 0.0f);
    float8 det = e0 + e1 + e2;
    // Scaled distance, compared with the range before dividing by det
    float8 t_scaled = r->shear.z * (e0 * z0 + e1 * z1 + e2 * z2);
    float8 t_range = tmax * det;
    int8 outside = det < 0.0f ? (t_scaled >= 0.0f) | (t_scaled < t_range)
                              : (t_scaled <= 0.0f) | (t_scaled > t_range);
    int8 inside = ~(negative & positive) & (det != 0.0f) & ~outside;
    // No lane left: no division (the usual case; the same decisions)
    if (Lanes_Bits(inside) == 0u) {
        *t_out = t_scaled;
        return inside;
    }
    float8 t = t_scaled * (1.0f / det);
    *t_out = t;
    return inside & (t > 0.0f) & (t < tmax);
}

// The nearest triangle of a block hit before tmax: its distance (tmax if none) and its hit id
// in *id, hit_base (the block's lane 0's) + its lane (unchanged if none).
CL_INLINE float TriangleBlock_Intersect(__global const TriangleBlock *block, const TriangleRay *r,
                                        float tmax, int hit_base, int *id)
{
    float8 t;
    int8 hit = TriangleBlock_Hits(block, r, tmax, &t);
    float8 t_hit = hit ? t : (float8)(INFINITY);
    float t_min = Lanes_Min(t_hit);
    if (!(t_min < tmax))
        return tmax;
    *id = hit_base + (int)Ctz(Lanes_Bits(t_hit == t_min));
    return t_min;
}

// Words of a TriangleBlock in bvh_prims.
#define TRIANGLE_BLOCK_WORDS ((int)(sizeof(TriangleBlock) / sizeof(uint)))

// The nearest primitive of a group of a node's leaves (the group's record at word `record` of
// bvh_prims, `count` as their lanes') along the ray before *t: triangles and quads a block at a
// time, then spheres one by one; *t and *id (a hit id) updated if one is closer. With any_hit,
// stops at the first hit.
CL_INLINE void BVHLeaves_Intersect(const SceneData *scene, uint record, int count, float3 o,
                                   float3 d, const TriangleRay *r, bool any_hit, float *t, int *id)
{
    // Triangle blocks
    __global const TriangleBlock *triangles =
        (__global const TriangleBlock *)(scene->bvh_prims + record);
    int triangle_blocks = BVH_LEAF_TRIANGLE_BLOCKS(count);
    int hit_base = (int)(scene->quad_count + scene->sphere_count + record);
    for (int b = 0; b < triangle_blocks; ++b) {
        int block_hit_base = hit_base + b * TRIANGLE_BLOCK_WORDS;
        *t = TriangleBlock_Intersect(&triangles[b], r, *t, block_hit_base, id);
        if (any_hit && *id >= 0)
            return;
    }
    // Quad blocks
    __global const QuadBlock *quads = (__global const QuadBlock *)(triangles + triangle_blocks);
    int quad_blocks = BVH_LEAF_QUAD_BLOCKS(count);
    for (int b = 0; b < quad_blocks; ++b) {
        int lane;
        float tb = QuadBlock_Intersect(&quads[b], o, d, *t, &lane);
        if (tb < *t) {
            *t = tb;
            *id = quads[b].quad[lane];
            if (any_hit)
                return;
        }
    }
    // Spheres
    __global const uint *spheres = (__global const uint *)(quads + quad_blocks);
    int sphere_count = BVH_LEAF_SPHERES(count);
    for (int k = 0; k < sphere_count; ++k) {
        uint p = spheres[k];
        float tp = Sphere_Intersect(&scene->spheres[p - scene->quad_count], o, d, *t);
        if (tp < *t) {
            *t = tp;
            *id = (int)p;
            if (any_hit)
                return;
        }
    }
}

// Distances at which the ray o + t d (inv_d = 1 / d) enters each child box of a node if it
// meets it within [0, tmax], else INFINITY (the slab test of Bounds_Hit, 8 boxes at once, the
// range [0, tmax] folded into the entry and exit: entries clamped to 0). A NaN (a zero direction
// component on a slab's plane) never rejects.
CL_INLINE float8 BVHNode_Enter(__global const BVHNode *node, float3 o, float3 inv_d, float tmax)
{
    float8 t0x = (Load8(node->lower[0]) - o.x) * inv_d.x;
    float8 t1x = (Load8(node->upper[0]) - o.x) * inv_d.x;
    float8 t0y = (Load8(node->lower[1]) - o.y) * inv_d.y;
    float8 t1y = (Load8(node->upper[1]) - o.y) * inv_d.y;
    float8 t0z = (Load8(node->lower[2]) - o.z) * inv_d.z;
    float8 t1z = (Load8(node->upper[2]) - o.z) * inv_d.z;
    float8 near_x = t0x < t1x ? t0x : t1x;
    float8 far_x = t0x < t1x ? t1x : t0x;
    float8 near_y = t0y < t1y ? t0y : t1y;
    float8 far_y = t0y < t1y ? t1y : t0y;
    float8 near_z = t0z < t1z ? t0z : t1z;
    float8 far_z = t0z < t1z ? t1z : t0z;
    // (a NaN on the left of each comparison drops out)
    float8 t_enter = near_x > 0.0f ? near_x : (float8)(0.0f);
    t_enter = near_y > t_enter ? near_y : t_enter;
    t_enter = near_z > t_enter ? near_z : t_enter;
    float8 t_exit = far_x < tmax ? far_x : (float8)(tmax);
    t_exit = far_y < t_exit ? far_y : t_exit;
    t_exit = far_z < t_exit ? far_z : t_exit;
    return t_enter > t_exit ? (float8)(INFINITY) : t_enter;
}

// The closest primitive in the BVH along the ray before tmax (ids as Scene_Intersect's), or,
// with any_hit, the first one found (shadow rays); root_enter is BVHNode_Enter of the root
// (BVH_RootReached: most rays around a mesh reach none of its children and never get here). At
// each node all children's boxes are tested at once; the leaves the ray reaches are tested right
// away, each group's shared record once (up to 8 primitives of a kind at a time:
// scene_device.pack_bvh_leaves), nearest first for the closest hit, in lane order for any hit;
// the nearest child node (any hit: the first) is visited next and the others kept on a private
// stack with their entry distances, nearest on top (skipped when taken if a closer hit was found
// since).
CL_INLINE float BVH_Traverse(const SceneData *scene, float3 o, float3 d, float3 inv_d,
                             float8 root_enter, float tmax, bool any_hit, int *prim)
{
    // Made at the first leaf (many rays reach none)
    TriangleRay r;
    bool r_made = false;
    uint stack[BVH_STACK_SIZE];
    float stack_enter[BVH_STACK_SIZE];
    int top = 0;
    float t = tmax;
    int id = -1;
    uint node_id = 0;
    union {
        float8 v;
        float s[BVH_WIDTH];
    } enter;
    enter.v = root_enter;
    for (;;) {
        __global const BVHNode *node = &scene->bvh_nodes[node_id];
        int8 count = Load8Int(node->count);
        int8 reached = enter.v < INFINITY;
        // The leaves the ray reaches, nearest first (any hit: in lane order), each while it is
        // nearer than the closest hit; a lone one (the usual case) without a search
        uint leaves = Lanes_Bits(reached & (count > 0));
        if (leaves != 0u && !r_made) {
            r = TriangleRay_Make(o, d);
            r_made = true;
        }
        float8 leaf_enter = (reached & (count > 0)) ? enter.v : (float8)(INFINITY);
        while (leaves != 0u) {
            int j = Ctz(leaves);
            if (!any_hit && (leaves & (leaves - 1u)) != 0u) {
                float leaf_nearest = Lanes_Min(leaf_enter);
                if (!(leaf_nearest <= t))
                    break;
                j = Ctz(Lanes_Bits(leaf_enter == leaf_nearest));
            } else if (!(enter.s[j] <= t)) {
                break;
            }
            // Its record, shared by the leaves of its group: tested once for all of them
            int record = node->child[j];
            int8 group = Load8Int(node->child) == record;
            leaf_enter = group ? (float8)(INFINITY) : leaf_enter;
            leaves &= ~Lanes_Bits(group);
            BVHLeaves_Intersect(scene, (uint)record, node->count[j], o, d, &r, any_hit, &t, &id);
            if (any_hit && id >= 0) {
                *prim = id;
                return t;
            }
        }
        // The child nodes it reaches before the closest hit: the nearest next (any hit: the
        // first; a lone one without a search), the others kept
        int8 inner = reached & (count == 0) & (enter.v <= t);
        uint others = Lanes_Bits(inner);
        if (others != 0u) {
            int j_near = Ctz(others);
            if (!any_hit && (others & (others - 1u)) != 0u) {
                float8 inner_enter = inner ? enter.v : (float8)(INFINITY);
                j_near = Ctz(Lanes_Bits(inner_enter == Lanes_Min(inner_enter)));
            }
            others &= ~(1u << j_near);
            int first = top;
            while (others != 0u) {
                int j = Ctz(others);
                others &= others - 1u;
                // Closest hit: kept farthest first, so the nearest is taken next (insertion
                // sort); any hit: in lane order
                float e = enter.s[j];
                uint c = (uint)node->child[j];
                int k = top++;
                while (!any_hit && k > first && stack_enter[k - 1] < e) {
                    stack[k] = stack[k - 1];
                    stack_enter[k] = stack_enter[k - 1];
                    --k;
                }
                stack[k] = c;
                stack_enter[k] = e;
            }
            node_id = (uint)node->child[j_near];
            enter.v = BVHNode_Enter(&scene->bvh_nodes[node_id], o, inv_d, t);
            continue;
        }
        // Next: the most recently kept node (the nearest of the last node's others, for the
        // closest hit) the ray can still reach before the closest hit
        bool visit = false;
        while (top > 0 && !visit) {
            --top;
            node_id = stack[top];
            visit = stack_enter[top] <= t;
        }
        if (!visit)
            break;
        enter.v = BVHNode_Enter(&scene->bvh_nodes[node_id], o, inv_d, t);
    }
    *prim = id;
    return t;
}

// The BVH's closest hit and any hit (shadow rays): the root's children tested first, then the
// traversal only if the ray reaches one. On PoCL (CLRENDER_BVH_CALLED, set by
// clrender/runtime.py build_options) they are called, not inlined (unlike every other device
// function): inlined into the path tracer, the traversal's code slowed the brute-force path
// sharing the kernel by about 5 % (bench/primitive_scaling.py; the root's test alone inlined,
// the Cornell boxes by 3 %), and the calls cost the BVH nothing measurable; the traversal is a
// second call (its set-up is skipped by the rays that reach none of the root's children: 77 %
// of closest-hit rays and 49 % of shadow rays around bvh_scaling.py's sphere). Elsewhere they
// are inlined: Intel's CPU runtime returns wrong hits from the called form (tests/test_bvh.py,
// tests/test_mesh_emitters.py fail there).
#ifdef CLRENDER_BVH_CALLED
#define BVH_FUNCTION __attribute__((noinline))
#else
#define BVH_FUNCTION CL_INLINE
#endif

// Whether the ray reaches any child of the BVH's root before tmax, their entries in *root_enter
// (BVHNode_Enter): the traversal's first step, taken before its call.
CL_INLINE bool BVH_RootReached(const SceneData *scene, float3 o, float3 inv_d, float tmax,
                               float8 *root_enter)
{
    *root_enter = BVHNode_Enter(&scene->bvh_nodes[0], o, inv_d, tmax);
    return Lanes_Bits(*root_enter < INFINITY) != 0u;
}

BVH_FUNCTION float BVH_IntersectFromRoot(const SceneData *scene, float3 o, float3 d, float3 inv_d,
                                         float8 root_enter, float tmax, int *prim)
{
    return BVH_Traverse(scene, o, d, inv_d, root_enter, tmax, false, prim);
}

BVH_FUNCTION bool BVH_OccludedFromRoot(const SceneData *scene, float3 o, float3 d, float3 inv_d,
                                       float8 root_enter, float tmax)
{
    int prim;
    BVH_Traverse(scene, o, d, inv_d, root_enter, tmax, true, &prim);
    return prim >= 0;
}

BVH_FUNCTION float BVH_Intersect(const SceneData *scene, float3 o, float3 d, float tmax, int *prim)
{
    float3 inv_d = 1.0f / d;
    float8 root_enter;
    *prim = -1;
    if (!BVH_RootReached(scene, o, inv_d, tmax, &root_enter))
        return tmax;
    return BVH_IntersectFromRoot(scene, o, d, inv_d, root_enter, tmax, prim);
}

BVH_FUNCTION bool BVH_Occluded(const SceneData *scene, float3 o, float3 d, float tmax)
{
    float3 inv_d = 1.0f / d;
    float8 root_enter;
    return BVH_RootReached(scene, o, inv_d, tmax, &root_enter) &&
           BVH_OccludedFromRoot(scene, o, d, inv_d, root_enter, tmax);
}

// Whether a scene's quads are tested by brute force (a block at a time): always without a BVH,
// and beside it while they are few (BVH_MAX_BRUTE_QUADS; clrender/scene_device.py pack_bvh
// leaves them out of the tree then).
CL_INLINE bool Scene_QuadsBruteForce(const SceneData *scene)
{
    return scene->bvh_node_count == 0u || scene->quad_count <= BVH_MAX_BRUTE_QUADS;
}

// The closest primitive along the ray before tmax: its distance, and its hit id in *prim.
// Brute force: ties go to the lowest quad index, then to the sphere, then to the triangle
// (blocks hold quads in scene order); the BVH's primitives lose ties with brute-force quads.
CL_INLINE float Scene_Intersect(const SceneData *scene, float3 o, float3 d, float tmax,
                                int *prim)
{
    float t = tmax;
    int id = -1;
    float3 inv_d = 1.0f / d;
    if (Scene_QuadsBruteForce(scene)) {
        for (uint b = 0; b < scene->quad_block_count; ++b) {
            __global const QuadBlock *block = &scene->quad_blocks[b];
            if (!QuadBlock_BoundsHit(block, o, inv_d, t))
                continue;
            int lane;
            float tb = QuadBlock_Intersect(block, o, d, t, &lane);
            if (tb < t) {
                id = block->quad[lane];
                t = tb;
            }
        }
    }
    if (scene->bvh_node_count > 0u) {
        int bvh_id;
        float tb = BVH_Intersect(scene, o, d, t, &bvh_id);
        *prim = bvh_id >= 0 ? bvh_id : id;
        return bvh_id >= 0 ? tb : t;
    }
    for (uint i = 0; i < scene->sphere_count; ++i) {
        float ti = Sphere_Intersect(&scene->spheres[i], o, d, t);
        id = ti < t ? (int)(scene->quad_count + i) : id;
        t = ti;
    }
    if (scene->triangle_count > 0u) {
        TriangleRay r = TriangleRay_Make(o, d);
        uint first = scene->quad_count + scene->sphere_count;
        for (uint k = 0; k < scene->triangle_count; ++k) {
            float tk = Triangle_Intersect(&scene->triangles[k], &r, t);
            id = tk < t ? (int)(first + k) : id;
            t = tk;
        }
    }
    *prim = id;
    return t;
}

// Whether anything lies along the ray closer than tmax (shadow rays): an any-hit query that
// returns at the first blocker. Brute force: spheres first, then the quad blocks from the
// last: scene files list the enclosing walls first and the objects inside later, and walls of
// a convex room never block a ray between two points inside it. With a BVH: its brute-force
// quads (so), then the BVH.
CL_INLINE bool Scene_Occluded(const SceneData *scene, float3 o, float3 d, float tmax)
{
    if (scene->bvh_node_count == 0u) {
        if (scene->triangle_count > 0u) {
            TriangleRay r = TriangleRay_Make(o, d);
            for (uint k = 0; k < scene->triangle_count; ++k) {
                if (Triangle_Intersect(&scene->triangles[k], &r, tmax) < tmax)
                    return true;
            }
        }
        for (uint i = 0; i < scene->sphere_count; ++i) {
            if (Sphere_Intersect(&scene->spheres[i], o, d, tmax) < tmax)
                return true;
        }
    }
    if (Scene_QuadsBruteForce(scene)) {
        float3 inv_d = 1.0f / d;
        for (uint b = scene->quad_block_count; b-- > 0u;) {
            __global const QuadBlock *block = &scene->quad_blocks[b];
            if (QuadBlock_BoundsHit(block, o, inv_d, tmax) &&
                QuadBlock_Occluded(block, o, d, tmax))
                return true;
        }
    }
    return scene->bvh_node_count > 0u && BVH_Occluded(scene, o, d, tmax);
}

// The surface record of a hit at distance t along the ray.
CL_INLINE Surface Scene_Surface(const SceneData *scene, float3 o, float3 d, float t, int prim)
{
    Surface s;
    if (prim < (int)scene->quad_count) {
        __global const Quad *q = &scene->quads[prim];
        s.p = o + t * d;
        s.ng = Load3(q->normal);
        s.ns = s.ng;
        s.material = q->material;
        s.emitter = q->emitter;
        // The plane distance and o + t d round at the magnitudes of o, t d and the corner
        float magnitude = MaxAbs3(o) + t * MaxAbs3(d) + MaxAbs3(Load3(q->corner));
        s.error = SURFACE_ERROR_SCALE * magnitude;
    } else if (prim < (int)(scene->quad_count + scene->sphere_count)) {
        __global const Sphere *sp = &scene->spheres[prim - (int)scene->quad_count];
        float3 center = Load3(sp->center);
        // Re-project the hit onto the sphere so the ray offset is measured from its surface
        s.ng = Normalize3(o + t * d - center);
        s.ns = s.ng;
        s.p = center + sp->radius * s.ng;
        s.material = sp->material;
        s.emitter = sp->emitter;
        s.error = SURFACE_ERROR_SCALE * (MaxAbs3(center) + sp->radius);
    } else {
        // The triangle's vertices and indices: from the BVH leaf block the traversal has just
        // tested (cached), else from the Triangle
        int k = prim - (int)(scene->quad_count + scene->sphere_count);
        float3 p0, p1, p2;
        int normals;
        if (scene->bvh_node_count > 0u) {
            __global const TriangleBlock *block =
                (__global const TriangleBlock *)(scene->bvh_prims + (k & -BVH_BLOCK_WIDTH));
            int lane = k & (BVH_BLOCK_WIDTH - 1);
            p0 = (float3)(block->p0[0][lane], block->p0[1][lane], block->p0[2][lane]);
            p1 = (float3)(block->p1[0][lane], block->p1[1][lane], block->p1[2][lane]);
            p2 = (float3)(block->p2[0][lane], block->p2[1][lane], block->p2[2][lane]);
            normals = block->normals[lane];
            s.material = block->material[lane];
            s.emitter = block->emitter[lane];
        } else {
            __global const Triangle *tri = &scene->triangles[k];
            p0 = Load3(tri->p0);
            p1 = Load3(tri->p1);
            p2 = Load3(tri->p2);
            normals = tri->normals;
            s.material = tri->material;
            s.emitter = tri->emitter;
        }
        // The hit's barycentric coordinates (the intersection test again, at no range limit)
        TriangleRay r = TriangleRay_Make(o, d);
        float th;
        float3 b = (float3)(1.0f / 3.0f);
        Triangle_HitVertices(p0, p1, p2, &r, INFINITY, &th, &b);
        // The point from the vertices: its rounding follows the vertices' magnitudes only
        s.p = b.x * p0 + b.y * p1 + b.z * p2;
        s.ng = Normalize3(Cross3(p1 - p0, p2 - p0));
        s.ns = s.ng;
        if (normals >= 0) {
            // Interpolated vertex normal, on the side of the geometric normal
            __global const TriangleNormals *vn = &scene->triangle_normals[normals];
            float3 n = b.x * Load3(vn->n[0]) + b.y * Load3(vn->n[1]) + b.z * Load3(vn->n[2]);
            if (Dot3(n, n) > 0.0f)
                s.ns = Normalize3(Dot3(n, s.ng) < 0.0f ? -n : n);
        }
        s.error = SURFACE_ERROR_SCALE * Fmax(MaxAbs3(p0), Fmax(MaxAbs3(p1), MaxAbs3(p2)));
    }
    return s;
}

// The primitive id of a hit id (Scene_Intersect's): a triangle found through the BVH by its
// leaf block's id lane, any other hit as it is.
CL_INLINE int Scene_HitPrimitive(const SceneData *scene, int prim)
{
    int k = prim - (int)(scene->quad_count + scene->sphere_count);
    if (k < 0 || scene->bvh_node_count == 0u)
        return prim;
    __global const TriangleBlock *block =
        (__global const TriangleBlock *)(scene->bvh_prims + (k & -BVH_BLOCK_WIDTH));
    return block->id[k & (BVH_BLOCK_WIDTH - 1)];
}

// A ray origin off the surface at p, on the side (of the normal ng) that direction w leaves to.
CL_INLINE float3 Surface_OffsetOrigin(float3 p, float3 ng, float3 w, float eps)
{
    return p + (Dot3(w, ng) > 0.0f ? eps : -eps) * ng;
}

#endif
