"""Single-pixel study on the authors' Cornell box, its glossy variant and Veach's MIS scene:
the paper's Figures 6 and 9, over every sampler.

    python bench/pixel_study.py [--quick] [--runs R] [--spp 64 128 ...] [--pixels NAME ...]
                                [--batch-runs B] [--workers N | --scheduler ADDRESS] [--out DIR]

Pixels found from the scenes' geometry (clrender.probes, never hard-coded), each in its scene
(PROBES): in cornell-box, one the light's outline crosses (light covering closest to half of
it), one deep inside the lit part of the back wall, one seeing the glass ball's centre, and one
of the floor that the tall box's shadow boundary crosses (the visible share of the light
changes most across it); in cornell-box-glossy, one on the edge of the glossy box's highlight,
found in a short deterministic render (mc over Sobol points, SHORT_RENDER_SPP spp, seed
SHORT_RENDER_SEED); in veach-mis, where the outlines of the large and medium spherical lights
cross (light covering closest to half), and on the glossy reflections of the lights (the
light's centre mirrored in a plate's plane, projected): large on the smooth plate (alpha 0.01),
medium on the glossy one (0.05), small on both. --pixels picks some of them (default all). For
each pixel and spp, R independent estimates of every (estimator, sampler) of GROUPS: mc, cvor
and pvor over independent samples; mc over stratified, stratified-pixel, sobol and zsobol; pvor
over stratified and sobol points with a random toroidal shift per run (as the render settings
do for it); mc_n, vor, vor_sn and fvor over sppp and sppp-sobol. A sampler is skipped at a
count it does not take (stratified: squares; zsobol: powers of two). Run r of a point (pixel,
sampler, spp) is redraw number r of its (seed, pixel), an independent randomisation (zsobol's
key includes it too); runs are drawn, traced and estimated by tasks of --batch-runs runs
(default BATCH_RUNS), each estimator applied to ESTIMATE_RUNS runs at a time (estimate_all:
estimators sharing a tessellation share it). SPPP runs a Voronoi estimator rejects (an
unbounded W cell) are replaced by further runs, as the paper's redraw does; all SPPP estimators
of a sampler use the same accepted runs, the first R in run order.

Where it runs: the tasks of one pixel (all its points, then any redraw rounds) go to the
executor of --workers N (a Dask LocalCluster of N processes) or --scheduler ADDRESS (an
existing cluster), this process by default; the scene travels as its loaded records, each
worker opens its own device and sends back NumPy arrays. A run's random numbers are keyed by
(seed, pixel, sample, dimension, redraw = run), and its estimate block is fixed by its index,
so every number but the times is bit-identical whatever the executor and --batch-runs
(tests/test_cluster_studies.py). Before the executor, each point's runs were estimated in one
batch: the Qhull estimators' last bits depend on a run's company in a batch, so the Voronoi
estimates can differ from that version's in their last bits (the runs traced are the same).

Timings: the estimator and device-cell times are taken in this process, once a pixel's tasks
are done (the cluster idle), on the point's first --timing-runs runs, whose sample sets the
tasks send back: timings on workers that share the cores would not be comparable. The
tracing time is the tasks' own (draw + trace + download of each launch, summed, per run),
measured where they ran: on a LocalCluster sharing this machine's cores it includes that
contention (results.json's settings name the executor).

The value of a pixel is the mean of its RGB channels. Per (pixel, estimator/sampler, spp):
mean, std and variance over the R runs; milliseconds per estimate of the estimator alone (each
estimator run alone on the first --timing-runs runs, the fastest of >= 3 calls / runs;
tessellation + sums, on the host) and of tracing (see Timings); variance against their sum;
ratios to mc/independent. And the Voronoi question: per pixel and spp, each Voronoi estimator
over low-discrepancy samples (VORONOI_LD) against the best low-discrepancy mc (LD_MC, the
lowest variance at that spp): var(best) / var(estimator) with a 95 % bootstrap interval, the
efficiency ratio, and wins / loses / tie. Outputs (default bench/results/pixel_study/):
results.json, report.md, fig6_<pixel>.png (mean +- std against spp), fig9_<pixel>.png (time
against spp, variance against time, each variance with its 95 % bootstrap interval over the R
runs: var_ci in results.json), each figure with a caption of its parameters (in the figure and
under it in the report).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from itertools import pairwise
from pathlib import Path
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from bootstrap import ratio_interval, statistic_interval  # noqa: E402
from common import (  # noqa: E402
    MAX_DEPTH,
    RESULTS,
    add_executor_options,
    command_line,
    executor_from_args,
    executor_label,
    machine,
    make_tracer,
    markdown_table,
    timed_render,
    write_json,
)
from figures import caption, draw_caption, report_caption, save_figure  # noqa: E402

from clrender.api import runtime_for  # noqa: E402
from clrender.estimators import ESTIMATORS, estimate, estimate_all  # noqa: E402
from clrender.estimators.device_cells import device_sppp_cells_from_arrays  # noqa: E402
from clrender.probes import (  # noqa: E402
    PixelRuns,
    ProbePixel,
    diffuse_wall_pixel,
    glossy_highlight_edge_pixel,
    glossy_reflection_pixel,
    light_edge_pixel,
    shadow_boundary_pixel,
    sphere_light_edge_pixel,
    sphere_pixel,
    trace_pixel_runs,
)
from clrender.radiance import PathTracerSource  # noqa: E402
from clrender.samples import SampleSets  # noqa: E402
from clrender.sampling import SAMPLERS, SamplerConfig, make_sampler  # noqa: E402
from clrender.scene import Scene  # noqa: E402
from clrender.trace import PathTracer  # noqa: E402


@dataclass(frozen=True)
class Probe:
    """A pixel of the study: its scene and its finder (clrender.probes), called with (scene,
    width, height), or with (scene, short render) when it reads a render."""

    scene: str
    finder: Callable[..., ProbePixel]
    reads_render: bool = False


PROBES = {
    "light_edge": Probe("cornell-box", light_edge_pixel),
    "diffuse_wall": Probe("cornell-box", diffuse_wall_pixel),
    "glass_ball": Probe("cornell-box", sphere_pixel),
    "shadow_boundary": Probe("cornell-box", shadow_boundary_pixel),
    "glossy_highlight_edge": Probe(
        "cornell-box-glossy", glossy_highlight_edge_pixel, reads_render=True
    ),
    # veach-mis: emitters 0, 1, 2 are the spheres of radius 1, 0.5, 0.05
    "veach_large_light_edge": Probe("veach-mis", partial(sphere_light_edge_pixel, emitter=0)),
    "veach_medium_light_edge": Probe("veach-mis", partial(sphere_light_edge_pixel, emitter=1)),
    "veach_large_on_smooth": Probe(
        "veach-mis", partial(glossy_reflection_pixel, emitter=0, material="Smooth")
    ),
    "veach_medium_on_glossy": Probe(
        "veach-mis", partial(glossy_reflection_pixel, emitter=1, material="Glossy")
    ),
    "veach_small_on_smooth": Probe(
        "veach-mis", partial(glossy_reflection_pixel, emitter=2, material="Smooth")
    ),
    "veach_small_on_glossy": Probe(
        "veach-mis", partial(glossy_reflection_pixel, emitter=2, material="Glossy")
    ),
}
# The short render a finder reads: mc over Sobol points, a fixed seed (deterministic).
SHORT_RENDER_SPP = 256
SHORT_RENDER_SEED = 3


@dataclass(frozen=True)
class Group:
    """Runs of one sampler (toroidally shifted per run for pvor over low-discrepancy points, as
    the render settings do) and the estimators applied to them; labels "estimator/sampler"."""

    sampler: str
    estimators: tuple[str, ...]
    shift: bool = False
    seed: int = 0

    @property
    def key(self) -> str:
        return f"{self.sampler}+shift" if self.shift else self.sampler


GROUPS = [
    Group("independent", ("mc", "cvor", "pvor"), seed=11),
    Group("stratified", ("mc",), seed=12),
    Group("stratified", ("pvor",), shift=True, seed=14),
    Group("stratified-pixel", ("mc",), seed=15),
    Group("sobol", ("mc",), seed=16),
    Group("sobol", ("pvor",), shift=True, seed=17),
    Group("zsobol", ("mc",), seed=18),
    Group("sppp", ("mc_n", "vor", "vor_sn", "fvor"), seed=13),
    Group("sppp-sobol", ("mc_n", "vor", "vor_sn", "fvor"), seed=19),
]
BASELINE = "mc/independent"
# The reference of a pixel: this estimator's pooled mean at the highest spp.
REFERENCE_LABEL = "mc/sobol"
# Low-discrepancy Monte Carlo, and Voronoi weighting over low-discrepancy samples (pvor over
# stratified or Sobol positions; the SPPP-cell estimators over Poisson positions with Sobol
# paths): compared per pixel and spp in voronoi_vs_ld.
LD_MC = ("mc/stratified", "mc/sobol", "mc/zsobol")
VORONOI_LD = (
    "pvor/stratified",
    "pvor/sobol",
    "vor/sppp-sobol",
    "vor_sn/sppp-sobol",
    "fvor/sppp-sobol",
)
BOOTSTRAP = 2000
# Runs per task: a few tasks per point at the default R (200), so that one pixel's points keep
# two workers busy; the numbers do not depend on it.
BATCH_RUNS = 64
# Runs estimated together (one estimate_all call). The Qhull estimators pack a call's pixels
# into shared Qhull calls and size their ghost margins from its mean count, which changes the
# last bits of a run's estimate with its company: so the blocks are fixed by the run index
# (runs [16 k, 16 k + 16) of a round), whatever the tasks, and the numbers are bit-identical
# for every --batch-runs (a multiple of it) and every executor.
ESTIMATE_RUNS = 16
BOOTSTRAP_ERROR_BARS = 1000  # resamples behind a variance's error bar
# The estimators of SPPP cells (vor, vor_sn, fvor): they reject runs with an unbounded W cell,
# and the device kernel can compute their cells.
REJECTING = tuple(name for name, entry in ESTIMATORS.items() if entry.cells == "sppp")


def usable(group: Group, spp: int) -> bool:
    """Whether the group's sampler takes spp samples per pixel."""
    counts = SAMPLERS[group.sampler].counts
    if counts == "square":
        return math.isqrt(spp) ** 2 == spp
    if counts == "power of two":
        return spp & (spp - 1) == 0
    return True


