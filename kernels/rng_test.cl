// Test kernel (built only by tests/test_rng.py): rng.h's uniforms, one slot per work-item, for
// a bit-for-bit comparison with the NumPy twin clrender/rng.py. The raw Philox blocks are the
// product's self-check kernel, kernels/selfcheck.cl.
#include "rng.h"

// Four uniforms of slot i = (pixel, sample, dim, redraw) under the seed.
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
