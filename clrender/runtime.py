"""OpenCL runtime: device selection, program building and launch-size helpers.

A device is chosen from an explicit request (index or name substring), else from the
PYOPENCL_CTX environment variable, else the first device of the first platform. Nothing here
ever prompts. Programs are built from the kernels/ folder with ``-I`` so compiler messages
keep their file:line, and each (source, options) pair is built once per process.

The CLRENDER_KERNELS_DIR environment variable, when set and not empty, replaces the kernels
folder (sources and ``-I`` path): for kernel development, and for tests that give the command
line a broken kernel to check how build failures are reported.

Nothing about the device is assumed: the local size is LOCAL_SIZE within the device's and each
kernel's work-group limits (queried), and double precision is used only where the device has
cl_khr_fp64 (has_fp64; CLRENDER_NO_FP64 set makes every device count as without it).
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.tools as cl_tools

from clrender import interrupts
from clrender.errors import DeviceError, KernelBuildError
from clrender.package_data import shipped_dir

KERNELS_DIR_VARIABLE = "CLRENDER_KERNELS_DIR"
# Set (not empty): every device is treated as lacking cl_khr_fp64, so the single-precision
# paths run on a device that has double precision (tests, bench/portability.py --no-fp64).
NO_FP64_VARIABLE = "CLRENDER_NO_FP64"
# One fixed local size per kernel: PoCL JIT-compiles a work-group function per new local size.
# The largest wanted; a device or kernel that allows fewer work-items per group gets fewer.
LOCAL_SIZE = 64
# The render's kernels: with every scalar argument 0, each one's work-item count is 0 and every
# work-item returns at once. Runtime.kernel launches each so once (a launch that does nothing),
# so that a device that generates a kernel's code at its first launch (PoCL, for each local
# size) does it then, and the time counts as compile time, not render time.
WARM_UP_FILES = frozenset(
    {"sampling.cl", "integrator.cl", "trace_simd.cl", "voronoi_cells.cl", "voronoi_sums.cl"}
)
# The render launches at least this many work-items (the extra ones return at once: about
# 0.15 ms per launch on PoCL): PoCL generates a second version of each kernel for grids of up to
# 32 768 work-items ("smallgrid"), which would double a cold start's code generation.
MIN_LAUNCH_SIZE = 1 << 16
# OpenCL C scalar types of those kernels' arguments
SCALAR_TYPES = {
    "uint": np.uint32,
    "int": np.int32,
    "float": np.float32,
    "ulong": np.uint64,
    "long": np.int64,
    "uchar": np.uint8,
}

# Per thread: a render's estimator thread builds on its own context (clrender.pipeline).
_THREAD_BUILD_TIME = threading.local()
# Per kernels folder, the fingerprints of its sources as this process's program builds found
# them (clrender.provenance.sources_fingerprint), in build order, each once
_BUILT_SOURCES: dict[Path, list[str]] = {}

INSTALL_HINT = (
    'no OpenCL platform found: install a CPU device with `pip install "pyopencl[pocl]"` '
    "(no root needed), or Debian's `pocl-opencl-icd`, or your GPU vendor's OpenCL driver"
)


def kernels_dir() -> Path:
    """The folder of OpenCL sources: $CLRENDER_KERNELS_DIR if set, else inside the installed
    package, else the source checkout."""
    override = os.environ.get(KERNELS_DIR_VARIABLE, "")
    if override:
        if not Path(override).is_dir():
            raise KernelBuildError(f"{KERNELS_DIR_VARIABLE}={override} is not a directory")
        return Path(override)
    return shipped_dir("kernels", "OpenCL kernel sources")


def list_devices() -> list[cl.Device]:
    """Every device of every platform, in platform order; DeviceError if there are none."""
    try:
        platforms = cl.get_platforms()
    except cl.LogicError as err:  # the ICD loader reports 'no platforms' as an error
        raise DeviceError(INSTALL_HINT) from err
    devices = []
    for platform in platforms:
        with contextlib.suppress(cl.Error):  # DEVICE_NOT_FOUND: a platform with none
            devices += platform.get_devices()
    if not devices and platforms:
        names = ", ".join(platform.name for platform in platforms)
        raise DeviceError(
            f"the OpenCL platforms ({names}) offer no device; PoCL offers none when it cannot "
            f"create its kernel cache: make {pocl_cache_dir()} writable, or point "
            "POCL_CACHE_DIR at a folder that is"
        )
    if not devices:
        raise DeviceError(INSTALL_HINT)
    return devices


def pocl_cache_dir() -> str:
    """Where PoCL keeps its compiled kernels: $POCL_CACHE_DIR, else $XDG_CACHE_HOME/pocl, else
    ~/.cache/pocl (PoCL's own order)."""
    if os.environ.get("POCL_CACHE_DIR"):
        return os.environ["POCL_CACHE_DIR"]
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(cache, "pocl")


def has_fp64(device: cl.Device) -> bool:
    """Whether the device has double precision (cl_khr_fp64), unless $CLRENDER_NO_FP64 is set."""
    if os.environ.get(NO_FP64_VARIABLE, ""):
        return False
    return "cl_khr_fp64" in device.extensions.split()


def device_local_size(device: cl.Device) -> int:
    """The local size for the device: LOCAL_SIZE, or its largest work-group if smaller."""
    return max(1, min(LOCAL_SIZE, int(device.max_work_group_size)))


def describe_device(device: cl.Device) -> str:
    return f"{device.name.strip()} [{device.platform.name.strip()}, {device.version.strip()}]"


def _pick_from_pyopencl_ctx(spec: str, platforms: list[cl.Platform]) -> cl.Device:
    """PYOPENCL_CTX syntax: 'platform[:device]', each an index or a name substring."""
    plat_spec, _, dev_spec = spec.partition(":")
    platform = (
        _match_one(plat_spec, platforms, "PYOPENCL_CTX platform") if plat_spec else platforms[0]
    )
    devices = platform.get_devices()
    return _match_one(dev_spec, devices, "PYOPENCL_CTX device") if dev_spec else devices[0]


def _match_one(spec: str, items: list, what: str):
    names = [item.name.strip() for item in items]
    if spec.isdigit():
        index = int(spec)
        if index < len(items):
            return items[index]
    else:
        for item, name in zip(items, names, strict=True):
            if spec.lower() in name.lower():
                return item
    accepted = ", ".join(f"{i}: {name}" for i, name in enumerate(names))
    raise DeviceError(f"{what} {spec!r} matches nothing; accepted: {accepted}")


def match_device(request: str, devices: list[cl.Device]) -> cl.Device:
    """The device `--device REQUEST` names among `devices`: by index, by its whole name, or by
    a part of its description (describe_device: name, platform, version) that no other device's
    has. DeviceError in one line otherwise, listing the devices (several share "Intel(R) Xeon"
    when PoCL and Intel's runtime drive the same CPU)."""
    listed = "; ".join(f"{i}: {describe_device(device)}" for i, device in enumerate(devices))
    what = "--device (device=)"
    if request.isdigit():
        if int(request) < len(devices):
            return devices[int(request)]
        raise DeviceError(f"{what} {request!r} matches nothing; accepted: {listed}")
    wanted = request.lower()
    whole = [device for device in devices if device.name.strip().lower() == wanted]
    if len(whole) == 1:
        return whole[0]
    found = [i for i, device in enumerate(devices) if wanted in describe_device(device).lower()]
    if len(found) == 1:
        return devices[found[0]]
    if found:
        raise DeviceError(
            f"{what} {request!r} matches {len(found)} devices ({', '.join(map(str, found))}): "
            f"give an index or a part of one description only; accepted: {listed}"
        )
    raise DeviceError(f"{what} {request!r} matches nothing; accepted: {listed}")


def select_device(request: str | None = None) -> cl.Device:
    """The device for `--device REQUEST` (match_device: index, whole name or a part of one
    device's description), else PYOPENCL_CTX, else the first available device."""
    devices = list_devices()
    if request is not None and request != "":
        return match_device(str(request), devices)
    env = os.environ.get("PYOPENCL_CTX", "").strip()
    if env:
        return _pick_from_pyopencl_ctx(env, cl.get_platforms())
    return devices[0]


@dataclass
class Runtime:
    """One OpenCL context and in-order queue on one device.

    Per-launch buffers come from a memory pool (allocate, upload): a render allocates the same
    sizes tile after tile, and the pool hands the same memory back instead of new allocations
    (which a CPU device must fault in and clear page by page).
    """

    device: cl.Device
    context: cl.Context
    queue: cl.CommandQueue
    # queried: LOCAL_SIZE within the device's work-group limit (kernel_local_size: the kernel's)
    local_size: int = LOCAL_SIZE
    pool: cl_tools.MemoryPool = field(init=False, repr=False)
    # a second context on the device, for another thread (clrender.pipeline.sibling_runtime)
    sibling: Runtime | None = field(default=None, init=False, repr=False)
    # side_queue's, made at its first use
    _side_queue: cl.CommandQueue | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.pool = cl_tools.MemoryPool(cl_tools.ImmediateAllocator(self.queue))

    def build(self, source_file: str, defines: dict[str, object] | None = None) -> cl.Program:
        """Build kernels/<source_file> with -D defines; cached per (context, kernels folder, file,
        defines)."""
        return _build_cached(self.context, kernels_dir(), source_file, define_key(defines))

    def kernel(
        self, source_file: str, name: str, defines: dict[str, object] | None = None
    ) -> cl.Kernel:
        """One kernel of a built program, retrieved once per process (retrieval is costly)."""
        items = define_key(defines)
        kernel = _kernel_cached(self.context, kernels_dir(), source_file, items, name)
        if source_file in WARM_UP_FILES:
            self.warm_up(kernel, source_file, items, name)
        return kernel

    def warm_up(
        self,
        kernel: cl.Kernel,
        source_file: str,
        defines: tuple[tuple[str, object], ...],
        name: str,
    ) -> None:
        """Launch a kernel of WARM_UP_FILES with every scalar argument 0 (no work-item does
        anything) and a small dummy buffer for each pointer, as the render launches it
        (launch_global_size), once per (context, kernel, its local size); the time counts as build
        time (thread_build_seconds)."""
        local = self.kernel_local_size(kernel)
        key = (self.context.int_ptr, source_file, defines, name, local, kernels_dir())
        if key in _WARMED:
            return
        start = time.perf_counter()
        try:
            args = warm_up_arguments(source_file, name, self.allocate(64))
            global_size = launch_global_size(0, local)
            kernel(self.queue, (global_size,), (local,), *args).wait()
            _WARMED.add(key)
        finally:
            _count_build_time(start)

    def kernel_local_size(self, kernel: cl.Kernel) -> int:
        """The local size a kernel runs with here: local_size, or fewer where the device
        cannot run this kernel with that many work-items per group (its registers or local
        memory: a GPU may limit a large kernel below the device's maximum)."""
        return min(self.local_size, _kernel_work_group_size(kernel, self.device))

    def launch_1d(
        self, kernel: cl.Kernel, count: int, *args, queue: cl.CommandQueue | None = None
    ) -> cl.Event:
        """Enqueue kernel over count work-items (launch_global_size: padded; the kernel skips
        the padding itself) on this runtime's queue, or on `queue` (side_queue)."""
        local = self.kernel_local_size(kernel)
        queue = self.queue if queue is None else queue
        return kernel(queue, (launch_global_size(count, local),), (local,), *args)

    @property
    def side_queue(self) -> cl.CommandQueue:
        """A second in-order queue on this context (made once, with the main queue's
        properties), for short work whose result the host waits for and which must not wait
        behind the work queued on `queue`: SPPP's Poisson counts (clrender.sampling), read
        while the tile before is traced. Its buffers are plain cl.Buffers, not the pool's: a
        pooled buffer goes back to the pool when dropped and may be handed out again at once
        for work on the main queue, which only that queue's order keeps apart from its earlier
        use. A buffer written on one queue may be read by work queued on the other only after
        the host has seen the write complete (a blocking read, or an event waited for)."""
        if self._side_queue is None:
            self._side_queue = cl.CommandQueue(
                self.context, self.queue.device, properties=self.queue.properties
            )
        return self._side_queue

    def allocate(self, nbytes: int) -> cl.MemoryObjectHolder:
        """A read-write device buffer of at least nbytes (at least 16) from the pool; it goes
        back to the pool when no longer referenced."""
        return self.pool.allocate(max(16, int(nbytes)))

    def upload(self, array: np.ndarray) -> cl.MemoryObjectHolder:
        """A device copy of a host array (a pooled, read-write buffer), once copied."""
        buffer, copy = self.upload_async(array)
        if copy is not None:
            copy.wait()
        return buffer

    def upload_async(self, array: np.ndarray) -> tuple[cl.MemoryObjectHolder, cl.Event | None]:
        """Like upload, without waiting: the copy runs in queue order. Keep the returned event
        until a later blocking call on the queue has returned (it holds the host array, and
        dropping it waits for the copy). Each blocking upload costs a round trip to the
        device's worker threads (tens of microseconds on PoCL)."""
        data = np.ascontiguousarray(array).reshape(-1)
        buffer = self.allocate(data.nbytes)
        if not data.nbytes:
            return buffer, None
        return buffer, cl.enqueue_copy(self.queue, buffer, data, is_blocking=False)

    def describe(self) -> str:
        return describe_device(self.device)

    @property
    def profiled(self) -> bool:
        """Whether the queue records when its commands run (profiling_queue)."""
        return bool(self.queue.properties & cl.command_queue_properties.PROFILING_ENABLE)


def create_runtime(request: str | None = None) -> Runtime:
    device = select_device(request)
    context = cl.Context([device])
    return Runtime(device, context, profiling_queue(context), device_local_size(device))


def profiling_queue(context: cl.Context) -> cl.CommandQueue:
    """An in-order queue that records when its commands run (a render times its device stages
    by the device's own clock, without a wait per stage: clrender.pipeline.StageClock)."""
    return cl.CommandQueue(context, properties=cl.command_queue_properties.PROFILING_ENABLE)


@functools.cache
def default_runtime() -> Runtime:
    """The process-wide runtime on the default device (PYOPENCL_CTX or the first one)."""
    return create_runtime(None)


# Defines per OpenCL implementation (platform name): code shapes measured faster there and
# known to compile correctly (kernels/geometry.h BVH_FUNCTION; kernels/vecmath.h Sqrt, Floor,
# Ctz and others: the clang builtins, which other OpenCL C compilers need not have)
PLATFORM_DEFINES = {
    "Portable Computing Language": ("CLRENDER_BVH_CALLED", "CLRENDER_CLANG_BUILTINS"),
    "Intel(R) OpenCL": ("CLRENDER_SCALAR_WORK_ITEMS",),
}


def define_key(defines: dict[str, object] | None) -> tuple[tuple[str, object], ...]:
    """Defines as the program caches key them: sorted by name, each value as its option spells
    it (True: a bare -DNAME), so that values giving the same options (8 and "8", 0.5 and
    np.float32(0.5)) share one program instead of building it twice."""
    return tuple(
        sorted(
            (name, value if value is True else _c_literal(value))
            for name, value in (defines or {}).items()
        )
    )


def build_options(
    defines: tuple[tuple[str, object], ...], platform_name: str = "", folder: Path | None = None
) -> list[str]:
    """The compiler options of a program of the kernels folder (default kernels_dir())."""
    options = [f"-I{kernels_dir() if folder is None else folder}", "-cl-std=CL1.2"]
    options += [f"-D{name}" for name in PLATFORM_DEFINES.get(platform_name.strip(), ())]
    for name, value in defines:
        options.append(f"-D{name}" if value is True else f"-D{name}={_c_literal(value)}")
    return options


def _c_literal(value: object) -> str:
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, float | np.floating):
        return repr(float(value)) + "f"
    return str(value)


