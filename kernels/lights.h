// Area lights: emitting quads, one-sided (they emit on the side their normal points to).
// An emitter is picked with probability proportional to its power, then a point uniformly by
// area on it (pdfA = 1 / area), converted to solid angle at the receiving point:
// pdfW = pick_pdf * pdfA * dist^2 / cos_light.
#ifndef CLRENDER_LIGHTS_H
#define CLRENDER_LIGHTS_H

#include "scene_types.h"
#include "vecmath.h"

// The emitter whose selection-CDF interval holds u (linear scan: scenes have few emitters).
CL_INLINE uint Light_Pick(const SceneData *scene, float u)
{
    uint last = scene->emitter_count - 1u;
    uint chosen = last;
    for (uint i = last; i-- > 0u;)
        chosen = u < scene->emitters[i].pick_cdf ? i : chosen;
    return chosen;
}

// Solid-angle pdf of NEE producing a point of `emitter` at distance dist whose normal makes
// cosine cos_light with the direction back to the receiver.
CL_INLINE float Light_PdfW(__global const Emitter *emitter, float dist, float cos_light)
{
    return emitter->pick_pdf * dist * dist / (cos_light * emitter->area);
}

// Sample an emitter point seen from p: returns its radiance towards p (zero if p is behind
// the emitter), the unit direction *wi to it, its distance and the solid-angle pdf.
CL_INLINE float3 Light_SampleLi(const SceneData *scene, float3 p, float3 u, float3 *wi,
                                float *dist, float *pdfW)
{
    __global const Emitter *emitter = &scene->emitters[Light_Pick(scene, u.x)];
    __global const Quad *quad = &scene->quads[emitter->quad];
    float3 y = Load3(quad->corner) + u.y * Load3(quad->edge1) +
               u.z * Load3(quad->edge2);
    float3 to_light = y - p;
    *dist = Length3(to_light);
    *wi = to_light / *dist;
    float cos_light = -Dot3(Load3(quad->normal), *wi);
    if (!(cos_light > 0.0f)) {
        *pdfW = 0.0f;
        return (float3)(0.0f);
    }
    *pdfW = Light_PdfW(emitter, *dist, cos_light);
    return Load3(emitter->radiance);
}

#endif
