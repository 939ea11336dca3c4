"""Every kernel family of clrender run once under Oclgrind, the OpenCL device simulator, with its
checks on: the errors a GPU would not forgive and a CPU device (PoCL) does.

    python bench/oclgrind_check.py                      # every family
    python bench/oclgrind_check.py --families sampling voronoi
    python bench/oclgrind_check.py --oclgrind-lib /opt/oclgrind/lib/liboclgrind-rt-icd.so
    python bench/oclgrind_check.py --list               # the families

Oclgrind (https://github.com/jrprice/Oclgrind) interprets each work-item's LLVM IR and reports
reads and writes outside a buffer, uses of uninitialised values (OCLGRIND_UNINITIALIZED), data
races between work-items (OCLGRIND_DATA_RACES), barrier divergence, misaligned accesses and
OpenCL API misuse (OCLGRIND_CHECK_API). It is 100 to 10 000 times slower than PoCL, so every
family runs on tiny inputs: 4 x 4 or 8 x 8 pixels at 4 samples each.

Families (each in its own child process, with its own Oclgrind log):
  integrator   trace_paths (kernels/integrator.cl) on every shipped scene with sppp, and on the
               Cornell box with every sampler; one ordinary render of 4 x 4 pixels (its padded
               launches and its warm-up launches, every argument 0)
  wavefront    the wavefront stages (kernels/wavefront.cl) on every shipped scene
  sampling     count_samples and the fill kernels (kernels/sampling.cl) for every sampler
  voronoi      the device Voronoi cells and sums (kernels/voronoi_cells.cl, voronoi_sums.cl):
               one render with every estimator, then the cells of edge cases (ties, k-gons,
               near-hull and degenerate pixels, vertex overflow, torus and mirror copies), in
               double and in single precision
  test-kernels the tests' kernels (kernels/*_test.cl) through the tests' own launch code
  selfcheck    kernels/selfcheck.cl (the Philox known answers)

Oclgrind's device: an ICD whose platform is named "Oclgrind". The script finds it among the
platforms the ICD loader already lists, else through --oclgrind-lib or a liboclgrind-rt-icd.so
in the usual places (Debian's oclgrind package: /usr/lib/oclgrind/), for which it writes an
ICD folder (a one-line .icd file) and runs the children with OCL_ICD_VENDORS set to it. Needs
Oclgrind 26.03 or later: Debian 12's oclgrind 21.10 stops at LLVM intrinsics its interpreter
lacks (llvm.experimental.noalias.scope.decl, which clang 14 emits on inlining) before any kernel
runs (README: "Oclgrind check" says how to build it), built with bench/oclgrind-26.03.patch:
26.03.1's uninitialised-value plugin calls every byte of a buffer past its last host store's
length uninitialised (a fill left all but its first pattern so, even once a kernel wrote them)
and crashes on a host store executed on a second thread. A probe (a child, first) checks both
and refuses an Oclgrind that has them (exit status 2). The kernels are built without
optimisation (OCLGRIND_BUILD_OPTIONS=-cl-opt-disable): LLVM's optimiser turns bit tricks into
intrinsics Oclgrind cannot run either (llvm.bitreverse, llvm.ctpop), and unoptimised code keeps
every access the source makes.

Output: one JSON object on stdout: per family its seconds, exit status and error counts per
kernel (and per API function), with the first lines of each distinct error. One API error is
not counted: clGetDeviceInfo with CL_INVALID_VALUE at each kernel's creation is pyopencl asking
for NVIDIA's CL_DEVICE_COMPUTE_CAPABILITY_MAJOR_NV (0x4000; it expects the refusal), listed as
"ignored". Exit status 0 when no family reported an error and every one ran to its end, 1
otherwise, 2 when Oclgrind is not installed or fails the probe (one line on stderr) or for bad
arguments.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLATFORM = "Oclgrind"
ICD_LIBRARY = "liboclgrind-rt-icd.so"
LIBRARY_PLACES = (
    "/usr/lib/oclgrind",
    "/usr/local/lib",
    "/usr/lib/x86_64-linux-gnu",
    "/opt/oclgrind/lib",
)
FAMILIES = ("integrator", "wavefront", "sampling", "voronoi", "test-kernels", "selfcheck")
SCENES = ("cornell-box", "cornell-box-glossy", "mitsuba-cbox", "furnace", "veach-mis")
SIZE = 4  # pixels per side of most launches
SPP = 4  # a square and a power of two: every sampler takes it
CHECKS = {
    "OCLGRIND_CHECK_API": "1",
    "OCLGRIND_DATA_RACES": "1",
    "OCLGRIND_UNINITIALIZED": "1",
    "OCLGRIND_BUILD_OPTIONS": "-cl-opt-disable",
    "OCLGRIND_MAX_ERRORS": "100",
    # pyopencl keeps built binaries of non-PoCL devices; Oclgrind's depend on the options above
    "PYOPENCL_NO_CACHE": "1",
}
# pyopencl's query of CL_DEVICE_COMPUTE_CAPABILITY_MAJOR_NV at each kernel's creation
IGNORED_API = ("clGetDeviceInfo", "CL_INVALID_VALUE")
PATCH = "bench/oclgrind-26.03.patch"


def fail(message: str) -> None:
    print(f"oclgrind_check: {message}", file=sys.stderr)
    raise SystemExit(2)


# ------------------------------------------------------------------------------ finding Oclgrind


def visible_platforms(env: dict[str, str]) -> list[str]:
    """The platform names a child with this environment sees (empty if none)."""
    code = "import pyopencl as cl; print('\\n'.join(p.name for p in cl.get_platforms()))"
    run = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    return [line.strip() for line in run.stdout.splitlines() if line.strip()]


def find_library(requested: str | None) -> Path | None:
    if requested:
        path = Path(requested)
        if not path.is_file():
            fail(f"--oclgrind-lib {requested}: no such file")
        return path
    for place in LIBRARY_PLACES:
        path = Path(place) / ICD_LIBRARY
        if path.is_file():
            return path
    return None


def oclgrind_environment(requested: str | None, icd_dir: Path) -> dict[str, str]:
    """The children's environment: Oclgrind selected, its checks on. Exits (2) without it."""
    env = dict(os.environ)
    library = find_library(requested)
    if library is not None:
        icd_dir.mkdir(parents=True, exist_ok=True)
        (icd_dir / "oclgrind.icd").write_text(f"{library}\n")
        env["OCL_ICD_VENDORS"] = str(icd_dir)
    if not any(PLATFORM in name for name in visible_platforms(env)):
        fail(
            "Oclgrind is not installed (no OpenCL platform named Oclgrind, no "
            f"{ICD_LIBRARY} in {', '.join(LIBRARY_PLACES)}): build Oclgrind 26.03 or later "
            "(README: Oclgrind check) and pass --oclgrind-lib"
        )
    env.update(CHECKS)
    env["PYOPENCL_CTX"] = PLATFORM
    env.pop("CLRENDER_NO_FP64", None)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT), str(ROOT / "tests"), *filter(None, [env.get("PYTHONPATH", "")])]
    )
    return env


