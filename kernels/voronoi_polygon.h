// Voronoi cells as convex polygons around their nucleus, cut by bisectors: the polygon that
// kernels/voronoi_cells.cl builds each cell with (walked, or clipped from a box), its clipping,
// and its area from the recomputed corners.
//
// All geometry is relative to the nucleus. Each polygon edge remembers the neighbour whose
// bisector carries it, and the final vertices are recomputed as intersections of two bisectors
// from the input coordinates, so the area does not inherit the rounding of the clipping
// history. Precision: float clipping with the final vertices in float (~1e-5 relative on the
// worst cells), or in double with -DVORONOI_AREA_DOUBLE (~1e-14); -DVORONOI_DOUBLE runs all
// of it in double.
#ifndef CLRENDER_VORONOI_POLYGON_H
#define CLRENDER_VORONOI_POLYGON_H

#include "vecmath.h"
#include "voronoi_common.h"

// real: the clipping arithmetic; area_real (voronoi_common.h): final vertices, areas and the
// inside test
#ifdef VORONOI_DOUBLE
typedef double real;
typedef double2 real2;
#define REAL2(v) convert_double2(v)
#else
typedef float real;
typedef float2 real2;
#define REAL2(v) (v)
#endif

#ifndef VORONOI_MAX_VERTICES
#define VORONOI_MAX_VERTICES 32
#endif

// pip's PoCL cannot inline its builtins into these kernels (its builtin library targets another
// CPU, see kernels/vecmath.h): min, max and abs (of ints, floats or doubles) are these macros,
// floor and sqrt vecmath.h's Floor and Sqrt (the compiler builtins on PoCL), and the helpers
// are forced inline (CL_INLINE).
#define VORONOI_MIN(a, b) ((a) < (b) ? (a) : (b))
#define VORONOI_MAX(a, b) ((a) > (b) ? (a) : (b))
#define VORONOI_ABS(a) ((a) < 0 ? -(a) : (a))

// A convex polygon around the nucleus x (vertices relative to x). Edge k runs from vertex k to
// vertex k + 1 and lies on the bisector of x and the neighbour at absolute position e[k] (the
// input coordinates, exact); e[k] = x marks an edge of the start box (a nucleus coincident
// with x never cuts).
typedef struct {
    real vx[VORONOI_MAX_VERTICES];
    real vy[VORONOI_MAX_VERTICES];
    float ex[VORONOI_MAX_VERTICES];
    float ey[VORONOI_MAX_VERTICES];
    int count;
    real radius2;  // squared distance of the farthest vertex
} VoronoiPolygon;

// The box [lo, hi] (relative to the nucleus), counter-clockwise, edges marked as box edges.
CL_INLINE void VoronoiPolygon_InitBox(VoronoiPolygon *poly, float2 x, real2 lo, real2 hi)
{
    poly->vx[0] = lo.x; poly->vy[0] = lo.y;
    poly->vx[1] = hi.x; poly->vy[1] = lo.y;
    poly->vx[2] = hi.x; poly->vy[2] = hi.y;
    poly->vx[3] = lo.x; poly->vy[3] = hi.y;
    real fx = VORONOI_MAX(VORONOI_ABS(lo.x), VORONOI_ABS(hi.x));
    real fy = VORONOI_MAX(VORONOI_ABS(lo.y), VORONOI_ABS(hi.y));
    poly->radius2 = fx * fx + fy * fy;
    for (int k = 0; k < 4; ++k) {
        poly->ex[k] = x.x;
        poly->ey[k] = x.y;
    }
    poly->count = 4;
}

// Replace the polygon by the clipped vertices and edges, and update the farthest vertex distance.
CL_INLINE void VoronoiPolygon_Store(VoronoiPolygon *poly, const real *nx, const real *ny,
                                    const float *nex, const float *ney, int count)
{
    real radius2 = 0;
    for (int k = 0; k < count; ++k) {
        poly->vx[k] = nx[k]; poly->vy[k] = ny[k];
        poly->ex[k] = nex[k]; poly->ey[k] = ney[k];
        real r2 = nx[k] * nx[k] + ny[k] * ny[k];
        radius2 = r2 > radius2 ? r2 : radius2;
    }
    poly->count = count;
    poly->radius2 = radius2;
}

