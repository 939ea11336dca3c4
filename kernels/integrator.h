// The path integrator's device functions, shared by the megakernel (integrator.cl trace_paths)
// and the SIMD-across-paths kernel (trace_simd.cl trace_paths_simd, whose per-lane fallbacks
// call them): pbrt-v4's PathIntegrator::Li with emitters as the only lights, split into
// Integrator_Vertex (what happens where a ray hits a surface) and the loop over vertices
// (Integrator_Li). See integrator.cl for the dimensions, depth and roulette conventions.
#ifndef CLRENDER_INTEGRATOR_H
#define CLRENDER_INTEGRATOR_H

// Philox inlined at its call sites (a call spills the path state held in vector registers)
#pragma clang attribute push(__attribute__((always_inline)), apply_to = function)
#include "sampler.h"
#pragma clang attribute pop
#include "launch.h"
#include "scene_types.h"
#include "geometry.h"
#include "bsdf.h"
#include "lights.h"
#include "camera.h"
#include "roulette.h"
#include "path_vertex.h"

// counters[0]: samples whose radiance was not finite (stored as 0);
// counters[1 + work-group id]: rays traced by that work-group (camera, bounce and shadow).
#define COUNTER_NONFINITE 0
#define COUNTER_RAYS 1

// A path between vertices: radiance so far, throughput, the ray to trace next, the solid-angle
// pdf of the last BSDF sample, whether that was specular, and the product of eta'^2 over the
// refractions so far (for Russian roulette).
typedef struct {
    float3 L;
    float3 beta;
    float3 origin;
    float3 dir;
    float prev_pdfW;
    float eta_scale;
    bool specularBounce;
} PathState;

// Next event estimation at a non-specular vertex: one emitter point, a shadow ray, and the
// power-heuristic weight against the BSDF's pdf for the same direction.
CL_INLINE float3 Integrator_SampleDirect(const SceneData *scene, Surface *surface, Frame frame,
                                         __global const Material *material, float3 wo_local,
                                         float3 u, uint *rays)
{
    float3 wi;
    float dist, light_pdfW;
    uint picked;
    float3 Le = Light_SampleLi(scene, surface->p, u, &wi, &dist, &light_pdfW, &picked);
    if (!(light_pdfW > 0.0f))
        return (float3)(0.0f);
    float3 wi_local = Frame_ToLocal(frame, wi);
    float3 f = BSDF_Eval(material, wo_local, wi_local) * Fabs(wi_local.z);
    if (!AnyPositive3(f))
        return (float3)(0.0f);
    float3 origin = Surface_OffsetOrigin(surface->p, surface->ng, wi, surface->error);
    // The shadow ray stops short of the emitter by both points' rounding bounds
    float light_error = SURFACE_ERROR_SCALE * MaxAbs3(surface->p + dist * wi);
    *rays += 1u;
#ifndef PROFILE_SKIP_SHADOW_RAYS // profiling build: every shadow ray counts as unblocked
    float tmax = Light_ShadowDistance(scene, picked, origin, wi, dist) -
                 2.0f * (surface->error + light_error);
    if (Scene_Occluded(scene, origin, wi, tmax))
        return (float3)(0.0f);
#endif
    float weight =
        PathVertex_PowerHeuristic(light_pdfW, BSDF_PdfW(material, wo_local, wi_local));
    return f * Le * (weight / light_pdfW);
}

