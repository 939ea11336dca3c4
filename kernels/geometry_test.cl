// Test kernel (built only by tests/test_geometry.py): geometry.h's Scene_Intersect on arrays
// of rays, against a float64 NumPy reference.
#include "scene_types.h"
#include "geometry.h"

// Closest hit of each ray (unit directions): distance (INFINITY on a miss) and primitive id.
__kernel void intersect_rays(uint count, __global const QuadBlock *quad_blocks,
                             uint quad_count, uint quad_block_count,
                             __global const Sphere *spheres, uint sphere_count,
                             __global const float *origins, __global const float *directions,
                             __global float *t, __global int *prim)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = {0, quad_blocks, spheres, 0, 0, quad_count, quad_block_count, sphere_count,
                       0u};
    int id;
    t[i] = Scene_Intersect(&scene, vload3(i, origins), vload3(i, directions), INFINITY, &id);
    prim[i] = id;
}
