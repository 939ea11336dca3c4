"""Launching a test kernel (kernels/*_test.cl) that writes per-item output arrays."""

import numpy as np
import pyopencl as cl

from clrender.runtime import padded_global_size


def run_test_kernel(runtime, source: str, name: str, count: int, outputs: dict, *arguments):
    """Launch `name` of `source` over `count` items with (count, *arguments, *output buffers),
    the outputs in the order of the `outputs` dict (name -> empty NumPy array, filled here);
    returns `outputs`."""
    buffers = {
        key: cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, array.nbytes)
        for key, array in outputs.items()
    }
    runtime.kernel(source, name)(
        runtime.queue,
        (padded_global_size(count),),
        (runtime.local_size,),
        np.uint32(count),
        *arguments,
        *buffers.values(),
    )
    for key, array in outputs.items():
        cl.enqueue_copy(runtime.queue, array, buffers[key])
    return outputs
