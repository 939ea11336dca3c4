"""Renders on a Dask cluster: the same image as a local render, bit for bit, from tasks that
each render a run of tiles on a worker process with its own OpenCL runtime.

Where work runs is an `Executor`:

- `LocalExecutor` (the default, no Dask needed): tasks run one after another in this process.
  The render command without --workers or --scheduler does not split the render into tasks:
  it runs clrender.pipeline.render, whose tiles overlap tracing with the host stage.
- `DaskExecutor`: a Dask distributed client, on a LocalCluster of N worker processes on this
  machine (``--workers N``; one thread each: a worker's OpenCL device already uses every core
  it is given) or on an existing cluster (``--scheduler ADDRESS``).

Why Dask distributed: it is the well-kept engine for NumPy work in Python (scheduling, data
movement, worker restarts, progress); clrender adds only the split of a render into tasks.

A distributed render (`render_on`) splits the image's pixels (scanline order) into ranges of
consecutive pixels, one task each; a task renders its range in tiles of the render's sample
budget (clrender.pipeline.pixels_per_tile), overlapping tracing with its host stage as a local
render does. Every random
number is keyed by (seed, pixel, sample, dimension, redraw), and a task redraws its own
rejected pixels, so each pixel's estimate is the one a local render gives, whatever the number
of workers or which worker runs a task. What travels: the `RenderJob` (the loaded Scene's NumPy
records or an analytic image's name, the sampler's settings, estimator names), sent once
to the cluster as one task's result; results come back as NumPy arrays (`PixelRangeResult`); no
OpenCL object is ever pickled. Each worker process keeps its runtime (compiled programs) for
its lifetime (clrender.api.runtime_for) and the radiance source of the job it last ran.

The device of a worker: the job's ``device`` (``--device``) if given, else the worker's own
PYOPENCL_CTX, else its first device. A LocalCluster's workers inherit this process's
environment; on another machine, set PYOPENCL_CTX where the worker starts. The client opens no
device (it may have none): a task reports the device it rendered on and its precision, and a
device its worker lacks fails the task, reported as below.

Placement: tasks that take the shared job would all start on the worker holding it (Dask
places a task beside its inputs); they are dealt out to the workers in turn instead, with
loose restrictions (`task_placement`).

Faults: a worker that dies mid-task has its tasks rerun elsewhere by the scheduler (a pure
function of the job and the tiles, so the image does not change). A task that raises is
reported in one line naming the worker and the error (`ClusterTaskError`), on the client: the
task returns its failure as a value, so the workers log no traceback for it. Ctrl-C cancels
the outstanding tasks; the finished pixels are returned with `stats.interrupted` set, as a
local render returns its finished tiles. On LocalExecutor a task's own pipeline catches Ctrl-C:
its interrupted result ends the render the same way (no later task runs).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from clrender import interrupts
from clrender.errors import ClrenderError, ParameterError
from clrender.film import Film, PixelLayers
from clrender.pipeline import (
    DEFAULT_TILE_SAMPLES,
    RenderResult,
    RenderSettings,
    RenderStats,
    TilePipeline,
    pixels_per_tile,
    plan_tiles,
)
from clrender.provenance import REPORTED
from clrender.runtime import thread_build_seconds
from clrender.sampling import SamplerConfig
from clrender.scene import Scene
from clrender.trace import DEFAULT_MAX_DEPTH

# Tasks per worker: enough that a slow or lost worker delays the render by a fraction of it,
# few enough that each task's overhead (scheduling, source set-up) stays small beside its work.
TASKS_PER_WORKER = 4
# A LocalCluster worker waits this long for its scheduler; a --scheduler address as long.
CONNECT_TIMEOUT_S = 30


class ClusterError(ClrenderError):
    """The cluster could not be used: Dask missing, no scheduler at the address."""


class ClusterTaskError(ClrenderError):
    """A task raised on a worker: the message names the worker and the error."""


# --------------------------------------------------------------------------------- executors


class ClosingExecutor:
    """An executor as a context manager: `with make_executor(...) as executor:` closes it
    (its cluster, if it made one) however the block ends."""

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class LocalExecutor(ClosingExecutor):
    """Runs tasks in this process, in order (no Dask)."""

    workers = 1

    def map(self, function: Callable, items: Sequence, *common: Any) -> Iterator[tuple[int, Any]]:
        """(index, function(item, *common)) for each item, as they finish."""
        for index, item in enumerate(items):
            yield index, function(item, *common)


class DaskExecutor(ClosingExecutor):
    """Tasks on a Dask cluster: a LocalCluster of `workers` processes, or the scheduler at
    `scheduler` (an address such as tcp://host:8786)."""

    # Tasks taking a shared value dealt out to the workers in turn (`task_placement`); False
    # leaves their placement to the scheduler, as bench/cluster_scaling.py compares
    spread_shared = True

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        try:
            from distributed import Client, LocalCluster
        except ImportError as err:
            raise ClusterError(
                f"--workers and --scheduler need Dask: pip install 'dask[distributed]' ({err})"
            ) from None
        if (workers is None) == (scheduler is None):
            raise ParameterError("give a number of local workers or a scheduler address")
        self.cluster = None
        if scheduler is not None:
            check_scheduler_address(scheduler)
            try:
                self.client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError) as err:
                raise ClusterError(f"no Dask scheduler at {scheduler}: {err}") from None
            except (ValueError, TypeError) as err:  # a scheme that needs more (tls: security)
                raise ClusterError(
                    f"cannot connect to {scheduler}: {type(err).__name__}: {one_line(err)}"
                ) from None
            except MemoryError:  # a server that is not Dask's sent bytes read as a length
                raise ClusterError(
                    f"{scheduler} answered, but not as a Dask scheduler (is it the dashboard "
                    "or another service's port?)"
                ) from None
        else:
            if isinstance(workers, bool) or not isinstance(workers, int) or workers <= 0:
                raise ParameterError(f"workers must be a positive integer, got {workers!r}")
            self.cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.ERROR,
                preload=[__name__],  # dask_setup: the workers leave Ctrl-C to this process
            )
            self.client = Client(self.cluster, timeout=CONNECT_TIMEOUT_S)

    @property
    def workers(self) -> int:
        return max(len(self.client.nthreads()), 1)

    def share(self, value: Any) -> Any:
        """value sent to the cluster once: a future the tasks take in its place. It is a task's
        result, not scattered data, so that the scheduler recomputes it if the worker holding
        it dies."""
        return self.client.submit(_identity, value, pure=False)

    def map(self, function: Callable, items: Sequence, *common: Any) -> Iterator[tuple[int, Any]]:
        """(index, result) of function(item, *common) on the cluster, as tasks finish. A
        KeyboardInterrupt cancels the tasks not yet finished. Tasks that take a shared value
        (`share`) are dealt out to the workers in turn (`task_placement`)."""
        from distributed import Future, as_completed

        task = shipped(function)
        token = uuid.uuid4().hex[:12]
        shares = self.spread_shared and any(isinstance(value, Future) for value in common)
        places = task_placement(self.client.nthreads(), len(items)) if shares else None
        futures = [
            self.client.submit(
                _run_task,
                task,
                item,
                *common,
                key=f"clrender-{token}-{index}",
                pure=False,
                **({} if places is None else {"workers": [places[index]]}),
                allow_other_workers=places is not None,
            )
            for index, item in enumerate(items)
        ]
        index_of = {future.key: index for index, future in enumerate(futures)}
        try:
            for future in as_completed(futures):
                try:
                    result = future.result()
                except Exception as err:  # Dask's own: workers that kept dying, a lost scheduler
                    raise ClusterError(
                        f"the cluster failed: {type(err).__name__}: {one_line(err)}"
                    ) from None
                if isinstance(result, TaskFailure):
                    raise ClusterTaskError(result.message)
                yield index_of[future.key], result
        finally:
            pending = [future for future in futures if not future.done()]
            if pending:
                self.client.cancel(pending)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def check_scheduler_address(scheduler: object) -> None:
    """ParameterError unless scheduler is an address Dask can connect to (a known scheme, and
    a host and port where the scheme needs them), checked before any connection is tried."""
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    try:
        if not isinstance(scheduler, str):
            raise TypeError(f"got {type(scheduler).__name__}")
        scheme, location = parse_address(scheduler)
        get_backend(scheme)
        if scheme in ("tcp", "tls", "ws", "wss"):
            port = parse_host_port(location)[1]
            if not 0 < int(port) < 65536:
                raise ValueError(f"port {port} is not in 1-65535")
    except (ValueError, TypeError) as err:
        raise ParameterError(
            f"--scheduler (scheduler=) {scheduler!r} is not a Dask scheduler address such as "
            f"tcp://host:8786: {one_line(err)}"
        ) from None


