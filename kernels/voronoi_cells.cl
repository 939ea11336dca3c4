// Voronoi cell areas of per-pixel SPPP sample sets.
//
// Each pixel's nuclei (its traced samples in W plus its auxiliary nuclei in the strip W' \ W)
// form their own diagram; only the cells of the traced nuclei are computed. Two kernels:
//   voronoi_build_grid: one work-item per pixel sorts the pixel's nuclei into a uniform
//     grid_side x grid_side grid over [-half_extent, half_extent]^2 (counting sort: counts,
//     prefix sums, fill), so a cell's nuclei are contiguous and a row of cells is one range;
//     each sorted nucleus keeps its index (sorted_index: traced nuclei below traced_total).
//   voronoi_cell_areas: one work-item per (pixel, grid cell that can hold traced nuclei) copies
//     the nuclei of the 3 x 3 block of grid cells around it once, then does each traced nucleus
//     of its grid cell. It walks around the nucleus among the block's nuclei: from the nearest
//     nucleus (always a Voronoi neighbour), each edge ends where the first other bisector
//     crosses it, whose nucleus is the next neighbour; two walks, one each way round, until
//     they meet (two independent chains of steps, which the processor overlaps). That is the exact
//     cell among the block's nuclei; a nucleus outside the block can only change it if it is
//     closer than the nucleus to one of its vertices (inside a disc through the nucleus centred
//     on a vertex), so the grid cells meeting those discs' bounding box are searched and their
//     nuclei clip the polygon. Where the walk cannot decide (a cell unbounded within the
//     block, a full buffer, a rounding-degenerate loop), the cell is clipped from a box by the
//     block's nuclei and then searched the same way ("meshless Voronoi"). The traced nuclei of
//     a grid cell go two at a time, their walks' steps interleaved (four independent chains:
//     one walk alone leaves the processor waiting on latencies; 9-10 % less CPU at n = 256),
//     with the same results as one at a time (-DVORONOI_NO_PAIRS, kept to compare).
// The polygons, their clipping and their areas are in kernels/voronoi_polygon.h.
//
// A clipped polygon that still has an edge of the start box after the search is either
// unbounded (the nucleus lies on the convex hull of its pixel's nuclei) or larger than the box;
// an O(N) test of the cell's recession cone tells them apart. Status bits per traced nucleus:
//   VORONOI_BOUNDED   the cell is bounded (area valid)
//   VORONOI_INSIDE    every vertex lies in [-inside_box, inside_box]^2 (fvor's W' test); built
//                     with VORONOI_INSIDE_DISCS: every vertex's disc through the nucleus does
//                     (image-level cells: the cell is then the same among all nuclei beyond),
//                     and no other nucleus is within near_length of the nucleus (an
//                     argument: 0 elsewhere)
//   VORONOI_FALLBACK  not decided here (vertex overflow, cell beyond the start box, degenerate
//                     collinear configuration): the host recomputes the pixel with Qhull.
//   VORONOI_WALKED    the cell came from the walk (diagnostic: the rest were clipped from a box)
//   VORONOI_WALKED_ONE_WAY  ... from the one-way walk, where the two-way walk met a tie
//                     (diagnostic)
// Coincident nuclei share their cell equally, as in the host reference.
//
// Torus cells (pvor) use the same two kernels: voronoi_periodic_copies first writes each traced
// nucleus and its 8 translates as the pixel's "auxiliary" nuclei, among which a traced nucleus's
// cell is exactly its cell on the torus W.
// Cells clipped to W (cvor) too: voronoi_mirror_copies writes each traced nucleus's mirror
// images in W's four sides as the pixel's "auxiliary" nuclei, among which a traced nucleus's cell
// is exactly its cell among the pixel's traced nuclei clipped to W.

#include "voronoi_polygon.h"

#ifndef VORONOI_BLOCK_CAPACITY
#define VORONOI_BLOCK_CAPACITY 64
#endif
#if VORONOI_BLOCK_CAPACITY % 8 != 0
#error "VORONOI_BLOCK_CAPACITY must be a multiple of 8 (the walk runs over groups of 8)"
#endif
#if VORONOI_BLOCK_CAPACITY > 64
#error "VORONOI_BLOCK_CAPACITY must be at most 64 (the walk marks its edges' lanes in a ulong)"
#endif

#ifndef VORONOI_FIRST_BOX_SPACINGS
#define VORONOI_FIRST_BOX_SPACINGS 2.5f
#endif

// Stop and skip tests keep a relative safety margin for rounding (they only cost extra clips).
#define VORONOI_RADIUS_SLACK 1.0001f

// ---------------------------------------------------------------------------------------------
// Torus copies

// One work-item per traced nucleus j: the nucleus wrapped into [-1/2, 1/2)^2 (x = 1/2 is the
// torus point x = -1/2) goes to slot j, its translates by (dx, dy) in {-1, 0, 1}^2 \ {0} to
// slots traced_total + 8 j + k, so pixel p's translates start at 8 traced_offsets[p]. A torus
// cell lies in x + [-1/2, 1/2]^2, where the nearest copy of every nucleus is one of these 9:
// the cells among them are exact and bounded. Translates are rounded to float (about 6e-8).
__kernel void voronoi_periodic_copies(uint traced_total, __global const float2 *positions,
                                      __global float2 *nuclei)
{
    uint j = get_global_id(0);
    if (j >= traced_total)
        return;
    float2 x = positions[j];
    x.x = x.x >= 0.5f ? x.x - 1.0f : x.x;
    x.y = x.y >= 0.5f ? x.y - 1.0f : x.y;
    nuclei[j] = x;
    __global float2 *copies = nuclei + traced_total + 8 * (size_t)j;
    int k = 0;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx)
            if (dx != 0 || dy != 0)
                copies[k++] = x + (float2)((float)dx, (float)dy);
}

// ---------------------------------------------------------------------------------------------
// Mirror copies

// One work-item per traced nucleus j: the nucleus goes to slot j, its mirror images in the lines
// x = 1/2, x = -1/2, y = 1/2, y = -1/2 to slots traced_total + 4 j + k, so pixel p's mirrors
// start at 4 traced_offsets[p]. The bisector of a nucleus and its mirror in a side is that
// side's line, and for a point z of W a mirror q' is never nearer than its nucleus q (z and q
// lie on the same side of the mirror line): the cells among nuclei and mirrors are exactly the
// nuclei's cells clipped to W, all bounded. Mirrors are rounded to float (about 6e-8), which
// moves a side by half that. A nucleus on a side would coincide with its mirror and share its
// cell: nuclei are taken to the nearest float strictly inside W first (the host reference moves
// them 1e-9 inside; samplers never draw a point on a side).
__kernel void voronoi_mirror_copies(uint traced_total, __global const float2 *positions,
                                    __global float2 *nuclei)
{
    uint j = get_global_id(0);
    if (j >= traced_total)
        return;
    float2 x = clamp(positions[j], -0x1.fffffep-2f, 0x1.fffffep-2f);
    nuclei[j] = x;
    __global float2 *mirrors = nuclei + traced_total + 4 * (size_t)j;
    mirrors[0] = (float2)(1.0f - x.x, x.y);
    mirrors[1] = (float2)(-1.0f - x.x, x.y);
    mirrors[2] = (float2)(x.x, 1.0f - x.y);
    mirrors[3] = (float2)(x.x, -1.0f - x.y);
}

