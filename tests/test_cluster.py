"""Renders on a Dask LocalCluster (clrender.cluster): bit-identical to the local render, whatever
the split into tasks, a worker killed mid-render, an interrupt; errors in one line."""

import json
import os
import signal
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clrender.api import radiance_source
from clrender.cli import main
from clrender.cluster import (
    TASKS_PER_WORKER,
    ClusterError,
    ClusterTaskError,
    LocalExecutor,
    RenderJob,
    make_executor,
    render_on,
    split_pixels,
)
from clrender.errors import ClrenderError, ParameterError
from clrender.pipeline import RenderSettings, pixels_per_tile, render
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import DEFAULT_MAX_DEPTH

pytest.importorskip("distributed")

pytestmark = pytest.mark.device  # the workers open the device PYOPENCL_CTX names

MAX_DEPTH = 8


def local_and_job(runtime, scene, settings):
    source = radiance_source(runtime, scene, (settings.width, settings.height), MAX_DEPTH)
    return render(runtime, source, settings), RenderJob.of(scene, settings, MAX_DEPTH)


def assert_same_render(local, distributed):
    assert list(distributed.films) == list(local.films)
    for name in local.films:
        assert np.array_equal(distributed.images[name], local.images[name]), name
        assert np.array_equal(distributed.films[name].flagged, local.films[name].flagged)
        assert distributed.films[name].complete
    for layer, values in local.layers.images().items():
        assert np.array_equal(distributed.layers.images()[layer], values, equal_nan=True), layer
    assert distributed.stats.traced_samples == local.stats.traced_samples
    assert distributed.stats.redrawn_pixels == local.stats.redrawn_pixels
    assert distributed.stats.tiles >= local.stats.tiles  # each task tiles its own range


def test_analytic_render_is_bit_identical_to_the_local_one(runtime, cluster):
    # eps 0.02 makes most pixels redraw (and widen eps): the redraws happen inside the tasks.
    sampler = make_sampler("sppp", 16, eps=0.02)
    settings = RenderSettings(24, 16, sampler, ["vor_sn", "mc", "ivor"], 7, 40 * 16)
    local, job = local_and_job(runtime, "analytic:mix", settings)
    assert local.stats.redrawn_pixels > 0 and local.first_draw_layers is not None
    for tasks in (1, 3, 11):
        distributed = render_on(cluster, job, tasks=tasks)
        assert_same_render(local, distributed)
        assert np.array_equal(
            distributed.first_draw_layers.variance, local.first_draw_layers.variance
        )


def test_cornell_box_render_is_bit_identical_to_the_local_one(runtime, cluster):
    scene = load_scene("cornell-box")
    settings = RenderSettings(24, 24, make_sampler("sppp", 16), ["vor_sn", "mc"], 3, 64 * 34)
    local, job = local_and_job(runtime, scene, settings)
    assert_same_render(local, render_on(cluster, job))
    # The local executor runs the same tasks in this process: the same image again
    assert_same_render(local, render_on(LocalExecutor(), job, tasks=5))


def test_a_worker_killed_mid_render_changes_nothing(runtime, cluster):
    scene = load_scene("cornell-box")
    settings = RenderSettings(32, 24, make_sampler("stratified", 16), ["mc"], 5, 32 * 16)
    local, job = local_and_job(runtime, scene, settings)
    pids = list(cluster.client.run(os.getpid).values())
    killed = []

    def kill_a_worker_after_the_first_task(done, total):
        if not killed and done < total:
            os.kill(pids[-1], signal.SIGKILL)  # its nanny starts a new worker process
            killed.append(done)

    distributed = render_on(cluster, job, kill_a_worker_after_the_first_task, tasks=16)
    assert killed, "the render finished before a worker could be killed"
    assert_same_render(local, distributed)
    cluster.client.wait_for_workers(2, timeout=60)


