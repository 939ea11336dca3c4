"""Wavefront (streaming) path tracing: clrender.trace's integrator cut into one kernel per
stage, each run over a queue of paths (kernels/wavefront.cl; Laine, Karras and Aila 2013,
"Megakernels Considered Harmful"; LuxCoreRender's PATHOCL).

    tracer = WavefrontPathTracer(runtime, load_scene("cornell-box"), max_depth=8)
    result = tracer.trace(sets, seed, width, height)  # a TraceResult, as PathTracer.trace's

It is a drop-in PathTracer (same parameters, same TraceResult): each sample's radiance, the ray
count and the non-finite count are bit-identical to the megakernel's (tests/test_wavefront.py).
A launch is traced in chunks of at most `wave_paths` paths (the state of a chunk's paths is
about 170 bytes each: rays, paths, two queues, the shadow rays); per chunk the host enqueues
generate, then per bounce intersect, shade and shadow, reading back only the two queue lengths
that shade leaves (8 bytes) to size the next launches. No Python runs per sample.

Which structure is faster where: bench/kernel_structure.py (results under
bench/results/kernel_structure/).

`trace_recording` traces the same way and also reads back every queue: which paths traced a
ray, and which a shadow ray, at each depth (the per-path lengths the lockstep SIMD figures of
`simd_efficiency` and `queue_efficiency` need). It is for measurements; `trace` is the product.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.runtime import Runtime, padded_global_size
from clrender.sampling import DeviceSampleSets
from clrender.scene import Scene
from clrender.trace import DEFAULT_MAX_DEPTH, PathTracer, TraceResult

# Bytes per path of each state array; kernels/wavefront.cl checks its struct sizes against them.
RAY_BYTES = 32
PATH_BYTES = 64
SHADOW_RAY_BYTES = 64
QUEUE_ENTRY_BYTES = 4
# The shadow ray's path id: word 7 of its 16 (kernels/wavefront.cl, WavefrontShadowRay).
SHADOW_RAY_WORDS = SHADOW_RAY_BYTES // 4
SHADOW_RAY_PATH_WORD = 7
BYTES_PER_PATH = RAY_BYTES + PATH_BYTES + SHADOW_RAY_BYTES + 2 * QUEUE_ENTRY_BYTES
# Paths traced together: about 45 MB of state (bench/kernel_structure.py measured the choice).
DEFAULT_WAVE_PATHS = 1 << 18
MAX_WAVE_PATHS = 1 << 26
STAGES = ("generate", "intersect", "shade", "shadow", "finish")


@dataclass
class QueueRecord:
    """The queues of one traced launch, in the order the stages saw them.

    rays[d]: the launch indices of the samples whose path traced a ray at depth d (camera rays
    at d = 0), in the intersect and shade stages' queue order, chunk after chunk.
    shadow_rays[d]: the launch indices of the samples that traced a shadow ray at depth d, in
    the shadow stage's order.
    """

    sample_count: int
    rays: list[np.ndarray] = field(default_factory=list)
    shadow_rays: list[np.ndarray] = field(default_factory=list)
    # (chunk, depth, ray queue length, shadow queue length) of every bounce traced
    queue_lengths: list[tuple[int, int, int, int]] = field(default_factory=list)

    def _append(self, kind: str, depth: int, ids: np.ndarray) -> None:
        lists = self.rays if kind == "rays" else self.shadow_rays
        while len(lists) <= depth:
            lists.append(np.empty(0, np.int64))
        lists[depth] = np.concatenate([lists[depth], ids.astype(np.int64)])

    def path_lengths(self) -> np.ndarray:
        """Rays each path traced (camera and bounce rays: the megakernel's loop iterations)."""
        lengths = np.zeros(self.sample_count, np.int64)
        for ids in self.rays:
            lengths[ids] += 1
        return lengths

    def shadow_mask(self) -> np.ndarray:
        """(sample_count, depths) bool: which paths traced a shadow ray at each depth."""
        mask = np.zeros((self.sample_count, max(1, len(self.rays))), bool)
        for depth, ids in enumerate(self.shadow_rays):
            mask[ids, depth] = True
        return mask


def simd_efficiency(lengths: np.ndarray, width: int) -> float:
    """Lane utilisation of a lockstep SIMD machine running `width` consecutive work-items
    together, each for lengths[i] loop iterations: sum(lengths) / (width * sum over groups of
    the group's longest). The last group is padded with idle lanes (as a padded launch is)."""
    lengths = np.asarray(lengths, np.int64)
    if width < 1:
        raise ParameterError(f"SIMD width must be at least 1, got {width}")
    if lengths.size == 0 or lengths.sum() == 0:
        return 1.0
    padded = np.zeros(-(-lengths.size // width) * width, np.int64)
    padded[: lengths.size] = lengths
    longest = padded.reshape(-1, width).max(axis=1)
    return float(lengths.sum() / (width * longest.sum()))


def branch_efficiency(mask: np.ndarray, width: int) -> float:
    """Lane utilisation of a branch taken where mask[i, d] (work-item i at iteration d), on a
    lockstep machine of `width` lanes that runs the branch whenever one of its lanes takes it."""
    mask = np.asarray(mask, bool)
    if mask.ndim == 1:
        mask = mask[:, None]
    taken = int(mask.sum())
    if taken == 0:
        return 1.0
    rows = -(-mask.shape[0] // width) * width
    padded = np.zeros((rows, mask.shape[1]), bool)
    padded[: mask.shape[0]] = mask
    runs = padded.reshape(-1, width, mask.shape[1]).any(axis=1).sum()
    return float(taken / (width * runs))


def queue_efficiency(queue_lengths, width: int) -> float:
    """Lane utilisation of dense queues: every lane busy but the last group's padding."""
    lengths = np.asarray(list(queue_lengths), np.int64)
    lengths = lengths[lengths > 0]
    if lengths.size == 0:
        return 1.0
    return float(lengths.sum() / (width * (-(-lengths // width)).sum()))


class WavefrontPathTracer(PathTracer):
    """A scene uploaded once to the device, and the wavefront kernels for it (a PathTracer:
    same parameters, same results). wave_paths: paths traced together (state memory)."""

    def __init__(
        self,
        runtime: Runtime,
        scene: Scene,
        max_depth: int = DEFAULT_MAX_DEPTH,
        russian_roulette: bool = False,
        next_event_estimation: bool = True,
        wave_paths: int = DEFAULT_WAVE_PATHS,
        profile_defines: dict[str, object] | None = None,
    ):
        if (
            isinstance(wave_paths, bool)
            or not isinstance(wave_paths, int | np.integer)
            or not 1 <= wave_paths <= MAX_WAVE_PATHS
        ):
            raise ParameterError(
                f"wave_paths must be an integer in [1, {MAX_WAVE_PATHS}], got {wave_paths!r}"
            )
        # (its parent's kernel is the megakernel, which builds faster than the simd kernel)
        super().__init__(
            runtime,
            scene,
            max_depth,
            russian_roulette,
            next_event_estimation,
            trace_kernel="megakernel",
        )
        self.trace_kernel = "wavefront"
        self.wave_paths = int(wave_paths)
        # A list to collect (stage name, event) of every launch in (for stage timings on a
        # profiling queue); None: nothing kept
        self.stage_events: list[tuple[str, cl.Event]] | None = None
        # Profiling builds only, e.g. {"PROFILE_SKIP_SHADOW_RAYS": True} (as PathTracer's)
        self._stages = {
            name: runtime.kernel("wavefront.cl", f"wavefront_{name}", profile_defines)
            for name in STAGES
        }

    def trace(
        self,
        sample_sets: DeviceSampleSets,
        seed: int,
        image_width: int | None = None,
        image_height: int | None = None,
    ) -> TraceResult:
        """Trace every traced sample of `sample_sets` (never the auxiliary nuclei); pixel
        indices are y * image_width + x. Returns once the last chunk's last bounce is enqueued
        (the host has waited for each bounce's queue lengths)."""
        return self._trace(sample_sets, seed, image_width, image_height, None)

    def trace_recording(
        self,
        sample_sets: DeviceSampleSets,
        seed: int,
        image_width: int | None = None,
        image_height: int | None = None,
    ) -> tuple[TraceResult, QueueRecord]:
        """trace, and the queues of every stage read back (slower: for measurements)."""
        record = QueueRecord(sample_sets.traced_total)
        result = self._trace(sample_sets, seed, image_width, image_height, record)
        return result, record

    def _scene_arguments(self) -> tuple:
        return self.scene_arguments()

    def _trace(self, sample_sets, seed, image_width, image_height, record) -> TraceResult:
        width, height = self.check_launch(sample_sets, seed, image_width, image_height)
        runtime = self.runtime
        queue = runtime.queue
        count = sample_sets.traced_total
        radiance = runtime.allocate(12 * count)
        # counters: non-finite paths, then per chunk its camera rays and per bounce the two
        # queue lengths shade leaves (kernels/wavefront.cl)
        depths = self.max_depth + 1
        chunk_slots = 1 + 2 * depths
        wave = self.wave_paths
        chunks = [(base, min(wave, count - base)) for base in range(0, count, wave)]
        counts = np.zeros(1 + chunk_slots * len(chunks), np.uint32)
        for k, (_, size) in enumerate(chunks):
            counts[1 + chunk_slots * k] = size
        counters = runtime.upload(counts)
        if count == 0:
            return TraceResult(radiance, 0, queue, counters, len(counts), None)
        capacity = min(self.wave_paths, count)
        rays = runtime.allocate(RAY_BYTES * capacity)
        paths = runtime.allocate(PATH_BYTES * capacity)
        shadow_rays = runtime.allocate(SHADOW_RAY_BYTES * capacity)
        ray_queues = [runtime.allocate(QUEUE_ENTRY_BYTES * capacity) for _ in range(2)]
        scene_args = self._scene_arguments()
        path_args = sample_sets.config.path_arguments((width, height))
        paths_kind, fixed_count, strata, zsobol_log2_count, zsobol_bits = path_args
        local = runtime.local_size
        stages = self._stages
        if self.stage_events is not None:
            stages = {
                name: _Recorded(name, kernel, self.stage_events) for name, kernel in stages.items()
            }
        lengths = np.empty(2, np.uint32)
        event = None
        for k, (base, size) in enumerate(chunks):
            # Camera rays of the chunk's paths; queue 0 holds them all
            stages["generate"](
                queue,
                (padded_global_size(size, local),),
                (local,),
                np.uint32(base),
                np.uint32(size),
                np.uint32(sample_sets.pixel_count),
                np.uint32(seed),
                np.uint32(width),
                np.uint32(height),
                *path_args,
                sample_sets.positions,
                sample_sets.offsets_buffer,
                sample_sets.pixels_buffer,
                sample_sets.redraws_buffer,
                self.camera_buffer(width, height),
                rays,
                paths,
                ray_queues[0],
            )
            ray_count = size
            for depth in range(depths):
                if ray_count == 0:
                    break
                current, following = ray_queues[depth % 2], ray_queues[(depth + 1) % 2]
                global_size = (padded_global_size(ray_count, local),)
                stages["intersect"](
                    queue, global_size, (local,), np.uint32(ray_count), current, rays, *scene_args
                )
                if record is not None:
                    record._append("rays", depth, base + _read_uints(queue, current, ray_count))
                slot = 1 + chunk_slots * k + 1 + 2 * depth
                stages["shade"](
                    queue,
                    global_size,
                    (local,),
                    np.int32(depth),
                    np.int32(self.max_depth),
                    np.int32(self.next_event_estimation),
                    np.int32(self.russian_roulette),
                    np.uint32(ray_count),
                    paths_kind,
                    np.uint32(seed),
                    fixed_count,
                    strata,
                    zsobol_bits,
                    current,
                    rays,
                    paths,
                    following,
                    shadow_rays,
                    counters,
                    np.uint32(slot),
                    *scene_args,
                )
                # The one read-back per bounce: the lengths of the next and the shadow queues
                cl.enqueue_copy(queue, lengths, counters, src_offset=4 * slot)
                if record is not None:
                    record.queue_lengths.append((k, depth, ray_count, int(lengths[1])))
                ray_count, shadow_count = int(lengths[0]), int(lengths[1])
                if record is not None and shadow_count:
                    words = _read_uints(queue, shadow_rays, shadow_count * SHADOW_RAY_WORDS)
                    path_ids = words.reshape(-1, SHADOW_RAY_WORDS)[:, SHADOW_RAY_PATH_WORD]
                    record._append("shadow_rays", depth, base + path_ids.astype(np.int64))
                if shadow_count:
                    stages["shadow"](
                        queue,
                        (padded_global_size(shadow_count, local),),
                        (local,),
                        np.uint32(shadow_count),
                        shadow_rays,
                        paths,
                        *scene_args,
                    )
            # Each path's radiance into its slot of the launch
            event = stages["finish"](
                queue,
                (padded_global_size(size, local),),
                (local,),
                np.uint32(base),
                np.uint32(size),
                paths,
                radiance,
                counters,
            )
        return TraceResult(radiance, count, queue, counters, len(counts), event)


class _Recorded:
    """A kernel whose launches append (stage name, event) to a list."""

    def __init__(self, name: str, kernel: cl.Kernel, events: list):
        self.name, self.kernel, self.events = name, kernel, events

    def __call__(self, *args) -> cl.Event:
        event = self.kernel(*args)
        self.events.append((self.name, event))
        return event


def _read_uints(queue: cl.CommandQueue, buffer: cl.Buffer, count: int) -> np.ndarray:
    out = np.empty(count, np.uint32)
    if count:
        cl.enqueue_copy(queue, out, buffer)
    return out
