// Per-pixel sample sets in pixel-local coordinates, W = [-1/2, 1/2]^2.
//
// A launch covers a list of pixels (a tile, or the pixels to redraw after a rejection), each
// given by its global index and its redraw number. Two passes:
//   count_samples: how many traced samples each pixel gets (n, or N ~ Poisson(n) for SPPP);
//   (the host turns the counts into offsets with a prefix sum)
//   fill_traced: one work-item per traced slot writes one position; fill_auxiliary: one per
//   8 auxiliary nuclei of a pixel writes them (8-wide vectors).
// Output layout, one contiguous float2 buffer: all traced samples, pixel by pixel
// (traced_offsets), then all auxiliary nuclei, pixel by pixel (n_aux each). Auxiliary nuclei are
// never traced; they only shape Voronoi cells.
// Positions: i.i.d. (independent), the stratified-pixel grid in order, SPPP, or dimensions 0 and
// 1 of a path sampler (stratified, sobol, zsobol; kernels/sampler.h), optionally shifted on the
// torus W as a whole (a Cranley-Patterson rotation, per pixel and redraw, for pvor).
// Random numbers and Poisson draws are inlined: pip PoCL cannot inline calls across its
// builtin library's CPU target (see vecmath.h), and a call spills every vector register.
#pragma clang attribute push(__attribute__((always_inline)), apply_to = function)
#include "poisson.h"
#include "sampler.h"
#pragma clang attribute pop
#include "launch.h"
#include "vecmath.h"

#define POSITIONS_INDEPENDENT 0
#define POSITIONS_STRATIFIED_IN_ORDER 1
#define POSITIONS_SPPP 2
#define POSITIONS_FROM_SAMPLER 3

__kernel void count_samples(uint pixel_count, uint seed, int positions_kind, uint n, float mean,
                            __global const uint *pixels, __global const uint *redraws,
                            __global uint *counts)
{
    uint p = get_global_id(0);
    if (p >= pixel_count)
        return;
    bool poisson = positions_kind == POSITIONS_SPPP;
    counts[p] = poisson ? Poisson_Sample(mean, seed, pixels[p], redraws[p]) : n;
}

// Jittered strata: sample s falls in stratum (s mod m, s div m) of an m x m grid.
inline float2 Sampling_StratifiedPosition(uint s, uint strata, float2 jitter)
{
    float2 cell = (float2)((float)(s % strata), (float)(s / strata));
    // Rounding may land on the edge: keep the point strictly inside W like the other samplers.
    return clamp((cell + jitter) / (float)strata - 0.5f, -0x1.fffffep-2f, 0x1.fffffep-2f);
}

// Points uniform by area over the strip W' \ W, 8 at once (lane k from the four uniforms
// (u0.k, u1.k, u2.k, u3.k) of one nucleus; u3 is unused): top and bottom rectangles
// (1 + 2 eps) x eps hold the corners, left and right rectangles are 1 x eps; one is picked in
// proportion to area. Written with selects, not branches.
CL_INLINE void Sampling_StripPositions8(float eps, float8 u0, float8 u1, float8 u2, float8 *x,
                                        float8 *y)
{
    float long_side = 1.0f + 2.0f * eps;
    float area_tb = long_side * eps;
    float8 pick = u0 * (2.0f * area_tb + 2.0f * eps);
    int8 top_or_bottom = pick < 2.0f * area_tb;
    int8 negative_side = top_or_bottom ? pick < area_tb : pick < 2.0f * area_tb + eps;
    float8 outward = (negative_side ? (float8)(-1.0f) : (float8)(1.0f)) * (0.5f + u2 * eps);
    *x = top_or_bottom ? -0.5f - eps + u1 * long_side : outward;
    *y = top_or_bottom ? outward : -0.5f + u1;
}

// Rng_Philox4x32 (kernels/rng.h) on 8 counters at once under one key: the same bits lane by
// lane. On explicit 8-wide vectors because PoCL leaves the scalar form scalar in its work-item
// loop (measured: ~30 ns per nucleus); the 32 x 32 -> 64-bit products as 64-bit lanes
// (__builtin_convertvector: convert_ulong8 is a library call on pip's PoCL, see vecmath.h).
CL_INLINE void Sampling_Philox8(uint8 *c0, uint8 *c1, uint8 *c2, uint8 *c3, uint2 key)
{
#pragma unroll
    for (int round = 0; round < 10; ++round) {
        ulong8 product0 = (ulong8)PHILOX_M0 * __builtin_convertvector(*c0, ulong8);
        ulong8 product1 = (ulong8)PHILOX_M1 * __builtin_convertvector(*c2, ulong8);
        uint8 next0 = __builtin_convertvector(product1 >> 32, uint8) ^ *c1 ^ key.x;
        uint8 next2 = __builtin_convertvector(product0 >> 32, uint8) ^ *c3 ^ key.y;
        *c1 = __builtin_convertvector(product1, uint8);
        *c3 = __builtin_convertvector(product0, uint8);
        *c0 = next0;
        *c2 = next2;
        key += (uint2)(PHILOX_W0, PHILOX_W1);
    }
}