def one_line(err: BaseException) -> str:
    """An exception's text on one line (its type's name if it has none, or none it can say)."""
    try:
        text = str(err)
    except Exception:  # Dask's KilledWorker formats a worker it may not hold
        text = ""
    return " ".join(text.split()) or type(err).__name__


def dask_setup(worker) -> None:
    """Run in each worker process of a LocalCluster this process starts (its preload module),
    on the worker's main thread: Ctrl-C at a terminal reaches the whole process group, and this
    process handles it (it cancels the tasks and closes the cluster), so the workers ignore
    SIGINT (each printed a KeyboardInterrupt traceback as it stopped)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def task_placement(nthreads: dict[str, int], tasks: int) -> list[str] | None:
    """The worker each of `tasks` tasks is first offered to: the workers' threads in turn (by
    address). Dask sends a task to a worker that holds its inputs, so tasks sharing one value
    held by one worker would all start there (6 of 8 on a fresh cluster of 2), leaving the
    others to work stealing. A loose restriction (workers=[address], allow_other_workers=True)
    spreads them from the start, yet lets the scheduler run a task elsewhere when its worker
    is gone and steal it for an idle one. None with no worker."""
    threads = [address for address in sorted(nthreads) for _ in range(max(nthreads[address], 1))]
    if not threads:
        return None
    return [threads[index % len(threads)] for index in range(tasks)]


def shipped(function: Callable) -> Callable | bytes:
    """The function as the tasks take it: itself when the workers can import it (clrender's
    own functions, installed libraries), else pickled by value here (cloudpickle), as for a
    function of a bench script imported from its folder, which a worker cannot import. The
    script's sibling modules (bench/common.py, a study that reads another's functions) travel
    by value with it, the script run as __main__ too."""
    import cloudpickle

    name = getattr(function, "__module__", None) or "__main__"
    module = sys.modules.get(name)
    path = getattr(module, "__file__", None) or ""
    importable = name.split(".")[0] == "clrender" or "-packages" in path
    if module is None or importable:
        return function
    folder = os.path.dirname(os.path.abspath(path)) if path else None
    modules = [
        other
        for other_name, other in list(sys.modules.items())
        if other_name != "__main__"
        and (other is module or (folder is not None and _folder_of(other) == folder))
    ]
    if name == "__main__" and not modules:
        return function
    registered = set(cloudpickle.list_registry_pickle_by_value())
    added = [other for other in modules if other.__name__ not in registered]
    for other in added:
        cloudpickle.register_pickle_by_value(other)
    try:
        return cloudpickle.dumps(function)
    finally:
        for other in added:
            cloudpickle.unregister_pickle_by_value(other)


def _folder_of(module) -> str | None:
    path = getattr(module, "__file__", None)
    return os.path.dirname(os.path.abspath(path)) if path else None


# What tasks keep in this process between them: name -> dict (see `process_cache`)
_process_caches: dict[str, dict] = {}


def process_cache(name: str) -> dict:
    """A dict that lives as long as this process, one per name: where a task keeps what it
    built (an OpenCL runtime, radiance sources) for the next task on the same worker. A bench
    script's function, pickled by value (`shipped`), gets fresh module globals with every
    task; this module is imported once per worker."""
    return _process_caches.setdefault(name, {})


def worker_name() -> str:
    """The Dask worker this runs on (its address), or "this process" outside a worker."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "this process"


