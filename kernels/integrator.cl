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
#include "integrator.h"

// One work-item per traced sample: radiance (RGB float) to radiance[3 i .. 3 i + 2].
__kernel KERNEL_SCALAR_WORK_ITEMS void
trace_paths(uint traced_total, uint pixel_count, uint seed, uint image_width, uint image_height,
            int max_depth, int nee, int russian_roulette, int paths_kind, uint fixed_count,
            uint strata, uint zsobol_log2_count, uint zsobol_bits, __global const float2 *positions,
            __global const uint *traced_offsets, __global const uint *pixels,
            __global const uint *redraws, __global const Camera *camera, __global const Quad *quads,
            __global const QuadBlock *quad_blocks, uint quad_count, uint quad_block_count,
            __global const Sphere *spheres, uint sphere_count, __global const Material *materials,
            __global const Emitter *emitters, uint emitter_count,
            __global const Triangle *triangles, uint triangle_count,
            __global const TriangleNormals *triangle_normals, __global const BVHNode *bvh_nodes,
            uint bvh_node_count, __global const uint *bvh_prims, __global float *radiance,
            __global uint *counters)
{
    uint i = get_global_id(0);
    if (i >= traced_total)
        return;
    SceneData scene = SCENE_DATA_OF_ARGUMENTS;

    // Find the sample's pixel, its index in the pixel and its image position
    uint slot, sample;
    float2 image_pos = Integrator_SamplePosition(positions, traced_offsets, pixels, pixel_count,
                                                 image_width, i, &slot, &sample);
    uint pixel = pixels[slot];

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
