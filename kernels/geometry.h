// Ray-primitive intersection: every block of quads (one vector test per block) whose bounding
// box the ray meets, then every sphere.
// Primitive ids: quads are 0 .. quad_count-1, sphere s is quad_count + s; -1 is a miss.
#ifndef CLRENDER_GEOMETRY_H
#define CLRENDER_GEOMETRY_H

#include "scene_types.h"
#include "vecmath.h"

// A surface point found by a ray: position, geometric normal (the quad's front side, the
// sphere's outside), material and emitter, and a bound on p's distance from the true surface
// (float rounding), which is how far rays leaving it start off the surface.
typedef struct {
    float3 p;
    float3 ng;
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

// Whether the ray o + t d (inv_d = 1 / d) can meet the block's bounding box for some t in
// [0, tmax] (slab test). Always true for a block flagged as enclosing the scene (lower[3] = 1:
// every ray meets it). A NaN (zero direction on a slab's plane) never rejects.
CL_INLINE bool QuadBlock_BoundsHit(__global const QuadBlock *block, float3 o, float3 inv_d,
                                   float tmax)
{
    if (block->lower[3] != 0.0f)
        return true;
    float3 t0 = (Load3(block->lower) - o) * inv_d;
    float3 t1 = (Load3(block->upper) - o) * inv_d;
    float3 t_near = t0 < t1 ? t0 : t1;
    float3 t_far = t0 < t1 ? t1 : t0;
    float t_enter = t_near.x > t_near.y ? t_near.x : t_near.y;
    t_enter = t_enter > t_near.z ? t_enter : t_near.z;
    float t_exit = t_far.x < t_far.y ? t_far.x : t_far.y;
    t_exit = t_exit < t_far.z ? t_exit : t_far.z;
    return !(t_enter > t_exit || t_exit < 0.0f || t_enter > tmax);
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
    int8 lane_ids = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    *lane = Lanes_MinInt(t_hit == t_min ? lane_ids : (int8)(QUAD_BLOCK_WIDTH));
    return t_min < tmax ? t_min : tmax;
}

// Whether any quad of a block lies along the ray before tmax.
CL_INLINE bool QuadBlock_Occluded(__global const QuadBlock *block, float3 o, float3 d,
                                  float tmax)
{
    float8 t;
    int8 hit = QuadBlock_Hits(block, o, d, tmax, &t);
    int4 h4 = hit.lo | hit.hi;
    int2 h2 = h4.lo | h4.hi;
    return (h2.x | h2.y) != 0;
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

// The closest primitive along the ray before tmax: its distance, and its id in *prim.
// (Ties go to the lowest quad index, then to the sphere: blocks hold quads in scene order.)
CL_INLINE float Scene_Intersect(const SceneData *scene, float3 o, float3 d, float tmax,
                                int *prim)
{
    float t = tmax;
    int id = -1;
    float3 inv_d = 1.0f / d;
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
    for (uint i = 0; i < scene->sphere_count; ++i) {
        float ti = Sphere_Intersect(&scene->spheres[i], o, d, t);
        id = ti < t ? (int)(scene->quad_count + i) : id;
        t = ti;
    }
    *prim = id;
    return t;
}

// Whether anything lies along the ray closer than tmax (shadow rays): an any-hit query that
// returns at the first blocker. Spheres first, then the quad blocks from the last: scene files
// list the enclosing walls first and the objects inside later, and walls of a convex room
// never block a ray between two points inside it.
CL_INLINE bool Scene_Occluded(const SceneData *scene, float3 o, float3 d, float tmax)
{
    for (uint i = 0; i < scene->sphere_count; ++i) {
        if (Sphere_Intersect(&scene->spheres[i], o, d, tmax) < tmax)
            return true;
    }
    float3 inv_d = 1.0f / d;
    for (uint b = scene->quad_block_count; b-- > 0u;) {
        __global const QuadBlock *block = &scene->quad_blocks[b];
        if (QuadBlock_BoundsHit(block, o, inv_d, tmax) && QuadBlock_Occluded(block, o, d, tmax))
            return true;
    }
    return false;
}

// The surface record of a hit at distance t along the ray.
CL_INLINE Surface Scene_Surface(const SceneData *scene, float3 o, float3 d, float t, int prim)
{
    Surface s;
    if (prim < (int)scene->quad_count) {
        __global const Quad *q = &scene->quads[prim];
        s.p = o + t * d;
        s.ng = Load3(q->normal);
        s.material = q->material;
        s.emitter = q->emitter;
        // The plane distance and o + t d round at the magnitudes of o, t d and the corner
        float magnitude = MaxAbs3(o) + t * MaxAbs3(d) + MaxAbs3(Load3(q->corner));
        s.error = SURFACE_ERROR_SCALE * magnitude;
    } else {
        __global const Sphere *sp = &scene->spheres[prim - (int)scene->quad_count];
        float3 center = Load3(sp->center);
        // Re-project the hit onto the sphere so the ray offset is measured from its surface
        s.ng = Normalize3(o + t * d - center);
        s.p = center + sp->radius * s.ng;
        s.material = sp->material;
        s.emitter = sp->emitter;
        s.error = SURFACE_ERROR_SCALE * (MaxAbs3(center) + sp->radius);
    }
    return s;
}

// A ray origin off the surface at p, on the side (of the normal ng) that direction w leaves to.
CL_INLINE float3 Surface_OffsetOrigin(float3 p, float3 ng, float3 w, float eps)
{
    return p + (Dot3(w, ng) > 0.0f ? eps : -eps) * ng;
}

#endif
