"""Device Voronoi cell areas (clrender.estimators.device_cells) against the host Qhull stage.

    python bench/device_voronoi_speed.py [--quick] [--repeats K] [--precision P] [--out FILE]

For n = 64, 256, 1024, 4096 the SPPP sample sets of a batch of pixels are drawn on the device
(clrender.sampling, as in a render tile); then, on the same points, it times
  device: device_sppp_cells(runtime, sets, box)  (positions already on the device; grid build,
          cell kernel, read-back of areas and flags, host fallbacks)
  host:   qhull_cells.sppp_cells on the host copy (what the render's estimator stage runs).
Reported per traced nucleus, as medians over K repeats after a warm-up run: wall time and
process CPU time (all threads: PoCL's workers for the device, Qhull's one thread for the host),
plus the largest relative area difference between the two and the host-fallback pixel count.
The machine is shared: compare CPU times first. JSON goes to bench/results/ (git-ignored).

    python bench/device_voronoi_speed.py --stages [--repeats K]

instead accounts for what a vor_sn render does beyond an mc_n render over the same SPPP
samples, stage by stage, on one render tile (4096 pixels) at n = 64 and 256: the auxiliary
nuclei (sample sets drawn with them against without), the grid build, the cell kernel, and the
per-pixel Voronoi sums against the plain sums mc_n forms; medians of K runs (alternating),
CPU seconds per tile and per 256 x 256 image (16 such tiles). Where Linux reports each thread's
CPU time (/proc/self/task), each stage's busiest thread too: the stage's wall time on an
otherwise idle machine is at least that, so busiest / CPU tells how well the stage spreads over
the cores (1 / cores at best) whatever the load. Also the cell kernel's CPU-ns per traced cell
(times the clock rate: cycles per cell).

    python bench/device_voronoi_speed.py --variants - VORONOI_NO_SIDE_TEST,X=2 [--n N]

instead times kernel variants against each other: the grid build and cell kernel (the kernel's
own build options plus each variant's, comma-separated NAME or NAME=VALUE; "-" adds none) on
one tile (4096 pixels, 1024 above n = 256), alternating the variants in one process, the order
reversed every other round, for --repeats rounds (default 7; use 20 or more). Two names are not
build options: GRID_SIDE=S runs the variant on an S x S grid per pixel (instead of the one
device_cells.grid_side picks), KERNELS=DIR builds it from the kernels folder DIR (another
worktree's, e.g. main's against a branch's). Per variant: the median and least CPU per tile,
the median and quartiles of its ratio to the first variant's time in the same round, whether
its areas and status bytes are bit for bit the first variant's, and if not how many areas
differ and by how much at most (relative). On a shared machine separate runs of one kernel
differ by 10 % and more; ratios within a round resolve 1 to 2 % (at load 4 to 6, medians over
40 to 60 rounds still moved by 2 to 3 % between runs). `--variants VORONOI_NO_PAIRS -` gives
what walking a grid cell's nuclei two at a time saves (kernels/voronoi_cells.cl).

    python bench/device_voronoi_speed.py --variants - KERNELS=DIR --processes 4 [--repeats K]

runs that comparison in 4 fresh processes, one after another, and pools their rounds: per
variant the ratio quartiles over all rounds, each process's median ratio and median CPU per tile
(a process that ran one variant slower throughout stands out there). Separate processes of one
kernel differ by up to 10 % (the cell kernel's median: 189 to 214 CPU-ns per traced cell over
38 processes on both PoCLs; its least 187 to 208) and one process drifts as much within a
minute (medians of 30 rounds from 203 down to 189), while builds of one kernel, or copies of its
buffers, alternated within a process agree within 1 to 5 %: the machine's load and its host's,
not the build or where the memory lies. Compare separate processes only as medians over several.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from common import machine, thread_seconds

from clrender.estimators import device_cells
from clrender.estimators.device_cells import device_sppp_cells, resolve_precision
from clrender.estimators.qhull_cells import sppp_cells
from clrender.runtime import KERNELS_DIR_VARIABLE, create_runtime
from clrender.sampling import generate_sample_sets, make_sampler

# (n, pixels): about 260 000 traced nuclei each.
CASES = [(64, 4096), (256, 1024), (1024, 256), (4096, 64)]
DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "device_voronoi_speed.json"


def timed(fn, repeats: int) -> tuple[float, float, object]:
    """Median wall and CPU seconds of fn() over repeats (after one warm-up call), last result."""
    result = fn()
    walls, cpus = [], []
    for _ in range(repeats):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        result = fn()
        walls.append(time.perf_counter() - wall0)
        cpus.append(time.process_time() - cpu0)
    return float(np.median(walls)), float(np.median(cpus)), result


def measure(runtime, n: int, pixels: int, repeats: int, precision: str) -> dict:
    config = make_sampler("sppp", n)
    sets = generate_sample_sets(runtime, config, 1, np.arange(pixels, dtype=np.uint32))
    host_sets = sets.to_host(runtime.queue)
    box = float(np.float32(0.5 + config.eps))
    traced = host_sets.traced.astype(np.float64)
    aux = host_sets.aux.astype(np.float64)
    nuclei = len(traced)

    dev_wall, dev_cpu, device = timed(
        lambda: device_sppp_cells(runtime, sets, box, precision), repeats
    )
    host_repeats = max(1, repeats // 2)
    host_wall, host_cpu, host = timed(
        lambda: sppp_cells(traced, host_sets.offsets, aux, host_sets.aux_offsets, box), host_repeats
    )
    both = device.bounded & host.bounded
    rel = np.abs(device.areas[both] / host.areas[both] - 1.0)
    us = 1e6 / nuclei
    return {
        "n": n,
        "pixels": pixels,
        "traced_nuclei": nuclei,
        "aux_nuclei": int(len(aux)),
        "device_wall_us_per_nucleus": dev_wall * us,
        "device_cpu_us_per_nucleus": dev_cpu * us,
        "host_wall_us_per_nucleus": host_wall * us,
        "host_cpu_us_per_nucleus": host_cpu * us,
        "wall_speedup": host_wall / dev_wall,
        "cpu_speedup": host_cpu / dev_cpu,
        "max_relative_area_difference": float(rel.max()) if rel.size else 0.0,
        "flags_identical": bool(
            (device.bounded == host.bounded).all() and (device.inside_box == host.inside_box).all()
        ),
        "host_fallback_pixels": device.stats.recomputed_pixels,
    }


# --stages: a render tile of 4096 pixels; a 256 x 256 image is 16 of them
STAGE_PIXELS, IMAGE_PIXELS = 4096, 256 * 256


def parse_defines(variant: str) -> dict[str, object]:
    """Build options of one --variants argument: NAME or NAME=VALUE, comma-separated; "-" none."""
    defines: dict[str, object] = {}
    for item in filter(None, variant.split(",")):
        if item != "-":
            name, _, value = item.partition("=")
            defines[name] = value if value else True
    return defines


@contextmanager
def kernels_folder(folder: str | None):
    """CLRENDER_KERNELS_DIR set to folder (None: left as it is) for the kernels looked up inside:
    the runtime caches them per folder, so a variant's every launch must see its folder."""
    saved = os.environ.get(KERNELS_DIR_VARIABLE)
    if folder:
        os.environ[KERNELS_DIR_VARIABLE] = folder
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(KERNELS_DIR_VARIABLE, None)
        else:
            os.environ[KERNELS_DIR_VARIABLE] = saved