class Study:
    def __init__(self, args):
        self.args = args
        # The tasks of the local executor share this runtime (its compiled programs)
        self.runtime = runtime_for(None)
        scenes = dict.fromkeys(PROBES[name].scene for name in args.pixels)
        self.tracers = {scene: make_tracer(self.runtime, scene) for scene in scenes}
        self.size = args.size
        for tracer in self.tracers.values():  # warm-up: kernel builds are not timed
            for group in GROUPS:
                trace_pixel_runs(
                    self.runtime, tracer, sampler_of(group, 16), 0, 0, 2, self.size, self.size
                )

    def find_pixel(self, probe: Probe) -> ProbePixel:
        scene = self.tracers[probe.scene].scene
        if probe.reads_render:
            return probe.finder(scene, self.short_render(probe.scene))
        return probe.finder(scene, self.size, self.size)

    def short_render(self, scene: str) -> np.ndarray:
        """(size, size, 3) render of the scene for a finder that reads one."""
        source = PathTracerSource(self.tracers[scene], self.size, self.size)
        image, _ = timed_render(
            self.runtime, source, "mc", "sobol", SHORT_RENDER_SPP, SHORT_RENDER_SEED
        )
        return image

    def points(self, scene: str, pixel: int, executor) -> dict[tuple[int, str], dict]:
        """{(spp, group key): {label: {"values": (R,), "estimator_ms", "trace_ms", ...}}} for
        every usable (spp, group) of a pixel: the runs on the executor, then the timings here."""
        points = [(spp, group) for spp in self.args.spp for group in GROUPS if usable(group, spp)]
        scene_data = self.tracers[scene].scene
        shared = executor.share(scene_data) if hasattr(executor, "share") else scene_data
        runs = gather_runs(
            executor,
            shared,
            [point_of(group, spp, pixel, self.args) for spp, group in points],
            self.args.runs,
            self.args.batch_runs,
        )
        return {
            (spp, group.key): self.timed(group, spp, point)
            for (spp, group), point in zip(points, runs, strict=True)
        }

    def timed(self, group: Group, spp: int, point: PointRuns) -> dict:
        """A point's entries, with the times of its estimators taken here (see the module's
        docstring: Timings)."""
        sampler = sampler_of(group, spp)
        names = group.estimators
        timing, timing_values = point.timing
        seconds = {
            name: min_seconds(lambda name=name: estimate(name, timing, timing_values))
            / timing.pixel_count
            for name in names
        }
        device = device_times(self.runtime, timing, timing_values, sampler, names)
        return {
            f"{name}/{group.sampler}": {
                "values": point.values[name],
                "estimator_ms": 1e3 * seconds[name],
                "trace_ms": 1e3 * point.trace_seconds / point.drawn,
                "rejected_runs": point.drawn - point.accepted,
                "device_cells_ms": 1e3 * device[name] if name in REJECTING else None,
            }
            for name in names
        }


