"""The tile pipeline: determinism across tilings and overlap, sample budgets, redraws after
rejection, non-finite radiance, interruption."""

import concurrent.futures
from dataclasses import dataclass

import numpy as np
import pytest

from clrender.analytic import AnalyticSource, sample_image_positions
from clrender.errors import ParameterError
from clrender.estimators import check_compatible
from clrender.pipeline import RenderSettings, pixels_per_tile, plan_tiles, render, tile_pixels
from clrender.radiance import DeviceRadiance, SampleRadiance
from clrender.sampling import make_sampler

WIDTH, HEIGHT = 40, 24
# The tiling identities' image: odd sides, so that tiles split rows; a few rows (one-pixel
# tiles make a host call a pixel, so the size sets the test's time)
TILING_WIDTH, TILING_HEIGHT = 17, 9


def analytic_source(runtime, scene="analytic:mix", width=WIDTH, height=HEIGHT):
    return AnalyticSource.for_scene(scene, runtime.queue, width, height)


def settings(
    sampler="sppp", estimator="vor_sn", spp=16, eps=None, width=WIDTH, height=HEIGHT, **options
):
    config = (
        make_sampler(sampler, spp, eps=eps) if sampler == "sppp" else make_sampler(sampler, spp)
    )
    return RenderSettings(width, height, config, estimator, seed=5, **options)


# --- determinism ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "sampler, estimator",
    [
        ("sppp", "vor_sn"),
        ("sppp", "fvor"),
        ("stratified", "pvor"),
        ("sppp", "ivor_sn"),
        ("sobol", "pvor"),
        ("independent", "cvor"),
        ("zsobol", "mc"),
        ("sppp-sobol", "vor_sn"),
    ],
)
def test_image_is_bit_identical_whatever_the_tiling_and_overlap(runtime, sampler, estimator):
    size = dict(width=TILING_WIDTH, height=TILING_HEIGHT)
    source = analytic_source(runtime, **size)
    reference = render(runtime, source, settings(sampler, estimator, **size)).film.image()
    # One big tile, 1-pixel tiles, and an odd tile length that splits rows, each both ways.
    for tile_samples, overlap in [(10**8, False), (1, True), (13 * 17, False), (13 * 17, True)]:
        options = dict(tile_samples=tile_samples, overlap=overlap, **size)
        image = render(runtime, source, settings(sampler, estimator, **options)).film.image()
        assert np.array_equal(image, reference), (tile_samples, overlap)


def test_tiles_cover_the_image_in_order_within_the_sample_budget():
    for budget in [1, 100, 5000, 10**7]:
        config = settings(tile_samples=budget)
        tiles = [tile_pixels(config, start) for start in plan_tiles(config)]
        assert np.array_equal(np.concatenate(tiles), np.arange(WIDTH * HEIGHT))
        per_pixel = config.sampler.n + config.sampler.n_aux
        assert all(len(t) == 1 or len(t) * per_pixel <= budget for t in tiles)
    assert len(plan_tiles(settings(tile_samples=10**9))) == 4  # 960 px, MIN_TILE_PIXELS 256


def test_device_torus_and_clipped_cells_count_their_copies_in_the_sample_budget():
    # pvor's device cells hold each traced nucleus and its 8 translates: 9 n nuclei a pixel;
    # cvor's its 4 mirror images: 5 n
    for estimator, backend, per_pixel in [
        ("pvor", "device", 9 * 16),
        ("pvor", "qhull", 16),
        ("cvor", "device", 5 * 16),
        ("cvor", "qhull", 16),
        (["cvor", "pvor"], "device", 9 * 16),
    ]:
        config = RenderSettings(
            WIDTH,
            HEIGHT,
            make_sampler("independent", 16),
            estimator,
            tile_samples=2000,
            voronoi_backend=backend,
        )
        assert pixels_per_tile(config) == 2000 // per_pixel, (estimator, backend)


def test_different_seeds_give_different_images(runtime):
    source = analytic_source(runtime)
    first = render(runtime, source, settings()).film.image()
    other = RenderSettings(WIDTH, HEIGHT, make_sampler("sppp", 16), "vor_sn", seed=6)
    assert not np.array_equal(first, render(runtime, source, other).film.image())


