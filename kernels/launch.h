// Launch layout shared by the kernels that run one work-item per traced sample: a launch covers
// a list of pixels, and pixel p's traced samples are [offsets[p], offsets[p + 1]).
#ifndef CLRENDER_LAUNCH_H
#define CLRENDER_LAUNCH_H

// The launch slot p whose [offsets[p], offsets[p+1]) range holds sample i: a binary search
// with the same number of steps for every work-item (from the largest power of two <=
// pixel_count down), so that PoCL can keep work-items in step.
inline uint Launch_OwnerPixel(__global const uint *offsets, uint pixel_count, uint i)
{
    uint lo = 0u;
    uint span = pixel_count ? 1u << (31u - clz(pixel_count)) : 0u;
    for (uint step = span; step > 0u; step >>= 1) {
        uint mid = lo + step;
        if (mid < pixel_count && offsets[mid] <= i)
            lo = mid;
    }
    return lo;
}

#endif