def thread_build_seconds() -> float:
    """Seconds the calling thread has spent building OpenCL programs and creating kernels
    (first uses only: both are cached), and warming up the render's kernels (Runtime.warm_up:
    PoCL generates a kernel's code at its first launch for each local size). A render reports
    them apart from its stages."""
    return getattr(_THREAD_BUILD_TIME, "seconds", 0.0)


_WARMED: set[tuple] = set()


@functools.cache
def kernel_parameters(path: Path, name: str) -> tuple[str, ...]:
    """Each parameter of kernel `name` in the source file: "global" or "local" for a pointer,
    else its scalar type (a key of SCALAR_TYPES). KernelBuildError if the kernel is not there or
    a parameter's type is not one of those."""
    text = path.read_text()
    # (attribute macros may stand between __kernel and void, as in trace_simd.cl)
    match = re.search(rf"__kernel\s+(?:\w+\s+)*?void\s+{name}\s*\(([^)]*)\)", text)
    if match is None:
        raise KernelBuildError(f"{path}: no __kernel void {name}(...) to warm up")
    kinds = []
    for parameter in match.group(1).split(","):
        words = parameter.replace("*", " * ").split()
        if "*" in words:
            kinds.append("local" if "__local" in words or "local" in words else "global")
            continue
        scalar = [word for word in words[:-1] if word not in ("const", "__private")]
        if len(scalar) != 1 or scalar[0] not in SCALAR_TYPES:
            raise KernelBuildError(
                f"{path}: kernel {name} parameter {parameter.strip()!r}: expected a pointer or "
                f"one of {', '.join(SCALAR_TYPES)}"
            )
        kinds.append(scalar[0])
    return tuple(kinds)