# ------------------------------------------------------------------------------ reading the log


def parse_log(text: str) -> dict:
    """Oclgrind's messages, counted per kernel ('Kernel: NAME' in a kernel error) and per API
    function ('Function: NAME' in a runtime error), each distinct one's first lines kept."""
    blocks, current = [], []
    for line in text.splitlines():
        if not line.strip():
            if current:
                blocks.append(current)
                current = []
            continue
        current.append(line.rstrip())
    if current:
        blocks.append(current)
    kernels: dict[str, int] = {}
    api: dict[str, int] = {}
    ignored = 0
    fatal: list[str] = []
    examples: dict[str, list[str]] = {}
    for block in blocks:
        text_block = "\n".join(block)
        if block[0].startswith("OCLGRIND FATAL"):
            fatal.append(" ".join(line.strip() for line in block))
            continue
        function = re.search(r"Function:\s*(\S+)", text_block)
        if block[0].startswith("Oclgrind - OpenCL runtime error") and function:
            error = re.search(r"Error:\s*(\S+)", text_block)
            if (function.group(1), error.group(1) if error else "") == IGNORED_API:
                ignored += 1
                continue
            api[function.group(1)] = api.get(function.group(1), 0) + 1
            key = f"api {function.group(1)}: {error.group(1) if error else '?'}"
        else:
            kernel = re.search(r"Kernel:\s*(\S+)", text_block)
            name = kernel.group(1) if kernel else "(no kernel named)"
            kernels[name] = kernels.get(name, 0) + 1
            at = re.search(r"At line (\d+) of (\S+)", text_block)
            message = re.sub(r" at \S+ memory address 0x[0-9a-f]+", "", block[0].strip())
            key = f"{name}: {message}" + (f" ({at.group(2)}:{at.group(1)})" if at else "")
        if key not in examples and len(examples) < 20:
            examples[key] = block[:12]
    return {
        "kernel_errors": kernels,
        "api_errors": api,
        "ignored_api_errors": ignored,
        "fatal": fatal,
        "examples": examples,
    }


