// Test kernel (built only by tests/test_samplers.py): the low-discrepancy building blocks of
// lowdiscrepancy.h and the samplers of sampler.h, value by value, for checks on the host.
#include "sampler.h"

// out[i] = (Sobol dimension 0, Sobol dimension 1) of index i, unscrambled.
__kernel void sobol_points(uint count, __global uint2 *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = (uint2)(Sobol_Dimension0(i), Sobol_Dimension1(i));
}

// out[i] = Owen scramble of values[i] under the seed.
__kernel void owen_scramble(uint count, uint seed, __global const uint *values,
                            __global uint *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = LD_OwenScramble(values[i], seed);
}

// out[i] = element i of the permutation of [0, n) chosen by (key, rotation).
__kernel void permutation_elements(uint n, uint key, uint rotation, __global uint *out)
{
    uint i = get_global_id(0);
    if (i >= n)
        return;
    out[i] = LD_PermutationElement(i, n, key, rotation);
}

// out[i] = (Morton code of xy[i], digit hash_digit[i].y under the permutation hash_digit[i].x
// picks).
__kernel void morton_and_digits(uint count, __global const uint2 *xy,
                                __global const uint2 *hash_digit, __global uint2 *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    out[i] = (uint2)(LD_Morton2(xy[i].x, xy[i].y),
                     LD_PermuteDigit4(hash_digit[i].x, hash_digit[i].y));
}

// Every dimension a path of `depths` bounces would draw, for item i = (pixel, sample, redraw):
// out[i * stride ...] = position (x, y in W), then per bounce: emitter choice, emitter point
// (2), lobe, direction (2), roulette; stride = 2 + 7 depths.
__kernel void sampler_dimensions(uint count, int kind, uint seed, uint n, uint strata,
                                 uint image_width, uint zsobol_log2_count, uint zsobol_bits,
                                 uint depths, __global const uint4 *items, __global float *out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    uint4 item = items[i]; // (pixel, sample, redraw, unused)
    Sampler s = Sampler_Make(kind, seed, item.x, item.y, item.z, n, strata, image_width,
                             zsobol_log2_count, zsobol_bits);
    uint stride = 2u + SAMPLER_BOUNCE_DIMENSIONS * depths;
    __global float *o = out + (ulong)i * stride;
    float2 position = Sampler_Position(&s);
    o[0] = position.x;
    o[1] = position.y;
    for (uint d = 0u; d < depths; ++d) {
        BounceSamples b = Sampler_Bounce(&s, d);
        __global float *ob = o + 2u + SAMPLER_BOUNCE_DIMENSIONS * d;
        ob[0] = b.emitter_choice;
        ob[1] = b.emitter_point.x;
        ob[2] = b.emitter_point.y;
        ob[3] = b.lobe;
        ob[4] = b.direction.x;
        ob[5] = b.direction.y;
        ob[6] = b.roulette;
    }
}