# --- rejections ----------------------------------------------------------------------------


def test_rejected_pixels_are_redrawn_deterministically_and_stay_accurate(runtime):
    # eps = 0.02 instead of 0.19 leaves many W nuclei on the hull: most pixels need redraws,
    # and the driver widens eps after a few.
    source = analytic_source(runtime)
    narrow = render(runtime, source, settings(eps=0.02))
    assert narrow.stats.redrawn_pixels > WIDTH * HEIGHT // 2
    assert narrow.stats.eps_enlargements > 0
    assert narrow.film.complete and narrow.film.flagged_count == 0
    retiled = render(runtime, source, settings(eps=0.02, tile_samples=50 * 16, overlap=False))
    assert np.array_equal(retiled.film.image(), narrow.film.image())
    assert retiled.stats.redrawn_pixels == narrow.stats.redrawn_pixels
    errors = narrow.film.image() - source.pixel_integrals()
    assert np.sqrt(np.mean(errors**2)) < 0.03  # the default eps gives 0.015 here


def test_sampler_without_auxiliary_nuclei_is_rejected_with_advice():
    with pytest.raises(ParameterError, match="'vor'.*sppp.*mc, mc_n, cvor, pvor"):
        check_compatible("vor", "independent")
    with pytest.raises(ParameterError, match="'ivor_sn' needs the Poisson sample counts"):
        check_compatible("ivor_sn", "stratified")
    with pytest.raises(ParameterError, match="unknown estimator 'vr'; accepted: mc, "):
        check_compatible("vr", "sppp")
    check_compatible("pvor", "stratified")
    check_compatible("mc", "sppp")


# --- non-finite radiance -------------------------------------------------------------------


@dataclass
class PoisonedPending:
    inner: object
    sample_sets: object
    queue: object
    reported: int

    def to_host(self) -> SampleRadiance:
        radiance = self.inner.to_host()
        host = self.sample_sets.to_host(self.queue)
        x, _ = sample_image_positions(self.sample_sets.pixels, host.offsets, host.traced, WIDTH)
        values = radiance.values.copy()
        values[(x > 3.0) & (x < 3.5), 1] = np.nan  # the left half of column 3
        values[(x > 7.0) & (x < 7.25), 0] = np.inf
        return SampleRadiance(values, 0, self.reported)

    def to_device(self, runtime) -> DeviceRadiance:
        return DeviceRadiance(
            runtime.upload(self.to_host().values.astype(np.float32)), 0, self.reported
        )


@dataclass
class PoisonedSource:
    """An analytic source whose samples in columns 3 and 7 come back NaN or Inf; it also
    reports `reported` non-finite samples per launch, as the path tracer does."""

    inner: AnalyticSource
    reported: int = 0
    description: str = "poisoned"
    width: int = WIDTH
    height: int = HEIGHT

    def trace(self, sample_sets, seed):
        pending = self.inner.trace(sample_sets, seed)
        return PoisonedPending(pending, sample_sets, self.inner.queue, self.reported)


@pytest.mark.parametrize("estimator", ["vor_sn", "mc"])
def test_non_finite_samples_are_counted_and_their_pixels_flagged(runtime, estimator):
    source = PoisonedSource(analytic_source(runtime), reported=2)
    result = render(runtime, source, settings(estimator=estimator))
    image, film = result.film.image(), result.film
    assert np.isfinite(image).all()
    flagged = film.flagged.reshape(HEIGHT, WIDTH)
    assert flagged[:, 3].all() and flagged[:, 7].all()
    assert film.flagged_count == 2 * HEIGHT  # every pixel of those columns has such samples
    assert np.all(image[flagged] == 0.0)
    clean = render(runtime, analytic_source(runtime), settings(estimator=estimator))
    assert np.array_equal(image[~flagged], clean.film.image()[~flagged])
    # Samples in 3/4 of a column (Poisson, mean 16 per pixel), plus 2 reported per launch.
    found = result.stats.nonfinite_samples - 2 * result.stats.tiles
    expected = 0.75 * 16 * HEIGHT
    assert abs(found - expected) < 5 * np.sqrt(expected)