def test_interrupt_keeps_the_finished_pixels(runtime, cluster):
    settings = RenderSettings(24, 16, make_sampler("sppp", 16), ["vor_sn"], 2, 24 * 16)
    local, job = local_and_job(runtime, "analytic:mix", settings)

    def interrupt_after_the_first_task(done, total):
        raise KeyboardInterrupt

    partial = render_on(cluster, job, interrupt_after_the_first_task, tasks=8)
    assert partial.stats.interrupted
    rendered = partial.film.rendered
    assert 0 < rendered.sum() < rendered.size
    local_pixels = local.film.pixels
    assert np.array_equal(partial.film.pixels[rendered], local_pixels[rendered])
    assert not partial.film.pixels[~rendered].any()


def test_an_interrupted_task_of_the_local_executor_ends_the_render(runtime, monkeypatch):
    """Ctrl-C during the second task of a render on the local executor (its tasks run here,
    and a task's pipeline catches the interrupt): the render stops there and says it was
    interrupted; the first range and the second's finished tile are kept, the rest is black
    (before: the task's unfinished pixels were recorded as rendered black ones, the next
    tasks ran, and the render said it was complete)."""
    from clrender import api, pipeline

    options = dict(spp=16, sampler="independent", estimator="mc", resolution=(24, 16), seed=2)
    local = api.render("analytic:mix", tile_samples=16 * 16, **options)
    per_tile = pixels_per_tile(local.settings)
    ranges = split_pixels(24 * 16, TASKS_PER_WORKER)
    second = ranges[1][0]
    assert ranges[1][1] - second >= 3 * per_tile
    real_tile_pixels = pipeline.tile_pixels
    starts = []

    def interrupting_tile_pixels(settings, start, end=None):
        starts.append(start)
        if start == second + 2 * per_tile:  # tile 2 of the second task: tile 0 recorded
            raise KeyboardInterrupt
        return real_tile_pixels(settings, start, end)

    monkeypatch.setattr(pipeline, "tile_pixels", interrupting_tile_pixels)
    with pytest.raises(api.RenderInterrupted) as info:
        api.render("analytic:mix", tile_samples=16 * 16, executor=LocalExecutor(), **options)
    partial = info.value.result
    assert partial.stats.interrupted
    assert max(starts) == second + 2 * per_tile  # no later tile, no later task
    kept = second + per_tile  # (tile 1, queued on the device, is dropped)
    film = partial.film
    assert film.rendered[:kept].all() and not film.rendered[kept:].any()
    assert np.array_equal(film.pixels[:kept], local.film.pixels[:kept])
    assert not film.pixels[kept:].any()
    assert partial.layers.samples[kept:].sum() == 0


def test_a_signal_as_a_local_task_hands_its_range_back_keeps_it(runtime, monkeypatch):
    """Ctrl-C while the second task of a render on the local executor gathers its finished
    range (after its pipeline returned): the range is kept whole and the render stops there,
    interrupted (before: the interrupt lost the whole range)."""
    from clrender import api, cluster

    options = dict(spp=16, sampler="independent", estimator="mc", resolution=(24, 16), seed=2)
    local = api.render("analytic:mix", tile_samples=16 * 16, **options)
    real_result, calls = cluster.PixelRangeResult, []

    def interrupted_result(*args):
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
        return real_result(*args)

    monkeypatch.setattr(cluster, "PixelRangeResult", interrupted_result)
    # Ctrl-C as at a terminal (a test run in the background ignores SIGINT)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(api.RenderInterrupted) as info:
            api.render("analytic:mix", tile_samples=16 * 16, executor=LocalExecutor(), **options)
        partial = info.value.result
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    kept = split_pixels(24 * 16, TASKS_PER_WORKER)[1][1]
    assert partial.stats.interrupted and len(calls) == 2
    assert partial.film.rendered[:kept].all() and not partial.film.rendered[kept:].any()
    assert np.array_equal(partial.film.pixels[:kept], local.film.pixels[:kept])


