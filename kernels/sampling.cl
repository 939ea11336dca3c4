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