// Rng_ToUnit on 8 lanes: (k + 1/2) 2^-23 from the top 23 bits, exactly.
CL_INLINE float8 Sampling_ToUnit8(uint8 bits)
{
    return (__builtin_convertvector(bits >> 9, float8) + 0.5f) * 0x1p-23f;
}

// Traced sample s of pixel p: its position (dimensions 0 and 1 of its sample).
__kernel void fill_traced(uint pixel_count, uint seed, int positions_kind, int paths_kind,
                          uint fixed_count, uint strata, uint image_width,
                          uint zsobol_log2_count, uint zsobol_bits, int toroidal_shift,
                          uint traced_total, __global const uint *pixels,
                          __global const uint *redraws, __global const uint *traced_offsets,
                          __global float2 *positions)
{
    uint i = get_global_id(0);
    if (i >= traced_total)
        return;
    // Fixed-count samplers find the pixel by a division, SPPP by searching the offsets.
    uint p = positions_kind == POSITIONS_SPPP ? Launch_OwnerPixel(traced_offsets, pixel_count, i)
                                              : i / fixed_count;
    uint s = i - traced_offsets[p];
    uint pixel = pixels[p], redraw = redraws[p];
    float2 position;
    // Its position: the path sampler's, a jittered stratum in order, else uniform in W
    if (positions_kind == POSITIONS_FROM_SAMPLER) {
        Sampler sampler = Sampler_Make(paths_kind, seed, pixel, s, redraw, fixed_count, strata,
                                       image_width, zsobol_log2_count, zsobol_bits);
        position = Sampler_Position(&sampler);
    } else if (positions_kind == POSITIONS_STRATIFIED_IN_ORDER) {
        float4 u = Rng_Uniform4(seed, pixel, s, 0u, redraw);
        position = Sampling_StratifiedPosition(s, strata, u.xy);
    } else {
        position = Rng_Centered2(seed, pixel, s, 0u, redraw);
    }
    // The pixel's toroidal shift, if asked for
    positions[i] = toroidal_shift ? Sampler_ToroidalShift(seed, pixel, redraw, position)
                                  : position;
}

// Auxiliary nuclei 8 g .. 8 g + 7 of pixel p (those below n_aux), written after all traced
// samples: nucleus j from dimension 0 of its own sample index RNG_AUX_BASE + j, so it never
// shares random numbers with a traced sample (Rng_Uniform4, 8 lanes at once).
__kernel void fill_auxiliary(uint pixel_count, uint seed, float eps, uint n_aux,
                             uint traced_total, __global const uint *pixels,
                             __global const uint *redraws, __global float2 *positions)
{
    uint groups = (n_aux + 7u) / 8u;
    uint id = get_global_id(0);
    if (id >= groups * pixel_count)
        return;
    uint p = id / groups;
    uint first = 8u * (id - p * groups);
    // The eight nuclei's uniforms: counters (sample, dimension 0, redraw, 0), key (seed, pixel)
    uint8 c0 = RNG_AUX_BASE + first + (uint8)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u);
    uint8 c1 = 0u, c2 = redraws[p], c3 = 0u;
    Sampling_Philox8(&c0, &c1, &c2, &c3, (uint2)(seed, pixels[p]));
    // Their positions in the strip, stored lane by lane up to n_aux
    union {
        float8 v;
        float lane[8];
    } x, y;
    Sampling_StripPositions8(eps, Sampling_ToUnit8(c0), Sampling_ToUnit8(c1),
                             Sampling_ToUnit8(c2), &x.v, &y.v);
    __global float2 *out = positions + traced_total + (size_t)p * n_aux + first;
    uint count = n_aux - first < 8u ? n_aux - first : 8u;
    for (uint k = 0; k < count; ++k)
        out[k] = (float2)(x.lane[k], y.lane[k]);
}