def test_local_cluster_workers_leave_ctrl_c_to_the_client(cluster):
    # Ctrl-C at a terminal reaches the workers of a LocalCluster too (one process group): they
    # ignore it, the client cancels the tasks and closes the cluster (before: each worker
    # printed a KeyboardInterrupt traceback)
    handlers = cluster.client.run(lambda: signal.getsignal(signal.SIGINT))
    assert len(handlers) == 2 and set(handlers.values()) == {signal.SIG_IGN}


def test_a_failing_task_names_the_worker_and_the_error_in_one_line(cluster):
    job = RenderJob(
        "analytic:mix", 8, 8, make_sampler("sppp", 4), ("vor_sn",), device="no-such-device"
    )
    failures_logged = worker_logs_mentioning(cluster, "Compute Failed")
    with pytest.raises(ClusterTaskError) as info:
        render_on(cluster, job, tasks=1)
    message = str(info.value)
    assert "\n" not in message
    assert "task failed on worker tcp://" in message
    assert "no-such-device" in message
    # The failure came back as a value: no worker logged a traceback for it
    assert worker_logs_mentioning(cluster, "Compute Failed") == failures_logged


def worker_logs_mentioning(cluster, text: str) -> int:
    """How many records of the workers' recent logs contain the text."""
    logs = cluster.client.get_worker_logs()
    return sum(text in message for records in logs.values() for _, message in records)


def test_the_recorded_device_is_the_tasks_devices_not_this_process(tmp_path, monkeypatch, capsys):
    # Tasks that ran on two devices other than this process's (a local executor runs them
    # here; the device each reports is faked): the JSON and EXR name those two, sorted, once
    from clrender import cluster
    from clrender.imageio import read_exr

    original = cluster.render_pixels

    def render_on_another_device(pixel_range, job):
        part = original(pixel_range, job)
        part.device = "device B [worker 2]" if pixel_range[0] == 0 else "device A [worker 1]"
        return part

    monkeypatch.setattr(cluster, "render_pixels", render_on_another_device)
    monkeypatch.setattr(cluster, "make_executor", lambda workers, scheduler: LocalExecutor())
    out = tmp_path / "cluster.exr"
    command = ["render", "analytic:mix", "--res", "16x8", "--spp", "8", "-o", str(out)]
    assert main([*command, "--workers", "1", "--json"]) == 0  # 4 tasks on the one "worker"
    both = "device A [worker 1]; device B [worker 2]"
    assert json.loads(capsys.readouterr().out)["device"] == both
    assert read_exr(out)[1]["device"] == both


def test_the_recorded_kernels_are_the_workers_and_other_ones_are_warned_of(
    tmp_path, monkeypatch, capsys
):
    # Tasks whose workers built other OpenCL sources than this process (a local executor
    # runs them here; the fingerprint each reports is faked, one older worker reports none):
    # the JSON and EXR record theirs, and one warning line says so
    from clrender import cluster
    from clrender.imageio import read_exr
    from clrender.provenance import kernels_fingerprint

    ours = kernels_fingerprint()
    original = cluster.render_pixels

    def render_with_other_kernels(pixel_range, job):
        part = original(pixel_range, job)
        assert part.kernels_sha256 == ours  # as a worker with this process's sources reports
        part.kernels_sha256 = None if pixel_range[0] == 0 else "0123456789abcdef"
        return part

    monkeypatch.setattr(cluster, "render_pixels", render_with_other_kernels)
    monkeypatch.setattr(cluster, "make_executor", lambda workers, scheduler: LocalExecutor())
    out = tmp_path / "cluster.exr"
    command = ["render", "analytic:mix", "--res", "16x8", "--spp", "8", "-o", str(out)]
    assert main([*command, "--workers", "1", "--json"]) == 0
    theirs = "0123456789abcdef; unknown (an older worker)"
    captured = capsys.readouterr()
    (image,) = json.loads(captured.out)["images"].values()
    assert image["metadata"]["kernels_sha256"] == theirs
    assert read_exr(out)[1]["kernels_sha256"] == theirs
    warning = f"the workers built other OpenCL sources (kernels {theirs}) than this clrender"
    assert captured.err.count("\n") == 1 and warning in captured.err, captured.err
    # Workers with this process's sources: recorded as such, no warning
    monkeypatch.setattr(cluster, "render_pixels", original)
    assert main([*command, "--workers", "1", "--json"]) == 0
    captured = capsys.readouterr()
    (image,) = json.loads(captured.out)["images"].values()
    assert image["metadata"]["kernels_sha256"] == ours == read_exr(out)[1]["kernels_sha256"]
    assert "warning" not in captured.err