// Keep the half-plane closer to the origin than to v = neighbour - x: v.p <= |v|^2 / 2.
// Returns false on vertex overflow (the polygon is then unusable).
// The general case of VoronoiPolygon_Clip (Sutherland-Hodgman), for rounding-degenerate
// polygons whose outside vertices do not form one run.
__attribute__((noinline)) bool VoronoiPolygon_ClipGeneral(VoronoiPolygon *poly, real2 v,
                                                          float2 neighbour)
{
    int m = poly->count;
    real level = 0.5f * (v.x * v.x + v.y * v.y);
    real d[VORONOI_MAX_VERTICES];
    bool any_out = false;
    for (int k = 0; k < m; ++k) {
        d[k] = v.x * poly->vx[k] + v.y * poly->vy[k] - level;
        any_out |= d[k] > 0;
    }
    if (!any_out)
        return true;

    // Sutherland-Hodgman: walk the edges, keeping inside vertices and the two crossings
    real nx[VORONOI_MAX_VERTICES], ny[VORONOI_MAX_VERTICES];
    float nex[VORONOI_MAX_VERTICES], ney[VORONOI_MAX_VERTICES];
    int out = 0;
    for (int k = 0; k < m; ++k) {
        int k1 = k + 1 == m ? 0 : k + 1;
        bool in_a = d[k] <= 0, in_b = d[k1] <= 0;
        if (in_a) {
            if (out >= VORONOI_MAX_VERTICES)
                return false;
            nx[out] = poly->vx[k]; ny[out] = poly->vy[k];
            nex[out] = poly->ex[k]; ney[out] = poly->ey[k];
            ++out;
        }
        if (in_a != in_b) {
            if (out >= VORONOI_MAX_VERTICES)
                return false;
            real t = d[k] / (d[k] - d[k1]);
            nx[out] = poly->vx[k] + t * (poly->vx[k1] - poly->vx[k]);
            ny[out] = poly->vy[k] + t * (poly->vy[k1] - poly->vy[k]);
            // Leaving: the new edge runs along the bisector; entering: along edge k
            nex[out] = in_a ? neighbour.x : poly->ex[k];
            ney[out] = in_a ? neighbour.y : poly->ey[k];
            ++out;
        }
    }

    VoronoiPolygon_Store(poly, nx, ny, nex, ney, out);
    return true;
}

// Bit k set: vertex k lies beyond the bisector of the origin and v = neighbour - x, i.e. is
// closer to the neighbour (v.p > |v|^2 / 2); 0 when the bisector does not cut the polygon.
CL_INLINE uint VoronoiPolygon_OutsideMask(const VoronoiPolygon *poly, real2 v)
{
    real level = 0.5f * (v.x * v.x + v.y * v.y);
    uint out_mask = 0u;
    for (int k = 0; k < poly->count; ++k) {
        real d = v.x * poly->vx[k] + v.y * poly->vy[k] - level;
        out_mask |= (uint)(d > 0) << k;
    }
    return out_mask;
}