def oclgrind_messages(stderr: str) -> str:
    """The blocks of a child's stderr that Oclgrind wrote (not the child's own lines)."""
    kept, keep = [], False
    for line in stderr.splitlines():
        if line.startswith(("OCLGRIND FATAL", "Oclgrind - ")):
            keep = True
        elif not line.strip():
            keep = False
        if keep:
            kept.append(line)
        elif not line.strip() and kept and kept[-1]:
            kept.append("")
    return "\n".join(kept)


# ------------------------------------------------------------------------------ the parent


def run_family(family: str, env: dict[str, str], log_dir: Path, timeout: float) -> dict:
    log = log_dir / f"{family}.log"
    log.unlink(missing_ok=True)
    child_env = dict(env, OCLGRIND_LOG=str(log))
    start = time.perf_counter()
    try:
        run = subprocess.run(
            [sys.executable, __file__, "--child", family],
            env=child_env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        status, stderr = run.returncode, run.stderr
    except subprocess.TimeoutExpired as err:
        status, stderr = "timeout", (err.stderr or b"").decode(errors="replace")
    seconds = time.perf_counter() - start
    text = log.read_text(errors="replace") if log.exists() else ""
    # Messages not sent to the log (a fatal error of the interpreter) reach stderr
    result = parse_log(text + "\n\n" + oclgrind_messages(stderr))
    result.update(family=family, seconds=round(seconds, 1), exit_status=status, log=str(log))
    if status != 0:
        result["stderr_tail"] = stderr.strip().splitlines()[-8:]
    result["errors"] = (
        sum(result["kernel_errors"].values())
        + sum(result["api_errors"].values())
        + len(result["fatal"])
    )
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--families", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    parser.add_argument("--oclgrind-lib", help=f"path of Oclgrind's {ICD_LIBRARY}")
    parser.add_argument("--out", type=Path, help="folder for the Oclgrind logs (default: temp)")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds per family")
    parser.add_argument("--list", action="store_true", help="print the families and exit")
    parser.add_argument("--child", choices=(*FAMILIES, "probe"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        CHILDREN[args.child]()
        return 0
    if args.list:
        print("\n".join(FAMILIES))
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="oclgrind_check_"))
    out.mkdir(parents=True, exist_ok=True)
    env = oclgrind_environment(args.oclgrind_lib, out / "icd")
    probe = run_family("probe", env, out, 600.0)
    if probe["errors"] or probe["exit_status"] != 0:
        fail(
            f"this Oclgrind's uninitialised-value check is unreliable (a filled buffer read as "
            f"uninitialised, or a crash on a host store from a second thread; {probe['log']}): "
            f"build it with {PATCH} (README: Oclgrind check)"
        )
    families = []
    for family in args.families:
        result = run_family(family, env, out, args.timeout)
        families.append(result)
        print(
            f"oclgrind_check: {family}: {result['errors']} error(s), exit status "
            f"{result['exit_status']}, {result['seconds']} s",
            file=sys.stderr,
        )
    total = sum(f["errors"] for f in families)
    ok = total == 0 and all(f["exit_status"] == 0 for f in families)
    summary = {"ok": ok, "errors": total, "checks": CHECKS, "logs": str(out), "families": families}
    print(json.dumps(summary, indent=1))
    return 0 if ok else 1


# ------------------------------------------------------------------------------ the children
# Each runs in a child process on the Oclgrind device (PYOPENCL_CTX=Oclgrind).


def tiny_launches() -> None:
    """Launch only what the work needs (padded to the local size): the render's minimum launch
    of 65 536 work-items (PoCL's "smallgrid" code) would be interpreted item by item."""
    import clrender.runtime as runtime_module

    runtime_module.MIN_LAUNCH_SIZE = 1


def sample_sets(runtime, sampler: str, size: int = SIZE, spp: int = SPP, seed: int = 3):
    from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels

    pixels = rectangle_pixels(size, 0, 0, size, size)
    config = make_sampler(sampler, spp)
    return generate_sample_sets(runtime, config, seed, pixels, None, (size, size))


PROBE_SOURCE = """
__kernel void write_all(__global uchar *bytes, __global uchar *scratch)
{
    bytes[get_global_id(0)] = 9;
    scratch[get_global_id(0)] = 1;
}
__kernel void branch_on(__global const uchar *bytes, __global uint *out)
{
    uint i = get_global_id(0);
    out[i] = 0;
    if (bytes[i] & 1)
        out[i] = 1;
}
"""


def child_probe() -> None:
    """Oclgrind's own faults, which the PATCH fixes (its uninitialised-value plugin, 26.03.1):
    a host store (write, fill, copy) replaced the buffer's shadow by one as long as the store,
    so after a fill of byte patterns every byte but the first read as uninitialised, even once
    a kernel wrote it; and a host store executed on a thread other than the context's (the
    thread that waits for the queue: the render's estimator thread), and a kernel launched
    there, crashed on a null per-thread memory pool. Here: a fill and a kernel that writes
    every byte from a second thread, then one that branches on every byte. Unpatched: a crash,
    or 7 errors."""
    import threading

    import numpy as np
    import pyopencl as cl

    from clrender.runtime import default_runtime

    runtime = default_runtime()
    count = 8
    data = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, count)
    out = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, 4 * count)
    scratch = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, count)
    program = cl.Program(runtime.context, PROBE_SOURCE).build()

    def fill_and_write() -> None:
        cl.enqueue_fill_buffer(runtime.queue, data, np.uint8(4), 0, count)
        # scratch: a buffer the host never wrote (its shadow is made at the launch)
        program.write_all(runtime.queue, (count,), None, data, scratch)
        runtime.queue.finish()

    thread = threading.Thread(target=fill_and_write)
    thread.start()
    thread.join()
    program.branch_on(runtime.queue, (count,), None, data, out)
    result = np.empty(count, np.uint32)
    cl.enqueue_copy(runtime.queue, result, out)
    if not (result == 1).all():
        raise SystemExit(f"probe: read {result.tolist()}, expected every byte odd")


