"""Tracing: radiance of every traced sample of a launch (kernels/integrator.cl, or the same to
the bit from kernels/trace_simd.cl: PathTracer(..., trace_kernel="simd")).

    tracer = PathTracer(runtime, load_scene("cornell-box"), max_depth=8)
    sets = generate_sample_sets(runtime, make_sampler("sppp", 64), seed, pixels)
    result = tracer.trace(sets, seed, width, height)
    radiance = result.to_host()  # (T, 3) float32, in the order of sets' traced samples

The integrator is a unidirectional path tracer with next event estimation and MIS (power
heuristic) on emission only (next_event_estimation=False: BSDF sampling only, emission at full
weight; for checks and profiling); Russian roulette (off by default) starts after the second
vertex; max_depth counts scattering vertices (pbrt's convention, Mitsuba's
max_depth minus 1). Each number a path uses depends only on (seed, pixel, sample, dimension,
redraw), so radiance is bit-identical whatever the tiling. A non-finite radiance is stored as 0
and counted in `TraceResult.nonfinite`: report it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.runtime import Runtime, launch_global_size
from clrender.sampling import PATHS_ZSOBOL, DeviceSampleSets, check_seed
from clrender.scene import Scene
from clrender.scene_device import BRUTE_FORCE_LIMIT, EMITTER_SHAPES, QUAD_BLOCK_WIDTH

# Dimensions 1 + 2d and 2 + 2d of a 32-bit counter: any sane depth fits; this keeps a typo
# (max_depth=10**9) from running for ever.
MAX_DEPTH_LIMIT = 1024
# Scattering vertices per path unless asked otherwise (pbrt's maxdepth; Mitsuba's max_depth 9).
DEFAULT_MAX_DEPTH = 8
# The tracing kernels, the same radiance to the bit: "megakernel" one path a work-item
# (integrator.cl trace_paths), "simd" SIMD_WIDTH paths a work-item, one a vector lane
# (trace_simd.cl trace_paths_simd).
TRACE_KERNELS = ("megakernel", "simd")
# What a render may ask for: a kernel, or "auto" (choose_trace_kernel).
TRACE_KERNEL_CHOICES = ("auto", *TRACE_KERNELS)
# Paths per work-item of the simd kernel unless asked otherwise (trace_simd.cl: 16 or 8).
SIMD_WIDTH = 16
SIMD_WIDTHS = (8, 16)


@dataclass
class TraceResult:
    """Per-sample radiance of one launch, on the device until asked for.

    radiance: float32 buffer of sample_count x 3 (RGB), samples in the launch's order.
    nonfinite: samples whose radiance was NaN or infinite (stored as 0).
    rays: rays traced (camera, bounce and shadow rays), for rays/s figures.
    """

    radiance: cl.Buffer
    sample_count: int
    queue: cl.CommandQueue
    counters: cl.Buffer  # uint32: non-finite count, rays per work-group, then extra_counters
    counter_count: int
    event: cl.Event | None
    # Counters after the rays (the simd kernel: its steps)
    extra_counters: int = 0
    _counts: np.ndarray | None = field(default=None, repr=False)
    _counter_read: tuple[np.ndarray, cl.Event] | None = field(default=None, repr=False)

    def to_host(self) -> np.ndarray:
        return self.queue_to_host()()

    def queue_to_host(self) -> Callable[[], np.ndarray]:
        """Queue to_host's read-back without a wait; the function returned waits for it and
        gives the (T, 3) float32 radiance (it holds the array the read fills)."""
        out = np.empty((self.sample_count, 3), np.float32)
        read = None
        if self.sample_count:
            read = cl.enqueue_copy(self.queue, out, self.radiance, is_blocking=False)

        def host() -> np.ndarray:
            if read is not None:
                read.wait()
            return out

        return host

    def enqueue_counter_read(self) -> None:
        """Queue the counters' read-back without waiting: nonfinite and rays then wait for it
        alone (after a later blocking call on the queue, not at all)."""
        if self._counts is None and self._counter_read is None:
            counts = np.empty(self.counter_count, np.uint32)
            event = cl.enqueue_copy(self.queue, counts, self.counters, is_blocking=False)
            self._counter_read = counts, event

    def _read_counters(self) -> np.ndarray:
        if self._counts is None:
            self.enqueue_counter_read()
            counts, event = self._counter_read
            event.wait()
            self._counts, self._counter_read = counts.astype(np.int64), None
        return self._counts

    @property
    def nonfinite(self) -> int:
        return int(self._read_counters()[0])

    @property
    def rays(self) -> int:
        counts = self._read_counters()
        return int(counts[1 : len(counts) - self.extra_counters].sum())

    @property
    def steps(self) -> int | None:
        """The simd kernel's vector steps (a vertex of each running lane's path a step): its
        lane occupancy is (rays without shadow rays) / (steps x SIMD_WIDTH); None for the
        megakernel."""
        return int(self._read_counters()[-1]) if self.extra_counters else None

    def wait(self) -> None:
        if self.event is not None:
            self.event.wait()


def device_triangles(triangles: np.ndarray, has_bvh: bool) -> np.ndarray:
    """The Triangle records the device needs: all of them for brute force; with a BVH, whose
    leaf blocks hold every triangle's vertices and surface indices (kernels/geometry.h), only
    when some triangle emits (next event estimation samples emitters from these records by
    index), else none. Saves 48 bytes a triangle of device memory on large meshes."""
    if has_bvh and not (triangles["emitter"] >= 0).any():
        return triangles[:0]
    return triangles


def check_max_depth(max_depth: object) -> None:
    """ParameterError unless max_depth is an integer in [0, MAX_DEPTH_LIMIT]."""
    if (
        isinstance(max_depth, bool)
        or not isinstance(max_depth, int | np.integer)
        or not 0 <= max_depth <= MAX_DEPTH_LIMIT
    ):
        raise ParameterError(
            f"max_depth must be an integer in [0, {MAX_DEPTH_LIMIT}], got {max_depth!r}"
        )


def check_trace_kernel(trace_kernel: object) -> None:
    """ParameterError unless trace_kernel names one of TRACE_KERNEL_CHOICES."""
    if not isinstance(trace_kernel, str) or trace_kernel not in TRACE_KERNEL_CHOICES:
        raise ParameterError(
            f"trace_kernel must be one of {', '.join(TRACE_KERNEL_CHOICES)}, got {trace_kernel!r}"
        )


def choose_trace_kernel(
    device: cl.Device,
    trace_kernel: str = "auto",
    scene: Scene | None = None,
    has_bvh: bool = False,
) -> str:
    """The kernel of TRACE_KERNELS that traces the scene on the device: trace_kernel itself,
    or for "auto" the faster one as measured (README, "Benchmarks": bench/trace_throughput.py
    --trace-kernel megakernel simd). That is "simd" on a CPU device, whose compiler leaves the
    megakernel's work-items scalar, for a scene whose paths run in its vector lanes: no
    triangles and no BVH (has_bvh: the tracer built one; intersection through either runs lane
    by lane) and only quad emitters (a light sample on a sphere or triangle runs lane by lane).
    Otherwise the megakernel: on a GPU, which runs work-items in lanes itself, and for the
    other scenes, which the simd kernel traces more slowly on a CPU (veach-mis 0.8x, a 20 000
    triangle mesh 0.95x, 151 quads or 120 spheres in a BVH about 0.9x)."""
    check_trace_kernel(trace_kernel)
    if trace_kernel != "auto":
        return trace_kernel
    if not device.type & cl.device_type.CPU or has_bvh:
        return "megakernel"
    if scene is not None and (
        len(scene.triangles) or np.any(scene.emitters["shape"] != EMITTER_SHAPES["quad"])
    ):
        return "megakernel"
    return "simd"


def image_size(scene: Scene, width: int | None, height: int | None) -> tuple[int, int]:
    """(width, height) of a scene's image, known without a device: the scene's resolution by
    default; a width alone keeps the scene's aspect ratio."""
    scene_w, scene_h = scene.resolution
    if width is None:
        width, height = (scene_w, scene_h) if height is None else (None, height)
    if width is None:
        width = max(1, round(height * scene_w / scene_h))
    if height is None:
        height = max(1, round(width * scene_h / scene_w))
    for name, value in (("image_width", width), ("image_height", height)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
            raise ParameterError(f"{name} must be a positive integer, got {value!r}")
    return int(width), int(height)


class PathTracer:
    """A scene uploaded once to the device, and the path-tracing kernel for it: trace_kernel
    "megakernel" (one path a work-item), "simd" (SIMD_WIDTH paths a work-item, one a vector
    lane; simd_defines {"SIMD_WIDTH": 8} or {"SIMD_PORTABLE": True} build variants) or "auto"
    (choose_trace_kernel: simd on a CPU device for a scene without triangles, BVH or emitters
    other than quads); `.trace_kernel` is the one chosen. Both give every sample the same
    radiance to the bit, and count the same rays. The default is the megakernel: benchmarks and
    tests name their kernel; renders ask for "auto" (clrender.render's trace_kernel)."""

    def __init__(
        self,
        runtime: Runtime,
        scene: Scene,
        max_depth: int = DEFAULT_MAX_DEPTH,
        russian_roulette: bool = False,
        next_event_estimation: bool = True,
        profile_defines: dict[str, object] | None = None,
        brute_force_limit: int = BRUTE_FORCE_LIMIT,
        trace_kernel: str = "megakernel",
        simd_defines: dict[str, object] | None = None,
    ):
        check_max_depth(max_depth)
        check_trace_kernel(trace_kernel)
        self.runtime = runtime
        self.scene = scene
        self.max_depth = int(max_depth)
        self.russian_roulette = bool(russian_roulette)
        self.next_event_estimation = bool(next_event_estimation)
        self._buffers = {
            name: runtime.upload(getattr(scene, name))
            for name in ("quads", "spheres", "materials", "emitters")
        }
        self._quad_blocks = scene.quad_blocks(QUAD_BLOCK_WIDTH)
        self._buffers["quad_blocks"] = runtime.upload(self._quad_blocks)
        # Triangles and the BVH (none where brute force is cheaper: scene_device.pack_bvh)
        self.bvh_nodes, self.bvh_prims = scene.bvh(brute_force_limit)
        for name, array in (
            ("triangles", device_triangles(scene.triangles, len(self.bvh_nodes) > 0)),
            ("triangle_normals", scene.triangle_normals),
            ("bvh_nodes", self.bvh_nodes),
            ("bvh_prims", self.bvh_prims),
        ):
            self._buffers[name] = runtime.upload(array)
        self._cameras: dict[tuple[int, int], cl.Buffer] = {}
        # Profiling builds only (bench/trace_throughput.py --profile), e.g.
        # {"PROFILE_SKIP_SHADOW_RAYS": True}: shadow rays counted but not traced.
        # simd_defines: the simd kernel's build options (SIMD_WIDTH 8 or 16, SIMD_PORTABLE).
        trace_kernel = choose_trace_kernel(
            runtime.device, trace_kernel, scene, has_bvh=len(self.bvh_nodes) > 0
        )
        self.trace_kernel = trace_kernel
        if trace_kernel == "simd":
            defines = dict(profile_defines or {}) | dict(simd_defines or {})
            width = defines.setdefault("SIMD_WIDTH", SIMD_WIDTH)
            if isinstance(width, bool) or width not in SIMD_WIDTHS:
                raise ParameterError(
                    f"SIMD_WIDTH must be one of {', '.join(map(str, SIMD_WIDTHS))}, got {width!r}"
                )
            chunk = defines.get("SIMD_CHUNK", 1)
            whole = isinstance(chunk, int) and not isinstance(chunk, bool)
            if not whole or not 0 < chunk * width < 2**31:
                raise ParameterError(
                    f"SIMD_CHUNK must be a positive integer below 2^31 / SIMD_WIDTH, got {chunk!r}"
                )
            self.samples_per_item = int(width)
            self._kernel = runtime.kernel("trace_simd.cl", "trace_paths_simd", defines)
        else:
            if simd_defines:
                raise ParameterError("simd_defines need trace_kernel='simd'")
            self.samples_per_item = 1
            self._kernel = runtime.kernel("integrator.cl", "trace_paths", profile_defines)

    def scene_arguments(self) -> tuple:
        """The scene's kernel arguments, in the order trace_paths and every wavefront stage
        take them."""
        scene = self.scene
        buffers = self._buffers
        return (
            buffers["quads"],
            buffers["quad_blocks"],
            np.uint32(len(scene.quads)),
            np.uint32(len(self._quad_blocks)),
            buffers["spheres"],
            np.uint32(len(scene.spheres)),
            buffers["materials"],
            buffers["emitters"],
            np.uint32(len(scene.emitters)),
            buffers["triangles"],
            np.uint32(len(scene.triangles)),
            buffers["triangle_normals"],
            buffers["bvh_nodes"],
            np.uint32(len(self.bvh_nodes)),
            buffers["bvh_prims"],
        )

    def camera_buffer(self, width: int, height: int) -> cl.Buffer:
        key = (width, height)
        if key not in self._cameras:
            self._cameras[key] = self.runtime.upload(self.scene.camera.basis(width, height))
        return self._cameras[key]

    def image_size(self, width: int | None, height: int | None) -> tuple[int, int]:
        """(width, height) of the scene's image at the requested size (see `image_size`)."""
        return image_size(self.scene, width, height)

    def check_launch(
        self,
        sample_sets: DeviceSampleSets,
        seed: int,
        image_width: int | None,
        image_height: int | None,
    ) -> tuple[int, int]:
        """ParameterError for a launch trace cannot make; the image's (width, height)."""
        check_seed(seed)
        width, height = self.image_size(image_width, image_height)
        pixels = sample_sets.pixels
        if len(pixels) and int(pixels.max()) >= width * height:
            raise ParameterError(
                f"pixel index {int(pixels.max())} outside the {width} x {height} image"
            )
        drawn_for = sample_sets.image_size
        if sample_sets.config.kind.paths == PATHS_ZSOBOL and drawn_for != (width, height):
            drawn = "no image size" if drawn_for is None else f"{drawn_for[0]} x {drawn_for[1]}"
            raise ParameterError(
                f"zsobol sample sets drawn for {drawn} cannot be traced at {width} x {height}: "
                f"draw them with image_size=({width}, {height})"
            )
        return width, height

    def trace(
        self,
        sample_sets: DeviceSampleSets,
        seed: int,
        image_width: int | None = None,
        image_height: int | None = None,
    ) -> TraceResult:
        """Enqueue the paths of every traced sample of `sample_sets` (never the auxiliary
        nuclei); pixel indices are y * image_width + x."""
        width, height = self.check_launch(sample_sets, seed, image_width, image_height)
        runtime = self.runtime
        queue = runtime.queue
        count = sample_sets.traced_total
        local = runtime.kernel_local_size(self._kernel)
        # simd: a work-item per samples_per_item samples (the work-items that run a chunk of
        # samples spread over them: trace_simd.cl)
        global_size = launch_global_size(-(-count // self.samples_per_item), local)
        groups = global_size // local
        # simd: its steps after the rays (trace_simd.cl)
        extra = 1 if self.trace_kernel == "simd" else 0
        slots = 1 + groups + extra
        radiance = runtime.allocate(12 * count)
        counters = runtime.allocate(4 * slots)
        cl.enqueue_fill_buffer(queue, counters, np.uint32(0), 0, 4 * slots)  # no wait
        if count == 0:
            return TraceResult(radiance, 0, queue, counters, slots, None, extra)
        event = self._kernel(
            queue,
            (global_size,),
            (local,),
            np.uint32(count),
            np.uint32(sample_sets.pixel_count),
            np.uint32(seed),
            np.uint32(width),
            np.uint32(height),
            np.int32(self.max_depth),
            np.int32(self.next_event_estimation),
            np.int32(self.russian_roulette),
            *sample_sets.config.path_arguments((width, height)),
            sample_sets.positions,
            sample_sets.offsets_buffer,
            sample_sets.pixels_buffer,
            sample_sets.redraws_buffer,
            self.camera_buffer(width, height),
            *self.scene_arguments(),
            radiance,
            counters,
        )
        return TraceResult(radiance, count, queue, counters, slots, event, extra)
