// What kernels/voronoi_cells.cl (with voronoi_polygon.h) and kernels/voronoi_sums.cl share: the
// precision of areas (-DVORONOI_AREA_DOUBLE or -DVORONOI_DOUBLE: float64) and the status byte of
// each traced nucleus (the bits are documented in voronoi_cells.cl's header).
#ifndef CLRENDER_VORONOI_COMMON_H
#define CLRENDER_VORONOI_COMMON_H

#if defined(VORONOI_DOUBLE) || defined(VORONOI_AREA_DOUBLE)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double area_real;
typedef double2 area_real2;
#define AREA_REAL2(v) convert_double2(v)
#else
typedef float area_real;
typedef float2 area_real2;
#define AREA_REAL2(v) (v)
#endif

#define VORONOI_BOUNDED 1
#define VORONOI_INSIDE 2
#define VORONOI_FALLBACK 4
#define VORONOI_WALKED 8
#define VORONOI_WALKED_ONE_WAY 16

#endif