# --- interruption --------------------------------------------------------------------------


def test_interrupted_render_keeps_finished_tiles_and_leaves_the_rest_black(runtime):
    source = analytic_source(runtime)
    full = render(runtime, source, settings(tile_samples=100 * 16)).film

    def interrupt_after_first_tile(done, total):
        raise KeyboardInterrupt

    result = render(runtime, source, settings(tile_samples=100 * 16), interrupt_after_first_tile)
    film = result.film
    assert result.stats.interrupted and not film.complete
    # The first tile, plus the second whose estimate was in flight.
    assert 0 < film.rendered_count < film.pixel_count
    done = film.rendered
    assert np.array_equal(film.pixels[done], full.pixels[done])
    assert np.all(film.pixels[~done] == 0.0)


def test_an_interrupt_right_after_an_estimate_is_handed_over_keeps_it(runtime, monkeypatch):
    """Ctrl-C that lands as the estimator thread takes tile 1's estimate, before the render
    holds its future: the estimate is recorded once done (before: its future was lost, and
    tile 1 with it). The interrupt is raised right after the submit, as the signal handler
    raises it when the call returns."""
    from concurrent.futures import ThreadPoolExecutor

    from clrender import pipeline

    config = settings("independent", "mc", tile_samples=100 * 16)
    source = analytic_source(runtime)
    full = render(runtime, source, config).film
    submitted = []

    class InterruptedPool(ThreadPoolExecutor):
        def submit(self, function, *args, **kwargs):
            future = super().submit(function, *args, **kwargs)
            if function is int:  # (the thread's start)
                return future
            submitted.append(future)
            if len(submitted) == 2:
                raise KeyboardInterrupt
            return future

    monkeypatch.setattr(pipeline, "ThreadPoolExecutor", InterruptedPool)
    result = render(runtime, source, config)
    film = result.film
    tiles = plan_tiles(result.settings)
    two_tiles = tiles[2] if len(tiles) > 2 else film.pixel_count
    assert len(submitted) == 2 and result.stats.interrupted
    # Tiles 0 and 1, and nothing after them
    assert film.rendered[:two_tiles].all() and not film.rendered[two_tiles:].any()
    assert np.array_equal(film.pixels[:two_tiles], full.pixels[:two_tiles])


@pytest.mark.parametrize("overlap", [True, False])
def test_an_interrupt_while_an_estimate_is_recorded_keeps_it(runtime, monkeypatch, overlap):
    """Ctrl-C inside the recording of tile 1's estimate (the first film write): run()'s handler
    records it whole (before: it was taken from in_flight first, and lost)."""
    from clrender.film import Film

    config = settings("independent", "mc", tile_samples=100 * 16, overlap=overlap)
    source = analytic_source(runtime)
    full = render(runtime, source, config).film
    writes = []
    real_record = Film.record

    def interrupted_record(film, *args):
        writes.append(1)
        if len(writes) == 2:
            raise KeyboardInterrupt
        return real_record(film, *args)

    monkeypatch.setattr(Film, "record", interrupted_record)
    result = render(runtime, source, config)
    film = result.film
    tiles = plan_tiles(result.settings)
    two_tiles = tiles[2] if len(tiles) > 2 else film.pixel_count
    assert result.stats.interrupted
    assert film.rendered[:two_tiles].all() and not film.rendered[two_tiles:].any()
    assert np.array_equal(film.pixels[:two_tiles], full.pixels[:two_tiles])


