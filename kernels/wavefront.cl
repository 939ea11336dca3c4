// Wavefront (streaming) path tracing: the integrator of integrator.cl (trace_paths) cut into one
// kernel per stage, each run over a queue of path ids (Laine, Karras and Aila, "Megakernels
// Considered Harmful: Wavefront Path Tracing on GPUs", HPG 2013; LuxCoreRender's PATHOCL).
//
// The host (clrender/wavefront.py) runs, for each chunk of a launch's samples:
//   wavefront_generate                    camera rays of every path; queue 0 = every path
//   for depth d = 0, 1, ... while queue d is not empty:
//     wavefront_intersect  (queue d)      closest hit of each queued path's ray
//     wavefront_shade      (queue d)      emission with MIS; a light sample -> shadow queue;
//                                         a BSDF sample (and Russian roulette) -> queue d + 1
//     wavefront_shadow     (shadow queue) occlusion test; the light sample's term added to L
//   wavefront_finish                      radiance of every path (non-finite: counted, 0)
// reading back only the two queue lengths after each shade.
//
// Each stage does the megakernel's operations, in its order, on the same values and with the
// same random dimensions, so a sample's radiance is bit-identical to trace_paths' (checked by
// tests/test_wavefront.py): change the two files together. Queues are compacted with atomic
// counters, so their order changes from run to run; but every path's state is written only by
// the one work-item that holds its id, so the radiance does not.
//
// State is kept as arrays of structures indexed by path id: PoCL runs these kernels one
// work-item at a time (it vectorises no loop that holds another loop), and a path's fields in
// one or two cache lines beat one cache line per field.
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

// counters[0]: paths whose radiance was not finite (stored as 0); then the ray counts: per
// chunk its camera rays (set by the host), then per bounce the lengths of the two queues that
// shade fills, at counters[count_slot + QUEUE_NEXT] and counters[count_slot + QUEUE_SHADOW].
#define COUNTER_NONFINITE 0
#define QUEUE_NEXT 0
#define QUEUE_SHADOW 1

// The ray of a path at its current vertex, and what the intersect stage found along it.
typedef struct {
    float origin[3];
    float dir[3];
    float t;  // distance to the closest hit
    int prim; // hit id (kernels/geometry.h), -1 for none
} WavefrontRay;

// What the integrator's loop carries from one vertex to the next, and the sampler's identity.
typedef struct {
    float beta[3]; // path throughput
    float L[3];    // radiance gathered so far
    float prev_pdfW;
    uint specular; // 1 when the last bounce was specular
    uint pixel, sample, redraw;
    uint key[2];       // the sampler's Philox key of (seed, pixel, redraw): drawn once
    uint zsobol_index; // zsobol's image-wide index of the sample
    float eta_scale;   // product of eta'^2 over the refractions (for Russian roulette)
    uint pad;
} WavefrontPath;

// A light sample waiting for its occlusion test: if nothing lies along the ray before tmax,
// its path gains beta * contribution (kept apart, as the megakernel computes the product).
typedef struct {
    float origin[3];
    float dir[3];
    float tmax;
    uint path;
    float beta[3];
    float contribution[3];
    uint pad[2];
} WavefrontShadowRay;

// The host allocates these sizes (clrender/wavefront.py): a mismatch fails the build.
typedef char WavefrontRay_size_is_32[sizeof(WavefrontRay) == 32 ? 1 : -1];
typedef char WavefrontPath_size_is_64[sizeof(WavefrontPath) == 64 ? 1 : -1];
typedef char WavefrontShadowRay_size_is_64[sizeof(WavefrontShadowRay) == 64 ? 1 : -1];

// The scene as kernel arguments (every stage takes the same list; SCENE_DATA_OF_ARGUMENTS in
// scene_types.h makes them a SceneData).
#define WAVEFRONT_SCENE_PARAMS                                                                 \
    __global const Quad *quads, __global const QuadBlock *quad_blocks, uint quad_count,        \
        uint quad_block_count, __global const Sphere *spheres, uint sphere_count,              \
        __global const Material *materials, __global const Emitter *emitters,                  \
        uint emitter_count, __global const Triangle *triangles, uint triangle_count,           \
        __global const TriangleNormals *triangle_normals, __global const BVHNode *bvh_nodes,   \
        uint bvh_node_count, __global const uint *bvh_prims