def sampler_of(group: Group, spp: int):
    return replace(make_sampler(group.sampler, spp), toroidal_shift=group.shift)


# ---------------------------------------------------------------------------------------------
# Runs on the executor


@dataclass(frozen=True)
class Point:
    """One (pixel, sampler group, spp) of the study, as plain data for the tasks."""

    sampler: SamplerConfig
    estimators: tuple[str, ...]
    seed: int
    pixel: int
    size: int
    timing_runs: int


def point_of(group: Group, spp: int, pixel: int, args) -> Point:
    return Point(
        sampler_of(group, spp),
        group.estimators,
        args.seed + group.seed,
        pixel,
        args.size,
        args.timing_runs,
    )


@dataclass(frozen=True)
class RunBatch:
    """Runs [first, first + count) of a point: one task."""

    index: int  # the point's, in the study's list
    point: Point
    first: int
    count: int


@dataclass
class BatchResult:
    """A task's estimates of its runs (count,) per estimator, which runs an SPPP-cell estimator
    rejected, the device time of the launch, and the sample sets of its runs below the point's
    timing_runs (for the timings, taken by the client) with their values."""

    estimates: dict[str, np.ndarray]
    rejected: np.ndarray
    trace_seconds: float
    timing: tuple[SampleSets, np.ndarray] | None


