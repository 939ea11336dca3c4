// Area lights: emitting quads, spheres and mesh triangles, one-sided (a quad or triangle emits
// on the side its normal points to, a sphere outwards). An emitter is picked with probability
// proportional to its power, then a point on it seen from the receiving point p:
//   quad, triangle: uniformly by area (pdfA = 1 / area), converted to solid angle at p:
//           pdfW = pick_pdf * pdfA * dist^2 / cos_light;
//   sphere: uniformly in the cone of directions from p that meets the sphere (the visible
//           cap, as pbrt-v4's Sphere::Sample with a reference point outside the sphere):
//           pdfW = pick_pdf / (2 pi (1 - cos_theta_max)), sin^2 theta_max = r^2 / d^2.
//           From a point inside or on the sphere the outward emitter is invisible: the sample
//           and its pdf are zero (pbrt samples by area there; nothing here can use it).
// All take the same two random numbers (the emitter point u.y, u.z).
#ifndef CLRENDER_LIGHTS_H
#define CLRENDER_LIGHTS_H

#include "bsdf.h"
#include "geometry.h"
#include "scene_types.h"
#include "vecmath.h"

// The emitter whose selection-CDF interval holds u: the first i with u < pick_cdf[i], the last
// emitter if none (u rounding up to 1). A binary search (a mesh makes an emitter of every
// triangle); the CDF never decreases, so it picks what a linear scan of the intervals would.
CL_INLINE uint Light_Pick(const SceneData *scene, float u)
{
    uint lo = 0u;
    uint hi = scene->emitter_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (u < scene->emitters[mid].pick_cdf)
            hi = mid;
        else
            lo = mid + 1u;
    }
    return lo;
}

// Barycentric coordinates (b0, b1, b2) of a point uniform by area on a triangle, from u in
// [0, 1)^2 (the square-root parametrisation, pbrt-v3's UniformSampleTriangle):
// b0 = 1 - sqrt(u0), b1 = u1 sqrt(u0), b2 = 1 - b0 - b1.
CL_INLINE float3 Triangle_SampleUniform(float2 u)
{
    float su0 = Sqrt(u.x);
    float b0 = 1.0f - su0;
    float b1 = u.y * su0;
    return (float3)(b0, b1, 1.0f - b0 - b1);
}

// Solid-angle pdf of NEE producing a point of an emitting quad or triangle (sampled by area)
// at distance dist whose normal makes cosine cos_light with the direction back to the receiver.
CL_INLINE float Light_PdfW(__global const Emitter *emitter, float dist, float cos_light)
{
    return emitter->pick_pdf * dist * dist / (cos_light * emitter->area);
}

// The cone from p around the unit direction *axis to the sphere's centre that holds the
// sphere: sin^2 and 1 - cos of its half-angle theta_max, and the distance to the centre.
// False when p is inside or on the sphere. 1 - cos is written sin^2 / (1 + cos): no
// cancellation for far, small spheres (the small-angle care pbrt takes below 1.5 degrees by
// approximating 1 - cos by sin^2 / 2; here exact at every angle).
CL_INLINE bool Light_SphereCone(__global const Sphere *sphere, float3 p, float3 *axis,
                                float *dist_center, float *sin2_max, float *one_minus_cos_max)
{
    float3 to_center = Load3(sphere->center) - p;
    float dc2 = Dot3(to_center, to_center);
    float r = sphere->radius;
    if (!(dc2 > r * r))
        return false;
    *dist_center = Sqrt(dc2);
    *axis = to_center / *dist_center;
    *sin2_max = r * r / dc2;
    *one_minus_cos_max = *sin2_max / (1.0f + Sqrt(1.0f - *sin2_max));
    return true;
}

// Solid-angle pdf (emitter pick included) of NEE producing a direction from p that meets an
// emitting sphere; 0 from inside or on it.
CL_INLINE float Light_SpherePdfW(__global const Emitter *emitter,
                                 __global const Sphere *sphere, float3 p)
{
    float3 axis;
    float dist_center, sin2_max, one_minus_cos_max;
    if (!Light_SphereCone(sphere, p, &axis, &dist_center, &sin2_max, &one_minus_cos_max))
        return 0.0f;
    return emitter->pick_pdf / (2.0f * M_PI_F * one_minus_cos_max);
}

// Solid-angle pdf of NEE for the emitter point a ray from origin hit at distance t, where
// the emitter's normal makes cosine cos_light with the direction back to origin.
CL_INLINE float Light_HitPdfW(const SceneData *scene, __global const Emitter *emitter,
                              float3 origin, float t, float cos_light)
{
    if (emitter->shape == EMITTER_SPHERE)
        return Light_SpherePdfW(emitter, &scene->spheres[emitter->index], origin);
    return Light_PdfW(emitter, t, cos_light);
}

