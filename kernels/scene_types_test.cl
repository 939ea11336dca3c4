// Test kernel (built only by tests/test_scene.py): the sizes of scene_types.h's structs, which
// clrender/scene_device.py's dtypes must match.
#include "scene_types.h"

// sizeof of the structs shared with the host, to check the NumPy dtypes.
__kernel void struct_sizes(__global uint *sizes)
{
    sizes[0] = sizeof(Quad);
    sizes[1] = sizeof(Sphere);
    sizes[2] = sizeof(Material);
    sizes[3] = sizeof(Emitter);
    sizes[4] = sizeof(Camera);
    sizes[5] = sizeof(QuadBlock);
}