// The vertex at depth `depth` where the path's ray met primitive `prim` (a hit id >= 0) at
// distance t: add the emission found there, then (unless the path ends there) next event
// estimation and the BSDF sample that gives the path its next ray. False when the path ends.
// With nee = 0 paths find emitters by BSDF sampling only, and emission takes full weight.
CL_INLINE bool Integrator_Vertex(const SceneData *scene, PathState *path, int depth, float t,
                                 int prim, int max_depth, int nee, int russian_roulette,
                                 const Sampler *sampler, uint *rays)
{
    Surface surface = Scene_Surface(scene, path->origin, path->dir, t, prim);
    float3 wo = -path->dir;

    // Add emission found by the ray, MIS-weighted unless it came from the camera or a
    // specular bounce (NEE cannot sample those paths)
    if (surface.emitter >= 0 && Dot3(surface.ng, wo) > 0.0f) {
        __global const Emitter *emitter = &scene->emitters[surface.emitter];
        float3 Le = Load3(emitter->radiance);
        if (depth == 0 || path->specularBounce || !nee) {
            path->L += path->beta * Le;
        } else {
            float light_pdfW =
                Light_HitPdfW(scene, emitter, path->origin, t, Dot3(surface.ng, wo));
            path->L += path->beta * Le * PathVertex_PowerHeuristic(path->prev_pdfW, light_pdfW);
        }
    }

    // End the path at the maximum depth or on a surface that only emits
    if (depth == max_depth || surface.material < 0)
        return false;
    __global const Material *material = &scene->materials[surface.material];

    // Shading frame: two-sided surfaces face wo, one-sided ones are black from behind
    float3 n;
    if (!PathVertex_ShadingNormal(material, surface.ng, surface.ns, wo, &n))
        return false;
    Frame frame = Frame_FromNormal(n);
    float3 wo_local = Frame_ToLocal(frame, wo);
    BounceSamples u = Sampler_Bounce(sampler, (uint)depth);

    // Sample direct illumination from the emitters (skipped at specular vertices)
    if (nee && !BSDF_IsSpecular(material) && scene->emitter_count > 0u)
        path->L += path->beta * Integrator_SampleDirect(scene, &surface, frame, material,
                                                        wo_local,
                                                        (float3)(u.emitter_choice,
                                                                 u.emitter_point),
                                                        rays);

    // Sample the BSDF to get the new path direction
    float3 wi_local;
    float pdfW;
    float3 weight =
        BSDF_Sample(material, wo_local, (float3)(u.direction, u.lobe), &wi_local, &pdfW);
    if (!AnyPositive3(weight))
        return false;
    path->beta *= weight;
    path->specularBounce = BSDF_IsSpecular(material);
    path->eta_scale = Roulette_EtaScale(path->eta_scale, material, wo_local, wi_local);
    path->prev_pdfW = pdfW;
    path->dir = Frame_ToWorld(frame, wi_local);
    path->origin = Surface_OffsetOrigin(surface.p, surface.ng, path->dir, surface.error);

    // Possibly terminate the path with Russian roulette
    float q = Roulette_EndProbability(russian_roulette, depth, path->beta, path->eta_scale);
    if (q > 0.0f) {
        if (u.roulette < q)
            return false;
        path->beta /= 1.0f - q;
    }
    return true;
}

// A path at its camera ray: nothing gathered yet, full throughput.
CL_INLINE PathState PathState_Start(float3 origin, float3 dir)
{
    PathState path;
    path.L = (float3)(0.0f);
    path.beta = (float3)(1.0f);
    path.origin = origin;
    path.dir = dir;
    path.prev_pdfW = 0.0f;
    path.eta_scale = 1.0f;
    path.specularBounce = false;
    return path;
}

// Radiance along one camera ray: a vertex at each surface the path's rays find, until it ends.
CL_INLINE float3 Integrator_Li(const SceneData *scene, float3 origin, float3 dir, int max_depth,
                               int nee, int russian_roulette, const Sampler *sampler,
                               uint *rays)
{
    PathState path = PathState_Start(origin, dir);
    for (int depth = 0;; ++depth) {
        // Find the closest surface along the ray
        int prim;
        *rays += 1u;
        float t = Scene_Intersect(scene, path.origin, path.dir, INFINITY, &prim);
        if (prim < 0 || !Integrator_Vertex(scene, &path, depth, t, prim, max_depth, nee,
                                           russian_roulette, sampler, rays))
            break;
    }
    return path.L;
}

// The image position (in pixels) of traced sample i of a launch, its pixel's slot in the launch
// and its index in the pixel (trace_paths' first step; trace_simd.cl does it on lanes).
CL_INLINE float2 Integrator_SamplePosition(__global const float2 *positions,
                                           __global const uint *traced_offsets,
                                           __global const uint *pixels, uint pixel_count,
                                           uint image_width, uint i, uint *slot, uint *sample)
{
    *slot = Launch_OwnerPixel(traced_offsets, pixel_count, i);
    uint pixel = pixels[*slot];
    *sample = i - traced_offsets[*slot];
    float2 u_pixel = positions[i];
    return (float2)((float)(pixel % image_width) + 0.5f + u_pixel.x,
                    (float)(pixel / image_width) + 0.5f + u_pixel.y);
}

#endif