def compare_variants(runtime, n: int, variants: list[str], rounds: int) -> dict:
    """CPU seconds of the grid build and cell kernel per tile for each variant's build options,
    alternating in one process; ratios to the first variant within each round."""
    import pyopencl as cl

    config = make_sampler("sppp", n)
    pixels = STAGE_PIXELS if n <= 256 else STAGE_PIXELS // 4
    sets = generate_sample_sets(runtime, config, 1, np.arange(pixels, dtype=np.uint32))
    default_layout = device_cells._sample_set_layout(sets)
    box = float(np.float32(0.5 + config.eps))
    base, real = device_cells.precision_setup(runtime, "auto")
    size = np.dtype(real).itemsize
    options, layouts, folders = [], [], []
    for k, variant in enumerate(variants):
        defines = {**base, **parse_defines(variant)}
        side = defines.pop("GRID_SIDE", None)
        layouts.append(replace(default_layout, grid_side=int(side)) if side else default_layout)
        folders.append(defines.pop("KERNELS", None))
        if folders[-1]:  # a build option of its own: the kernels are cached per build options
            defines["CLRENDER_BENCH_KERNELS"] = k
        options.append(defines)
    outputs = []
    for defines, layout, folder in zip(options, layouts, folders, strict=True):
        # Builds the kernels (from the variant's folder); the results to compare
        with kernels_folder(folder):
            areas_buf, status_buf, _, _ = device_cells._enqueue_cells(
                runtime, layout, box, defines, size
            )
        areas = np.empty(layout.traced_total, real)
        status = np.empty(layout.traced_total, np.uint8)
        cl.enqueue_copy(runtime.queue, areas, areas_buf)
        cl.enqueue_copy(runtime.queue, status, status_buf)
        outputs.append((areas, status))
    cpu = np.zeros((len(options), rounds))
    for r in range(rounds):
        order = range(len(options)) if r % 2 == 0 else reversed(range(len(options)))
        for k in order:
            runtime.queue.finish()
            # (in the variant's folder: elsewhere the lookup built the variant's options from
            # the default folder's sources, and timed that program instead)
            with kernels_folder(folders[k]):
                cpu0 = time.process_time()
                device_cells._enqueue_cells(runtime, layouts[k], box, options[k], size)
                runtime.queue.finish()
                cpu[k, r] = time.process_time() - cpu0
    rows = []
    first_areas, first_status = outputs[0]
    for k, variant in enumerate(variants):
        ratio = cpu[k] / cpu[0]
        areas, status = outputs[k]
        differ = ~((areas == first_areas) | (np.isnan(areas) & np.isnan(first_areas)))
        both = np.isfinite(areas) & np.isfinite(first_areas)
        relative = np.abs(areas[both] / first_areas[both] - 1.0)
        rows.append(
            {
                "variant": variant,
                "median_cpu_s_per_tile": float(np.median(cpu[k])),
                "least_cpu_s_per_tile": float(cpu[k].min()),
                "ratio_to_first": [float(np.quantile(ratio, q)) for q in (0.25, 0.5, 0.75)],
                "cpu_s_per_round": [float(x) for x in cpu[k]],
                "identical_to_first": bool(
                    not differ.any() and np.array_equal(status, first_status)
                ),
                "areas_differing": int(differ.sum()),
                "largest_relative_area_difference": float(relative.max()) if relative.size else 0.0,
            }
        )
    traced = default_layout.traced_total
    return {"n": n, "pixels": pixels, "traced_nuclei": traced, "variants": rows}


