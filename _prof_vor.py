import numpy as np, pyopencl as cl, time
from clrender.runtime import create_runtime, Runtime
from clrender.sampling import generate_sample_sets, make_sampler
from clrender.estimators import device_cells as dc
base = create_runtime()
q = cl.CommandQueue(base.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
rt = Runtime(base.device, base.context, q, base.local_size)
events = []
orig = rt.launch_1d
def launch(kernel, count, *args):
    ev = orig(kernel, count, *args); events.append((kernel.function_name, count, ev)); return ev
rt.launch_1d = launch
for n, pixels in ((256, 4096), (64, 16384)):
    cfg = make_sampler("sppp", n)
    sets = generate_sample_sets(rt, cfg, 3, np.arange(pixels, dtype=np.uint32))
    rad = rt.upload(np.random.default_rng(1).uniform(0,1,(sets.traced_total,3)).astype(np.float32))
    for rep in range(3):
        events.clear()
        t=time.perf_counter(); c0=time.process_time()
        s = dc.device_sppp_sums(rt, sets, rad, 0.5+cfg.eps)
        q.finish()
        wall=time.perf_counter()-t; cpu=time.process_time()-c0
        parts = {name: (ev.profile.end-ev.profile.start)*1e-9 for name,_,ev in events}
        print(n, pixels, sets.traced_total, f"wall {wall:.3f} cpu {cpu:.3f}", {k: round(v,3) for k,v in parts.items()}, f"ns/cell {wall/sets.traced_total*1e9:.0f}")