def warm_up_arguments(source_file: str, name: str, dummy: cl.MemoryObjectHolder) -> list:
    """The arguments of a warm-up launch: 0 for each scalar, `dummy` for each global pointer."""
    arguments: list[object] = []
    for kind in kernel_parameters(kernels_dir() / source_file, name):
        if kind == "global":
            arguments.append(dummy)
        elif kind == "local":
            arguments.append(cl.LocalMemory(16))
        else:
            arguments.append(SCALAR_TYPES[kind](0))
    return arguments


def _count_build_time(start: float) -> None:
    _THREAD_BUILD_TIME.seconds = thread_build_seconds() + time.perf_counter() - start


def built_sources_fingerprints(folder: Path) -> list[str]:
    """The fingerprints of a kernels folder's sources as this process's program builds found
    them, in build order ([] before its first build from there): what its renders run, even
    if the files changed since (its programs are built once)."""
    return list(_BUILT_SOURCES.get(folder, ()))


@functools.cache
def _build_cached(
    context: cl.Context, folder: Path, source_file: str, defines: tuple[tuple[str, object], ...]
) -> cl.Program:
    """The program of folder/source_file (folder: kernels_dir() when the build was asked for,
    so that a changed CLRENDER_KERNELS_DIR builds the other folder's sources)."""
    from clrender.provenance import sources_fingerprint  # (which imports this module)

    start = time.perf_counter()
    path = folder / source_file
    built = _BUILT_SOURCES.setdefault(folder, [])
    fingerprint = sources_fingerprint(folder)
    if fingerprint not in built:
        built.append(fingerprint)
    # Compile from an #include of the real file so the compiler log names it with its line.
    source = f'#include "{path.name}"\n'
    options = build_options(defines, context.devices[0].platform.name, folder)
    try:
        # Signals blocked: a signal mid-build failed the compiler's calls. A successful build's
        # log is no warning: Intel's CPU runtime logs every build (its stages, vectorisation
        # remarks), which pyopencl reports as a CompilerWarning on every render (two lines on
        # stderr); PYOPENCL_COMPILER_OUTPUT=1 still shows it. A failed build's log is the error.
        with interrupts.signals_blocked(), warnings.catch_warnings():
            if not os.environ.get("PYOPENCL_COMPILER_OUTPUT", ""):
                warnings.simplefilter("ignore", cl.CompilerWarning)
            return cl.Program(context, source).build(options=options)
    except cl.RuntimeError as err:
        log = _build_log(err)
        raise KernelBuildError(
            f"OpenCL build of {path} failed (options: {' '.join(options)}):\n{log}"
        ) from None
    finally:
        _count_build_time(start)


