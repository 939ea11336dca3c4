// Test kernels (built only by tests/test_bvh_traversal.py): the BVH leaves' 8-lane triangle test
// (geometry.h TriangleBlock_Hits) against the one-triangle test it replaces (Triangle_Hit).
#include "scene_types.h"
#include "geometry.h"

// Ray i against every triangle k = 8 b + lane, up to tmax[i]: the distance where each test
// reports a hit, INFINITY elsewhere; by the block test (t_block) and by the scalar test
// (t_scalar), both ray_count x block_count x BVH_BLOCK_WIDTH.
__kernel void triangle_block_hits(uint ray_count, __global const float *origins,
                                  __global const float *directions, __global const float *tmax,
                                  __global const TriangleBlock *blocks,
                                  __global const Triangle *triangles, uint block_count,
                                  __global float *t_block, __global float *t_scalar)
{
    uint i = get_global_id(0);
    if (i >= ray_count)
        return;
    TriangleRay r = TriangleRay_Make(vload3(i, origins), vload3(i, directions));
    for (uint b = 0; b < block_count; ++b) {
        union {
            float8 v;
            float s[BVH_BLOCK_WIDTH];
        } t;
        int8 hit = TriangleBlock_Hits(&blocks[b], &r, tmax[i], &t.v);
        t.v = hit ? t.v : (float8)(INFINITY);
        for (uint lane = 0; lane < BVH_BLOCK_WIDTH; ++lane) {
            uint k = b * BVH_BLOCK_WIDTH + lane;
            float tk;
            float3 bary;
            bool scalar_hit = Triangle_Hit(&triangles[k], &r, tmax[i], &tk, &bary);
            t_block[(size_t)i * block_count * BVH_BLOCK_WIDTH + k] = t.s[lane];
            t_scalar[(size_t)i * block_count * BVH_BLOCK_WIDTH + k] =
                scalar_hit ? tk : INFINITY;
        }
    }
}

__kernel void struct_sizes(__global uint *sizes)
{
    sizes[0] = sizeof(TriangleBlock);
}