def child_integrator() -> None:
    from clrender.api import render
    from clrender.runtime import default_runtime
    from clrender.sampling import SAMPLERS
    from clrender.scene import load_scene
    from clrender.trace import PathTracer

    runtime = default_runtime()
    # an ordinary render first, with the render's own launch sizes and warm-up launches
    render("cornell-box", spp=SPP, sampler="independent", resolution=(SIZE, SIZE))
    tiny_launches()
    for scene_name in SCENES:
        tracer = PathTracer(runtime, load_scene(scene_name))
        samplers = SAMPLERS if scene_name == "cornell-box" else ("sppp",)
        for sampler in samplers:
            sets = sample_sets(runtime, sampler)
            tracer.trace(sets, 3, SIZE, SIZE).to_host()
            print(f"integrator: {scene_name} {sampler}", file=sys.stderr, flush=True)


def child_wavefront() -> None:
    from clrender.runtime import default_runtime
    from clrender.scene import load_scene
    from clrender.wavefront import WavefrontPathTracer

    tiny_launches()
    runtime = default_runtime()
    for scene_name in SCENES:
        # chunks of 40 paths: several chunks, the last one partial
        tracer = WavefrontPathTracer(runtime, load_scene(scene_name), wave_paths=40)
        tracer.trace(sample_sets(runtime, "sppp"), 3, SIZE, SIZE).to_host()
        print(f"wavefront: {scene_name}", file=sys.stderr, flush=True)


def child_sampling() -> None:
    from clrender.runtime import default_runtime
    from clrender.sampling import SAMPLERS

    tiny_launches()
    runtime = default_runtime()
    for sampler in SAMPLERS:
        sample_sets(runtime, sampler, size=5)  # 5 x 5: groups not a whole local size
        print(f"sampling: {sampler}", file=sys.stderr, flush=True)