@functools.cache
def _kernel_cached(
    context: cl.Context,
    folder: Path,
    source_file: str,
    defines: tuple[tuple[str, object], ...],
    name: str,
) -> cl.Kernel:
    program = _build_cached(context, folder, source_file, defines)
    start = time.perf_counter()
    try:
        return cl.Kernel(program, name)
    finally:
        _count_build_time(start)


@functools.cache
def _kernel_work_group_size(kernel: cl.Kernel, device: cl.Device) -> int:
    """The kernel's largest work-group on the device (CL_KERNEL_WORK_GROUP_SIZE)."""
    return int(kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device))


def _build_log(err: cl.RuntimeError) -> str:
    text = str(err)
    marker = "Build on <pyopencl.Device"
    return text[text.find(marker) :] if marker in text else text


def launch_global_size(count: int, local_size: int = LOCAL_SIZE) -> int:
    """The global size of a render kernel's launch over count work-items: padded to the local
    size, and at least MIN_LAUNCH_SIZE (one version of each kernel's code)."""
    return max(
        padded_global_size(count, local_size), padded_global_size(MIN_LAUNCH_SIZE, local_size)
    )


def padded_global_size(count: int, local_size: int = LOCAL_SIZE) -> int:
    """Round count up to a multiple of the local size (PoCL rejects other global sizes);
    kernels return early for ids >= count."""
    return max(local_size, -(-count // local_size) * local_size)
