// Ray-primitive intersection: brute force over every quad, then every sphere.
// Primitive ids: quads are 0 .. quad_count-1, sphere s is quad_count + s; -1 is a miss.
#ifndef CLRENDER_GEOMETRY_H
#define CLRENDER_GEOMETRY_H

#include "scene_types.h"

// A surface point found by a ray: position, geometric normal (the quad's front side, the
// sphere's outside), material and emitter.
typedef struct {
    float3 p;
    float3 ng;
    int material;
    int emitter;
} Surface;

// Distance along d (unit) to the quad, or tmax when it is missed or not closer than tmax.
inline float Quad_Intersect(__global const Quad *q, float3 o, float3 d, float tmax)
{
    float3 n = vload3(0, q->normal);
    float t = (q->plane_d - dot(n, o)) / dot(n, d);
    float3 rel = o + t * d - vload3(0, q->corner);
    float a = dot(rel, vload3(0, q->u_dual));
    float b = dot(rel, vload3(0, q->v_dual));
    bool hit = t > 0.0f && t < tmax && a >= 0.0f && a <= 1.0f && b >= 0.0f && b <= 1.0f;
    return hit ? t : tmax;
}

// Distance along d (unit) to the nearest sphere crossing ahead, or tmax.
// (Ray Tracing Gems, ch. 7: discriminant from the closest-approach vector, stable roots.)
inline float Sphere_Intersect(__global const Sphere *s, float3 o, float3 d, float tmax)
{
    float3 oc = o - vload3(0, s->center);
    float r = s->radius;
    float b = dot(oc, d);
    float3 f = oc - b * d;
    float disc = r * r - dot(f, f);
    if (disc < 0.0f)
        return tmax;
    float c = dot(oc, oc) - r * r;
    float q = -b - copysign(sqrt(disc), b);
    float t0 = c / q;
    float t1 = q;
    float tnear = fmin(t0, t1);
    float tfar = fmax(t0, t1);
    float t = tnear > 0.0f ? tnear : tfar;
    return (t > 0.0f && t < tmax) ? t : tmax;
}

// The closest primitive along the ray before tmax: its distance, and its id in *prim.
inline float Scene_Intersect(const SceneData *scene, float3 o, float3 d, float tmax, int *prim)
{
    float t = tmax;
    int id = -1;
    for (uint i = 0; i < scene->quad_count; ++i) {
        float ti = Quad_Intersect(&scene->quads[i], o, d, t);
        id = ti < t ? (int)i : id;
        t = ti;
    }
    for (uint i = 0; i < scene->sphere_count; ++i) {
        float ti = Sphere_Intersect(&scene->spheres[i], o, d, t);
        id = ti < t ? (int)(scene->quad_count + i) : id;
        t = ti;
    }
    *prim = id;
    return t;
}

// Whether anything lies along the ray closer than tmax (shadow rays).
inline bool Scene_Occluded(const SceneData *scene, float3 o, float3 d, float tmax)
{
    int prim;
    Scene_Intersect(scene, o, d, tmax, &prim);
    return prim >= 0;
}

// The surface record of a hit at distance t along the ray.
inline Surface Scene_Surface(const SceneData *scene, float3 o, float3 d, float t, int prim)
{
    Surface s;
    if (prim < (int)scene->quad_count) {
        __global const Quad *q = &scene->quads[prim];
        s.p = o + t * d;
        s.ng = vload3(0, q->normal);
        s.material = q->material;
        s.emitter = q->emitter;
    } else {
        __global const Sphere *sp = &scene->spheres[prim - (int)scene->quad_count];
        float3 center = vload3(0, sp->center);
        // Re-project the hit onto the sphere so the ray offset is measured from its surface
        s.ng = normalize(o + t * d - center);
        s.p = center + sp->radius * s.ng;
        s.material = sp->material;
        s.emitter = -1;
    }
    return s;
}

// A ray origin off the surface at p, on the side (of the normal ng) that direction w leaves to.
inline float3 Surface_OffsetOrigin(float3 p, float3 ng, float3 w, float eps)
{
    return p + (dot(w, ng) > 0.0f ? eps : -eps) * ng;
}

#endif