def child_voronoi() -> None:
    from clrender.api import render
    from clrender.estimators import ESTIMATORS

    tiny_launches()
    names = [name for name, info in ESTIMATORS.items() if name not in ("mc", "mc_n")]
    for precision in ("double", "single"):
        if precision == "single":
            os.environ["CLRENDER_NO_FP64"] = "1"
        render(
            "cornell-box",
            spp=SPP,
            sampler="sppp",
            estimators=names,
            resolution=(SIZE, SIZE),
            voronoi_backend="device",
        )
        print(f"voronoi: {precision} {names}", file=sys.stderr, flush=True)
        voronoi_cell_cases()
        print(f"voronoi: {precision} cell cases", file=sys.stderr, flush=True)


def voronoi_cell_cases() -> None:
    """The cell kernels on the cases a render rarely reaches (tests/test_device_cells.py's):
    lattice ties (the one-way walk), regular k-gons (more than 8 edges), near-hull cells (the
    clipping search), degenerate pixels, vertex overflow (host fallback), torus and mirror
    copies."""
    import numpy as np
    import test_device_cells as cases

    from clrender.estimators import device_cells
    from clrender.runtime import default_runtime

    runtime = default_runtime()

    def cells(traced, offsets, aux, aux_offsets, box):
        rounded = cases.rounded
        device_cells.device_sppp_cells_from_arrays(
            runtime, rounded(traced), offsets, rounded(aux), aux_offsets, box
        )

    for n, pixels, eps in ((4, 8, None), (64, 2, None), (16, 4, 0.003)):
        batch, box = cases.sppp_batch(n, pixels, seed=n, eps=eps)
        cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box)
    cells(*cases.degenerate_pixels(), 0.55)
    side = 8
    centres = (np.arange(side) + 0.5) / side - 0.5
    lattice = np.array([(x, y) for y in centres for x in centres])
    ring = (np.arange(-1, side + 1) + 0.5) / side - 0.5
    frame = np.array([(x, y) for y in ring for x in ring if max(abs(x), abs(y)) > 0.5])
    offsets = cases.offsets_of
    cells(lattice, offsets([len(lattice)]), frame, offsets([len(frame)]), 0.5 + 1 / side)
    gons = [2 * np.pi * np.arange(k) / k + 0.1 for k in (3, 8, 9, 12)]
    rings = [0.2 * np.column_stack([np.cos(a), np.sin(a)]) for a in gons]
    cells(
        np.zeros((len(rings), 2)),
        offsets([1] * len(rings)),
        np.concatenate(rings),
        offsets([len(r) for r in rings]),
        None,
    )
    batch, _ = cases.sppp_batch(16, 3, seed=4)
    inside = np.clip(batch.traced, -0.49, 0.49)
    device_cells.device_periodic_cells_from_arrays(runtime, inside, batch.offsets)
    device_cells.device_clipped_cells_from_arrays(runtime, inside, batch.offsets)
    limit = device_cells.MAX_VERTICES
    device_cells.MAX_VERTICES = 5  # overflow: the host recomputes those pixels
    try:
        batch, box = cases.sppp_batch(16, 4, seed=5)
        cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box)
    finally:
        device_cells.MAX_VERTICES = limit