// ---------------------------------------------------------------------------------------------
// Pixels and grid

// Grid column (or row) of coordinate x; points outside the grid go to the border cells, which
// keeps the ring search's distance bound valid (they lie beyond those cells).
CL_INLINE int VoronoiGrid_Index(float x, float half_extent, float inv_cell, int grid_side)
{
    int c = (int)Floor((x + half_extent) * inv_cell);
    return VORONOI_MIN(VORONOI_MAX(c, 0), grid_side - 1);
}

CL_INLINE int VoronoiGrid_CellOf(float2 x, float half_extent, float inv_cell, int grid_side)
{
    return VoronoiGrid_Index(x.y, half_extent, inv_cell, grid_side) * grid_side
           + VoronoiGrid_Index(x.x, half_extent, inv_cell, grid_side);
}

// offsets: the pixels' traced offsets (pixel_count + 1 values), then their auxiliary offsets
// (as many), in one buffer (one upload).

// One pixel per work-item (spread over the launch: Voronoi_SpreadPixel): counting sort of its
// nuclei into grid cells, written from slot base = traced_offsets[p] + aux_offsets[p] of
// sorted_points, with each nucleus's index in positions in sorted_index (traced nuclei: below
// traced_total). cell_of (scratch, as long as sorted_points) keeps each nucleus's grid cell
// from the counting pass for the fill pass.
__kernel void voronoi_build_grid(uint pixel_count, uint pixel_stride, uint traced_total,
                                 int grid_side, float half_extent,
                                 __global const float2 *positions, __global const uint *offsets,
                                 __global uint *cell_start, __global float2 *sorted_points,
                                 __global uint *sorted_index, __global uint *cell_of)
{
    uint p;
    if (!Voronoi_SpreadPixel(pixel_count, pixel_stride, &p))
        return;
    __global const uint *traced_offsets = offsets;
    __global const uint *aux_offsets = offsets + pixel_count + 1;
    int cells = grid_side * grid_side;
    float inv_cell = (float)grid_side / (2.0f * half_extent);
    __global uint *start = cell_start + (size_t)p * (uint)(cells + 1);
    uint t0 = traced_offsets[p], t1 = traced_offsets[p + 1];
    uint a0 = traced_total + aux_offsets[p], a1 = traced_total + aux_offsets[p + 1];
    uint base = t0 + aux_offsets[p];
    __global uint *cell = cell_of + base;  // traced nuclei first, then auxiliary ones

    // Count the nuclei of each grid cell
    for (int c = 0; c <= cells; ++c)
        start[c] = 0u;
    uint k = 0u;
    for (uint j = t0; j < t1; ++j, ++k) {
        cell[k] = (uint)VoronoiGrid_CellOf(positions[j], half_extent, inv_cell, grid_side);
        start[cell[k]] += 1u;
    }
    for (uint j = a0; j < a1; ++j, ++k) {
        cell[k] = (uint)VoronoiGrid_CellOf(positions[j], half_extent, inv_cell, grid_side);
        start[cell[k]] += 1u;
    }

    // Inclusive prefix sums: start[c] becomes the end of cell c
    uint running = 0u;
    for (int c = 0; c < cells; ++c) {
        running += start[c];
        start[c] = running;
    }
    start[cells] = running;

    // Fill back to front: each decrement leaves start[c] at the first slot of cell c
    for (uint j = a1; j > a0; --j) {
        uint s = --start[cell[--k]];
        sorted_points[base + s] = positions[j - 1u];
        sorted_index[base + s] = j - 1u;
    }
    for (uint j = t1; j > t0; --j) {
        uint s = --start[cell[--k]];
        sorted_points[base + s] = positions[j - 1u];
        sorted_index[base + s] = j - 1u;
    }
}

// ---------------------------------------------------------------------------------------------
// Neighbour search

// Clip by the nuclei in sorted slots [s0, s1) that are close enough to cut, counting those that
// coincide with the nucleus (itself included). Returns false on vertex overflow.
CL_INLINE bool VoronoiCell_ClipRange(VoronoiPolygon *poly, real2 x, uint s0, uint s1,
                                     __global const float2 *sorted_points, int *coincident)
{
    for (uint s = s0; s < s1; ++s) {
        float2 neighbour = sorted_points[s];
        real2 v = REAL2(neighbour) - x;
        real dist2 = v.x * v.x + v.y * v.y;
        if (dist2 == 0) {
            *coincident += 1;
            continue;
        }
        // A bisector at distance >= R cannot cut a polygon within radius R
        if (dist2 >= 4.0f * VORONOI_RADIUS_SLACK * poly->radius2)
            continue;
        uint out_mask = VoronoiPolygon_OutsideMask(poly, v);
        if (out_mask != 0u && !VoronoiPolygon_Clip(poly, v, neighbour, out_mask))
            return false;
    }
    return true;
}

// Clip by the grid cells of ring k (Chebyshev distance k from cell (cx, cy)): full rows at the
// ring's top and bottom (contiguous slots), two cells on each row in between.
CL_INLINE bool VoronoiCell_ClipRing(VoronoiPolygon *poly, real2 x, int cx, int cy, int k,
                                    int grid_side, __global const uint *start, uint base,
                                    __global const float2 *sorted_points, int *coincident)
{
    int y0 = VORONOI_MAX(cy - k, 0), y1 = VORONOI_MIN(cy + k, grid_side - 1);
    int x0 = VORONOI_MAX(cx - k, 0), x1 = VORONOI_MIN(cx + k, grid_side - 1);
    bool ok = true;
    for (int y = y0; y <= y1 && ok; ++y) {
        int row = y * grid_side;
        if (y == cy - k || y == cy + k) {
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + x0],
                                       base + start[row + x1 + 1], sorted_points, coincident);
            continue;
        }
        if (cx - k >= 0)
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + cx - k],
                                       base + start[row + cx - k + 1], sorted_points,
                                       coincident);
        if (ok && cx + k < grid_side)
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + cx + k],
                                       base + start[row + cx + k + 1], sorted_points,
                                       coincident);
    }
    return ok;
}

// Clip by the grid cells of rows y0..y1 and columns x0..x1 (indices clamped to the grid) that
// lie outside the block of columns bx0..bx1 on rows by0..by1 (already visited).
CL_INLINE bool VoronoiCell_ClipBoxOutside(VoronoiPolygon *poly, real2 x, int x0, int x1,
                                          int y0, int y1, int bx0, int bx1, int by0,
                                          int by1, int grid_side,
                                          __global const uint *start, uint base,
                                          __global const float2 *sorted_points,
                                          int *coincident)
{
    bool ok = true;
    for (int y = y0; y <= y1 && ok; ++y) {
        int row = y * grid_side;
        if (y < by0 || y > by1) {
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + x0],
                                       base + start[row + x1 + 1], sorted_points, coincident);
            continue;
        }
        if (x0 < bx0)
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + x0],
                                       base + start[row + VORONOI_MIN(x1, bx0 - 1) + 1],
                                       sorted_points, coincident);
        if (ok && x1 > bx1)
            ok = VoronoiCell_ClipRange(poly, x, base + start[row + VORONOI_MAX(x0, bx1 + 1)],
                                       base + start[row + x1 + 1], sorted_points, coincident);
    }
    return ok;
}