def test_an_interrupt_is_not_replaced_by_the_estimate_it_failed(runtime, monkeypatch):
    """A signal during a build on the estimator thread can fail that build (clang's signal
    handler removes its temporary files) as the main thread takes the interrupt: the render
    ends interrupted with the tiles before, not with the build error (before: run()'s handler
    took the failed estimate's result, which raised the error)."""
    from clrender.pipeline import TilePipeline
    from clrender.runtime import KernelBuildError

    config = settings("independent", "mc", tile_samples=100 * 16, overlap=True)
    real_estimate, real_finish = TilePipeline.estimate, TilePipeline.finish_in_flight
    estimates = []

    def estimate(pipeline, tile):
        estimates.append(1)
        if len(estimates) == 2:
            raise KernelBuildError("OpenCL build of x.cl failed: unable to rename temporary")
        return real_estimate(pipeline, tile)

    def finish_in_flight(pipeline, progress):
        if pipeline.in_flight is not None:
            concurrent.futures.wait([pipeline.in_flight])
            if pipeline.in_flight.exception() is not None:
                raise KeyboardInterrupt  # the signal reaches the main thread now
        real_finish(pipeline, progress)

    monkeypatch.setattr(TilePipeline, "estimate", estimate)
    monkeypatch.setattr(TilePipeline, "finish_in_flight", finish_in_flight)
    result = render(runtime, analytic_source(runtime), config)
    film = result.film
    one_tile = plan_tiles(result.settings)[1]
    assert result.stats.interrupted
    assert film.rendered[:one_tile].all() and not film.rendered[one_tile:].any()


@pytest.mark.parametrize("overlap", [True, False])
def test_an_estimate_recorded_again_after_an_interrupt_counts_once(runtime, monkeypatch, overlap):
    """Ctrl-C after tile 1's estimate was recorded, before the render let go of it: run()'s
    handler records it again (same pixels) and its counts are on the stats once."""
    from clrender.pipeline import TilePipeline

    config = settings("independent", "mc", tile_samples=100 * 16, overlap=overlap)
    real_estimate, real_record = TilePipeline.estimate, TilePipeline.record
    records = []

    def estimate(pipeline, tile):
        result = real_estimate(pipeline, tile)
        result.nonfinite_samples = 1  # one per tile, to count the recordings by
        return result

    def record(pipeline, result):
        real_record(pipeline, result)
        records.append(1)
        if len(records) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(TilePipeline, "estimate", estimate)
    monkeypatch.setattr(TilePipeline, "record", record)
    result = render(runtime, analytic_source(runtime), config)
    assert result.stats.interrupted and len(records) == 3
    assert result.stats.nonfinite_samples == 2


def test_an_interrupt_as_the_estimator_thread_starts_leaves_no_estimate_running(
    runtime, monkeypatch
):
    """Ctrl-C inside the estimator thread's start (as its pool lists it): no tile has been
    handed over, and none is estimated after the render returned (before: tile 0's estimate
    ran on in a thread the pool did not join, and was not kept)."""
    import threading
    import time

    from clrender.pipeline import TilePipeline

    config = settings("independent", "mc", tile_samples=100 * 16, overlap=True)
    real_estimate, real_start = TilePipeline.estimate, threading.Thread.start
    estimates, starts = [], []

    def estimate(pipeline, tile):
        estimates.append(1)
        return real_estimate(pipeline, tile)

    def start(thread):
        real_start(thread)
        starts.append(1)
        if len(starts) == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(TilePipeline, "estimate", estimate)
    monkeypatch.setattr(threading.Thread, "start", start)
    result = render(runtime, analytic_source(runtime), config)
    returned_with = len(estimates)
    time.sleep(0.3)
    assert result.stats.interrupted and result.film.rendered_count == 0
    assert returned_with == len(estimates) == 0