def _identity(value: Any) -> Any:
    return value


@dataclass(frozen=True)
class TaskFailure:
    """What a task returns instead of raising: one line naming the worker and the error (an
    exception raised on a worker would have Dask log its traceback there too)."""

    message: str


def _run_task(function: Callable | bytes, item: Any, *common: Any) -> Any:
    """function(item, *common) on a worker (function pickled by value: see `shipped`); any
    exception becomes a TaskFailure of one line naming the worker."""
    try:
        if isinstance(function, bytes):
            import cloudpickle

            function = cloudpickle.loads(function)
        return function(item, *common)
    except Exception as err:  # noqa: BLE001 (reported whole, in one line, to the client)
        from distributed import get_worker

        try:
            where = get_worker().address
        except ValueError:
            where = "this process"
        text = one_line(err)
        return TaskFailure(f"task failed on worker {where}: {type(err).__name__}: {text}")


def make_executor(workers: int | None, scheduler: str | None) -> LocalExecutor | DaskExecutor:
    """The executor of --workers / --scheduler: local when neither is given."""
    if workers is not None and scheduler is not None:
        raise ParameterError("give --workers or --scheduler, not both")
    if workers is None and scheduler is None:
        return LocalExecutor()
    return DaskExecutor(workers, scheduler)


# --------------------------------------------------------------------------------- renders