// Grid column and row of the nucleus.
CL_INLINE int2 VoronoiCell_GridCell(real2 x, int grid_side, real half_extent)
{
    float inv_cell = (float)grid_side / (2.0f * (float)half_extent);
    return (int2)(VoronoiGrid_Index((float)x.x, (float)half_extent, inv_cell, grid_side),
                  VoronoiGrid_Index((float)x.y, (float)half_extent, inv_cell, grid_side));
}

// Clip by the nuclei of the grid cells that meet the polygon's cut box, outside the 3 x 3 block
// around the nucleus's grid cell g (which the polygon already accounts for): no other nucleus
// can cut, so the polygon is then the exact cell.
CL_INLINE bool VoronoiCell_ClipBeyondBlock(VoronoiPolygon *poly, real2 x, int2 g,
                                           int grid_side, real half_extent,
                                           __global const uint *start, uint base,
                                           __global const float2 *sorted_points,
                                           int *coincident)
{
    float extent = (float)half_extent;
    float inv_cell = (float)grid_side / (2.0f * extent);
    float cell = 2.0f * extent / (float)grid_side;
    // Most cells lie well inside the block: a nucleus that cuts lies within 2 R of x (in a disc
    // through x centred on a vertex), so none is beyond a block side farther than 2 R (a side
    // at the grid's border has no cell beyond). The margin narrowed by the grid's misplacement
    // (~1e-6 cell), the radius widened by the slack
    float fx = (float)x.x, fy = (float)x.y;
    float margin = INFINITY;
    if (g.x > 1)
        margin = VORONOI_MIN(margin, fx - (-extent + (float)(g.x - 1) * cell));
    if (g.x < grid_side - 2)
        margin = VORONOI_MIN(margin, -extent + (float)(g.x + 2) * cell - fx);
    if (g.y > 1)
        margin = VORONOI_MIN(margin, fy - (-extent + (float)(g.y - 1) * cell));
    if (g.y < grid_side - 2)
        margin = VORONOI_MIN(margin, -extent + (float)(g.y + 2) * cell - fy);
    margin -= 1e-5f * cell;
    if (margin > 0 && 4.0f * VORONOI_RADIUS_SLACK * (float)poly->radius2 < margin * margin)
        return true;
    // Widened for rounding: of the box (relative error ~1e-6 of the radius, with the slack)
    // and of the grid, which may misplace a nucleus by ~1e-6 cell
    float4 box = VoronoiPolygon_CutBox(poly);
    float slack = 1e-4f * (box.z - box.x + box.w - box.y) + 1e-5f / inv_cell;
    int x0 = VoronoiGrid_Index((float)x.x + box.x - slack, extent, inv_cell, grid_side);
    int x1 = VoronoiGrid_Index((float)x.x + box.z + slack, extent, inv_cell, grid_side);
    int y0 = VoronoiGrid_Index((float)x.y + box.y - slack, extent, inv_cell, grid_side);
    int y1 = VoronoiGrid_Index((float)x.y + box.w + slack, extent, inv_cell, grid_side);
    // Most cut boxes lie within the block: nothing to search
    if (x0 >= g.x - 1 && x1 <= g.x + 1 && y0 >= g.y - 1 && y1 <= g.y + 1)
        return true;
    return VoronoiCell_ClipBoxOutside(poly, x, x0, x1, y0, y1, g.x - 1, g.x + 1, g.y - 1,
                                      g.y + 1, grid_side, start, base, sorted_points,
                                      coincident);
}

// The clipping search: the 3 x 3 block of grid cells around the nucleus (its own cell first),
// then the cells beyond it within 2 R. Returns false on vertex overflow.
CL_INLINE bool VoronoiCell_Search(VoronoiPolygon *poly, real2 x, int grid_side, real half_extent,
                                  __global const uint *start, uint base,
                                  __global const float2 *sorted_points, int *coincident)
{
    int2 g = VoronoiCell_GridCell(x, grid_side, half_extent);
    *coincident = 0;
    return VoronoiCell_ClipRing(poly, x, g.x, g.y, 0, grid_side, start, base, sorted_points,
                                coincident)
           && VoronoiCell_ClipRing(poly, x, g.x, g.y, 1, grid_side, start, base, sorted_points,
                                   coincident)
           && VoronoiCell_ClipBeyondBlock(poly, x, g, grid_side, half_extent, start, base,
                                          sorted_points, coincident);
}

// ---------------------------------------------------------------------------------------------
// The walk around a cell

// The nuclei of the 3 x 3 block of grid cells around a grid cell, as copied once for all the
// traced nuclei of that cell, and the same nuclei relative to one nucleus of the cell, are
// held in groups of 8 lanes: the walk runs over whole groups as 8-wide vectors (written out,
// so that it does not depend on the compiler's loop vectoriser).
#ifdef VORONOI_DOUBLE
typedef double8 real8;
typedef double4 real4;
typedef long8 lane_index8;  // lane indices and masks of the width of real
typedef long4 lane_index4;
typedef long2 lane_index2;
#else
typedef float8 real8;
typedef float4 real4;
typedef int8 lane_index8;
typedef int4 lane_index4;
typedef int2 lane_index2;
#endif
#define VORONOI_GROUPS (VORONOI_BLOCK_CAPACITY / 8)

typedef union {
    real8 group[VORONOI_GROUPS];
    real lane[VORONOI_BLOCK_CAPACITY];
} VoronoiLanes;

// The block's nuclei (absolute), padded to a whole group with zeros.
typedef struct {
    VoronoiLanes x, y;
    int count;
} VoronoiNeighbourhood;

// The block's nuclei relative to one nucleus x of the cell, with their squared distances,
// padded to a whole group with zero vectors; those coincident with x (itself included) are
// only counted.
typedef struct {
    VoronoiLanes vx, vy, dist2;
    int count;
    int nearest;
} VoronoiBlock;

// The lane of the smallest value of 8 (the lowest index among equal ones), from per-lane
// values and indices: three halvings, all as vector selects (a branch on the comparison
// would mispredict half the time). Vectors by pointer: a double8 argument by value changes
// the ABI without AVX-512 (a compiler warning), even inlined.
CL_INLINE int VoronoiLanes_ArgMin(const real8 *values, const lane_index8 *indices,
                                  real *smallest)
{
    real8 value = *values;
    lane_index8 index = *indices;
    lane_index4 take4 = (value.hi < value.lo) | ((value.hi == value.lo) & (index.hi < index.lo));
    real4 v4 = take4 ? value.hi : value.lo;
    lane_index4 i4 = take4 ? index.hi : index.lo;
    lane_index2 take2 = (v4.hi < v4.lo) | ((v4.hi == v4.lo) & (i4.hi < i4.lo));
    real2 v2 = take2 ? v4.hi : v4.lo;
    lane_index2 i2 = take2 ? i4.hi : i4.lo;
    real2 v1 = v2.yx;
    lane_index2 i1 = i2.yx;
    lane_index2 take1 = (v1 < v2) | ((v1 == v2) & (i1 < i2));
    v2 = take1 ? v1 : v2;
    i2 = take1 ? i1 : i2;
    *smallest = v2.x;
    return (int)i2.x;
}

