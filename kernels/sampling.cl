// Per-pixel sample sets in pixel-local coordinates, W = [-1/2, 1/2]^2.
//
// A launch covers a list of pixels (a tile, or the pixels to redraw after a rejection), each
// given by its global index and its redraw number. Two passes:
//   count_samples: how many traced samples each pixel gets (n, or N ~ Poisson(n) for SPPP);
//   (the host turns the counts into offsets with a prefix sum)
//   fill_traced: one work-item per 8 traced samples of a pixel writes them (8-wide vectors;
//   SPPP's groups found from per-pixel group offsets, a second prefix sum on the host);
//   fill_traced_from_sampler: one work-item per SIMD_WIDTH traced samples of a pixel whose
//   positions come from a path sampler (on vector lanes, kernels/sampler_lanes.h); fill_auxiliary: one per 8 auxiliary nuclei of a pixel writes them (8-wide vectors).
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
#include "sampler_lanes.h"
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

// Rng_ToCentered on 8 lanes: (k + 1/2) 2^-24 - 1/2 from the top 24 bits, exactly.
CL_INLINE float8 Sampling_ToCentered8(uint8 bits)
{
    int8 k = __builtin_convertvector(bits >> 8, int8) - 0x800000;
    return (__builtin_convertvector(k, float8) + 0.5f) * 0x1p-24f;
}

// 16 floats to a 4-byte aligned address (vstore16 without the call).
typedef float Float16Unaligned __attribute__((ext_vector_type(16), aligned(4)));

// Traced samples 8 g .. 8 g + 7 of pixel p (those below its count), for positions drawn
// straight from Philox (independent, SPPP) or a jittered stratum in order: each sample's
// dimension 0 (counter (s, 0, redraw, 0), key (seed, pixel); Rng_Centered2 or Rng_Uniform4),
// 8 lanes at once. The pixel of a group: by a division for fixed counts, for SPPP by searching
// group_offsets (pixel p's groups are [group_offsets[p], group_offsets[p + 1])).
__kernel void fill_traced(uint pixel_count, uint seed, int positions_kind, uint fixed_count,
                          uint strata, int toroidal_shift, uint group_total,
                          __global const uint *pixels, __global const uint *redraws,
                          __global const uint *traced_offsets,
                          __global const uint *group_offsets, __global float2 *positions)
{
    uint id = get_global_id(0);
    if (id >= group_total)
        return;
    uint p, first;
    if (positions_kind == POSITIONS_SPPP) {
        p = Launch_OwnerPixel(group_offsets, pixel_count, id);
        first = 8u * (id - group_offsets[p]);
    } else {
        uint groups = (fixed_count + 7u) / 8u;
        p = id / groups;
        first = 8u * (id - p * groups);
    }
    uint pixel = pixels[p], redraw = redraws[p];
    // The eight samples' dimension-0 bits
    uint8 s = first + (uint8)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u);
    uint8 c0 = s, c1 = 0u, c2 = redraw, c3 = 0u;
    Sampling_Philox8(&c0, &c1, &c2, &c3, (uint2)(seed, pixel));
    // Their positions: a jittered stratum in order, else uniform in W
    float8 x, y;
    if (positions_kind == POSITIONS_STRATIFIED_IN_ORDER) {
        // Jittered stratum (s mod m, s div m) of the m x m grid, m = strata: s div m is the
        // integer part of (s + 1/2) / m, which lies at least 1/(2m) >= 2^-11 from any integer
        // (s < m^2 <= 2^20, s + 1/2 exact in float): so even a division within OpenCL's 2.5 ulp
        // (not correctly rounded) truncates right. Rounding may land the point on the edge: it
        // is kept strictly inside W like the other samplers
        float8 middle = __builtin_convertvector(s, float8) + 0.5f;
        uint8 row = __builtin_convertvector(middle / (float)strata, uint8);
        float8 cell_x = __builtin_convertvector(s - row * strata, float8);
        float8 cell_y = __builtin_convertvector(row, float8);
        float8 lower = (float8)(-0x1.fffffep-2f), upper = (float8)(0x1.fffffep-2f);
        x = (cell_x + Sampling_ToUnit8(c0)) / (float)strata - 0.5f;
        y = (cell_y + Sampling_ToUnit8(c1)) / (float)strata - 0.5f;
        x = x < lower ? lower : (x > upper ? upper : x);
        y = y < lower ? lower : (y > upper ? upper : y);
    } else {
        x = Sampling_ToCentered8(c0);
        y = Sampling_ToCentered8(c1);
    }
    // The pixel's toroidal shift, if asked for (Sampler_ToroidalShift, one draw for the group)
    if (toroidal_shift) {
        float4 shift =
            Rng_Uniform4(seed, pixel, RNG_PIXEL_STREAM, SAMPLER_SHIFT_DIMENSION, redraw);
        x += shift.x;
        y += shift.y;
        x = x >= 0.5f ? x - 1.0f : x;
        y = y >= 0.5f ? y - 1.0f : y;
        x = x > -SAMPLER_BELOW_HALF ? x : -SAMPLER_BELOW_HALF;
        y = y > -SAMPLER_BELOW_HALF ? y : -SAMPLER_BELOW_HALF;
    }
    // Stored interleaved, the whole group at once when full, else lane by lane
    union {
        float16 v;
        float2 lane[8];
    } xy;
    xy.v = __builtin_shufflevector(x, y, 0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15);
    uint count = traced_offsets[p + 1] - traced_offsets[p] - first;
    __global float2 *out = positions + traced_offsets[p] + first;
    if (count >= 8u) {
        *(__global Float16Unaligned *)out = xy.v;
    } else {
        for (uint k = 0; k < count; ++k)
            out[k] = xy.lane[k];
    }
}