def test_stages_are_timed_on_the_device_clock_without_a_wait_each(runtime):
    """On a profiling queue (the runtimes clrender makes) a stage queues its commands and
    returns without waiting for them; settle() then adds the device's time from the stage's
    start (the device free for it) to its commands' end: at least the commands' own profiled
    durations. On a queue without profiling, each stage waits for the device as before."""
    import pyopencl as cl

    from clrender.pipeline import RenderStats, StageClock

    assert runtime.profiled
    host = np.zeros(1 << 20, np.float32)
    device = runtime.allocate(host.nbytes)
    stats = RenderStats()
    clock = StageClock(stats, runtime.queue)
    gate = cl.UserEvent(runtime.context)  # holds the queue until the stage has returned
    with clock.stage("tracing"):
        cl.enqueue_barrier(runtime.queue, wait_for=[gate])
        copies = [cl.enqueue_copy(runtime.queue, device, host, is_blocking=False) for _ in range(4)]
    assert copies[-1].command_execution_status != cl.command_execution_status.COMPLETE
    assert stats.stage_seconds["tracing"] == 0.0
    gate.set_status(cl.command_execution_status.COMPLETE)
    clock.settle()
    busy = sum(copy.profile.end - copy.profile.start for copy in copies) * 1e-9
    assert 0.0 < busy <= stats.stage_seconds["tracing"] == stats.device_seconds
    assert not clock.queued
    # A queue that does not profile: the stage waits for its commands
    plain = cl.CommandQueue(runtime.context)
    other = StageClock(RenderStats(), plain)
    with other.stage("tracing"):
        copy = cl.enqueue_copy(plain, device, host, is_blocking=False)
    assert copy.command_execution_status == cl.command_execution_status.COMPLETE
    assert other.stats.stage_seconds["tracing"] > 0.0


def test_a_stage_that_builds_a_program_is_timed_with_a_wait(runtime, monkeypatch):
    """A build may overlap the device's earlier work, so the device's clock less the build
    time would undercount the stage (it came out 0 for a first tile's Voronoi stage): such a
    stage waits for its commands and takes the main thread's time less the build."""
    import pyopencl as cl

    import clrender.pipeline as pipeline

    built = [0.0]
    monkeypatch.setattr(pipeline, "thread_build_seconds", lambda: built[0])
    host = np.zeros(1 << 20, np.float32)
    device = runtime.allocate(host.nbytes)
    stats = pipeline.RenderStats()
    clock = pipeline.StageClock(stats, runtime.queue)
    with clock.stage("voronoi"):
        built[0] += 1e-4  # a program build met on the way
        copies = [cl.enqueue_copy(runtime.queue, device, host, is_blocking=False) for _ in range(4)]
    assert all(c.command_execution_status == cl.command_execution_status.COMPLETE for c in copies)
    assert not clock.queued
    assert stats.compile_seconds == pytest.approx(1e-4)
    busy = sum(copy.profile.end - copy.profile.start for copy in copies) * 1e-9
    assert stats.stage_seconds["voronoi"] >= busy - 1e-4 > 0.0