@dataclass(frozen=True)
class RenderJob:
    """Everything a worker needs to render tiles, as plain data: the scene (a loaded Scene, or
    an analytic image's name), the image size, the sampler and estimators, and the path
    settings. `token` names the job: a worker keeps the radiance source of its last job."""

    scene: Scene | str
    width: int
    height: int
    sampler: SamplerConfig
    estimators: tuple[str, ...]
    seed: int = 0
    tile_samples: int = DEFAULT_TILE_SAMPLES
    overlap: bool = True
    voronoi_backend: str = "device"
    max_depth: int = DEFAULT_MAX_DEPTH
    russian_roulette: bool = False
    device: str | None = None
    trace_kernel: str = "auto"  # as clrender.render's; each worker chooses for its device
    token: str = field(default_factory=lambda: uuid.uuid4().hex)

    @classmethod
    def of(
        cls,
        scene: Scene | str,
        settings: RenderSettings,
        max_depth: int,
        russian_roulette: bool = False,
        device: str | None = None,
        trace_kernel: str = "auto",
    ) -> RenderJob:
        return cls(
            scene,
            settings.width,
            settings.height,
            settings.sampler,
            tuple(entry.name for entry in settings.estimators),
            settings.seed,
            settings.tile_samples,
            settings.overlap,
            settings.voronoi_backend,
            max_depth,
            russian_roulette,
            device,
            trace_kernel,
        )

    def settings(self) -> RenderSettings:
        return RenderSettings(
            self.width,
            self.height,
            self.sampler,
            list(self.estimators),
            self.seed,
            self.tile_samples,
            self.overlap,
            self.voronoi_backend,
        )


@dataclass
class PixelRangeResult:
    """A task's pixels (global indices) and what the films and layers hold for them, the
    task's stats (its tiles, stage times, samples), and where and after what set-up it ran."""

    pixels: np.ndarray
    values: dict[str, np.ndarray]  # estimator -> (P, 3) float32, as on its film
    flagged: dict[str, np.ndarray]  # estimator -> (P,) bool
    samples: np.ndarray
    redraws: np.ndarray
    variance: np.ndarray
    first_draw: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    stats: RenderStats
    device: str  # the OpenCL device that rendered it (Runtime.describe)
    precision: str  # of that device's Voronoi cells and sums: "mixed" or "single"
    trace_kernel: str | None  # the kernel that traced its paths (None for an analytic image)
    worker: str  # the worker process that ran it (worker_name)
    # what kept it from its tiles: the set-up before its first tile (the job's radiance source
    # unless the worker kept it, the tile pipeline) and the program builds on its render thread
    setup_seconds: float
    # estimator -> (P,) bool: the pixels its film holds (an interrupted task's finished tiles;
    # None from a worker older than the field: all of them)
    rendered: dict[str, np.ndarray] | None = None
    # the OpenCL sources its worker built (clrender.provenance.kernels_fingerprint: its
    # CLRENDER_KERNELS_DIR or installed package, not the client's); None from an older worker
    kernels_sha256: str | None = None
    # the clrender Python code its worker ran (clrender.provenance.code_fingerprint: its
    # install as it imported it); None from an older worker
    code_sha256: str | None = None