def pool_variant_runs(reports: list[dict]) -> dict:
    """The --variants reports of several processes (same variants) as one: per variant the
    median of the processes' median CPU per tile, the ratio quartiles over every round of every
    process, and each process's median CPU and median ratio (to tell a slow process apart)."""
    names = [row["variant"] for row in reports[0]["variants"]]
    for report in reports[1:]:
        if [row["variant"] for row in report["variants"]] != names:
            raise ValueError(f"reports of different variants: {names} and {report['variants']}")
    first = [np.array(report["variants"][0]["cpu_s_per_round"]) for report in reports]
    rows = []
    for k, name in enumerate(names):
        own = [np.array(report["variants"][k]["cpu_s_per_round"]) for report in reports]
        ratios = [cpu / base for cpu, base in zip(own, first, strict=True)]
        pooled = np.concatenate(ratios)
        process_medians = [float(np.median(cpu)) for cpu in own]
        rows.append(
            {
                "variant": name,
                "median_cpu_s_per_tile": float(np.median(process_medians)),
                "process_median_cpu_s_per_tile": process_medians,
                "ratio_to_first": [float(np.quantile(pooled, q)) for q in (0.25, 0.5, 0.75)],
                "process_median_ratio_to_first": [float(np.median(r)) for r in ratios],
                "identical_to_first": all(r["variants"][k]["identical_to_first"] for r in reports),
            }
        )
    return {"processes": len(reports), "variants": rows}


def variants_in_processes(args: argparse.Namespace) -> dict:
    """--variants in args.processes fresh processes, one at a time; their reports pooled."""
    reports = []
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.processes):
            out = Path(folder) / DEFAULT_OUT.name  # (--variants writes beside it)
            command = [sys.executable, __file__, "--variants", *args.variants, "--n", str(args.n)]
            command += ["--repeats", str(args.repeats), "--out", str(out)]
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            reports.append(json.loads(out.with_name("device_voronoi_variants.json").read_text()))
    return pool_variant_runs(reports)