// Copy the nuclei of the 3 x 3 block of grid cells around g (one contiguous slot range per
// grid row); false when they are more than the buffer holds.
CL_INLINE bool VoronoiNeighbourhood_Gather(VoronoiNeighbourhood *hood, int2 g,
                                           int grid_side, __global const uint *start,
                                           uint base, __global const float2 *sorted_points)
{
    int y0 = VORONOI_MAX(g.y - 1, 0), y1 = VORONOI_MIN(g.y + 1, grid_side - 1);
    int x0 = VORONOI_MAX(g.x - 1, 0), x1 = VORONOI_MIN(g.x + 1, grid_side - 1);
    int count = 0;
    for (int y = y0; y <= y1; ++y) {
        int row = y * grid_side;
        uint s0 = base + start[row + x0];
        int n = (int)(base + start[row + x1 + 1] - s0);
        if (count + n > VORONOI_BLOCK_CAPACITY)
            return false;
        for (int k = 0; k < n; ++k) {
            float2 point = sorted_points[s0 + k];
            hood->x.lane[count + k] = point.x;
            hood->y.lane[count + k] = point.y;
        }
        count += n;
    }
    for (int k = count; k < ((count + 7) & ~7); ++k)
        hood->x.lane[k] = hood->y.lane[k] = 0;
    hood->count = count;
    return true;
}

// The neighbourhood relative to x: distances, coincident count and nearest nucleus. Lanes
// past the count are zero vectors: never the nearest, never bounding an edge.
CL_INLINE void VoronoiBlock_Relative(VoronoiBlock *block, const VoronoiNeighbourhood *hood,
                                     real2 x, int *coincident)
{
    int count = hood->count, groups = (count + 7) / 8;
    const lane_index8 lanes = (lane_index8)(0, 1, 2, 3, 4, 5, 6, 7);
    lane_index8 same = 0;
    real8 nearest_dist2 = INFINITY;
    lane_index8 nearest = VORONOI_BLOCK_CAPACITY;
    for (int j = 0; j < groups; ++j) {
        lane_index8 index = lanes + 8 * j;
        lane_index8 real_nucleus = index < count;
        real8 vx = real_nucleus ? hood->x.group[j] - x.x : (real8)0;
        real8 vy = real_nucleus ? hood->y.group[j] - x.y : (real8)0;
        real8 dist2 = vx * vx + vy * vy;
        block->vx.group[j] = vx;
        block->vy.group[j] = vy;
        block->dist2.group[j] = dist2;
        same -= real_nucleus & (dist2 == 0);  // masks are -1
        lane_index8 closer = (dist2 > 0) & (dist2 < nearest_dist2);
        nearest_dist2 = closer ? dist2 : nearest_dist2;
        nearest = closer ? index : nearest;
    }
    real nearest_value;
    int first = VoronoiLanes_ArgMin(&nearest_dist2, &nearest, &nearest_value);
    *coincident += (int)(same.s0 + same.s1 + same.s2 + same.s3 + same.s4 + same.s5 + same.s6
                         + same.s7);
    block->count = count;
    block->nearest = nearest_value < INFINITY ? first : -1;
}

// The first crossings over group j's nuclei, kept lane by lane (the lowest index on ties):
// of a's bisector going counter-clockwise, by the bisectors of the nuclei on a's left
// (cross > 0), and of c's bisector going clockwise, by those on c's right. One load of the
// group serves both walks; their two chains of selects are independent.
CL_INLINE void VoronoiBlock_CrossGroup(const VoronoiBlock *block, int j, real ax, real ay,
                                       real cx, real cy, real8 *ccw_t, lane_index8 *ccw_index,
                                       real8 *cw_t, lane_index8 *cw_index)
{
    // No fused multiply-adds: a nucleus at a's (c's) position must get a cross product of
    // exactly 0
#pragma OPENCL FP_CONTRACT OFF
    const lane_index8 lanes = (lane_index8)(0, 1, 2, 3, 4, 5, 6, 7);
    lane_index8 index = lanes + 8 * j;
    real8 bx = block->vx.group[j], by = block->vy.group[j], dist2 = block->dist2.group[j];
    // Counter-clockwise along a's bisector (direction perp(a) = (-ay, ax))
    real8 cross = ax * by - ay * bx;
    real8 t = (dist2 - (ax * bx + ay * by)) / cross;
    lane_index8 better = (cross > 0) & (t < *ccw_t);
    *ccw_t = better ? t : *ccw_t;
    *ccw_index = better ? index : *ccw_index;
    // Clockwise along c's bisector (direction -perp(c) = (cy, -cx)); the cross product is the
    // exact negation of the counter-clockwise one
    real8 cw_cross = cy * bx - cx * by;
    real8 cw_t_new = (dist2 - (cx * bx + cy * by)) / cw_cross;
    better = (cw_cross > 0) & (cw_t_new < *cw_t);
    *cw_t = better ? cw_t_new : *cw_t;
    *cw_index = better ? index : *cw_index;
}

// The first step of both walks, from the same edge a: the clockwise cross products and
// crossings are the exact negations of the counter-clockwise ones (CrossGroup with c = a).
CL_INLINE void VoronoiBlock_CrossGroupBothWays(const VoronoiBlock *block, int j, real ax,
                                               real ay, real8 *ccw_t, lane_index8 *ccw_index,
                                               real8 *cw_t, lane_index8 *cw_index)
{
#pragma OPENCL FP_CONTRACT OFF
    const lane_index8 lanes = (lane_index8)(0, 1, 2, 3, 4, 5, 6, 7);
    lane_index8 index = lanes + 8 * j;
    real8 bx = block->vx.group[j], by = block->vy.group[j];
    real8 cross = ax * by - ay * bx;
    real8 t = (block->dist2.group[j] - (ax * bx + ay * by)) / cross;
    lane_index8 better = (cross > 0) & (t < *ccw_t);
    *ccw_t = better ? t : *ccw_t;
    *ccw_index = better ? index : *ccw_index;
    better = (cross < 0) & (-t < *cw_t);
    *cw_t = better ? -t : *cw_t;
    *cw_index = better ? index : *cw_index;
}

// Both walks' next step: the first crossing of a's bisector counter-clockwise (its t in
// *ccw_best, INFINITY if none, and that nucleus returned in *ccw_next) and of c's bisector
// clockwise (*cw_best, *cw_next).
CL_INLINE void VoronoiBlock_FirstCrossings(const VoronoiBlock *block, real ax, real ay,
                                           real cx, real cy, int *ccw_next, real *ccw_best,
                                           int *cw_next, real *cw_best)
{
    int groups = (block->count + 7) / 8;
    real8 ccw_t = INFINITY, cw_t = INFINITY;
    lane_index8 ccw_index = VORONOI_BLOCK_CAPACITY, cw_index = VORONOI_BLOCK_CAPACITY;
    if (ax == cx && ay == cy) {
        for (int j = 0; j < groups; ++j)
            VoronoiBlock_CrossGroupBothWays(block, j, ax, ay, &ccw_t, &ccw_index, &cw_t,
                                            &cw_index);
    } else {
        for (int j = 0; j < groups; ++j)
            VoronoiBlock_CrossGroup(block, j, ax, ay, cx, cy, &ccw_t, &ccw_index, &cw_t,
                                    &cw_index);
    }
    *ccw_next = VoronoiLanes_ArgMin(&ccw_t, &ccw_index, ccw_best);
    *cw_next = VoronoiLanes_ArgMin(&cw_t, &cw_index, cw_best);
}