CL_INLINE void Wavefront_Store3(__global float *p, float3 v)
{
    p[0] = v.x;
    p[1] = v.y;
    p[2] = v.z;
}

// The path's sampler as Sampler_Make built it at the camera (its Philox key kept, not redrawn).
CL_INLINE Sampler Wavefront_Sampler(__global const WavefrontPath *path, int kind, uint seed,
                                    uint count, uint strata, uint zsobol_bits)
{
    Sampler s = {kind,
                 seed,
                 path->pixel,
                 path->sample,
                 path->redraw,
                 count,
                 strata,
                 path->zsobol_index,
                 kind == PATHS_ZSOBOL ? zsobol_bits : 0u,
                 (uint2)(path->key[0], path->key[1])};
    return s;
}

// Next event estimation at a non-specular vertex (integrator.cl's Integrator_SampleDirect up
// to its occlusion test): queues the shadow ray and returns true, or returns false where the
// megakernel's term is zero without a shadow ray (the caller then adds beta * 0, as it does).
CL_INLINE bool Wavefront_QueueDirect(const SceneData *scene, Surface *surface, Frame frame,
                                     __global const Material *material, float3 wo_local,
                                     float3 u, float3 beta, uint path,
                                     __global WavefrontShadowRay *shadow_rays,
                                     __global uint *shadow_count)
{
    float3 wi;
    float dist, light_pdfW;
    uint picked;
    float3 Le = Light_SampleLi(scene, surface->p, u, &wi, &dist, &light_pdfW, &picked);
    if (!(light_pdfW > 0.0f))
        return false;
    float3 wi_local = Frame_ToLocal(frame, wi);
    float3 f = BSDF_Eval(material, wo_local, wi_local) * Fabs(wi_local.z);
    if (!AnyPositive3(f))
        return false;
    float3 origin = Surface_OffsetOrigin(surface->p, surface->ng, wi, surface->error);
    // The shadow ray stops short of the emitter by both points' rounding bounds
    float light_error = SURFACE_ERROR_SCALE * MaxAbs3(surface->p + dist * wi);
    float weight =
        PathVertex_PowerHeuristic(light_pdfW, BSDF_PdfW(material, wo_local, wi_local));
    __global WavefrontShadowRay *shadow = &shadow_rays[atomic_inc(shadow_count)];
    Wavefront_Store3(shadow->origin, origin);
    Wavefront_Store3(shadow->dir, wi);
    shadow->tmax = Light_ShadowDistance(scene, picked, origin, wi, dist) -
                   2.0f * (surface->error + light_error);
    shadow->path = path;
    Wavefront_Store3(shadow->beta, beta);
    Wavefront_Store3(shadow->contribution, f * Le * (weight / light_pdfW));
    return true;
}

