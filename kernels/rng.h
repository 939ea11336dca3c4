// Philox4x32-10 counter-based RNG (Salmon et al., SC 2011; the Random123 reference).
//
// Stream layout used everywhere in clrender:
//   key     = (seed, pixel)                pixel = y * image_width + x (global, tile-independent)
//   counter = (sample, dimension, redraw, 0)
// so any number is a pure function of (seed, pixel, sample, dimension, redraw): the same seed
// gives the same image whatever the tile size or launch order.
// Reserved sample indices: traced samples use 0 .. RNG_AUX_BASE-1, auxiliary nuclei
// RNG_AUX_BASE + j, and per-pixel draws use RNG_PIXEL_STREAM: the Poisson count its dimensions
// below 4096 (poisson.h), the samplers' keys dimension 0x80000000 and the toroidal shift
// 0x7FFFFFFF (sampler.h; zsobol's image-wide keys use pixel 0xFFFFFFFF).
// Dimension 0 of a traced sample is its position in the pixel; the integrator uses 1 and up.
#ifndef CLRENDER_RNG_H
#define CLRENDER_RNG_H

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u

#define RNG_AUX_BASE 0x40000000u
#define RNG_PIXEL_STREAM 0xFFFFFFFFu

// Philox4x32-10: ten rounds, each two 32x32->64 multiplies and a Feistel-like mix with the key,
// with the Weyl key schedule between rounds. The products are taken as 64-bit integers: PoCL
// vectorises that across work-items, where mul_hi stays scalar (measured: 6x faster, identical
// bits).
inline uint4 Rng_Philox4x32(uint4 ctr, uint2 key)
{
#pragma unroll
    for (int round = 0; round < 10; ++round) {
        ulong product0 = (ulong)PHILOX_M0 * (ulong)ctr.x;
        ulong product1 = (ulong)PHILOX_M1 * (ulong)ctr.z;
        ctr = (uint4)((uint)(product1 >> 32) ^ ctr.y ^ key.x, (uint)product1,
                      (uint)(product0 >> 32) ^ ctr.w ^ key.y, (uint)product0);
        key += (uint2)(PHILOX_W0, PHILOX_W1);
    }
    return ctr;
}

// 32 random bits to a float strictly inside (0, 1): the top 23 bits plus half a step, so
// every value (k + 1/2) 2^-23 is exact in float (24 bits would round the largest up to 1).
inline float Rng_ToUnit(uint bits)
{
    return ((float)(bits >> 9) + 0.5f) * 0x1p-23f;
}

// 32 random bits to a float strictly inside (-1/2, 1/2) with 2^-24 resolution, exactly.
inline float Rng_ToCentered(uint bits)
{
    return ((float)((int)(bits >> 8) - 0x800000) + 0.5f) * 0x1p-24f;
}

inline uint4 Rng_Bits4(uint seed, uint pixel, uint sample, uint dim, uint redraw)
{
    return Rng_Philox4x32((uint4)(sample, dim, redraw, 0u), (uint2)(seed, pixel));
}

// Four independent uniforms in (0, 1) for one (sample, dimension) slot of a pixel.
inline float4 Rng_Uniform4(uint seed, uint pixel, uint sample, uint dim, uint redraw)
{
    uint4 b = Rng_Bits4(seed, pixel, sample, dim, redraw);
    return (float4)(Rng_ToUnit(b.x), Rng_ToUnit(b.y), Rng_ToUnit(b.z), Rng_ToUnit(b.w));
}

// Two coordinates strictly inside the pixel W = (-1/2, 1/2)^2 for one (sample, dimension).
inline float2 Rng_Centered2(uint seed, uint pixel, uint sample, uint dim, uint redraw)
{
    uint4 b = Rng_Bits4(seed, pixel, sample, dim, redraw);
    return (float2)(Rng_ToCentered(b.x), Rng_ToCentered(b.y));
}

#endif