// Keep the half-plane closer to the origin than to v = neighbour - x, given the polygon's
// (non-zero) outside mask. Returns false on vertex overflow (the polygon is then unusable). The
// outside vertices of a convex polygon form one cyclic run s..e: found branch-free from the
// mask, replaced by the two crossings (the same arithmetic as Sutherland-Hodgman, which
// handles any other case). Not inlined: its scratch arrays then live in its own frame (inlined
// copies at each call site measured slower on PoCL).
__attribute__((noinline)) bool VoronoiPolygon_Clip(VoronoiPolygon *poly, real2 v,
                                                   float2 neighbour, uint out_mask)
{
    int m = poly->count;
    real level = 0.5f * (v.x * v.x + v.y * v.y);
    uint full = m >= 32 ? 0xffffffffu : (1u << m) - 1u;
    uint prev_out = ((out_mask << 1) | (out_mask >> (m - 1))) & full;  // bit k: vertex k - 1
    uint next_out = ((out_mask >> 1) | (out_mask << (m - 1))) & full;  // bit k: vertex k + 1
    uint starts = out_mask & ~prev_out, ends = out_mask & ~next_out;
    if (out_mask == full || (starts & (starts - 1u)) != 0u)
        return VoronoiPolygon_ClipGeneral(poly, v, neighbour);
    int s = Ctz(starts), e = Ctz(ends);
    int a = s == 0 ? m - 1 : s - 1, b = e + 1 == m ? 0 : e + 1;
    int outside = e >= s ? e - s + 1 : e + m - s + 1;
    int inside = m - outside;
    if (inside + 2 > VORONOI_MAX_VERTICES)
        return false;
    real da = v.x * poly->vx[a] + v.y * poly->vy[a] - level;
    real ds = v.x * poly->vx[s] + v.y * poly->vy[s] - level;
    real de = v.x * poly->vx[e] + v.y * poly->vy[e] - level;
    real db = v.x * poly->vx[b] + v.y * poly->vy[b] - level;
    real ta = da / (da - ds), tb = de / (de - db);
    real pax = poly->vx[a] + ta * (poly->vx[s] - poly->vx[a]);
    real pay = poly->vy[a] + ta * (poly->vy[s] - poly->vy[a]);
    real pbx = poly->vx[e] + tb * (poly->vx[b] - poly->vx[e]);
    real pby = poly->vy[e] + tb * (poly->vy[b] - poly->vy[e]);
    float pbex = poly->ex[e], pbey = poly->ey[e];

    // New polygon: the inside run b..a, then the leaving crossing (its edge on the new
    // bisector) and the entering one (on edge e)
    real nx[VORONOI_MAX_VERTICES], ny[VORONOI_MAX_VERTICES];
    float nex[VORONOI_MAX_VERTICES], ney[VORONOI_MAX_VERTICES];
    for (int j = 0, k = b; j < inside; ++j) {
        nx[j] = poly->vx[k]; ny[j] = poly->vy[k];
        nex[j] = poly->ex[k]; ney[j] = poly->ey[k];
        k = k + 1 == m ? 0 : k + 1;
    }
    nx[inside] = pax; ny[inside] = pay; nex[inside] = neighbour.x; ney[inside] = neighbour.y;
    nx[inside + 1] = pbx; ny[inside + 1] = pby; nex[inside + 1] = pbex; ney[inside + 1] = pbey;
    VoronoiPolygon_Store(poly, nx, ny, nex, ney, inside + 2);
    return true;
}

CL_INLINE bool VoronoiPolygon_TouchesBox(const VoronoiPolygon *poly, float2 x)
{
    bool touches = false;
    for (int k = 0; k < poly->count; ++k)
        touches |= poly->ex[k] == x.x && poly->ey[k] == x.y;
    return touches;
}

// The determinant a.x b.y - a.y b.x, without fused multiply-adds: exactly 0 for a = b (with an
// fma, single precision leaves a rounding residue; products of floats are exact in double).
CL_INLINE area_real VoronoiPolygon_Det(area_real ax, area_real ay, area_real bx, area_real by)
{
#pragma OPENCL FP_CONTRACT OFF
    return ax * by - ay * bx;
}

// Vertex k (relative to x) recomputed from the bisectors of edges k - 1 and k, in area_real
// from the input coordinates. False when the two bisectors are parallel: the edges are then
// collinear (the same neighbour twice, or a coincident one), and the vertex, lying on a
// straight side, is not a corner of the cell.
CL_INLINE bool VoronoiPolygon_Vertex(const VoronoiPolygon *poly, area_real2 x, int k,
                                     area_real2 *vertex)
{
    int prev = k == 0 ? poly->count - 1 : k - 1;
    area_real2 a = (area_real2)(poly->ex[prev], poly->ey[prev]) - x;
    area_real2 b = (area_real2)(poly->ex[k], poly->ey[k]) - x;
    area_real ca = 0.5f * (a.x * a.x + a.y * a.y), cb = 0.5f * (b.x * b.x + b.y * b.y);
    area_real det = VoronoiPolygon_Det(a.x, a.y, b.x, b.y);
    if (det == 0)
        return false;
    *vertex = (area_real2)(ca * b.y - cb * a.y, a.x * cb - b.x * ca) / det;
    return true;
}