// Stage (a): the camera ray of path p = sample path_base + p of the launch; queue[p] = p.
__kernel void wavefront_generate(uint path_base, uint path_count, uint pixel_count, uint seed,
                                 uint image_width, uint image_height, int paths_kind,
                                 uint fixed_count, uint strata, uint zsobol_log2_count,
                                 uint zsobol_bits, __global const float2 *positions,
                                 __global const uint *traced_offsets,
                                 __global const uint *pixels, __global const uint *redraws,
                                 __global const Camera *camera, __global WavefrontRay *rays,
                                 __global WavefrontPath *paths, __global uint *queue)
{
    uint p = get_global_id(0);
    if (p >= path_count)
        return;
    uint i = path_base + p;

    // Find the sample's pixel, its index in the pixel and its image position
    uint slot = Launch_OwnerPixel(traced_offsets, pixel_count, i);
    uint pixel = pixels[slot];
    uint sample = i - traced_offsets[slot];
    uint redraw = redraws[slot];
    float2 u_pixel = positions[i];
    float2 image_pos = (float2)((float)(pixel % image_width) + 0.5f + u_pixel.x,
                                (float)(pixel / image_width) + 0.5f + u_pixel.y);

    // Start the path: its camera ray, unit throughput, no radiance yet
    float3 dir = Camera_Direction(camera, image_pos, image_width, image_height);
    Sampler sampler = Sampler_Make(paths_kind, seed, pixel, sample, redraw, fixed_count, strata,
                                   image_width, zsobol_log2_count, zsobol_bits);
    __global WavefrontRay *ray = &rays[p];
    Wavefront_Store3(ray->origin, Load3(camera->origin));
    Wavefront_Store3(ray->dir, dir);
    __global WavefrontPath *path = &paths[p];
    Wavefront_Store3(path->beta, (float3)(1.0f));
    Wavefront_Store3(path->L, (float3)(0.0f));
    path->prev_pdfW = 0.0f;
    path->eta_scale = 1.0f;
    path->specular = 0u;
    path->pixel = pixel;
    path->sample = sample;
    path->redraw = redraw;
    path->key[0] = sampler.key.x;
    path->key[1] = sampler.key.y;
    path->zsobol_index = sampler.zsobol_index;
    queue[p] = p;
}

// Stage (b): the closest surface along the ray of every queued path.
__kernel void wavefront_intersect(uint ray_count, __global const uint *queue,
                                  __global WavefrontRay *rays, WAVEFRONT_SCENE_PARAMS)
{
    uint q = get_global_id(0);
    if (q >= ray_count)
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;
    __global WavefrontRay *ray = &rays[queue[q]];
    int prim;
    ray->t = Scene_Intersect(&scene, Load3(ray->origin), Load3(ray->dir), INFINITY, &prim);
    ray->prim = prim;
}