# The radiance source of the last job a worker process ran: (token, source)
_worker_source: list = []


def _source_for(job: RenderJob):
    from clrender.api import radiance_source, runtime_for

    if _worker_source and _worker_source[0][0] == job.token:
        return _worker_source[0][1]
    runtime = runtime_for(job.device)
    source = radiance_source(
        runtime,
        job.scene,
        (job.width, job.height),
        job.max_depth,
        job.russian_roulette,
        job.trace_kernel,
    )
    _worker_source[:] = [(job.token, source)]
    return source


def render_pixels(pixel_range: tuple[int, int], job: RenderJob) -> PixelRangeResult:
    """Render pixels [first, end) of a job, in tiles of its sample budget; their estimates are
    those of a local render of the whole image."""
    set_up = time.perf_counter()
    from clrender.api import runtime_for

    first, end = pixel_range
    built = thread_build_seconds()
    source = _source_for(job)
    source_builds = thread_build_seconds() - built
    runtime = runtime_for(job.device)
    pipeline = TilePipeline(runtime, source, job.settings())
    start = time.perf_counter()
    pipeline.run(range(first, end, pixels_per_tile(pipeline.settings)), None, end)
    # Its finished range is handed back whole: a signal while it is gathered (a task run in
    # this process's main thread, LocalExecutor) is held and ends the render after this task
    with interrupts.signals_held() as held:
        result = _range_result(pipeline, source, runtime, (first, end), start, set_up)
    result.stats.setup_compile_seconds = source_builds
    result.stats.interrupted |= bool(held)
    return result


def _range_result(
    pipeline: TilePipeline, source, runtime, pixel_range: tuple[int, int], start, set_up
) -> PixelRangeResult:
    from clrender.estimators.device_cells import resolve_precision
    from clrender.provenance import code_fingerprint, kernels_fingerprint

    first, end = pixel_range
    pipeline.stats.wall_seconds = time.perf_counter() - start
    setup_seconds = start - set_up + pipeline.stats.main_compile_seconds
    pixels = np.arange(first, end, dtype=np.int64)
    layers = pipeline.layers
    first_draw = pipeline.first_draw_layers
    return PixelRangeResult(
        pixels,
        {name: film.pixels[pixels] for name, film in pipeline.films.items()},
        {name: film.flagged[pixels] for name, film in pipeline.films.items()},
        layers.samples[pixels],
        layers.redraws[pixels],
        layers.variance[pixels],
        None
        if first_draw is None
        else (first_draw.samples[pixels], first_draw.redraws[pixels], first_draw.variance[pixels]),
        pipeline.stats,
        runtime.describe(),
        resolve_precision(runtime, "auto"),
        getattr(getattr(source, "tracer", None), "trace_kernel", None),
        worker_name(),
        setup_seconds,
        {name: film.rendered[pixels] for name, film in pipeline.films.items()},
        kernels_fingerprint(),
        code_fingerprint(),
    )


