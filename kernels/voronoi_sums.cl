// Per-pixel sums of Voronoi-weighted radiance, one work-item per pixel (spread over the launch:
// Voronoi_SpreadPixel in voronoi_common.h): what the estimators vor, vor_sn and fvor need
// (clrender.estimators.registry.PixelSums), computed where the radiance and the cell areas
// already are, so that no per-sample array leaves the device.
//
// Inputs: each traced sample's RGB radiance (float), its cell area and status byte from
// voronoi_cell_areas (kernels/voronoi_cells.cl; same -D precision options, and area_real and
// the status bits from voronoi_common.h). Output per pixel: SUMS_PER_PIXEL values, in order
// sum v, sum f v (R, G, B), then the same over the nuclei whose cell lies inside W' (status
// VORONOI_INSIDE), then sum f and sum f^2 (R, G, B each) over every traced sample whatever its
// cell (the mc estimators and the per-pixel variance layer read them); flag bits:
//   SUMS_REDRAW     a traced nucleus has an unbounded cell: the pixel must be redrawn
//   SUMS_FALLBACK   a cell the device could not decide: the host recomputes the pixel
// and the number of samples whose radiance was NaN or infinite (they count as 0 here).
// Samples are summed in sample order. pixel_moments (at the end) forms the plain sums alone.

#include "vecmath.h"
#include "voronoi_common.h"

#define SUMS_PER_PIXEL 14
#define SUMS_REDRAW 1
#define SUMS_FALLBACK 2

// x - x is 0 for every finite x and NaN otherwise (no builtin call: see kernels/vecmath.h)
#define SUMS_FINITE(x) ((x) - (x) == 0)
// pixel_moments: count of the pixel's non-finite samples, then sum f, sum f^2 (R, G, B each)
#define MOMENTS_PER_PIXEL 6

// Sample s's radiance, or 0 if a channel is not finite; returns 1 for a non-finite sample.
CL_INLINE uint Sums_LoadFinite(__global const float *radiance, uint s, float *r, float *g,
                               float *b)
{
    *r = radiance[3 * (size_t)s];
    *g = radiance[3 * (size_t)s + 1];
    *b = radiance[3 * (size_t)s + 2];
    if (SUMS_FINITE(*r) && SUMS_FINITE(*g) && SUMS_FINITE(*b))
        return 0u;
    *r = *g = *b = 0.0f;
    return 1u;
}

// sum f and sum f^2 of one sample added to plain[0..2] and plain[3..5], in the area precision
CL_INLINE void Sums_AddPlain(area_real *plain, float r, float g, float b)
{
    plain[0] += r;
    plain[1] += g;
    plain[2] += b;
    plain[3] += (area_real)r * r;
    plain[4] += (area_real)g * g;
    plain[5] += (area_real)b * b;
}

__kernel KERNEL_SCALAR_WORK_ITEMS void
voronoi_pixel_sums(uint pixel_count, uint pixel_stride, __global const uint *traced_offsets,
                   __global const float *radiance, __global const area_real *areas,
                   __global const uchar *status, __global area_real *sums, __global uchar *flags,
                   __global uint *nonfinite)
{
    uint p;
    if (!Voronoi_SpreadPixel(pixel_count, pixel_stride, &p))
        return;
    area_real total[SUMS_PER_PIXEL] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    uchar flag = 0;
    uint bad = 0;
    for (uint s = traced_offsets[p]; s < traced_offsets[p + 1]; ++s) {
        float r, g, b;
        bad += Sums_LoadFinite(radiance, s, &r, &g, &b);
        // Plain sums and sums of squares, every sample (in the area precision, as on the host)
        Sums_AddPlain(total + 8, r, g, b);
        // Cells that are not exact bounded ones only flag the pixel
        uchar cell = status[s];
        if (!(cell & VORONOI_BOUNDED)) {
            flag |= (cell & VORONOI_FALLBACK) ? SUMS_FALLBACK : SUMS_REDRAW;
            continue;
        }
        // Weighted sums, all nuclei, then the kept ones
        area_real v = areas[s];
        total[0] += v;
        total[1] += r * v;
        total[2] += g * v;
        total[3] += b * v;
        if (cell & VORONOI_INSIDE) {
            total[4] += v;
            total[5] += r * v;
            total[6] += g * v;
            total[7] += b * v;
        }
    }
    for (int k = 0; k < SUMS_PER_PIXEL; ++k)
        sums[(size_t)p * SUMS_PER_PIXEL + k] = total[k];
    flags[p] = flag;
    nonfinite[p] = bad;
}

// The plain sums alone, one work-item per pixel (spread), for renders whose estimators need no cells
// (mc, mc_n and the per-pixel variance layer): per pixel MOMENTS_PER_PIXEL values, the same
// arithmetic and order as voronoi_pixel_sums' plain sums, and the non-finite sample count.
__kernel KERNEL_SCALAR_WORK_ITEMS void
pixel_moments(uint pixel_count, uint pixel_stride, __global const uint *traced_offsets,
              __global const float *radiance, __global area_real *moments, __global uint *nonfinite)
{
    uint p;
    if (!Voronoi_SpreadPixel(pixel_count, pixel_stride, &p))
        return;
    area_real total[MOMENTS_PER_PIXEL] = {0, 0, 0, 0, 0, 0};
    uint bad = 0;
    // Sum the pixel's samples in sample order
    for (uint s = traced_offsets[p]; s < traced_offsets[p + 1]; ++s) {
        float r, g, b;
        bad += Sums_LoadFinite(radiance, s, &r, &g, &b);
        Sums_AddPlain(total, r, g, b);
    }
    for (int k = 0; k < MOMENTS_PER_PIXEL; ++k)
        moments[(size_t)p * MOMENTS_PER_PIXEL + k] = total[k];
    nonfinite[p] = bad;
}
