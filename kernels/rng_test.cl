// Test entry points for rng.h: raw Philox blocks and unit floats, one slot per work-item.
#include "rng.h"

__kernel void philox_blocks(uint count, __global const uint4 *counters,
                            __global const uint2 *keys, __global uint4 *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = Rng_Philox4x32(counters[i], keys[i]);
}

__kernel void uniform_slots(uint count, uint seed, __global const uint4 *slots,
                            __global float4 *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    // slots[i] = (pixel, sample, dim, redraw)
    uint4 s = slots[i];
    out[i] = Rng_Uniform4(seed, s.x, s.y, s.z, s.w);
}
