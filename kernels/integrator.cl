// Path tracing of per-sample camera rays: unidirectional paths with next event estimation
// and multiple importance sampling (power heuristic) applied to emission only.
//
// One work-item per traced sample. Sample i belongs to the pixel whose traced_offsets range
// holds it; its position (pixel-local, in W = [-1/2, 1/2]^2) comes from the sample-set buffer
// (auxiliary nuclei, stored after the traced samples, are never read). Random numbers: the
// launch's path sampler (kernels/sampler.h: independent, stratified, sobol or zsobol), a pure
// function of (seed, pixel, sample, dimension, redraw). Dimensions 0 and 1 are the sample's
// position (drawn by sampling.cl); bounce d draws dimensions 2 + 7d ... 8 + 7d: emitter choice,
// emitter point (2), BSDF lobe choice, BSDF direction (2), Russian roulette.
//
// max_depth counts scattering vertices (pbrt's maxdepth; Mitsuba's max_depth minus 1):
// 0 shows emitters only, 1 adds direct lighting, ... Specular vertices count too.
//
// Russian roulette (russian_roulette set) is pbrt-v4's (kernels/roulette.h).
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

// Radiance along one camera ray (pbrt-v4's PathIntegrator::Li, emitters as the only lights).
// With nee = 0 paths find emitters by BSDF sampling only, and emission takes full weight.
CL_INLINE float3 Integrator_Li(const SceneData *scene, float3 origin, float3 dir, int max_depth,
                               int nee, int russian_roulette, const Sampler *sampler,
                               uint *rays)
{
    float3 L = (float3)(0.0f);
    float3 beta = (float3)(1.0f);
    bool specularBounce = false;
    float prev_pdfW = 0.0f;
    float eta_scale = 1.0f; // product of eta'^2 over the refractions (for Russian roulette)
    for (int depth = 0;; ++depth) {
        // Find the closest surface along the ray
        int prim;
        *rays += 1u;
        float t = Scene_Intersect(scene, origin, dir, INFINITY, &prim);
        if (prim < 0)
            break;
        Surface surface = Scene_Surface(scene, origin, dir, t, prim);
        float3 wo = -dir;

        // Add emission found by the ray, MIS-weighted unless it came from the camera or a
        // specular bounce (NEE cannot sample those paths)
        if (surface.emitter >= 0 && Dot3(surface.ng, wo) > 0.0f) {
            __global const Emitter *emitter = &scene->emitters[surface.emitter];
            float3 Le = Load3(emitter->radiance);
            if (depth == 0 || specularBounce || !nee) {
                L += beta * Le;
            } else {
                float light_pdfW =
                    Light_HitPdfW(scene, emitter, origin, t, Dot3(surface.ng, wo));
                L += beta * Le * PathVertex_PowerHeuristic(prev_pdfW, light_pdfW);
            }
        }

        // End the path at the maximum depth or on a surface that only emits
        if (depth == max_depth || surface.material < 0)
            break;
        __global const Material *material = &scene->materials[surface.material];

        // Shading frame: two-sided surfaces face wo, one-sided ones are black from behind
        float3 n;
        if (!PathVertex_ShadingNormal(material, surface.ng, surface.ns, wo, &n))
            break;
        Frame frame = Frame_FromNormal(n);
        float3 wo_local = Frame_ToLocal(frame, wo);
        BounceSamples u = Sampler_Bounce(sampler, (uint)depth);

        // Sample direct illumination from the emitters (skipped at specular vertices)
        if (nee && !BSDF_IsSpecular(material) && scene->emitter_count > 0u)
            L += beta * Integrator_SampleDirect(scene, &surface, frame, material, wo_local,
                                                (float3)(u.emitter_choice, u.emitter_point),
                                                rays);

        // Sample the BSDF to get the new path direction
        float3 wi_local;
        float pdfW;
        float3 weight = BSDF_Sample(material, wo_local, (float3)(u.direction, u.lobe),
                                     &wi_local, &pdfW);
        if (!AnyPositive3(weight))
            break;
        beta *= weight;
        specularBounce = BSDF_IsSpecular(material);
        eta_scale = Roulette_EtaScale(eta_scale, material, wo_local, wi_local);
        prev_pdfW = pdfW;
        dir = Frame_ToWorld(frame, wi_local);
        origin = Surface_OffsetOrigin(surface.p, surface.ng, dir, surface.error);

        // Possibly terminate the path with Russian roulette
        float q = Roulette_EndProbability(russian_roulette, depth, beta, eta_scale);
        if (q > 0.0f) {
            if (u.roulette < q)
                break;
            beta /= 1.0f - q;
        }
    }
    return L;
}

// One work-item per traced sample: radiance (RGB float) to radiance[3 i .. 3 i + 2].
__kernel void trace_paths(uint traced_total, uint pixel_count, uint seed, uint image_width,
                          uint image_height, int max_depth, int nee, int russian_roulette,
                          int paths_kind, uint fixed_count, uint strata,
                          uint zsobol_log2_count, uint zsobol_bits,
                          __global const float2 *positions,
                          __global const uint *traced_offsets, __global const uint *pixels,
                          __global const uint *redraws, __global const Camera *camera,
                          __global const Quad *quads,
                          __global const QuadBlock *quad_blocks, uint quad_count,
                          uint quad_block_count,
                          __global const Sphere *spheres, uint sphere_count,
                          __global const Material *materials,
                          __global const Emitter *emitters, uint emitter_count,
                          __global const Triangle *triangles, uint triangle_count,
                          __global const TriangleNormals *triangle_normals,
                          __global const BVHNode *bvh_nodes, uint bvh_node_count,
                          __global const uint *bvh_prims,
                          __global float *radiance, __global uint *counters)
{
    uint i = get_global_id(0);
    if (i >= traced_total)
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;

    // Find the sample's pixel, its index in the pixel and its image position
    uint slot = Launch_OwnerPixel(traced_offsets, pixel_count, i);
    uint pixel = pixels[slot];
    uint sample = i - traced_offsets[slot];
    float2 u_pixel = positions[i];
    float2 image_pos = (float2)((float)(pixel % image_width) + 0.5f + u_pixel.x,
                                (float)(pixel / image_width) + 0.5f + u_pixel.y);

    // Trace the camera ray's path
    uint rays = 0u;
    float3 dir = Camera_Direction(camera, image_pos, image_width, image_height);
    Sampler sampler = Sampler_Make(paths_kind, seed, pixel, sample, redraws[slot], fixed_count,
                                   strata, image_width, zsobol_log2_count, zsobol_bits);
    float3 L = Integrator_Li(&scene, Load3(camera->origin), dir, max_depth, nee,
                             russian_roulette, &sampler, &rays);

    // Store the radiance; a non-finite value is counted and stored as 0 (as pbrt does)
    if (!all(isfinite(L))) {
        atomic_inc(&counters[COUNTER_NONFINITE]);
        L = (float3)(0.0f);
    }
    vstore3(L, i, radiance);
    atomic_add(&counters[COUNTER_RAYS + get_group_id(0)], rays);
}