def split_pixels(pixel_count: int, tasks: int) -> list[tuple[int, int]]:
    """[first, end) ranges of consecutive pixels, `tasks` of them at most, as even as can be."""
    tasks = max(1, min(tasks, pixel_count))
    bounds = [pixel_count * k // tasks for k in range(tasks + 1)]
    return [(bounds[k], bounds[k + 1]) for k in range(tasks) if bounds[k + 1] > bounds[k]]


def add_stats(total: RenderStats, part: RenderStats) -> None:
    """Sum a task's stats into the render's, but for its wall time (the render's is the
    client's) and its render thread's builds (in its set-up: `worker_setup_seconds`)."""
    for item in dataclasses.fields(RenderStats):
        name = item.name
        if name in ("wall_seconds", "main_compile_seconds", "worker_setup_seconds", "interrupted"):
            continue
        value = getattr(part, name)
        if isinstance(value, dict):
            mine = getattr(total, name)
            for key, seconds in value.items():
                mine[key] = mine.get(key, 0.0) + seconds
        else:
            setattr(total, name, getattr(total, name) + value)


def render_on(
    executor: LocalExecutor | DaskExecutor,
    job: RenderJob,
    progress: Callable[[int, int], None] | None = None,
    tasks: int | None = None,
) -> RenderResult:
    """The job's image from tasks on the executor (TASKS_PER_WORKER per worker unless `tasks`
    says), bit-identical to clrender.pipeline.render of the same settings. Ctrl-C returns the
    finished pixels with stats.interrupted set."""
    settings = job.settings()
    plan_tiles(settings)  # checks the tile budget before any task starts
    ranges = split_pixels(settings.pixel_count, tasks or TASKS_PER_WORKER * executor.workers)
    films = {name: Film(job.width, job.height) for name in job.estimators}
    layers = PixelLayers(job.width, job.height)
    image_level = any(entry.image_level for entry in settings.estimators)
    rejecting = any(entry.needs_aux for entry in settings.estimators)
    first_draw = PixelLayers(job.width, job.height) if image_level and rejecting else None
    stats = RenderStats()
    devices: set[str] = set()
    precisions: set[str] = set()
    trace_kernels: set[str] = set()
    # the fingerprints each task reports (clrender.provenance.REPORTED), a worker older than
    # one "unknown"
    reported: dict[str, set[str]] = {key: set() for key in REPORTED}
    setup_by_worker: dict[str, float] = {}
    tasks_by_worker: dict[str, int] = {}
    shared = executor.share(job) if isinstance(executor, DaskExecutor) else job
    start = time.perf_counter()
    parts = executor.map(render_pixels, ranges, shared)
    try:
        for _, part in parts:
            for name, film in films.items():
                kept = slice(None) if part.rendered is None else part.rendered[name]
                film.record(part.pixels[kept], part.values[name][kept], part.flagged[name][kept])
            layers.record(part.pixels, part.samples, part.redraws, part.variance)
            if first_draw is not None and part.first_draw is not None:
                first_draw.record(part.pixels, *part.first_draw)
            add_stats(stats, part.stats)
            devices.add(part.device)
            precisions.add(part.precision)
            # (None from an analytic image's task, or from a worker older than the field)
            if getattr(part, "trace_kernel", None) is not None:
                trace_kernels.add(part.trace_kernel)
            for key, values in reported.items():
                values.add(getattr(part, key, None) or "unknown (an older worker)")
            setup_by_worker[part.worker] = (
                setup_by_worker.get(part.worker, 0.0) + part.setup_seconds
            )
            tasks_by_worker[part.worker] = tasks_by_worker.get(part.worker, 0) + 1
            if progress is not None:
                first = films[job.estimators[0]]
                progress(first.rendered_count, first.pixel_count)
            # A task run in this process (LocalExecutor) catches Ctrl-C in its own pipeline
            # and returns its finished tiles: the render ends there, as if interrupted here
            if part.stats.interrupted:
                raise KeyboardInterrupt
        interrupts.work_done()  # a command holds the signals from here (clrender.interrupts)
    except KeyboardInterrupt:
        stats.interrupted = True
    finally:
        parts.close()  # no further task starts (a cluster's outstanding ones are cancelled)
    stats.wall_seconds = time.perf_counter() - start
    # The workers set up at once, each before its first tile: the render waits for the longest
    stats.worker_setup_seconds = max(setup_by_worker.values(), default=0.0)
    first_name = job.estimators[0]
    paths = not isinstance(job.scene, str)  # (an analytic image has none)
    return RenderResult(
        films[first_name],
        stats,
        settings,
        films,
        layers,
        first_draw,
        max_depth=job.max_depth if paths else None,
        russian_roulette=job.russian_roulette if paths else None,
        device="; ".join(sorted(devices)) or None,
        device_precision="; ".join(sorted(precisions)) or None,
        trace_kernel="; ".join(sorted(trace_kernels)) or None,
        tasks_by_worker=dict(sorted(tasks_by_worker.items())),
        **{key: "; ".join(sorted(values)) or None for key, values in reported.items()},
    )