@pytest.mark.parametrize(
    "sampler, estimators, backend",
    [
        ("independent", ["mc"], "device"),  # the plain sums on the device
        ("sobol", ["mc", "mc_n"], "device"),
        ("stratified", ["pvor", "mc"], "device"),  # device cells
        ("independent", ["cvor"], "device"),
        ("stratified", ["pvor", "mc_n"], "qhull"),  # the samples read back
        ("sppp", ["mc_n"], "device"),  # Poisson counts read back before the fill
        ("sppp", ["vor_sn", "mc"], "device"),
    ],
)
def test_the_next_tile_is_queued_before_the_host_waits_for_a_tile(
    runtime, monkeypatch, sampler, estimators, backend
):
    """The device is kept fed: tile 1's sample sets and trace are queued while tile 0 is held
    on the device (its trace waits for a user event), i.e. before the host waits for tile 0's
    results; the images are those rendered without the hold. Tile 1's trace opens the gate;
    so does any wait for the device before it (a blocking copy, a wait for events, for a read
    or for a stage's marker, a read's event dropped), so that a pipeline that waits for each
    tile before it queues the next does not hang but fails. A copy on another queue (SPPP's
    Poisson counts, read back before the fill from the runtime's side queue) waits for that
    queue alone and leaves the gate shut."""
    import pyopencl as cl

    from clrender.api import radiance_source
    from clrender.scene import load_scene

    size = dict(width=16, height=8, tile_samples=32 * 4, voronoi_backend=backend)
    config = settings(sampler, estimators, spp=4, **size)
    source = radiance_source(runtime, load_scene("cornell-box"), (16, 8), 3)
    reference = render(runtime, source, config).images
    gate = cl.UserEvent(runtime.context)
    opened = []

    def open_gate(by):
        if not opened:
            opened.append(by)
            gate.set_status(cl.command_execution_status.COMPLETE)

    traced = []
    trace = source.trace

    def gated_trace(sample_sets, seed):
        traced.append(sample_sets.pixels[0])
        if len(traced) == 1:
            cl.enqueue_barrier(runtime.queue, wait_for=[gate])
        elif len(traced) == 2:
            open_gate("the second tile's trace")
        return trace(sample_sets, seed)

    copy, wait_for_events = cl.enqueue_copy, cl.wait_for_events

    class HeldRead:
        """A non-blocking read's event: waiting for it or dropping it (which waits for the
        read) opens the gate first."""

        def __init__(self, event):
            self.event = event

        def wait(self):
            open_gate("a wait for a read")
            self.event.wait()

        def __getattr__(self, name):
            return getattr(self.event, name)

        def __del__(self):
            open_gate("a dropped read")

    def copy_opening(queue, dest, src, **kwargs):
        if queue is not runtime.queue:
            return copy(queue, dest, src, **kwargs)
        if kwargs.get("is_blocking", True):
            open_gate("a blocking copy")
            return copy(queue, dest, src, **kwargs)
        event = copy(queue, dest, src, **kwargs)
        return HeldRead(event) if isinstance(dest, np.ndarray) else event

    def wait_opening(events):
        open_gate("a wait for events")
        return wait_for_events([getattr(event, "event", event) for event in events])

    event_wait = cl.Event.wait

    def event_wait_opening(event):
        # (a user event has no queue)
        if getattr(event.command_queue, "int_ptr", None) == runtime.queue.int_ptr:
            open_gate("a wait for an event")
        return event_wait(event)

    monkeypatch.setattr(source, "trace", gated_trace)
    monkeypatch.setattr(cl.Event, "wait", event_wait_opening)
    monkeypatch.setattr(cl, "enqueue_copy", copy_opening)
    monkeypatch.setattr(cl, "wait_for_events", wait_opening)
    result = render(runtime, source, config)
    assert opened == ["the second tile's trace"]
    assert result.stats.tiles > 2 and len(traced) == result.stats.tiles
    for name, image in reference.items():
        assert np.array_equal(result.images[name], image), name


@pytest.mark.parametrize(
    "sampler, estimators, backend",
    [
        ("independent", ["mc"], "device"),
        ("sppp", ["vor_sn", "mc_n"], "device"),
        ("stratified", ["pvor", "mc_n"], "qhull"),  # the samples read back
    ],
)
def test_a_tile_waits_for_its_stages_in_order_before_its_results(
    runtime, monkeypatch, sampler, estimators, backend
):
    """Intel's CPU runtime runs a kernel on the waiting host thread too only when the host
    waits for that kernel or for a marker right behind it, not for a read queued behind a
    marker: a tile waited for its results alone traced on one thread of two. So a tile's
    collect waits for its stages' end markers first, in the order they were queued, and only
    then for the reads of its results (and of its samples, when kept)."""
    import threading

    import pyopencl as cl

    import clrender.pipeline as pipeline
    from clrender.api import radiance_source
    from clrender.scene import load_scene

    waits = []  # per collect: the events the main thread waited for, in order
    event_wait, wait_for_events = cl.Event.wait, cl.wait_for_events

    def main_thread_collecting():
        return waits and threading.current_thread() is threading.main_thread()

    def recording_wait(event):
        if main_thread_collecting():
            waits[-1]["waited"].append(event.int_ptr)
        return event_wait(event)

    def recording_wait_for_events(events):
        if main_thread_collecting():
            waits[-1]["waited"].extend(event.int_ptr for event in events)
        return wait_for_events(events)

    collect = pipeline.QueuedTile.collect

    def recording_collect(tile, clock):
        # each stage's end marker, then the commands it ran on the side queue (SPPP's counts)
        ends = [event.int_ptr for _, _, last, _, side in tile.stages for event in (last, *side)]
        waits.append({"ends": ends, "waited": []})
        return collect(tile, clock)

    monkeypatch.setattr(cl.Event, "wait", recording_wait)
    monkeypatch.setattr(cl, "wait_for_events", recording_wait_for_events)
    monkeypatch.setattr(pipeline.QueuedTile, "collect", recording_collect)
    size = dict(width=16, height=8, tile_samples=32 * 4, voronoi_backend=backend)
    config = settings(sampler, estimators, spp=4, **size)
    source = radiance_source(runtime, load_scene("cornell-box"), (16, 8), 3)
    result = render(runtime, source, config)
    assert len(waits) == result.stats.tiles > 2
    for tile in waits:
        ends, waited = tile["ends"], tile["waited"]
        assert ends and waited[: len(ends)] == ends, tile
        assert len(waited) > len(ends)  # the results' reads, after the stages