def test_an_api_render_on_workers_with_other_kernels_warns(monkeypatch):
    # The same through clrender.render: a KernelsWarning, the workers' fingerprint recorded;
    # workers that match but for an older one that cannot tell get a warning that says so
    import clrender
    from clrender import cluster
    from clrender.provenance import KernelsWarning, kernels_fingerprint

    ours = kernels_fingerprint()
    original = cluster.render_pixels
    reported = {"other": "0123456789abcdef", "older": None}
    kind = []

    def render_with_reported_kernels(pixel_range, job):
        part = original(pixel_range, job)
        if pixel_range[0] == 0:
            part.kernels_sha256 = reported[kind[-1]]
        return part

    monkeypatch.setattr(cluster, "render_pixels", render_with_reported_kernels)
    options = dict(spp=4, resolution=(16, 8), tile_samples=16 * 16, executor=LocalExecutor())
    kind.append("other")
    with pytest.warns(KernelsWarning, match="the workers built other OpenCL sources"):
        result = clrender.render("analytic:mix", **options)
    assert result.kernels_sha256 == result.labels.kernels_sha256
    assert set(result.kernels_sha256.split("; ")) == {"0123456789abcdef", ours}
    kind.append("older")
    with pytest.warns(KernelsWarning, match="a worker could not tell which OpenCL sources"):
        result = clrender.render("analytic:mix", **options)
    assert result.labels.kernels_sha256 == f"{ours}; unknown (an older worker)"