def trace_batch(batch: RunBatch, scene: Scene) -> BatchResult:
    """Draw, trace and estimate runs [first, first + count) of a point on this process's
    runtime. Run r is redraw number r of the point's (seed, pixel), so its estimates do not
    depend on which task or worker computes it."""
    point = batch.point
    runtime = runtime_for(None)
    tracer = PathTracer(runtime, scene, max_depth=MAX_DEPTH)
    args = (runtime, tracer, point.sampler, point.seed, point.pixel)
    # One untimed run first: a worker's first launch of a sampler builds its kernels
    trace_pixel_runs(*args, 1, point.size, point.size, batch.first)
    runs = trace_pixel_runs(*args, batch.count, point.size, point.size, batch.first)
    # Estimate in blocks of ESTIMATE_RUNS runs aligned to the run index (see ESTIMATE_RUNS)
    estimates = {name: [] for name in point.estimators}
    rejected = []
    for start, end in estimate_blocks(batch.first, batch.count):
        samples, values = pixel_samples(runs, point.sampler, start, end)
        results = estimate_all(list(point.estimators), samples, values)
        rejected.append(np.zeros(end - start, bool))
        for name in point.estimators:
            estimates[name].append(results[name].estimates)
            if name in REJECTING:
                rejected[-1] |= results[name].needs_redraw
    timed = min(max(point.timing_runs - batch.first, 0), batch.count)
    return BatchResult(
        {name: np.concatenate(parts) for name, parts in estimates.items()},
        np.concatenate(rejected),
        runs.trace_seconds,
        pixel_samples(runs, point.sampler, 0, timed) if timed else None,
    )