// A direction from p uniform in the cone of the sphere (u in [0, 1)^2), *dist the distance
// along it to the sphere's near side; returns the cone's pdfW (no emitter pick), 0 from inside.
CL_INLINE float Light_SampleSphereCone(__global const Sphere *sphere, float3 p, float2 u,
                                       float3 *wi, float *dist)
{
    float3 axis;
    float dist_center, sin2_max, one_minus_cos_max;
    if (!Light_SphereCone(sphere, p, &axis, &dist_center, &sin2_max, &one_minus_cos_max))
        return 0.0f;
    // Uniform cos theta in [cos theta_max, 1]: 1 - cos theta = u (1 - cos theta_max), and
    // sin^2 theta = (1 - cos)(1 + cos), both free of cancellation
    float one_minus_cos = u.x * one_minus_cos_max;
    float cos_theta = 1.0f - one_minus_cos;
    float sin2_theta = one_minus_cos * (2.0f - one_minus_cos);
    float sin_theta = Sqrt(sin2_theta);
    float cos_phi;
    float sin_phi = SinCos2Pi(u.y, &cos_phi);
    Frame frame = Frame_FromNormal(axis);
    *wi = Frame_ToWorld(frame, (float3)(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta));
    // Near root of |p + s wi - c| = r: s = dc cos - r sqrt(1 - sin^2 / sin^2_max), written as
    // (dc^2 - r^2) / (dc cos + r sqrt(...)) (no cancellation when p is near the sphere)
    float r = sphere->radius;
    float chord = r * Sqrt(Fmax(1.0f - sin2_theta / sin2_max, 0.0f));
    *dist = (dist_center - r) * (dist_center + r) / (dist_center * cos_theta + chord);
    return 1.0f / (2.0f * M_PI_F * one_minus_cos_max);
}

// Sample an emitter point seen from p: returns its radiance towards p (zero if p is behind
// the emitter), the unit direction *wi to it, its distance, the solid-angle pdf and the
// emitter's index (for Light_ShadowDistance).
CL_INLINE float3 Light_SampleLi(const SceneData *scene, float3 p, float3 u, float3 *wi,
                                float *dist, float *pdfW, uint *picked)
{
    *picked = Light_Pick(scene, u.x);
    __global const Emitter *emitter = &scene->emitters[*picked];
    if (emitter->shape == EMITTER_SPHERE) {
        float cone_pdfW = Light_SampleSphereCone(&scene->spheres[emitter->index], p,
                                                 (float2)(u.y, u.z), wi, dist);
        *pdfW = emitter->pick_pdf * cone_pdfW;
        return cone_pdfW > 0.0f ? Load3(emitter->radiance) : (float3)(0.0f);
    }
    // A point uniform by area on the quad or triangle, and the emitter's unit normal
    float3 y, normal;
    if (emitter->shape == EMITTER_TRIANGLE) {
        __global const Triangle *tri = &scene->triangles[emitter->index];
        float3 p0 = Load3(tri->p0);
        float3 p1 = Load3(tri->p1);
        float3 p2 = Load3(tri->p2);
        float3 b = Triangle_SampleUniform((float2)(u.y, u.z));
        y = b.x * p0 + b.y * p1 + b.z * p2;
        normal = Normalize3(Cross3(p1 - p0, p2 - p0));
    } else {
        __global const Quad *quad = &scene->quads[emitter->index];
        y = Load3(quad->corner) + u.y * Load3(quad->edge1) + u.z * Load3(quad->edge2);
        normal = Load3(quad->normal);
    }
    float3 to_light = y - p;
    *dist = Length3(to_light);
    *wi = to_light / *dist;
    float cos_light = -Dot3(normal, *wi);
    if (!(cos_light > 0.0f)) {
        *pdfW = 0.0f;
        return (float3)(0.0f);
    }
    *pdfW = Light_PdfW(emitter, *dist, cos_light);
    return Load3(emitter->radiance);
}

// Where the shadow ray of a light sample (at distance dist from the receiving point, along
// wi) meets the emitter, measured from the ray's origin (the receiver's offset point); the
// caller stops the ray short of it by the points' rounding bounds. A quad or triangle: dist.
// A sphere: where this very ray meets it (Sphere_Intersect, as the occlusion test will compute
// it), at most dist: the offset origin moves the crossing of rays that graze the sphere's rim
// by many times the offset, and a shadow ray ending at dist would find the emitter itself there.
CL_INLINE float Light_ShadowDistance(const SceneData *scene, uint picked, float3 origin,
                                     float3 wi, float dist)
{
    __global const Emitter *emitter = &scene->emitters[picked];
    if (emitter->shape != EMITTER_SPHERE)
        return dist;
    return Fmin(Sphere_Intersect(&scene->spheres[emitter->index], origin, wi, INFINITY), dist);
}

#endif
