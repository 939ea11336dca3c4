// The product's device self-check (clrender/selfcheck.py, `python -m clrender devices`): raw
// Philox4x32-10 blocks of rng.h, compared on the host with Random123's known answers.
#include "rng.h"

// One Philox block per work-item: out[i] = Philox4x32-10(counters[i], keys[i]).
__kernel void philox_blocks(uint count, __global const uint4 *counters,
                            __global const uint2 *keys, __global uint4 *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = Rng_Philox4x32(counters[i], keys[i]);
}