// Traced samples SIMD_WIDTH g .. SIMD_WIDTH (g + 1) - 1 of pixel p (those below n), for
// positions from a path sampler (dimensions 0 and 1 of its sample: stratified, sobol, zsobol;
// Sampler_Position of kernels/sampler.h on lanes, kernels/sampler_lanes.h), one lane a sample.
__kernel SIMD_ATTR void fill_traced_from_sampler(uint pixel_count, uint seed, int paths_kind,
                                                 uint fixed_count, uint strata,
                                                 uint image_width, uint zsobol_log2_count,
                                                 uint zsobol_bits, int toroidal_shift,
                                                 __global const uint *pixels,
                                                 __global const uint *redraws,
                                                 __global const uint *traced_offsets,
                                                 __global float2 *positions)
{
    uint groups = (fixed_count + SIMD_WIDTH - 1u) / SIMD_WIDTH;
    uint id = get_global_id(0);
    if (id >= groups * pixel_count)
        return;
    uint p = id / groups;
    uint first = SIMD_WIDTH * (id - p * groups);
    uint pixel = pixels[p], redraw = redraws[p];
    uint count = fixed_count - first < SIMD_WIDTH ? fixed_count - first : SIMD_WIDTH;
    // The lanes' samples (lanes past the pixel's last sample repeat it, and are not stored)
    LANES(uint, vuint) sample_l;
    for (uint j = 0; j < SIMD_WIDTH; ++j)
        sample_l.s[j] = first + (j < count ? j : count - 1u);
    vuint sample = sample_l.v;
    // The pixel's Sampler (its key; zsobol's Morton code above the sample bits), then the lanes'
    Sampler base = Sampler_Make(paths_kind, seed, pixel, 0u, redraw, fixed_count, strata,
                                image_width, zsobol_log2_count, zsobol_bits);
    SamplerLanes lanes;
    lanes.kind = paths_kind;
    lanes.zsobol_bits = zsobol_bits;
    lanes.key_x = (vuint)base.key.x;
    lanes.key_y = (vuint)base.key.y;
    lanes.index = paths_kind == PATHS_ZSOBOL ? base.zsobol_index | sample : sample;
    LANES(float, vfloat) x, y;
    if (paths_kind == PATHS_STRATIFIED) {
        // The jitter (dimension 0's Philox uniforms), then the grid cell of dimension pair 0;
        // below 1 stays below 1/2 once centred, a tiny value may round to -1/2: kept inside
        Strata st = Strata_Make(fixed_count, strata);
        vfloat u2, u3;
        V_Uniform4(seed, (vuint)pixel, sample, 0u, (vuint)redraw, &x.v, &y.v, &u2, &u3);
        V_Stratified2(&lanes, &st, (vuint)0u, &x.v, &y.v);
        x.v -= 0.5f;
        y.v -= 0.5f;
        x.v = x.v > -SAMPLER_BELOW_HALF ? x.v : (vfloat)(-SAMPLER_BELOW_HALF);
        y.v = y.v > -SAMPLER_BELOW_HALF ? y.v : (vfloat)(-SAMPLER_BELOW_HALF);
    } else {
        vuint bits_x, bits_y;
        V_SobolBits(&lanes, (vuint)0u, &bits_x, &bits_y);
        x.v = V_ToCentered(bits_x);
        y.v = V_ToCentered(bits_y);
    }
    // Stored lane by lane, with the pixel's toroidal shift if asked for
    __global float2 *out = positions + traced_offsets[p] + first;
    float2 shift = toroidal_shift ? Sampler_ShiftOf(seed, pixel, redraw) : (float2)(0.0f);
    for (uint j = 0; j < count; ++j) {
        float2 position = (float2)(x.s[j], y.s[j]);
        out[j] = toroidal_shift ? Sampler_ShiftOnTorus(position, shift) : position;
    }
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