def stage_accounting(runtime, n: int, repeats: int) -> dict:
    """CPU (and wall) seconds per tile of each stage vor_sn adds to an mc_n render, medians of
    alternating runs, each ended by a queue finish."""

    config = make_sampler("sppp", n)
    pixels = np.arange(STAGE_PIXELS, dtype=np.uint32)
    sets = generate_sample_sets(runtime, config, 1, pixels)
    radiance = runtime.upload(
        np.random.default_rng(0).random((sets.traced_total, 3), dtype=np.float32)
    )
    layout = device_cells._sample_set_layout(sets)
    box = float(np.float32(0.5 + config.eps))
    defines = device_cells.kernel_defines(runtime, "auto")
    traced, total = layout.traced_total, layout.traced_total + int(layout.aux_offsets[-1])
    side = layout.grid_side
    offsets = runtime.upload(
        np.concatenate([layout.traced_offsets, layout.aux_offsets]).astype(np.uint32)
    )
    grid = [runtime.allocate(4 * STAGE_PIXELS * (side * side + 1))]
    grid += [runtime.allocate(8 * total), runtime.allocate(4 * total), runtime.allocate(4 * total)]
    build = runtime.kernel(device_cells.KERNEL_FILE, "voronoi_build_grid", defines)

    def build_grid():
        device_cells.launch_per_pixel(
            runtime,
            build,
            STAGE_PIXELS,
            np.uint32(traced),
            np.int32(side),
            np.float32(layout.half_extent),
            layout.positions,
            offsets,
            *grid,
        )

    stages = {
        "sample sets with auxiliary nuclei": lambda: generate_sample_sets(
            runtime, config, 1, pixels
        ),
        "sample sets without": lambda: generate_sample_sets(
            runtime, replace(config, n_aux=0), 1, pixels
        ),
        "grid build": build_grid,
        "grid build + cell kernel": lambda: device_cells._enqueue_cells(
            runtime, layout, box, defines, 8
        ),
        "cells + Voronoi sums (device_sppp_sums)": lambda: device_cells.device_sppp_sums(
            runtime, sets, radiance, box
        ),
        "plain sums (device_plain_sums, mc_n)": lambda: device_cells.device_plain_sums(
            runtime, sets, radiance
        ),
    }
    runs = {name: [] for name in stages}
    for repeat in range(repeats + 1):
        for name, stage in stages.items():
            # The threads' interval inside the process's, so that no thread's share can
            # exceed the process's CPU (reading /proc costs the main thread about a ms)
            wall0, cpu0 = time.perf_counter(), time.process_time()
            threads0, own0 = thread_seconds(), time.thread_time()
            stage()
            runtime.queue.finish()
            own, threads1 = time.thread_time() - own0, thread_seconds()
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            # This thread by its own clock: /proc's figure for a running thread can lag until
            # its next tick or switch (a stage that never sleeps here, on Intel's runtime: 0)
            threads1.pop(str(threading.get_native_id()), None)
            others = (s - threads0.get(t, 0.0) for t, s in threads1.items())
            busiest = max(own, max(others, default=0.0))
            if repeat:  # the first round warms up
                runs[name].append((wall, cpu, busiest))
    cpu = {name: float(np.median([r[1] for r in rows])) for name, rows in runs.items()}
    wall = {name: float(np.median([r[0] for r in rows])) for name, rows in runs.items()}
    busiest = {name: float(np.median([r[2] for r in rows])) for name, rows in runs.items()}
    with_cells = cpu["grid build + cell kernel"]
    extra = {
        "auxiliary nuclei": cpu["sample sets with auxiliary nuclei"] - cpu["sample sets without"],
        "grid build": cpu["grid build"],
        "cell kernel": with_cells - cpu["grid build"],
        "sums beyond the plain sums": cpu["cells + Voronoi sums (device_sppp_sums)"]
        - with_cells
        - cpu["plain sums (device_plain_sums, mc_n)"],
    }
    extra["total"] = sum(extra.values())
    tiles = IMAGE_PIXELS / STAGE_PIXELS
    return {
        "n": n,
        "pixels": STAGE_PIXELS,
        "traced_nuclei": traced,
        "aux_nuclei": total - traced,
        # the cell kernel's CPU per traced cell: times the clock rate, cycles per cell
        "cell_kernel_cpu_ns_per_cell": 1e9 * extra["cell kernel"] / max(traced, 1),
        "cpu_s_per_tile": cpu,
        "wall_s_per_tile": wall,
        "busiest_thread_s_per_tile": busiest,
        "extra_cpu_s_per_image": {name: value * tiles for name, value in extra.items()},
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1/8 of the pixels, 3 repeats")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--precision", default="auto", help="auto, single, mixed or double")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument(
        "--stages", action="store_true", help="vor_sn's stages beyond mc_n, per tile and image"
    )
    parser.add_argument(
        "--variants", nargs="+", metavar="DEFINES", help="cell kernel build options to compare"
    )
    parser.add_argument("--n", type=int, default=256, help="SPPP n of --variants")
    parser.add_argument(
        "--processes", type=int, default=1, help="--variants in this many fresh processes, pooled"
    )
    args = parser.parse_args(argv)
    if args.processes > 1:
        if not args.variants:
            parser.error("--processes goes with --variants")
        before = machine()
        report = variants_in_processes(args)
        for row in report["variants"]:
            q25, median, q75 = row["ratio_to_first"]
            per_process = ", ".join(f"{r:.3f}" for r in row["process_median_ratio_to_first"])
            cpu = ", ".join(f"{1e3 * c:.1f}" for c in row["process_median_cpu_s_per_tile"])
            print(
                f"{row['variant']:32s} {1e3 * row['median_cpu_s_per_tile']:8.1f} ms CPU per tile"
                f" ({cpu})  ratio to first {median:.3f} [{q25:.3f}, {q75:.3f}]"
                f" per process ({per_process})  identical: {row['identical_to_first']}"
            )
        out = args.out.with_name("device_voronoi_variants_pooled.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        report.update(rounds=args.repeats, machine_before=before, machine_after=machine())
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {out}")
        return
    runtime = create_runtime()
    before = machine()
    repeats = 3 if args.quick else args.repeats
    if args.variants:
        report = compare_variants(runtime, args.n, args.variants, repeats)
        report.update(device=runtime.describe(), rounds=repeats)
        for row in report["variants"]:
            q25, median, q75 = row["ratio_to_first"]
            print(
                f"{row['variant']:32s} {1e3 * row['median_cpu_s_per_tile']:8.1f} ms CPU per tile"
                f" (least {1e3 * row['least_cpu_s_per_tile']:.1f})  ratio to first {median:.3f}"
                f" [{q25:.3f}, {q75:.3f}]  identical: {row['identical_to_first']}"
                + (
                    ""
                    if row["identical_to_first"]
                    else f" ({row['areas_differing']} areas differ, by at most"
                    f" {row['largest_relative_area_difference']:.1e} relative)"
                )
            )
        out = args.out.with_name("device_voronoi_variants.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        report.update(machine_before=before, machine_after=machine())
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {out}")
        return
    if args.stages:
        report = {"device": runtime.describe(), "repeats": repeats, "stages": []}
        for n in (64, 256):
            row = stage_accounting(runtime, n, repeats)
            report["stages"].append(row)
            print(f"n={n}: {row['traced_nuclei']} traced, {row['aux_nuclei']} auxiliary nuclei")
            for name, value in row["cpu_s_per_tile"].items():
                top = row["busiest_thread_s_per_tile"][name]
                print(
                    f"  {name:42s} {1e3 * value:8.2f} ms CPU per tile, busiest thread "
                    f"{1e3 * top:7.2f} ms ({top / value if value else 0:.2f} of it)"
                )
            for name, value in row["extra_cpu_s_per_image"].items():
                print(f"  extra: {name:35s} {value:6.2f} CPU-s per 256 x 256 image")
            print(f"  cell kernel: {row['cell_kernel_cpu_ns_per_cell']:.0f} CPU-ns per traced cell")
        out = args.out.with_name("device_voronoi_stages.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        report.update(machine_before=before, machine_after=machine())
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {out}")
        return
    rows = []
    for n, pixels in CASES:
        row = measure(
            runtime, n, max(8, pixels // 8) if args.quick else pixels, repeats, args.precision
        )
        rows.append(row)
        print(
            f"n={n:5d} pixels={row['pixels']:5d}  device {row['device_wall_us_per_nucleus']:.3f}"
            f" us wall {row['device_cpu_us_per_nucleus']:.3f} us cpu  |  host "
            f"{row['host_wall_us_per_nucleus']:.3f} us wall {row['host_cpu_us_per_nucleus']:.3f}"
            f" us cpu  |  cpu x{row['cpu_speedup']:.1f} wall x{row['wall_speedup']:.1f}  "
            f"max rel diff {row['max_relative_area_difference']:.1e}  "
            f"fallback {row['host_fallback_pixels']}",
            flush=True,
        )
    report = {
        "device": runtime.describe(),
        "precision": resolve_precision(runtime, args.precision),
        "repeats": repeats,
        "cases": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report.update(machine_before=before, machine_after=machine())
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
