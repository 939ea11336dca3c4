// Pinhole camera rays through image positions (image row 0 is the top of the image).
#ifndef CLRENDER_CAMERA_H
#define CLRENDER_CAMERA_H

#include "scene_types.h"

// The unit direction of the ray through image position (x, y) in pixels of a width x height
// image: pixel (i, j) covers [i, i+1] x [j, j+1], y grows downwards.
inline float3 Camera_Direction(__global const Camera *camera, float2 image_pos, uint width,
                               uint height)
{
    float sx = 2.0f * image_pos.x / (float)width - 1.0f;
    float sy = 1.0f - 2.0f * image_pos.y / (float)height;
    float3 d = vload3(0, camera->forward) + sx * vload3(0, camera->right) +
               sy * vload3(0, camera->up);
    return normalize(d);
}

#endif