def child_test_kernels() -> None:
    import numpy as np
    import pyopencl as cl

    from clrender.runtime import default_runtime
    from clrender.scene import load_scene

    runtime = default_runtime()
    gen = np.random.default_rng(5)
    count = 13  # not a multiple of the local size: padding work-items

    def struct_sizes(source: str, slots: int) -> None:
        buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=4 * slots)
        runtime.kernel(source, "struct_sizes")(runtime.queue, (1,), None, buf)
        cl.enqueue_copy(runtime.queue, np.zeros(slots, np.uint32), buf)

    import geometry_device
    import test_bsdf
    import test_bvh_traversal
    import test_mesh_emitters
    import test_rng
    import test_samplers
    import test_sphere_lights

    for source in ("scene_types_test.cl", "bvh_test.cl", "geometry_test.cl"):
        struct_sizes(source, 16)
    # bsdf_test.cl: every material kind
    kernels = test_bsdf.BsdfKernels(runtime)
    for kind in test_bsdf.MATERIAL_TYPES:
        mat = test_bsdf.material(kind)
        wo = gen.normal(size=(count, 3))
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        kernels.sample(mat, wo, gen.uniform(size=(count, 3)))
        kernels.eval(mat, wo, wo[::-1].copy())
    # geometry_test.cl: rays through a scene, brute force and through its BVH
    for scene_name, bvh in (("cornell-box", False), ("veach-mis", True)):
        scene = load_scene(scene_name)
        origins = np.tile(np.asarray(scene.camera.look_from), (count, 1))
        directions = np.asarray(scene.camera.look_at) - origins + gen.normal(0, 0.3, (count, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        geometry_device.device_intersect(runtime, scene, origins, directions, bvh)
        geometry_device.device_occluded(
            runtime, scene, origins, directions, np.full(count, 5.0, np.float32), bvh
        )
        geometry_device.device_surface(runtime, scene, origins, directions, bvh)
    # bvh_test.cl: a block of triangles against rays
    tris = np.zeros(5, test_bvh_traversal.TRIANGLE_DTYPE)
    for key in ("p0", "p1", "p2"):
        tris[key] = gen.uniform(-1, 1, size=(5, 3))
    dirs = gen.normal(size=(count, 3))
    test_bvh_traversal.block_hits(
        runtime, tris, gen.uniform(-2, 2, (count, 3)), dirs, np.full(count, 10.0)
    )
    # lights_test.cl and mesh_lights_test.cl
    sphere, emitter = test_sphere_lights.sphere_records((0.0, 0.0, 0.0), 0.5)
    test_sphere_lights.run_test_kernel(
        runtime,
        "lights_test.cl",
        "sample_sphere_light",
        count,
        {
            "wi": np.empty((count, 3), np.float32),
            "dist": np.empty(count, np.float32),
            "pdf": np.empty(count, np.float32),
            "hit_pdf": np.empty(count, np.float32),
        },
        runtime.upload(sphere),
        runtime.upload(emitter),
        np.uint32(1),
        runtime.upload(gen.uniform(1, 2, (count, 3)).astype(np.float32)),
        runtime.upload(gen.uniform(size=(count, 2)).astype(np.float32)),
    )
    triangles, emitters = test_mesh_emitters.random_mesh(gen, 3)
    test_mesh_emitters.device_samples(
        runtime, triangles, emitters, gen.uniform(-2, 2, (count, 3)), gen.uniform(size=(count, 3))
    )
    # rng_test.cl and sampler_test.cl
    test_rng._device_uniform_slots(runtime, 7, gen.integers(0, 2**32, (count, 4), np.uint32))
    for sampler in ("independent", "stratified", "sobol", "zsobol", "sppp-sobol"):
        test_samplers.dimensions(runtime, sampler, SPP, [0, 1, 5], depths=2, size=(4, 4))
    u32 = np.uint32
    test_samplers.read(runtime, "sobol_points", count, (count, 2), np.uint32, u32(count))
    values = runtime.upload(gen.integers(0, 2**32, count, np.uint32))
    test_samplers.read(
        runtime, "owen_scramble", count, count, np.uint32, u32(count), u32(9), values
    )
    test_samplers.read(runtime, "permutation_elements", 7, 7, np.uint32, u32(7), u32(11), u32(3))
    xy = runtime.upload(gen.integers(0, 16, (count, 2), np.uint32))
    digits = runtime.upload(gen.integers(0, 2**16, (count, 2), np.uint32))
    test_samplers.read(
        runtime, "morton_and_digits", count, (count, 2), np.uint32, u32(count), xy, digits
    )
    print("test kernels: done", file=sys.stderr, flush=True)


def child_selfcheck() -> None:
    from clrender.runtime import default_runtime
    from clrender.selfcheck import run_self_check

    ok, message = run_self_check(default_runtime())
    print(f"selfcheck: {message}", file=sys.stderr, flush=True)
    if not ok:
        raise SystemExit(1)


CHILDREN = {
    "probe": child_probe,
    "integrator": child_integrator,
    "wavefront": child_wavefront,
    "sampling": child_sampling,
    "voronoi": child_voronoi,
    "test-kernels": child_test_kernels,
    "selfcheck": child_selfcheck,
}

if __name__ == "__main__":
    raise SystemExit(main())
