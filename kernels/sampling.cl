// Per-pixel sample sets in pixel-local coordinates, W = [-1/2, 1/2]^2.
//
// A launch covers a list of pixels (a tile, or the pixels to redraw after a rejection), each
// given by its global index and its redraw number. Two passes:
//   count_samples: how many traced samples each pixel gets (n, or N ~ Poisson(n) for SPPP);
//   (the host turns the counts into offsets with a prefix sum)
//   fill_traced, fill_auxiliary: one work-item per output slot writes one position.
// Output layout, one contiguous float2 buffer: all traced samples, pixel by pixel
// (traced_offsets), then all auxiliary nuclei, pixel by pixel (n_aux each). Auxiliary nuclei are
// never traced; they only shape Voronoi cells.
// Random numbers and Poisson draws are inlined: pip PoCL cannot inline calls across its
// builtin library's CPU target (see vecmath.h), and a call spills every vector register.
#pragma clang attribute push(__attribute__((always_inline)), apply_to = function)
#include "poisson.h"
#pragma clang attribute pop
#include "launch.h"

#define SAMPLER_UNIFORM 0
#define SAMPLER_STRATIFIED 1
#define SAMPLER_SPPP 2

__kernel void count_samples(uint pixel_count, uint seed, int sampler, uint n, float mean,
                            __global const uint *pixels, __global const uint *redraws,
                            __global uint *counts)
{
    uint p = get_global_id(0);
    if (p >= pixel_count)
        return;
    counts[p] = sampler == SAMPLER_SPPP ? Poisson_Sample(mean, seed, pixels[p], redraws[p]) : n;
}

// Jittered strata: sample s falls in stratum (s mod m, s div m) of an m x m grid.
inline float2 Sampling_StratifiedPosition(uint s, uint strata, float2 jitter)
{
    float2 cell = (float2)((float)(s % strata), (float)(s / strata));
    // Rounding may land on the edge: keep the point strictly inside W like the other samplers.
    return clamp((cell + jitter) / (float)strata - 0.5f, -0x1.fffffep-2f, 0x1.fffffep-2f);
}

// A point uniform by area over the strip W' \ W: top and bottom rectangles (1 + 2 eps) x eps
// hold the corners, left and right rectangles are 1 x eps; one is picked in proportion to area.
// Written with selects, not branches: PoCL vectorises it across work-items (3x faster).
inline float2 Sampling_StripPosition(float eps, float4 u)
{
    float long_side = 1.0f + 2.0f * eps;
    float area_tb = long_side * eps;
    float pick = u.x * (2.0f * area_tb + 2.0f * eps);
    bool top_or_bottom = pick < 2.0f * area_tb;
    bool negative_side = top_or_bottom ? pick < area_tb : pick < 2.0f * area_tb + eps;
    float outward = (negative_side ? -1.0f : 1.0f) * (0.5f + u.z * eps);
    float2 on_top_or_bottom = (float2)(-0.5f - eps + u.y * long_side, outward);
    float2 on_left_or_right = (float2)(outward, -0.5f + u.y);
    return top_or_bottom ? on_top_or_bottom : on_left_or_right;
}

// Traced sample s of pixel p: dimension 0 of its stream is its position.
__kernel void fill_traced(uint pixel_count, uint seed, int sampler, uint fixed_count,
                          uint strata, uint traced_total, __global const uint *pixels,
                          __global const uint *redraws, __global const uint *traced_offsets,
                          __global float2 *positions)
{
    uint i = get_global_id(0);
    if (i >= traced_total)
        return;
    // Fixed-count samplers find the pixel by a division, SPPP by searching the offsets.
    uint p = sampler == SAMPLER_SPPP ? Launch_OwnerPixel(traced_offsets, pixel_count, i)
                                     : i / fixed_count;
    uint s = i - traced_offsets[p];
    // Its position: a jittered stratum, else uniform in W
    if (sampler == SAMPLER_STRATIFIED) {
        float4 u = Rng_Uniform4(seed, pixels[p], s, 0u, redraws[p]);
        positions[i] = Sampling_StratifiedPosition(s, strata, u.xy);
    } else {
        positions[i] = Rng_Centered2(seed, pixels[p], s, 0u, redraws[p]);
    }
}

// Auxiliary nucleus j of pixel p, written after all traced samples; its sample index range is
// its own, so it never shares random numbers with a traced sample.
__kernel void fill_auxiliary(uint pixel_count, uint seed, float eps, uint n_aux,
                             uint traced_total, __global const uint *pixels,
                             __global const uint *redraws, __global float2 *positions)
{
    uint i = get_global_id(0);
    if (i >= n_aux * pixel_count)
        return;
    uint p = i / n_aux;
    uint j = i - p * n_aux;
    // Uniform by area over the strip, from dimension 0 of the nucleus's own sample index
    float4 u = Rng_Uniform4(seed, pixels[p], RNG_AUX_BASE + j, 0u, redraws[p]);
    positions[traced_total + i] = Sampling_StripPosition(eps, u);
}