// Shoelace area over the recomputed corners, skipping those of collinear edges; inside: all
// corners (absolute) lie in [-inside_box, inside_box]^2.
__attribute__((noinline)) area_real VoronoiPolygon_AreaSkipping(const VoronoiPolygon *poly,
                                                                float2 nucleus,
                                                                area_real inside_box,
                                                                bool *inside)
{
    area_real2 x = AREA_REAL2(nucleus);
    area_real twice_area = 0;
    bool in_box = true, have_first = false;
    area_real2 first = (area_real2)(0, 0), prev = first, cur;
    for (int k = 0; k < poly->count; ++k) {
        if (!VoronoiPolygon_Vertex(poly, x, k, &cur))
            continue;
        if (have_first)
            twice_area += prev.x * cur.y - prev.y * cur.x;
        else
            first = cur;
        have_first = true;
        area_real2 absolute = x + cur;
        in_box &= VORONOI_ABS(absolute.x) <= inside_box && VORONOI_ABS(absolute.y) <= inside_box;
        prev = cur;
    }
    twice_area += prev.x * first.y - prev.y * first.x;
    *inside = in_box;
    return 0.5f * twice_area;
}

// 8 lanes of area_real, and their comparison masks
#if defined(VORONOI_DOUBLE) || defined(VORONOI_AREA_DOUBLE)
typedef double8 area_real8;
typedef long8 area_mask8;
#else
typedef float8 area_real8;
typedef int8 area_mask8;
#endif

// Shoelace area of a polygon of at most 8 edges over its recomputed corners as the 8 lanes of
// vectors (lane k: corner k, from the bisectors of edges k - 1 and k, as in
// VoronoiPolygon_Vertex), summed pairwise; inside: all corners (absolute) lie in
// [-inside_box, inside_box]^2; *parallel: two consecutive edges are parallel (the area is then
// not valid: VoronoiPolygon_AreaSkipping skips their corner). Written on vectors: the compiler
// leaves the loop form scalar for fewer than 8 corners.
CL_INLINE area_real VoronoiPolygon_Area8(const VoronoiPolygon *poly, float2 nucleus,
                                         area_real inside_box, bool *inside, bool *parallel)
{
    // The edges' neighbours in lanes; lanes past the count hold the nucleus (masked below)
    int count = poly->count;
    union {
        float8 v;
        float lane[8];
    } ex, ey;
    for (int k = 0; k < 8; ++k) {
        ex.lane[k] = k < count ? poly->ex[k] : nucleus.x;
        ey.lane[k] = k < count ? poly->ey[k] : nucleus.y;
    }
    const area_mask8 lanes = (area_mask8)(0, 1, 2, 3, 4, 5, 6, 7);
    area_mask8 valid = lanes < (area_mask8)count;

    // Corner k from edge k - 1 (edge count - 1 for corner 0) and edge k, relative to x
    area_real2 x = AREA_REAL2(nucleus);
    float8 prev_x = __builtin_shufflevector((float8)(poly->ex[count - 1]), ex.v, 0, 8, 9, 10,
                                            11, 12, 13, 14);
    float8 prev_y = __builtin_shufflevector((float8)(poly->ey[count - 1]), ey.v, 0, 8, 9, 10,
                                            11, 12, 13, 14);
    area_real8 ax = __builtin_convertvector(prev_x, area_real8) - x.x;
    area_real8 ay = __builtin_convertvector(prev_y, area_real8) - x.y;
    area_real8 bx = __builtin_convertvector(ex.v, area_real8) - x.x;
    area_real8 by = __builtin_convertvector(ey.v, area_real8) - x.y;
    area_real8 ca = 0.5f * (ax * ax + ay * ay), cb = 0.5f * (bx * bx + by * by);
    area_real8 det;
    {
        // As VoronoiPolygon_Det: exactly 0 for parallel edges
#pragma OPENCL FP_CONTRACT OFF
        det = ax * by - ay * bx;
    }
    area_real8 vx = (ca * by - cb * ay) / det, vy = (ax * cb - bx * ca) / det;
    area_real8 absolute_x = x.x + vx, absolute_y = x.y + vy;
    area_mask8 in_box = (VORONOI_ABS(absolute_x) <= inside_box)
                        & (VORONOI_ABS(absolute_y) <= inside_box);

    // Twice the area: corner k against corner k + 1 (corner 0 after the last)
    area_real8 next_x = __builtin_shufflevector(vx, vx, 1, 2, 3, 4, 5, 6, 7, 0);
    area_real8 next_y = __builtin_shufflevector(vy, vy, 1, 2, 3, 4, 5, 6, 7, 0);
    area_mask8 last = lanes == (area_mask8)(count - 1);
    next_x = last ? (area_real8)(vx.s0) : next_x;
    next_y = last ? (area_real8)(vy.s0) : next_y;
    area_real8 twice = valid ? vx * next_y - vy * next_x : (area_real8)(0);

    // Over the lanes: bit 0 a parallel pair, bit 1 a corner outside the box; the sum
    area_mask8 flags = (valid & (det == 0) & 1) | (valid & ~in_box & 2);
    flags.lo |= flags.hi;
    flags.s01 |= flags.s23;
    *parallel = ((flags.s0 | flags.s1) & 1) != 0;
    *inside = ((flags.s0 | flags.s1) & 2) == 0;
    twice.lo += twice.hi;
    twice.s01 += twice.s23;
    return 0.5f * (twice.s0 + twice.s1);
}

