// Pinhole camera rays through image positions (image row 0 is the top of the image).
#ifndef CLRENDER_CAMERA_H
#define CLRENDER_CAMERA_H

#include "scene_types.h"
#include "vecmath.h"

// The unit direction of the ray through image position (x, y) in pixels of a width x height
// image: pixel (i, j) covers [i, i+1] x [j, j+1], y grows downwards.
CL_INLINE float3 Camera_Direction(__global const Camera *camera, float2 image_pos, uint width,
                                  uint height)
{
    float sx = 2.0f * image_pos.x / (float)width - 1.0f;
    float sy = 1.0f - 2.0f * image_pos.y / (float)height;
    float3 d = Load3(camera->forward) + sx * Load3(camera->right) +
               sy * Load3(camera->up);
    return Normalize3(d);
}

#endif
