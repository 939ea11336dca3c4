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

// One work-item per pixel, the pixels spread over the launch: pixel p is work-item p * stride.
// Launches are padded to at least 65 536 work-items (clrender.runtime.MIN_LAUNCH_SIZE) and PoCL
// deals work-groups to its threads in chunks from the front (up to 64 at a time, first come
// first served): packed at the front, a tile's 4096 pixels (64 work-groups) all went to one
// thread's first chunk. Spread, every chunk holds its share (the host's stride:
// device_cells.pixel_stride; 1 on a GPU). Sets *pixel; true for a work-item that has a pixel.
CL_INLINE bool Voronoi_SpreadPixel(uint pixel_count, uint stride, uint *pixel)
{
    uint id = get_global_id(0);
    if (stride == 0u || id % stride != 0u)
        return false;
    *pixel = id / stride;
    return *pixel < pixel_count;
}

#endif