// Stage (c): one vertex of each queued path (integrator.h's Integrator_Li loop body,
// Integrator_Vertex, at depth `depth`): emission, a light sample to the shadow queue, a BSDF sample to the next queue.
__kernel void wavefront_shade(int depth, int max_depth, int nee, int russian_roulette,
                              uint ray_count, int paths_kind, uint seed, uint fixed_count,
                              uint strata, uint zsobol_bits, __global const uint *queue,
                              __global WavefrontRay *rays, __global WavefrontPath *paths,
                              __global uint *next_queue, __global WavefrontShadowRay *shadow_rays,
                              __global uint *counters, uint count_slot, WAVEFRONT_SCENE_PARAMS)
{
    uint q = get_global_id(0);
    if (q >= ray_count)
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;
    __global uint *queue_counts = &counters[count_slot];
    uint p = queue[q];
    __global WavefrontRay *ray = &rays[p];
    __global WavefrontPath *path = &paths[p];

    // A ray that found no surface ends its path
    int prim = ray->prim;
    if (prim < 0)
        return;
    float3 dir = Load3(ray->dir);
    float t = ray->t;
    Surface surface = Scene_Surface(&scene, Load3(ray->origin), dir, t, prim);
    float3 wo = -dir;
    float3 beta = Load3(path->beta);
    float3 L = Load3(path->L);
    bool specularBounce = path->specular != 0u;

    // Add emission found by the ray, MIS-weighted unless it came from the camera or a
    // specular bounce (NEE cannot sample those paths)
    if (surface.emitter >= 0 && Dot3(surface.ng, wo) > 0.0f) {
        __global const Emitter *emitter = &scene.emitters[surface.emitter];
        float3 Le = Load3(emitter->radiance);
        if (depth == 0 || specularBounce || !nee) {
            L += beta * Le;
        } else {
            float light_pdfW = Light_HitPdfW(&scene, emitter, Load3(ray->origin), t,
                                              Dot3(surface.ng, wo));
            L += beta * Le * PathVertex_PowerHeuristic(path->prev_pdfW, light_pdfW);
        }
        Wavefront_Store3(path->L, L);
    }

    // End the path at the maximum depth or on a surface that only emits
    if (depth == max_depth || surface.material < 0)
        return;
    __global const Material *material = &scene.materials[surface.material];

    // Shading frame: two-sided surfaces face wo, one-sided ones are black from behind
    float3 n;
    if (!PathVertex_ShadingNormal(material, surface.ng, surface.ns, wo, &n))
        return;
    Frame frame = Frame_FromNormal(n);
    float3 wo_local = Frame_ToLocal(frame, wo);
    Sampler sampler = Wavefront_Sampler(path, paths_kind, seed, fixed_count, strata, zsobol_bits);
    BounceSamples u = Sampler_Bounce(&sampler, (uint)depth);

    // Sample direct illumination from the emitters (skipped at specular vertices): queue the
    // shadow ray; a sample with no shadow ray adds beta * 0 here, as the megakernel does
    if (nee && !BSDF_IsSpecular(material) && scene.emitter_count > 0u &&
        !Wavefront_QueueDirect(&scene, &surface, frame, material, wo_local,
                               (float3)(u.emitter_choice, u.emitter_point), beta, p,
                               shadow_rays, &queue_counts[QUEUE_SHADOW])) {
        L += beta * (float3)(0.0f);
        Wavefront_Store3(path->L, L);
    }

    // Sample the BSDF to get the new path direction
    float3 wi_local;
    float pdfW;
    float3 weight = BSDF_Sample(material, wo_local, (float3)(u.direction, u.lobe), &wi_local,
                                &pdfW);
    if (!AnyPositive3(weight))
        return;
    beta *= weight;
    specularBounce = BSDF_IsSpecular(material);
    float eta_scale = Roulette_EtaScale(path->eta_scale, material, wo_local, wi_local);
    float3 new_dir = Frame_ToWorld(frame, wi_local);
    float3 origin = Surface_OffsetOrigin(surface.p, surface.ng, new_dir, surface.error);

    // Possibly terminate the path with Russian roulette
    float q_end = Roulette_EndProbability(russian_roulette, depth, beta, eta_scale);
    if (q_end > 0.0f) {
        if (u.roulette < q_end)
            return;
        beta /= 1.0f - q_end;
    }

    // Queue the path's next ray
    Wavefront_Store3(ray->origin, origin);
    Wavefront_Store3(ray->dir, new_dir);
    Wavefront_Store3(path->beta, beta);
    path->eta_scale = eta_scale;
    path->prev_pdfW = pdfW;
    path->specular = specularBounce ? 1u : 0u;
    next_queue[atomic_inc(&queue_counts[QUEUE_NEXT])] = p;
}

// Stage (d): the occlusion test of every queued light sample; an unblocked one adds its term
// to its path's radiance (a blocked one adds beta * 0, as the megakernel does).
__kernel void wavefront_shadow(uint shadow_count,
                               __global const WavefrontShadowRay *shadow_rays,
                               __global WavefrontPath *paths, WAVEFRONT_SCENE_PARAMS)
{
    uint q = get_global_id(0);
    if (q >= shadow_count)
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;
    __global const WavefrontShadowRay *shadow = &shadow_rays[q];
    float3 contribution = Load3(shadow->contribution);
#ifndef PROFILE_SKIP_SHADOW_RAYS // profiling build: every shadow ray counts as unblocked
    if (Scene_Occluded(&scene, Load3(shadow->origin), Load3(shadow->dir), shadow->tmax))
        contribution = (float3)(0.0f);
#endif
    __global WavefrontPath *path = &paths[shadow->path];
    float3 L = Load3(path->L);
    L += Load3(shadow->beta) * contribution;
    Wavefront_Store3(path->L, L);
}

// Stage (e): each path's radiance to radiance[3 (path_base + p) ...]; a non-finite value is
// counted and stored as 0 (as pbrt does).
__kernel void wavefront_finish(uint path_base, uint path_count,
                               __global const WavefrontPath *paths, __global float *radiance,
                               __global uint *counters)
{
    uint p = get_global_id(0);
    if (p >= path_count)
        return;
    float3 L = Load3(paths[p].L);
    if (!all(isfinite(L))) {
        atomic_inc(&counters[COUNTER_NONFINITE]);
        L = (float3)(0.0f);
    }
    vstore3(L, path_base + p, radiance);
}