def estimate_blocks(first: int, count: int) -> list[tuple[int, int]]:
    """[start, end) of the estimate blocks of runs [first, first + count), relative to first:
    cut at every multiple of ESTIMATE_RUNS."""
    cuts = range((first // ESTIMATE_RUNS + 1) * ESTIMATE_RUNS, first + count, ESTIMATE_RUNS)
    bounds = [first, *cuts, first + count]
    return [(a - first, b - first) for a, b in pairwise(bounds) if b > a]


@dataclass
class PointRuns:
    """The first R accepted runs of a point (values per estimator), how many runs were drawn
    and accepted, the summed device time, and the timing runs (sample sets, values)."""

    values: dict[str, np.ndarray]
    drawn: int
    accepted: int
    trace_seconds: float
    timing: tuple[SampleSets, np.ndarray]


def split_runs(index: int, point: Point, first: int, count: int, batch_runs: int) -> list[RunBatch]:
    """Tasks of runs [first, first + count), cut at every multiple of batch_runs (itself a
    multiple of ESTIMATE_RUNS, so that a task never splits an estimate block)."""
    cuts = range((first // batch_runs + 1) * batch_runs, first + count, batch_runs)
    bounds = [first, *cuts, first + count]
    return [RunBatch(index, point, a, b - a) for a, b in pairwise(bounds) if b > a]


def gather_runs(
    executor, scene, points: list[Point], runs: int, batch_runs: int
) -> list[PointRuns]:
    """R accepted runs of every point, in rounds of tasks of at most batch_runs runs each:
    round one draws R runs of each point (and a few spare ones for SPPP samplers, whose
    Voronoi estimators reject some), each further round as many more as a point still
    lacks (plus the spare). A point keeps its first R accepted runs in run order, so the
    numbers depend neither on batch_runs nor on where the tasks ran."""
    spare = [max(4, runs // 20) if point.sampler.is_sppp else 0 for point in points]
    parts: list[list[tuple[int, BatchResult]]] = [[] for _ in points]
    drawn = [0] * len(points)
    accepted = [0] * len(points)
    wanted = {index: runs + spare[index] for index in range(len(points))}
    while wanted:
        batches = [
            batch
            for index, count in wanted.items()
            for batch in split_runs(index, points[index], drawn[index], count, batch_runs)
        ]
        for task, result in executor.map(trace_batch, batches, scene):
            batch = batches[task]
            parts[batch.index].append((batch.first, result))
            accepted[batch.index] += int((~result.rejected).sum())
        for index, count in wanted.items():
            drawn[index] += count
        wanted = {
            index: runs - accepted[index] + spare[index]
            for index in range(len(points))
            if accepted[index] < runs
        }
    return [
        point_runs(
            point, sorted(part, key=lambda item: item[0]), drawn[index], accepted[index], runs
        )
        for index, (point, part) in enumerate(zip(points, parts, strict=True))
    ]


def point_runs(
    point: Point, part: list[tuple[int, BatchResult]], drawn: int, accepted: int, runs: int
) -> PointRuns:
    results = [result for _, result in part]
    values = {
        name: np.concatenate([r.estimates[name][~r.rejected] for r in results])[:runs]
        for name in point.estimators
    }
    timing = [r.timing for r in results if r.timing is not None]
    return PointRuns(
        values,
        drawn,
        accepted,
        sum(r.trace_seconds for r in results),
        (join_sample_sets([t[0] for t in timing]), np.concatenate([t[1] for t in timing])),
    )


def join_sample_sets(parts: list[SampleSets]) -> SampleSets:
    """One SampleSets of the pixels of `parts`, in order (same n and eps)."""

    def offsets(name):
        ends = np.cumsum([0] + [getattr(p, name)[-1] for p in parts[:-1]])
        return np.concatenate(
            [getattr(parts[0], name)[:1]]
            + [getattr(p, name)[1:] + end for p, end in zip(parts, ends, strict=True)]
        )

    first = parts[0]
    has_aux = first.aux is not None
    return SampleSets(
        np.concatenate([p.traced for p in parts]),
        offsets("offsets"),
        first.n,
        np.concatenate([p.aux for p in parts]) if has_aux else None,
        offsets("aux_offsets") if has_aux else None,
        first.eps,
    )


def device_times(runtime, timing: SampleSets, timing_values, sampler, names) -> dict:
    """{name: seconds per run} of the SPPP-cell estimators (vor, vor_sn, fvor) with their cells
    from the device kernel (clrender.estimators.device_cells, upload included) instead of Qhull."""

    def run(name):
        box = 0.5 + sampler.eps if ESTIMATORS[name].kept_cells else None  # fvor
        cells = device_sppp_cells_from_arrays(
            runtime, timing.traced, timing.offsets, timing.aux, timing.aux_offsets, box
        )
        estimate(name, timing, timing_values, {"sppp": cells})

    return {
        name: min_seconds(lambda name=name: run(name)) / timing.pixel_count
        for name in names
        if name in REJECTING
    }


def min_seconds(call, min_calls: int = 3, budget: float = 0.1) -> float:
    """The fastest of at least min_calls calls, more while under budget seconds (up to 20):
    the minimum is the least disturbed by other processes on a shared machine."""
    times: list[float] = []
    while len(times) < min_calls or (sum(times) < budget and len(times) < 20):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def pixel_samples(
    runs: PixelRuns, sampler, start: int = 0, end: int | None = None
) -> tuple[SampleSets, np.ndarray]:
    """Runs [start, end) (default all) as a batch of pixels and the values of their traced
    samples; value = RGB mean."""
    sets = runs.sets
    end = runs.runs if end is None else end
    traced = slice(sets.offsets[start], sets.offsets[end])
    aux = slice(sets.aux_offsets[start], sets.aux_offsets[end])
    samples = SampleSets(
        sets.traced[traced].astype(np.float64),
        sets.offsets[start : end + 1] - sets.offsets[start],
        float(sampler.n),
        sets.aux[aux].astype(np.float64),
        sets.aux_offsets[start : end + 1] - sets.aux_offsets[start],
        sampler.eps,
    )
    return samples, runs.radiance[traced].mean(axis=1)


def summarise(entry: dict, rng: np.random.Generator) -> dict:
    """Mean, std and variance over the R runs (the variance with its 95 % percentile bootstrap
    interval over the runs, var_ci), and the times."""
    v = entry["values"]
    total = entry["estimator_ms"] + entry["trace_ms"]
    low, high = statistic_interval(v, variance, rng, resamples=BOOTSTRAP_ERROR_BARS)
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)),
        "var": float(v.var(ddof=1)),
        "var_ci": [float(low), float(high)],
        "estimator_ms": entry["estimator_ms"],
        "trace_ms": entry["trace_ms"],
        "total_ms": total,
        "rejected_runs": entry["rejected_runs"],
        **device_summary(entry),
    }


def device_summary(entry: dict) -> dict:
    if entry["device_cells_ms"] is None:
        return {}
    return {
        "device_cells_ms": entry["device_cells_ms"],
        "device_total_ms": entry["device_cells_ms"] + entry["trace_ms"],
    }


def study_pixel(study: Study, scene: str, pixel: ProbePixel, executor) -> tuple[dict, dict]:
    """({spp: {label: summary}}, {spp: {label: values (R,)}}) over the spp list."""
    table, values = {}, {}
    rng = np.random.default_rng([study.args.seed, 1])  # error bars only: the draws are not its
    points = study.points(scene, pixel.pixel, executor)
    for spp in study.args.spp:
        row = {}
        values[spp] = {}
        for group in GROUPS:
            if not usable(group, spp):
                continue
            for label, entry in points[spp, group.key].items():
                row[label] = summarise(entry, rng)
                values[spp][label] = entry["values"]
        table[spp] = row
        print(
            f"  {pixel.what} spp {spp}: "
            + ", ".join(f"{k} {v['std']:.3g}" for k, v in row.items()),
            flush=True,
        )
    return table, values


def variance_ratios(table: dict) -> dict:
    """{spp: {label: var(mc/independent) / var(label)}}."""
    return {
        spp: {label: row[BASELINE]["var"] / max(s["var"], 1e-300) for label, s in row.items()}
        for spp, row in table.items()
    }


def ratio_table(labels: list[str], ratios: dict) -> str:
    """A Markdown table of {spp: {label: ratio}}, one row per spp, blank where a label is
    missing."""
    rows = [[spp, *[row.get(lab, "") for lab in labels]] for spp, row in ratios.items()]
    return markdown_table(["spp", *labels], rows)


def device_labels(labels: list[str]) -> list[str]:
    return [label for label in labels if label.split("/")[0] in REJECTING]


def device_efficiency(row: dict, label: str) -> float:
    """efficiency_ratios' figure with the estimator's device-cell time."""
    base = row[BASELINE]
    return base["var"] * base["total_ms"] / (row[label]["var"] * row[label]["device_total_ms"])


def efficiency_ratios(table: dict) -> dict:
    """{spp: {label: (var x ms)(mc/independent) / (var x ms)(label)}}, ms = tracing + estimator:
    above 1, the estimator reaches a given variance sooner than mc over uniform samples."""

    def cost(s):
        return s["var"] * s["total_ms"]

    return {
        spp: {label: cost(row[BASELINE]) / max(cost(s), 1e-300) for label, s in row.items()}
        for spp, row in table.items()
    }


def variance(runs: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.var(runs, axis=axis, ddof=1)


def voronoi_vs_ld(table: dict, values: dict, seed: int = 0) -> dict:
    """{spp: {label: {...}}} for each Voronoi estimator over low-discrepancy samples
    (VORONOI_LD): against the best low-discrepancy mc at that spp (LD_MC, lowest variance),
    the variance ratio var(best LD mc) / var(label) with its bootstrap interval (above 1:
    the Voronoi estimator has the lower variance), the efficiency ratio with the per-estimate
    time of each (tracing + estimator on the host), and a verdict: "wins" or "loses" when the
    interval excludes 1, else "tie"."""
    rng = np.random.default_rng(seed)
    out = {}
    for spp, row in table.items():
        mcs = [label for label in LD_MC if label in row]
        if not mcs:
            continue
        best = min(mcs, key=lambda label: row[label]["var"])
        out[spp] = {}
        for label in VORONOI_LD:
            if label not in row:
                continue
            # Separate groups, own seeds: independent runs, each resampled on its own
            a, b = values[spp][best], values[spp][label]
            ratio, lo, hi = ratio_interval(a, b, variance, rng, paired=False, resamples=BOOTSTRAP)
            cost = row[label]["var"] * row[label]["total_ms"]
            out[spp][label] = {
                "best_ld_mc": best,
                "var_ratio": ratio,
                "ci95": [lo, hi],
                "efficiency_ratio": row[best]["var"] * row[best]["total_ms"] / max(cost, 1e-300),
                "verdict": "wins" if lo > 1 else ("loses" if hi < 1 else "tie"),
            }
    return out


# ---------------------------------------------------------------------------------------------
# Charts


def series(table: dict, label: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    spps = [spp for spp in table if label in table[spp]]
    return np.array(spps), np.array([table[spp][label][key] for spp in spps])


def labels_of(table: dict) -> list[str]:
    return list(dict.fromkeys(label for row in table.values() for label in row))


def plot_fig6(
    table: dict, name: str, scene: str, pixel: ProbePixel, reference: float, args, out: Path
) -> None:
    others = [label for label in labels_of(table) if label != BASELINE]
    cols = 4
    rows = math.ceil((len(others) + 1) / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(4 * cols, 3.3 * rows + 0.6), squeeze=False, layout="constrained"
    )
    for ax, label in zip(axes.flat, others, strict=False):
        for lab, colour in ((BASELINE, "0.4"), (label, "C1")):
            spp, mean = series(table, lab, "mean")
            _, std = series(table, lab, "std")
            ax.plot(spp, mean, color=colour, label=lab)
            ax.fill_between(spp, mean - std, mean + std, color=colour, alpha=0.25)
        ax.axhline(reference, color="k", lw=0.7, ls="--", label="reference")
        ax.set_xscale("log", base=2)
        ax.set(xlabel="spp (samples per pixel)", ylabel="radiance (RGB mean)", title=label)
        ax.legend(fontsize=7)
    ax = axes.flat[len(others)]
    for label in labels_of(table):
        spp, std = series(table, label, "std")
        ax.loglog(spp, std, marker="o", ms=3, label=label)
    ax.set(xlabel="spp", ylabel="std of the estimate", title="std against spp")
    ax.legend(fontsize=6)
    for ax in list(axes.flat)[len(others) + 1 :]:
        ax.set_visible(False)
    draw_caption(fig, figure_caption("fig6", name, scene, pixel, args), width=180)
    save_figure(fig, out / f"fig6_{name}.png", dpi=100)
    plt.close(fig)


def plot_fig9(table: dict, name: str, scene: str, pixel: ProbePixel, args, out: Path) -> None:
    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(15, 6), layout="constrained")
    cmap = plt.get_cmap("tab20")
    for i, label in enumerate(labels_of(table)):
        spp, ms = series(table, label, "estimator_ms")
        ax_t.loglog(spp, ms, marker="o", ms=3, color=cmap(i % 20), label=label)
        _, total = series(table, label, "total_ms")
        _, var = series(table, label, "var")
        _, ci = series(table, label, "var_ci")
        ax_v.errorbar(
            total,
            var,
            yerr=np.maximum(np.stack([var - ci[:, 0], ci[:, 1] - var]), 0.0),
            marker="o",
            ms=3,
            capsize=2,
            color=cmap(i % 20),
            label=label,
        )
        if label.split("/")[0] in REJECTING:
            device_style = dict(
                marker="x", ms=3, color=cmap(i % 20), label=f"{label}, device cells"
            )
            _, device = series(table, label, "device_cells_ms")
            ax_t.loglog(spp, device, ":", **device_style)
            _, device_total = series(table, label, "device_total_ms")
            ax_v.loglog(device_total, var, ":", **device_style)
    spp, trace = series(table, BASELINE, "trace_ms")
    ax_t.loglog(spp, trace, "k--", label="tracing (mc/independent runs)")
    ax_t.set(
        xlabel="spp (samples per pixel)",
        ylabel="ms per estimate",
        title="(a) estimator time per estimate (Qhull; dotted: device cells)",
    )
    ax_v.set(
        xscale="log",
        yscale="log",
        xlabel="ms per estimate (tracing + estimator)",
        ylabel="variance over the runs (95 % bootstrap interval)",
        title="(b) variance against time",
    )
    ax_v.legend(fontsize=6, loc="center left", bbox_to_anchor=(1.01, 0.5))
    draw_caption(fig, figure_caption("fig9", name, scene, pixel, args), width=170)
    save_figure(fig, out / f"fig9_{name}.png", dpi=100)
    plt.close(fig)


def figure_caption(figure: str, name: str, scene: str, pixel: ProbePixel, args) -> str:
    """Every parameter of a pixel's Figure 6 or 9."""
    what = {
        "fig6": f"Figure 6, pixel {name}: estimate (mean +- 1 std over the runs) against spp, "
        f"each configuration beside {BASELINE}, and the std of all",
        "fig9": f"Figure 9, pixel {name}: estimator time against spp, and variance against "
        "time per estimate",
    }[figure]
    return caption(
        what,
        {
            "scene": scene,
            "pixel": f"({pixel.x}, {pixel.y}) of {args.size} x {args.size}, {pixel.what}",
            "spp": ", ".join(str(spp) for spp in args.spp),
            "runs": f"R = {args.runs} independent estimates per point (seed {args.seed} + a "
            "per-sampler offset)",
            "labels": f"estimator/sampler; {BASELINE} is plain Monte Carlo over uniform "
            "samples, the paper's MC",
            "value": "mean of RGB",
            "error bars": f"variance: 95 % percentile bootstrap interval over the runs "
            f"({BOOTSTRAP_ERROR_BARS} resamples)"
            if figure == "fig9"
            else "band: +- 1 std over the runs",
            "times": f"estimator alone on {args.timing_runs} runs, fastest of >= 3 calls, "
            "host Qhull cells (dotted: device cells); tracing per run from the launch"
            if figure == "fig9"
            else None,
            "max depth": MAX_DEPTH,
            "device": args.device,
        },
    )


# ---------------------------------------------------------------------------------------------
# Main


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run (R = 16, spp 64, 256)")
    parser.add_argument(
        "--pixels",
        nargs="+",
        choices=list(PROBES),
        default=list(PROBES),
        help="probe pixels to study (default all)",
    )
    parser.add_argument("--size", type=int, default=256, help="image width = height")
    parser.add_argument("--runs", type=int, default=None, help="R runs per point (default 200)")
    parser.add_argument("--spp", type=int, nargs="+", default=None, help="default 64 128 ... 4096")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--timing-runs",
        type=int,
        default=32,
        help="runs each estimator is timed on alone (default 32)",
    )
    parser.add_argument(
        "--batch-runs",
        type=int,
        default=BATCH_RUNS,
        help=f"runs per task (default {BATCH_RUNS}; the numbers do not depend on it)",
    )
    parser.add_argument("--out", type=Path, default=RESULTS / "pixel_study")
    add_executor_options(parser)
    args = parser.parse_args(argv)
    if args.batch_runs < 1 or args.batch_runs % ESTIMATE_RUNS:
        parser.error(
            f"--batch-runs must be a positive multiple of {ESTIMATE_RUNS}, got {args.batch_runs}"
        )
    args.runs = args.runs or (16 if args.quick else 200)
    args.spp = args.spp or ([64, 256] if args.quick else [2**k for k in range(6, 13)])
    return args


def pixel_of(entry: dict) -> ProbePixel:
    """The pixel of a results entry, as figure_caption reads it (x, y, what)."""
    p = entry["pixel"]
    return SimpleNamespace(x=p["x"], y=p["y"], what=p["what"])


def vs_ld_table(vs: dict) -> str:
    labels = list(dict.fromkeys(label for row in vs.values() for label in row))
    rows = []
    for spp, row in vs.items():
        best = next(iter(row.values()))["best_ld_mc"] if row else ""
        cells = []
        for label in labels:
            e = row.get(label)
            cells.append(
                f"{e['var_ratio']:.2f} [{e['ci95'][0]:.2f}, {e['ci95'][1]:.2f}] "
                f"eff {e['efficiency_ratio']:.2g} {e['verdict']}"
                if e
                else ""
            )
        rows.append([spp, best, *cells])
    return markdown_table(["spp", "best LD mc", *labels], rows)


def report(results: dict, args, argv) -> str:
    lines = [
        "# Pixel study (paper Figures 6 and 9)",
        "",
        f"Command: `{command_line('pixel_study.py', argv)}`",
        "",
        f"{args.size}x{args.size}, R = {args.runs} runs per point, spp {args.spp}, max depth 8, "
        "pixel value = mean of RGB; each pixel's scene is in its heading. Machine: "
        f"{results['machine']['uptime']}",
        "",
        f"Runs traced and estimated in: {results['settings']['executor']}, tasks of "
        f"{results['settings']['batch_runs']} runs; estimator times in this process.",
        "",
    ]
    for name, entry in results["pixels"].items():
        table = entry["table"]
        labels = labels_of(table)
        lines += [
            f"## {name}: pixel ({entry['pixel']['x']}, {entry['pixel']['y']}) of {entry['scene']}",
            "",
            f"Found as: {entry['pixel']}",
            "",
            f"Reference (mean of {REFERENCE_LABEL} at {entry['reference_spp']} spp): "
            f"{entry['reference']:.4f}",
            "",
            "std over the runs:",
            "",
            markdown_table(
                ["spp", *labels],
                [
                    [spp, *[row[lab]["std"] if lab in row else "" for lab in labels]]
                    for spp, row in table.items()
                ],
            ),
            "",
            f"variance ratio var({BASELINE}) / var(estimator):",
            "",
            ratio_table(labels, entry["variance_ratio"]),
            "",
            f"efficiency (var x ms)({BASELINE}) / (var x ms)(estimator), ms = "
            "tracing + estimator per estimate (above 1: better at equal time):",
            "",
            ratio_table(labels, entry["efficiency_ratio"]),
            "",
            "ms per estimate of the SPPP-cell estimators with device cells "
            "(clrender.estimators.device_cells, upload included) / efficiency with them:",
            "",
            markdown_table(
                [
                    "spp",
                    *[f"{lab} ms" for lab in device_labels(labels)],
                    *[f"{lab} eff." for lab in device_labels(labels)],
                ],
                [
                    [
                        spp,
                        *[row[lab]["device_cells_ms"] for lab in device_labels(labels)],
                        *[device_efficiency(row, lab) for lab in device_labels(labels)],
                    ]
                    for spp, row in table.items()
                ],
            ),
            "",
            "ms per estimate, estimator only (tracing in the last column):",
            "",
            markdown_table(
                ["spp", *labels, "trace (mc/independent)"],
                [
                    [
                        spp,
                        *[row[lab]["estimator_ms"] if lab in row else "" for lab in labels],
                        row[BASELINE]["trace_ms"],
                    ]
                    for spp, row in table.items()
                ],
            ),
            "",
            "Voronoi weighting over low-discrepancy samples against the best low-discrepancy mc "
            "(lowest variance of " + ", ".join(LD_MC) + " at that spp): variance ratio "
            "var(best LD mc) / var(estimator) [95 % bootstrap interval], efficiency ratio "
            "(variance x ms), verdict (wins / loses: the interval excludes 1):",
            "",
            vs_ld_table(entry["voronoi_vs_ld"]),
            "",
            f"![fig6](fig6_{name}.png)",
            "",
            report_caption(figure_caption("fig6", name, entry["scene"], pixel_of(entry), args)),
            "",
            f"![fig9](fig9_{name}.png)",
            "",
            report_caption(figure_caption("fig9", name, entry["scene"], pixel_of(entry), args)),
            "",
        ]
    return "\n".join(lines)


def main(argv=None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    study = Study(args)
    args.device = study.runtime.describe()
    executor = executor_from_args(args)
    start = time.perf_counter()
    results = {
        "settings": {
            "scenes": {name: PROBES[name].scene for name in args.pixels},
            "size": args.size,
            "runs": args.runs,
            "spp": args.spp,
            "seed": args.seed,
            "quick": args.quick,
            "device": args.device,
            "batch_runs": args.batch_runs,
            "executor": executor_label(args),
        },
        "machine_before": machine(),
        "pixels": {},
    }
    with executor:
        for name in args.pixels:
            study_probe(study, name, executor, results["pixels"])
    results["machine"] = machine()
    results["seconds"] = time.perf_counter() - start
    write_json(args.out / "results.json", results)
    (args.out / "report.md").write_text(report(results, args, argv) + "\n")
    print(f"done in {results['seconds']:.0f} s; wrote {args.out}/results.json, report.md, PNGs")


def study_probe(study: Study, name: str, executor, pixels: dict) -> None:
    """Find a probe's pixel, measure it, write its figures and add its entry to pixels."""
    args = study.args
    scene = PROBES[name].scene
    pixel = study.find_pixel(PROBES[name])
    print(f"{name} ({scene}): {pixel.as_dict()}", flush=True)
    table, values = study_pixel(study, scene, pixel, executor)
    top = max(spp for spp in table if REFERENCE_LABEL in table[spp])
    ref = table[top][REFERENCE_LABEL]["mean"]
    pixels[name] = {
        "scene": scene,
        "pixel": pixel.as_dict(),
        "table": table,
        "reference": ref,
        "reference_spp": top,
        "variance_ratio": variance_ratios(table),
        "efficiency_ratio": efficiency_ratios(table),
        "voronoi_vs_ld": voronoi_vs_ld(table, values, args.seed),
    }
    plot_fig6(table, name, scene, pixel, ref, args, args.out)
    plot_fig9(table, name, scene, pixel, args, args.out)


if __name__ == "__main__":
    main()