// Shoelace area over the recomputed corners; inside: all corners (absolute) lie in
// [-inside_box, inside_box]^2. Up to 8 corners (most cells) in VoronoiPolygon_Area8; more are
// computed first, in a loop without branches, then summed in order: the same arithmetic as
// VoronoiPolygon_AreaSkipping, which takes over when two edges are collinear.
CL_INLINE area_real VoronoiPolygon_Area(const VoronoiPolygon *poly, float2 nucleus,
                                        area_real inside_box, bool *inside)
{
    if (poly->count <= 8) {
        bool parallel;
        area_real area = VoronoiPolygon_Area8(poly, nucleus, inside_box, inside, &parallel);
        return parallel ? VoronoiPolygon_AreaSkipping(poly, nucleus, inside_box, inside) : area;
    }
    area_real2 x = AREA_REAL2(nucleus);
    int count = poly->count;
    area_real cx[VORONOI_MAX_VERTICES], cy[VORONOI_MAX_VERTICES];
    bool parallel = false, in_box = true;
    for (int k = 0; k < count; ++k) {
        // Vertex k: the bisectors of edges k - 1 and k (VoronoiPolygon_Vertex)
        int prev = k == 0 ? count - 1 : k - 1;
        area_real ax = (area_real)poly->ex[prev] - x.x, ay = (area_real)poly->ey[prev] - x.y;
        area_real bx = (area_real)poly->ex[k] - x.x, by = (area_real)poly->ey[k] - x.y;
        area_real ca = 0.5f * (ax * ax + ay * ay), cb = 0.5f * (bx * bx + by * by);
        area_real det = VoronoiPolygon_Det(ax, ay, bx, by);
        area_real vx = (ca * by - cb * ay) / det, vy = (ax * cb - bx * ca) / det;
        cx[k] = vx;
        cy[k] = vy;
        parallel |= det == 0;
        area_real absolute_x = x.x + vx, absolute_y = x.y + vy;
        in_box &= (VORONOI_ABS(absolute_x) <= inside_box) & (VORONOI_ABS(absolute_y) <= inside_box);
    }
    if (parallel)
        return VoronoiPolygon_AreaSkipping(poly, nucleus, inside_box, inside);
    area_real twice_area = 0;
    for (int k = 1; k < count; ++k)
        twice_area += cx[k - 1] * cy[k] - cy[k - 1] * cx[k];
    twice_area += cx[count - 1] * cy[0] - cy[count - 1] * cx[0];
    *inside = in_box;
    return 0.5f * twice_area;
}

// The bounding box (relative to the nucleus) of the region where a nucleus can still cut the
// polygon: the union of the discs centred on its vertices p through the nucleus (a nucleus cuts
// iff it is closer than the nucleus to some vertex). The region only shrinks as clips go on.
CL_INLINE float4 VoronoiPolygon_CutBox(const VoronoiPolygon *poly)
{
    float4 box = (float4)(INFINITY, INFINITY, -INFINITY, -INFINITY);  // (lo.x, lo.y, hi.x, hi.y)
    for (int k = 0; k < poly->count; ++k) {
        float px = (float)poly->vx[k], py = (float)poly->vy[k];
        float r = Sqrt(px * px + py * py);
        box.x = VORONOI_MIN(box.x, px - r);
        box.y = VORONOI_MIN(box.y, py - r);
        box.z = VORONOI_MAX(box.z, px + r);
        box.w = VORONOI_MAX(box.w, py + r);
    }
    return box;
}

#endif