// The cell of x among the block's nuclei, walked both ways from the nearest nucleus (always
// a Voronoi neighbour) until the two walks meet. The edge on the bisector of neighbour a
// (points a / 2 + t perp(a) / 2, perp(a) = (-a.y, a.x)) ends, counter-clockwise, at the
// smallest t_b = (|b|^2 - a.b) / perp(a).b over the nuclei b on its left (perp(a).b > 0),
// and b is the next neighbour; clockwise, the same with -perp(a). The two walks are
// independent chains of dependent steps, so the processor overlaps them: about half the
// sequential steps of one walk around the cell. They meet when the counter-clockwise walk
// reaches the clockwise walk's edge, or both find the same new neighbour. Returns
// VORONOI_WALK_DONE, or VORONOI_WALK_FAILED for a cell unbounded within the block or with
// more than VORONOI_MAX_VERTICES edges (the clipping search then does the cell), or
// VORONOI_WALK_TIED when the walks do not meet cleanly: at a vertex shared by more than three
// cells (ties, as on a lattice) the two directions may take different zero-length edges, and
// the one-way walk (VoronoiBlock_WalkOneWay) then does the cell.
// Edges found counter-clockwise go to the polygon in order; those found clockwise wait in
// cw_lane (their start vertices in cw_vx, cw_vy) and follow in reverse.
#define VORONOI_WALK_DONE 1
#define VORONOI_WALK_FAILED 0
#define VORONOI_WALK_TIED -1
#define VORONOI_WALK_RUNNING 2

// The state of one two-way walk between its steps.
typedef struct {
    int a, c;  // the current edge of each walk
    int ccw_count, cw_count;  // edges found each way (the first counts as ccw)
    ulong seen;  // the lanes of both walks' edges
    real radius2;
    int cw_lane[VORONOI_MAX_VERTICES];
    real cw_vx[VORONOI_MAX_VERTICES], cw_vy[VORONOI_MAX_VERTICES];
} VoronoiWalk;

// The walk's first edge, on the bisector of the nearest nucleus: VORONOI_WALK_RUNNING, or
// VORONOI_WALK_FAILED when no nucleus of the block differs from x.
CL_INLINE int VoronoiWalk_Start(VoronoiWalk *walk, const VoronoiBlock *block,
                                const VoronoiNeighbourhood *hood, VoronoiPolygon *poly)
{
    int first = block->nearest;
    if (first < 0)
        return VORONOI_WALK_FAILED;
    walk->seen = (ulong)1 << first;
    walk->a = walk->c = first;
    walk->ccw_count = 1;
    walk->cw_count = 0;
    walk->radius2 = 0;
    poly->ex[0] = (float)hood->x.lane[first];  // the input coordinates (exact in real)
    poly->ey[0] = (float)hood->y.lane[first];
    return VORONOI_WALK_RUNNING;
}

// One step of both walks, from the first crossings of their edges (VoronoiBlock_
// FirstCrossings): VORONOI_WALK_RUNNING, or the walk's result.
CL_INLINE int VoronoiWalk_Step(VoronoiWalk *walk, const VoronoiBlock *block,
                               const VoronoiNeighbourhood *hood, VoronoiPolygon *poly,
                               int next, real ccw_best, int prev, real cw_best)
{
    // No fused multiply-adds (the vertices as computed before the walk ran over vectors)
#pragma OPENCL FP_CONTRACT OFF
    if (!(ccw_best < INFINITY) || !(cw_best < INFINITY))
        return VORONOI_WALK_FAILED;
    int a = walk->a, c = walk->c;
    int ccw_count = walk->ccw_count, cw_count = walk->cw_count;
    ulong seen = walk->seen;
    real ax = block->vx.lane[a], ay = block->vy.lane[a];
    real cx = block->vx.lane[c], cy = block->vy.lane[c];
    // The end of a's edge (p) and the start of c's edge (q)
    real half_t = 0.5f * ccw_best, cw_half_t = 0.5f * cw_best;
    real px = 0.5f * ax - half_t * ay, py = 0.5f * ay + half_t * ax;
    real qx = 0.5f * cx + cw_half_t * cy, qy = 0.5f * cy - cw_half_t * cx;
    real p2 = px * px + py * py, q2 = qx * qx + qy * qy;
    real radius2 = VORONOI_MAX(walk->radius2, VORONOI_MAX(p2, q2));
    walk->radius2 = radius2;
    if (cw_count == 0) {
        poly->vx[0] = qx;  // the first edge's start
        poly->vy[0] = qy;
    } else {
        walk->cw_vx[cw_count - 1] = qx;
        walk->cw_vy[cw_count - 1] = qy;
    }
    // Met: the counter-clockwise walk reached c (whose clockwise step must lead back to
    // a), or both walks found the same new edge (which runs from p to q)
    bool reached = next == c && cw_count > 0 && prev == a;
    bool shared = next == prev && (((seen >> next) & 1) == 0);
    if (reached || shared) {
        int count = ccw_count + cw_count + (shared ? 1 : 0);
        if (count > VORONOI_MAX_VERTICES)
            return VORONOI_WALK_FAILED;
        int k = ccw_count;
        if (shared) {
            poly->vx[k] = px;
            poly->vy[k] = py;
            poly->ex[k] = (float)hood->x.lane[next];
            poly->ey[k] = (float)hood->y.lane[next];
            ++k;
        }
        for (int f = cw_count - 1; f >= 0; --f, ++k) {
            poly->vx[k] = walk->cw_vx[f];
            poly->vy[k] = walk->cw_vy[f];
            poly->ex[k] = (float)hood->x.lane[walk->cw_lane[f]];
            poly->ey[k] = (float)hood->y.lane[walk->cw_lane[f]];
        }
        poly->count = count;
        poly->radius2 = radius2;
        return count >= 3 ? VORONOI_WALK_DONE : VORONOI_WALK_FAILED;
    }
    // Otherwise both walks go on to new edges (an edge seen before: they missed each other)
    if (next == prev || ((seen >> next) & 1) != 0 || ((seen >> prev) & 1) != 0)
        return VORONOI_WALK_TIED;
    walk->seen = seen | ((ulong)1 << next) | ((ulong)1 << prev);
    poly->vx[ccw_count] = px;
    poly->vy[ccw_count] = py;
    poly->ex[ccw_count] = (float)hood->x.lane[next];
    poly->ey[ccw_count] = (float)hood->y.lane[next];
    walk->ccw_count = ccw_count + 1;
    walk->cw_lane[cw_count] = prev;
    walk->cw_count = cw_count + 1;
    walk->a = next;
    walk->c = prev;
    return ccw_count + 1 + cw_count + 1 < VORONOI_MAX_VERTICES ? VORONOI_WALK_RUNNING
                                                               : VORONOI_WALK_FAILED;
}