def test_the_recorded_code_is_the_workers_and_other_code_is_warned_of(
    tmp_path, monkeypatch, capsys
):
    # Tasks whose workers ran other clrender code than this process (faked as the kernels
    # above; one older worker reports none): the JSON and EXR record theirs, one warning line
    # says so; with the kernels differing too, the one line says both
    from clrender import cluster
    from clrender.imageio import read_exr
    from clrender.provenance import code_fingerprint, kernels_fingerprint

    ours = code_fingerprint()
    original = cluster.render_pixels
    other_kernels = []

    def render_with_other_code(pixel_range, job):
        part = original(pixel_range, job)
        assert part.code_sha256 == ours  # as a worker running this process's code reports
        part.code_sha256 = None if pixel_range[0] == 0 else "0123456789abcdef"
        if other_kernels:
            part.kernels_sha256 = "fedcba9876543210"
        return part

    monkeypatch.setattr(cluster, "render_pixels", render_with_other_code)
    monkeypatch.setattr(cluster, "make_executor", lambda workers, scheduler: LocalExecutor())
    out = tmp_path / "cluster.exr"
    command = ["render", "analytic:mix", "--res", "16x8", "--spp", "8", "-o", str(out)]
    assert main([*command, "--workers", "1", "--json"]) == 0
    theirs = "0123456789abcdef; unknown (an older worker)"
    captured = capsys.readouterr()
    (image,) = json.loads(captured.out)["images"].values()
    assert image["metadata"]["code_sha256"] == theirs == read_exr(out)[1]["code_sha256"]
    assert image["metadata"]["kernels_sha256"] == kernels_fingerprint()
    warning = f"the workers ran other clrender code (code {theirs}) than this clrender ({ours})"
    assert captured.err.count("\n") == 1 and warning in captured.err, captured.err
    assert "OpenCL" not in captured.err
    other_kernels.append(True)
    assert main([*command, "--workers", "1", "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and warning in captured.err, captured.err
    assert "built other OpenCL sources (kernels fedcba9876543210)" in captured.err
    assert read_exr(out)[1]["kernels_sha256"] == "fedcba9876543210"
    # Workers running this process's code: recorded as such, no warning
    monkeypatch.setattr(cluster, "render_pixels", original)
    assert main([*command, "--workers", "1", "--json"]) == 0
    captured = capsys.readouterr()
    (image,) = json.loads(captured.out)["images"].values()
    assert image["metadata"]["code_sha256"] == ours == read_exr(out)[1]["code_sha256"]
    assert "warning" not in captured.err


def test_an_api_render_on_workers_with_other_code_warns(monkeypatch):
    # The same through clrender.render: a ProvenanceWarning (not a KernelsWarning: the kernels
    # agree), the workers' fingerprint recorded; an older worker that cannot tell is warned of
    import warnings

    import clrender
    from clrender import cluster
    from clrender.provenance import ProvenanceWarning, code_fingerprint

    ours = code_fingerprint()
    original = cluster.render_pixels
    reported = {"other": "0123456789abcdef", "older": None}
    kind = []

    def render_with_reported_code(pixel_range, job):
        part = original(pixel_range, job)
        if pixel_range[0] == 0:
            part.code_sha256 = reported[kind[-1]]
        return part

    monkeypatch.setattr(cluster, "render_pixels", render_with_reported_code)
    options = dict(spp=4, resolution=(16, 8), tile_samples=16 * 16, executor=LocalExecutor())
    for name, match in (
        ("other", "the workers ran other clrender code"),
        ("older", "a worker could not tell which clrender code it ran"),
    ):
        kind.append(name)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = clrender.render("analytic:mix", **options)
        (provenance,) = (w.message for w in caught if isinstance(w.message, ProvenanceWarning))
        assert type(provenance) is ProvenanceWarning and match in str(provenance)
        assert result.code_sha256 == result.labels.code_sha256
        other = reported[name] or "unknown (an older worker)"
        assert set(result.code_sha256.split("; ")) == {other, ours}


def test_cluster_timings_keep_the_workers_set_up_apart(monkeypatch):
    # Two "workers" (tasks alternate between two names), each slowed by 0.2 s of set-up in
    # its first task: the render waits for the longest worker's set-up, not their sum, and
    # paths/s leaves it out
    from clrender import cluster
    from clrender.report import RenderLabels, summary_json

    original_source_for = cluster._source_for
    names = iter(["w1", "w2"] * 4)
    current = []
    set_up = set()

    def worker_name():
        return current[-1]

    def slow_source_for(job):
        current.append(next(names))
        if current[-1] not in set_up:
            set_up.add(current[-1])
            time.sleep(0.2)
        return original_source_for(job)

    parts = []
    original = cluster.render_pixels

    def recorded(pixel_range, job):
        parts.append(original(pixel_range, job))
        return parts[-1]

    monkeypatch.setattr(cluster, "worker_name", worker_name)
    monkeypatch.setattr(cluster, "_source_for", slow_source_for)
    monkeypatch.setattr(cluster, "render_pixels", recorded)
    settings = RenderSettings(16, 8, make_sampler("sppp", 8), ["mc"], 1)
    job = RenderJob("analytic:mix", 16, 8, settings.sampler, ("mc",), 1)
    result = render_on(LocalExecutor(), job, tasks=8)
    stats = result.stats
    by_worker = {
        name: sum(part.setup_seconds for part in parts if part.worker == name)
        for name in ("w1", "w2")
    }
    assert min(by_worker.values()) >= 0.2
    assert stats.worker_setup_seconds == max(by_worker.values())
    assert stats.main_compile_seconds == 0.0  # the tasks' builds are in their set-up
    assert stats.run_seconds == stats.wall_seconds - stats.worker_setup_seconds
    assert stats.run_seconds <= stats.wall_seconds - 0.2
    summary = summary_json(result, RenderLabels("analytic:mix", result.device, None), {}, {}, None)
    assert summary["timings"]["worker_setup_s"] == stats.worker_setup_seconds
    assert summary["paths_per_second"] == stats.traced_samples / stats.run_seconds


def test_pixels_split_into_consecutive_ranges():
    assert split_pixels(100, 3) == [(0, 33), (33, 66), (66, 100)]
    assert split_pixels(2, 5) == [(0, 1), (1, 2)]
    assert split_pixels(7, 1) == [(0, 7)]


def test_executor_choice_and_bad_requests(monkeypatch):
    assert isinstance(make_executor(None, None), LocalExecutor)
    with pytest.raises(ParameterError, match="not both"):
        make_executor(2, "tcp://127.0.0.1:1")
    with pytest.raises(ParameterError, match="positive integer"):
        make_executor(0, None)
    monkeypatch.setattr("clrender.cluster.CONNECT_TIMEOUT_S", 1)
    with pytest.raises(ClusterError, match=r"no Dask scheduler at tcp://127.0.0.1:9"):
        make_executor(None, "tcp://127.0.0.1:9")
    for address in ("garbage", "", "http://x:1", "tcp://127.0.0.1:99999"):
        with pytest.raises(ParameterError, match="is not a Dask scheduler address"):
            make_executor(None, address)
    import distributed

    # TLS without a security configuration: the TypeError distributed raised
    with monkeypatch.context() as patch:
        patch.setattr(distributed, "Client", failing_client(TypeError("TLS expects a ssl_context")))
        with pytest.raises(ClusterError, match="^cannot connect to tls://127.0.0.1:9: TypeError"):
            make_executor(None, "tls://127.0.0.1:9")
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ClusterError, match=r"pip install 'dask\[distributed\]'"):
        make_executor(2, None)


def failing_client(error: BaseException):
    """A stand-in for distributed.Client that fails as the real one did at such an address
    (a real Client per case would start an IO loop thread each, which under a full suite's
    load now and then failed to start within distributed's 10 s: an AssertionError)."""

    def client(*args, **kwargs):
        raise error

    return client


def test_a_service_that_is_not_a_scheduler_is_named_as_such(monkeypatch):
    """A port whose server speaks first (an SSH banner) is not Dask's: one line, not the
    'out of host memory' of a length read from its bytes (distributed's MemoryError, seen
    with a real banner server: 'Unable to allocate 2.82 EiB')."""
    import distributed

    error = MemoryError(
        "Unable to allocate 2.82 EiB for an array with shape (3255307777713450285,)"
    )
    monkeypatch.setattr(distributed, "Client", failing_client(error))
    with pytest.raises(ClusterError, match="answered, but not as a Dask scheduler"):
        make_executor(None, "tcp://127.0.0.1:22")


def test_a_cluster_failure_is_one_line(cluster, monkeypatch):
    """Dask's own failures (a task whose workers kept dying: KilledWorker; a lost scheduler:
    a cancelled future) end the render with one ClusterError line, not a traceback."""
    import distributed
    from distributed.scheduler import KilledWorker

    class Failed:
        def __init__(self, future):
            self.key = future.key

        def result(self):
            raise KilledWorker("clrender-x-0", SimpleNamespace(address="tcp://127.0.0.1:1"), 3)

    monkeypatch.setattr(distributed, "as_completed", lambda futures: map(Failed, futures))
    job = RenderJob("analytic:mix", 8, 8, make_sampler("sppp", 4), ("vor_sn",))
    with pytest.raises(ClusterError, match="^the cluster failed: KilledWorker: ") as info:
        render_on(cluster, job, tasks=1)
    assert "\n" not in str(info.value)


def test_command_line_render_on_two_workers_matches_the_local_one(tmp_path, capsys):
    from clrender.imageio import read_exr

    common = ["render", "analytic:mix", "--res", "16x8", "--spp", "8", "--quiet"]
    assert main([*common, "-o", str(tmp_path / "local.exr")]) == 0
    assert main([*common, "--workers", "2", "-o", str(tmp_path / "cluster.exr")]) == 0
    local, _ = read_exr(tmp_path / "local.exr")
    distributed, metadata = read_exr(tmp_path / "cluster.exr")
    assert np.array_equal(local, distributed)
    assert main([*common, "--workers", "0"]) == 2
    assert "--workers must be a positive integer" in capsys.readouterr().err


def test_analytic_study_slice_gives_the_same_numbers_locally_and_on_the_cluster(cluster):
    bench = str(Path(__file__).resolve().parents[1] / "bench")
    if bench not in sys.path:
        sys.path.insert(0, bench)
    import analytic_study

    # 3 batches of 5 runs at n = 16 (80 points a batch); the cluster runs them as 3 tasks
    local, local_stats = analytic_study.run_estimates(16, 13, (9, 2), None, 80)
    remote, remote_stats = analytic_study.run_estimates(16, 13, (9, 2), cluster, 80)
    assert local_stats == remote_stats
    for name, values in local.items():
        assert values.shape == (13, 6)
        assert np.array_equal(remote[name], values, equal_nan=True), name
    # The stream decides the numbers: another one gives others
    other, _ = analytic_study.run_estimates(16, 13, (9, 3), None, 80)
    assert not np.array_equal(other["mc"], local["mc"])


def test_the_python_api_renders_on_an_executor(cluster):
    import clrender

    kwargs = dict(spp=8, estimators=["vor_sn", "mc_n"], resolution=(16, 12), seed=4)
    local = clrender.render("cornell-box", **kwargs)
    distributed = clrender.render("cornell-box", executor=cluster, **kwargs)
    assert_same_render(local, distributed)
    assert (distributed.max_depth, distributed.russian_roulette) == (local.max_depth, False)
    assert distributed.device == local.device  # the workers' device (same PYOPENCL_CTX here)
    assert local.max_depth == DEFAULT_MAX_DEPTH


def without_local_opencl(patch) -> None:
    """This process as a client with no OpenCL device (a laptop driving a GPU cluster): no
    platform to list, and the runtimes its earlier tests cached out of reach."""
    import pyopencl

    from clrender import api, runtime
    from clrender.errors import DeviceError

    def no_opencl(*args, **kwargs):
        raise DeviceError(runtime.INSTALL_HINT)

    patch.setattr(pyopencl, "get_platforms", no_opencl)
    patch.setattr(runtime, "list_devices", no_opencl)
    patch.setattr(api, "runtime_for", no_opencl)


def test_a_client_without_opencl_renders_on_the_workers_devices(runtime, cluster, monkeypatch):
    import clrender
    from clrender.estimators.device_cells import resolve_precision
    from clrender.provenance import code_fingerprint, kernels_fingerprint

    kwargs = dict(spp=8, estimators=["vor_sn", "mc_n"], resolution=12, seed=2)
    local = clrender.render("cornell-box", **kwargs)
    with monkeypatch.context() as patch:
        without_local_opencl(patch)
        with pytest.raises(ClrenderError, match="no OpenCL platform"):
            clrender.render("cornell-box", **kwargs)  # (the patch holds: nothing local renders)
        distributed = clrender.render("cornell-box", executor=cluster, **kwargs)
    assert (distributed.settings.width, distributed.settings.height) == (12, 12)
    assert_same_render(local, distributed)
    # the device and precision recorded are those the workers rendered with
    precision = resolve_precision(runtime, "auto")
    assert distributed.device == runtime.describe()
    assert distributed.device_precision == precision == local.device_precision
    assert distributed.labels.device == runtime.describe()
    assert distributed.labels.device_precision == precision
    # the kernels too: the workers' sources, here this process's
    assert distributed.kernels_sha256 == kernels_fingerprint() == distributed.labels.kernels_sha256
    # and the code: the workers import clrender from this checkout too
    assert distributed.code_sha256 == code_fingerprint() == distributed.labels.code_sha256


def test_a_command_line_client_without_opencl_drives_the_cluster(
    runtime, cluster, monkeypatch, tmp_path, capsys
):
    from clrender.estimators.device_cells import resolve_precision
    from clrender.imageio import read_exr

    common = ["render", "analytic:mix", "--res", "16x8", "--spp", "8", "-o"]
    assert main([*common, str(tmp_path / "local.exr"), "--quiet"]) == 0
    address = ["--scheduler", cluster.client.scheduler.address]
    with monkeypatch.context() as patch:
        without_local_opencl(patch)
        assert main([*common, str(tmp_path / "cluster.exr"), *address, "--json"]) == 0
        summary = json.loads(capsys.readouterr().out)
        # a device the workers lack is reported by them, in one line
        bad_device = [*common, str(tmp_path / "bad.exr"), *address, "--device", "no-such-gpu"]
        assert main(bad_device) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "task failed on worker tcp://" in error, error
    assert "'no-such-gpu' matches nothing" in error
    local, _ = read_exr(tmp_path / "local.exr")
    distributed, metadata = read_exr(tmp_path / "cluster.exr")
    assert np.array_equal(local, distributed)
    assert summary["device"] == metadata["device"] == runtime.describe()
    assert sum(summary["tasks_by_worker"].values()) == 8  # 4 a worker
    assert metadata["device_precision"] == resolve_precision(runtime, "auto")
    # the analytic image's exact pixel integrals, computed here without a device
    assert summary["images"]["vor_sn"]["errors"]["reference"] == "exact pixel integrals"
    assert summary["images"]["vor_sn"]["errors"]["mse"] > 0


def test_tasks_are_dealt_out_to_the_workers_threads_in_turn():
    from clrender.cluster import task_placement

    a, b = "tcp://a", "tcp://b"
    assert task_placement({b: 1, a: 1}, 5) == [a, b, a, b, a]
    assert task_placement({a: 2, b: 1}, 4) == [a, a, b, a]
    assert task_placement({}, 3) is None


def test_render_tasks_start_spread_over_the_workers_and_record_where_they_ran(cluster, monkeypatch):
    # The shared job is held by one worker, where Dask would start every task: each task is
    # offered to the workers in turn instead (a loose restriction: another worker may take it)
    settings = RenderSettings(16, 16, make_sampler("stratified", 4), ["mc"], 1)
    job = RenderJob.of(load_scene("cornell-box"), settings, MAX_DEPTH)
    submitted = []
    submit = cluster.client.submit

    def recorded_submit(*args, **kwargs):
        submitted.append(kwargs)
        return submit(*args, **kwargs)

    monkeypatch.setattr(cluster.client, "submit", recorded_submit)
    result = render_on(cluster, job, tasks=8)
    workers = sorted(cluster.client.nthreads())
    tasks = [kwargs for kwargs in submitted if kwargs.get("key", "").startswith("clrender-")]
    assert [kwargs["workers"] for kwargs in tasks] == [[workers[k % 2]] for k in range(8)]
    assert all(kwargs["allow_other_workers"] for kwargs in tasks)
    # Each worker ran some of the 8 tasks (a worker starts its first task at once: work
    # stealing may move a queued one, never that), and the result says how many
    assert sorted(result.tasks_by_worker) == workers
    assert min(result.tasks_by_worker.values()) >= 1
    assert sum(result.tasks_by_worker.values()) == 8