def test_a_count_pass_queued_ahead_counts_its_builds_as_compile_time(runtime, monkeypatch):
    """The counts queued ahead of a tile are queued outside its stages: a program build there
    (the first use of sampling.cl in a process) is compile time, not render time (before: it
    went into the render's run time, and its paths per second)."""
    import clrender.pipeline as pipeline

    build_clock = [0.0]
    real_queue_counts = pipeline.queue_counts

    def building_queue_counts(*args):
        build_clock[0] += 0.5  # as if each built a program for half a second
        return real_queue_counts(*args)

    monkeypatch.setattr(pipeline, "thread_build_seconds", lambda: build_clock[0])
    monkeypatch.setattr(pipeline, "queue_counts", building_queue_counts)
    config = settings("sppp", ["mc_n"], spp=4, tile_samples=40 * 4)
    result = render(runtime, analytic_source(runtime), config)
    calls = build_clock[0] / 0.5
    assert calls == len(plan_tiles(result.settings)) > 1
    assert result.stats.main_compile_seconds == result.stats.compile_seconds == build_clock[0]


@pytest.mark.parametrize("overlap", [True, False])
def test_sppp_counts_of_the_next_tile_are_queued_before_a_tile_is_traced(
    runtime, monkeypatch, overlap
):
    """Tile k + 1's count pass runs on the side queue and is queued before tile k's trace (a
    device that runs commands in the order they became ready, as PoCL's CPU device, then runs
    it before that trace, and tile k + 1's sample sets wait for nothing); no count pass runs on
    the main queue. The image is the one drawn without counts queued ahead."""
    import clrender.pipeline as pipeline

    config = settings("sppp", ["mc_n", "vor_sn"], spp=4, tile_samples=40 * 4, overlap=overlap)
    source = analytic_source(runtime)
    events = []
    launch, trace, queue = runtime.launch_1d, source.trace, pipeline.queue_counts

    def recording_launch(kernel, count, *args, **kwargs):
        if kernel.function_name == "count_samples":
            side = kwargs.get("queue") is runtime.side_queue
            events.append(("count",) if side else ("main-queue count",))
        return launch(kernel, count, *args, **kwargs)

    def recording_trace(sample_sets, seed):
        events.append(("trace", int(sample_sets.pixels[0])))
        return trace(sample_sets, seed)

    def recording_queue(runtime, sampler, seed, pixels, redraws):
        events.append(("queued", int(pixels[0])))
        return queue(runtime, sampler, seed, pixels, redraws)

    monkeypatch.setattr(runtime, "launch_1d", recording_launch)
    monkeypatch.setattr(source, "trace", recording_trace)
    monkeypatch.setattr(pipeline, "queue_counts", recording_queue)
    result = render(runtime, source, config)
    monkeypatch.undo()
    tiles = list(plan_tiles(result.settings))
    assert result.stats.tiles == len(tiles) > 2 and result.stats.redrawn_pixels == 0
    assert ("main-queue count",) not in events
    assert events.count(("count",)) == len(tiles)  # each tile counted once
    queued = [event[1] for event in events if event[0] == "queued"]
    assert queued == tiles
    for k, start in enumerate(tiles[:-1]):
        assert events.index(("queued", tiles[k + 1])) < events.index(("trace", start)), k
    monkeypatch.setattr(pipeline.TilePipeline, "count_ahead", lambda *args: None)
    reference = render(runtime, source, config)
    for name, image in reference.images.items():
        assert np.array_equal(result.images[name], image), name