// One step of a running walk: the first crossings of its edges, then the step.
CL_INLINE int VoronoiWalk_Advance(VoronoiWalk *walk, const VoronoiBlock *block,
                                  const VoronoiNeighbourhood *hood, VoronoiPolygon *poly)
{
    int next, prev;
    real ccw_best, cw_best;
    VoronoiBlock_FirstCrossings(block, block->vx.lane[walk->a], block->vy.lane[walk->a],
                                block->vx.lane[walk->c], block->vy.lane[walk->c], &next,
                                &ccw_best, &prev, &cw_best);
    return VoronoiWalk_Step(walk, block, hood, poly, next, ccw_best, prev, cw_best);
}

CL_INLINE int VoronoiBlock_Walk(const VoronoiBlock *block, const VoronoiNeighbourhood *hood,
                                VoronoiPolygon *poly)
{
    VoronoiWalk walk;
    int state = VoronoiWalk_Start(&walk, block, hood, poly);
    while (state == VORONOI_WALK_RUNNING)
        state = VoronoiWalk_Advance(&walk, block, hood, poly);
    return state;
}

// The first crossings of two walks' edges at once (VoronoiBlock_FirstCrossings for each, the
// same arithmetic and so the same results; the blocks hold the same nuclei): one pass over the
// groups, four independent chains of selects.
CL_INLINE void VoronoiBlock_FirstCrossingsPair(const VoronoiBlock *block0,
                                               const VoronoiWalk *walk0, int *ccw_next0,
                                               real *ccw_best0, int *cw_next0, real *cw_best0,
                                               const VoronoiBlock *block1,
                                               const VoronoiWalk *walk1, int *ccw_next1,
                                               real *ccw_best1, int *cw_next1, real *cw_best1)
{
    int groups = (block0->count + 7) / 8;
    real ax0 = block0->vx.lane[walk0->a], ay0 = block0->vy.lane[walk0->a];
    real cx0 = block0->vx.lane[walk0->c], cy0 = block0->vy.lane[walk0->c];
    real ax1 = block1->vx.lane[walk1->a], ay1 = block1->vy.lane[walk1->a];
    real cx1 = block1->vx.lane[walk1->c], cy1 = block1->vy.lane[walk1->c];
    real8 ccw_t0 = INFINITY, cw_t0 = INFINITY, ccw_t1 = INFINITY, cw_t1 = INFINITY;
    lane_index8 ccw_index0 = VORONOI_BLOCK_CAPACITY, cw_index0 = VORONOI_BLOCK_CAPACITY;
    lane_index8 ccw_index1 = VORONOI_BLOCK_CAPACITY, cw_index1 = VORONOI_BLOCK_CAPACITY;
    // CrossGroup with c = a gives CrossGroupBothWays' results (its clockwise products are
    // the exact negations): the cheaper form only when both walks are at their first step
    if (ax0 == cx0 && ay0 == cy0 && ax1 == cx1 && ay1 == cy1) {
        for (int j = 0; j < groups; ++j) {
            VoronoiBlock_CrossGroupBothWays(block0, j, ax0, ay0, &ccw_t0, &ccw_index0, &cw_t0,
                                            &cw_index0);
            VoronoiBlock_CrossGroupBothWays(block1, j, ax1, ay1, &ccw_t1, &ccw_index1, &cw_t1,
                                            &cw_index1);
        }
    } else {
        for (int j = 0; j < groups; ++j) {
            VoronoiBlock_CrossGroup(block0, j, ax0, ay0, cx0, cy0, &ccw_t0, &ccw_index0,
                                    &cw_t0, &cw_index0);
            VoronoiBlock_CrossGroup(block1, j, ax1, ay1, cx1, cy1, &ccw_t1, &ccw_index1,
                                    &cw_t1, &cw_index1);
        }
    }
    *ccw_next0 = VoronoiLanes_ArgMin(&ccw_t0, &ccw_index0, ccw_best0);
    *cw_next0 = VoronoiLanes_ArgMin(&cw_t0, &cw_index0, cw_best0);
    *ccw_next1 = VoronoiLanes_ArgMin(&ccw_t1, &ccw_index1, ccw_best1);
    *cw_next1 = VoronoiLanes_ArgMin(&cw_t1, &cw_index1, cw_best1);
}

// Two cells' walks (two nuclei of one grid cell, sharing its neighbourhood) in step: their
// four chains of dependent steps are independent, and the processor overlaps them (one walk's
// steps alone leave it waiting on latencies). Each walk's arithmetic is VoronoiBlock_Walk's,
// so are its results (*state0, *state1).
CL_INLINE void VoronoiBlock_WalkPair(const VoronoiBlock *block0, VoronoiPolygon *poly0,
                                     int *state0, const VoronoiBlock *block1,
                                     VoronoiPolygon *poly1, int *state1,
                                     const VoronoiNeighbourhood *hood)
{
    VoronoiWalk walk0, walk1;
    int s0 = VoronoiWalk_Start(&walk0, block0, hood, poly0);
    int s1 = VoronoiWalk_Start(&walk1, block1, hood, poly1);
    while (s0 == VORONOI_WALK_RUNNING && s1 == VORONOI_WALK_RUNNING) {
        int next0, prev0, next1, prev1;
        real ccw_best0, cw_best0, ccw_best1, cw_best1;
        VoronoiBlock_FirstCrossingsPair(block0, &walk0, &next0, &ccw_best0, &prev0, &cw_best0,
                                        block1, &walk1, &next1, &ccw_best1, &prev1, &cw_best1);
        s0 = VoronoiWalk_Step(&walk0, block0, hood, poly0, next0, ccw_best0, prev0, cw_best0);
        s1 = VoronoiWalk_Step(&walk1, block1, hood, poly1, next1, ccw_best1, prev1, cw_best1);
    }
    while (s0 == VORONOI_WALK_RUNNING)
        s0 = VoronoiWalk_Advance(&walk0, block0, hood, poly0);
    while (s1 == VORONOI_WALK_RUNNING)
        s1 = VoronoiWalk_Advance(&walk1, block1, hood, poly1);
    *state0 = s0;
    *state1 = s1;
}

// The same cell walked counter-clockwise only, until the walk is back at the nearest nucleus
// (ties are broken the same way at every step, so it closes where the two-way walk may not).
// Returns false when it cannot decide (as VORONOI_WALK_FAILED). Rare: not inlined, out of the
// way of the common path.
__attribute__((noinline)) bool VoronoiBlock_WalkOneWay(const VoronoiBlock *block,
                                                       const VoronoiNeighbourhood *hood,
                                                       VoronoiPolygon *poly)
{
#pragma OPENCL FP_CONTRACT OFF
    int first = block->nearest, a = first;
    real radius2 = 0;
    if (first < 0)
        return false;
    for (int m = 0; m < VORONOI_MAX_VERTICES; ++m) {
        real ax = block->vx.lane[a], ay = block->vy.lane[a];
        int next, unused_next;
        real best, unused_best;
        VoronoiBlock_FirstCrossings(block, ax, ay, ax, ay, &next, &best, &unused_next,
                                    &unused_best);
        if (!(best < INFINITY))
            return false;
        // Edge m lies on a's bisector; its end (t = best / 2) is vertex m + 1, or vertex 0
        // when the walk closes
        bool closes = next == first;
        int end = closes ? 0 : m + 1;
        if (end == VORONOI_MAX_VERTICES)
            return false;
        real half_t = 0.5f * best;
        real px = 0.5f * ax - half_t * ay, py = 0.5f * ay + half_t * ax;
        poly->vx[end] = px;
        poly->vy[end] = py;
        poly->ex[m] = (float)hood->x.lane[a];
        poly->ey[m] = (float)hood->y.lane[a];
        real r2 = px * px + py * py;
        radius2 = r2 > radius2 ? r2 : radius2;
        if (closes) {
            poly->count = m + 1;
            poly->radius2 = radius2;
            return m >= 2;
        }
        a = next;
    }
    return false;
}

// ---------------------------------------------------------------------------------------------
// Unbounded cells

// Whether x's cell among the nuclei in slots [s0, s1) is unbounded: some direction u has
// u.v <= 0 for every neighbour vector v (the cell's recession cone is not empty). The feasible
// directions form an arc [lo, hi] (counter-clockwise, at most a half-turn), cut by one
// half-circle per neighbour. Returns 1 unbounded, 0 bounded, -1 degenerate (collinear: left
// to the host).
CL_INLINE int VoronoiCell_Unbounded(real2 x, uint s0, uint s1,
                                    __global const float2 *sorted_points)
{
    bool full = true;
    real2 lo = (real2)(0, 0), hi = (real2)(0, 0);
    for (uint s = s0; s < s1; ++s) {
        real2 v = REAL2(sorted_points[s]) - x;
        if (v.x == 0 && v.y == 0)
            continue;
        real2 left = (real2)(-v.y, v.x), right = (real2)(v.y, -v.x);
        if (full) {
            // The half-circle u.v <= 0 runs counter-clockwise from left to right
            lo = left;
            hi = right;
            full = false;
            continue;
        }
        real dlo = lo.x * v.x + lo.y * v.y, dhi = hi.x * v.x + hi.y * v.y;
        if (dlo == 0 && dhi == 0)
            return -1;
        if (dlo > 0 && dhi > 0)
            return 0;
        if (dlo > 0)
            lo = left;
        else if (dhi > 0)
            hi = right;
    }
    return 1;
}

// ---------------------------------------------------------------------------------------------
// The cell of one traced nucleus

// The exact polygon of traced nucleus i (position x in the pixel's grid cell g) from its
// walk's result (walk: the VoronoiBlock_Walk result, VORONOI_WALK_FAILED when the
// neighbourhood was not gathered; poly: the walked polygon; *coincident: the block's nuclei at
// x): the one-way walk after a tie, the nuclei beyond the block, or else the clipping search.
// True when poly is then the exact bounded cell (*walked and *one_way say how it was found)
// for VoronoiCell_Measure; otherwise areas[i] and status[i] are written here.
CL_INLINE bool VoronoiCell_Settle(uint i, float2 nucleus, int2 g, const VoronoiBlock *block,
                                  const VoronoiNeighbourhood *hood, VoronoiPolygon *poly,
                                  int walk, int *coincident, bool *walked_out,
                                  bool *one_way_out, uint count, int grid_side,
                                  float half_extent, float start_box,
                                  __global const uint *start, uint base,
                                  __global const float2 *sorted_points,
                                  __global area_real *areas, __global uchar *status)
{
    real2 x = REAL2(nucleus);
    bool one_way = walk == VORONOI_WALK_TIED && VoronoiBlock_WalkOneWay(block, hood, poly);
    bool walked = walk == VORONOI_WALK_DONE || one_way;
    bool ok;
    if (walked) {
        ok = VoronoiCell_ClipBeyondBlock(poly, x, g, grid_side, half_extent, start, base,
                                         sorted_points, coincident);
    } else {
        // The clipping search, from a box of a few mean spacings around the nucleus (it keeps
        // the radius test tight); a cell that reaches its border is redone from the full box
        real reach = VORONOI_FIRST_BOX_SPACINGS * 2 * half_extent / Sqrt((float)count);
        bool small_box = reach < start_box;
        if (small_box)
            VoronoiPolygon_InitBox(poly, nucleus, (real2)(-reach, -reach), (real2)(reach, reach));
        else
            VoronoiPolygon_InitBox(poly, nucleus, -start_box - x, start_box - x);
        ok = VoronoiCell_Search(poly, x, grid_side, half_extent, start, base, sorted_points,
                                coincident);
        if (ok && small_box && VoronoiPolygon_TouchesBox(poly, nucleus)) {
            VoronoiPolygon_InitBox(poly, nucleus, -start_box - x, start_box - x);
            ok = VoronoiCell_Search(poly, x, grid_side, half_extent, start, base, sorted_points,
                                    coincident);
        }
    }
    if (!ok) {
        areas[i] = NAN;
        status[i] = VORONOI_FALLBACK;
        return false;
    }

    // A box edge left: the cell is unbounded, or reaches beyond the box (host decides). A
    // walked polygon has none: its edges lie on bisectors of other nuclei, as do the edges
    // clips add
    if (!walked && VoronoiPolygon_TouchesBox(poly, nucleus)) {
        int unbounded = VoronoiCell_Unbounded(x, base, base + count, sorted_points);
        areas[i] = NAN;
        status[i] = unbounded == 1 ? 0 : VORONOI_FALLBACK;
        return false;
    }

    *walked_out = walked;
    *one_way_out = one_way;
    return true;
}

// The area of an exact bounded cell (VoronoiCell_Settle), shared equally with the coincident
// nuclei, and its status: writes areas[i] and status[i].
CL_INLINE void VoronoiCell_Measure(uint i, float2 nucleus, const VoronoiPolygon *poly,
                                   bool walked, bool one_way, int coincident, float inside_box,
                                   float near_length, __global area_real *areas,
                                   __global uchar *status)
{
    real2 x = REAL2(nucleus);
    bool inside;
    area_real area = VoronoiPolygon_Area(poly, nucleus, inside_box, &inside);
#ifdef VORONOI_INSIDE_DISCS
    // Image-level cells: inside instead means every vertex's disc through the nucleus (the
    // Delaunay circumdiscs) lies in [-inside_box, inside_box]^2, where every nucleus is known,
    // and no other nucleus lies within near_length (the nearest is a neighbour): the
    // positions are rounded relative to the pixel, which leaves such a pair's bisector to
    // rounding (the host settles them exactly)
    float4 discs = VoronoiPolygon_CutBox(poly);
    float nearest2 = INFINITY;
    for (int k = 0; k < poly->count; ++k) {
        float dx = poly->ex[k] - nucleus.x, dy = poly->ey[k] - nucleus.y;
        nearest2 = VORONOI_MIN(nearest2, dx * dx + dy * dy);
    }
    inside = x.x + discs.x >= -inside_box && x.y + discs.y >= -inside_box
             && x.x + discs.z <= inside_box && x.y + discs.w <= inside_box && coincident <= 1
             && nearest2 >= near_length * near_length;
#endif
    areas[i] = area / VORONOI_MAX(coincident, 1);
    status[i] = VORONOI_BOUNDED | (inside ? VORONOI_INSIDE : 0) | (walked ? VORONOI_WALKED : 0)
                | (one_way ? VORONOI_WALKED_ONE_WAY : 0);
}

// The cell of traced nucleus i: its walk among the block's nuclei when the neighbourhood was
// gathered, then VoronoiCell_Settle and VoronoiCell_Measure.
CL_INLINE void VoronoiCell_Compute(uint i, float2 nucleus, int2 g,
                                   const VoronoiNeighbourhood *hood, bool have_hood,
                                   uint count, int grid_side, float half_extent,
                                   float start_box, float inside_box, float near_length,
                                   __global const uint *start, uint base,
                                   __global const float2 *sorted_points,
                                   __global area_real *areas, __global uchar *status)
{
    VoronoiPolygon poly;
    VoronoiBlock block;
    int coincident = 0, walk = VORONOI_WALK_FAILED;
    if (have_hood) {
        VoronoiBlock_Relative(&block, hood, REAL2(nucleus), &coincident);
        walk = VoronoiBlock_Walk(&block, hood, &poly);
    }
    bool walked, one_way;
    if (VoronoiCell_Settle(i, nucleus, g, &block, hood, &poly, walk, &coincident, &walked,
                           &one_way, count, grid_side, half_extent, start_box, start, base,
                           sorted_points, areas, status))
        VoronoiCell_Measure(i, nucleus, &poly, walked, one_way, coincident, inside_box,
                            near_length, areas, status);
}

// The cells of traced nuclei i0 and i1 of one grid cell, their walks in step
// (VoronoiBlock_WalkPair): the same results as VoronoiCell_Compute for each.
CL_INLINE void VoronoiCell_ComputePair(uint i0, float2 nucleus0, uint i1, float2 nucleus1,
                                       int2 g, const VoronoiNeighbourhood *hood,
                                       bool have_hood, uint count, int grid_side,
                                       float half_extent, float start_box, float inside_box,
                                       float near_length, __global const uint *start,
                                       uint base, __global const float2 *sorted_points,
                                       __global area_real *areas, __global uchar *status)
{
    VoronoiPolygon poly0, poly1;
    VoronoiBlock block0, block1;
    int coincident0 = 0, coincident1 = 0;
    int walk0 = VORONOI_WALK_FAILED, walk1 = VORONOI_WALK_FAILED;
    if (have_hood) {
        VoronoiBlock_Relative(&block0, hood, REAL2(nucleus0), &coincident0);
        VoronoiBlock_Relative(&block1, hood, REAL2(nucleus1), &coincident1);
        VoronoiBlock_WalkPair(&block0, &poly0, &walk0, &block1, &poly1, &walk1, hood);
    }
    bool walked0, one_way0, walked1, one_way1;
    bool exact0 = VoronoiCell_Settle(i0, nucleus0, g, &block0, hood, &poly0, walk0,
                                     &coincident0, &walked0, &one_way0, count, grid_side,
                                     half_extent, start_box, start, base, sorted_points, areas,
                                     status);
    bool exact1 = VoronoiCell_Settle(i1, nucleus1, g, &block1, hood, &poly1, walk1,
                                     &coincident1, &walked1, &one_way1, count, grid_side,
                                     half_extent, start_box, start, base, sorted_points, areas,
                                     status);
    // Both areas together when both cells are exact (the usual case): independent
    // arithmetic the processor overlaps
    if (exact0)
        VoronoiCell_Measure(i0, nucleus0, &poly0, walked0, one_way0, coincident0, inside_box,
                            near_length, areas, status);
    if (exact1)
        VoronoiCell_Measure(i1, nucleus1, &poly1, walked1, one_way1, coincident1, inside_box,
                            near_length, areas, status);
}

// One work-item per (pixel, grid cell that can hold traced nuclei): the cells of the grid
// cell's traced nuclei, which share one copy of their 3 x 3 block of grid cells. Traced nuclei
// lie in the span_side x span_side grid cells from (span_lo, span_lo) (the host bounds them:
// the strip's outer cells hold only auxiliary nuclei and get no work-item).
__kernel KERNEL_SCALAR_WORK_ITEMS void
voronoi_cell_areas(uint pixel_count, uint traced_total, int grid_side, int span_lo, int span_side,
                   float half_extent, float start_box, float inside_box, float near_length,
                   __global const uint *offsets, __global const uint *cell_start,
                   __global const float2 *sorted_points, __global const uint *sorted_index,
                   __global area_real *areas, __global uchar *status)
{
    // This work-item's pixel p and grid cell g (c in the grid), and where the pixel's nuclei
    // and grid are
    uint span_cells = (uint)(span_side * span_side);
    uint id = get_global_id(0);
    if (id >= pixel_count * span_cells)
        return;
    uint p = id / span_cells, r = id - p * span_cells;
    int2 g = (int2)(span_lo + (int)(r % (uint)span_side), span_lo + (int)(r / (uint)span_side));
    uint c = (uint)(g.y * grid_side + g.x);
    __global const uint *traced_offsets = offsets;
    __global const uint *aux_offsets = offsets + pixel_count + 1;
    uint base = traced_offsets[p] + aux_offsets[p];
    uint count = traced_offsets[p + 1] - traced_offsets[p] + aux_offsets[p + 1] - aux_offsets[p];
    __global const uint *start = cell_start + (size_t)p * (uint)(grid_side * grid_side + 1);

    // The cells of the traced nuclei of c two at a time, gathering the 3 x 3 block on the
    // first one
    VoronoiNeighbourhood hood;
    bool gathered = false, have_hood = false, pending = false;
    uint pending_i = 0u, pending_s = 0u;
    for (uint s = base + start[c]; s < base + start[c + 1]; ++s) {
        uint i = sorted_index[s];
        if (i >= traced_total)
            continue;  // an auxiliary nucleus: its cell is not needed
        if (!gathered) {
            have_hood = VoronoiNeighbourhood_Gather(&hood, g, grid_side, start, base,
                                                   sorted_points);
            gathered = true;
        }
#ifdef VORONOI_NO_PAIRS
        // One at a time (to compare: the results are the same)
        VoronoiCell_Compute(i, sorted_points[s], g, &hood, have_hood, count, grid_side,
                            half_extent, start_box, inside_box, near_length, start, base,
                            sorted_points, areas, status);
        continue;
#endif
        if (!pending) {
            pending = true;
            pending_i = i;
            pending_s = s;
            continue;
        }
        VoronoiCell_ComputePair(pending_i, sorted_points[pending_s], i, sorted_points[s], g,
                                &hood, have_hood, count, grid_side, half_extent, start_box,
                                inside_box, near_length, start, base, sorted_points, areas,
                                status);
        pending = false;
    }
    if (pending)
        VoronoiCell_Compute(pending_i, sorted_points[pending_s], g, &hood, have_hood, count,
                            grid_side, half_extent, start_box, inside_box, near_length, start,
                            base, sorted_points, areas, status);
}
