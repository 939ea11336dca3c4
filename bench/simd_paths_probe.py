"""Research probe: would tracing SIMD_WIDTH paths per work-item (kernels/simd_paths_probe.cl,
one path a vector lane) beat the megakernel (kernels/integrator.cl, one path a work-item)?

    PYOPENCL_CTX=0 python bench/simd_paths_probe.py                  # 64 spp, 7 rounds
    PYOPENCL_CTX=1 python bench/simd_paths_probe.py --variants 16 8 --rounds 9
    PYOPENCL_CTX=1 python bench/simd_paths_probe.py --variants 16 16r/front 16r/spread 16r/c8

On mitsuba-cbox (the only scene the prototype supports: quads, diffuse materials, one quad
emitter) with the independent sampler, max depth 8, NEE, no Russian roulette: draws one set
of samples, traces it with PathTracer and with the prototype at each width, and compares the
per-sample radiance (exactly equal samples, max relative difference, image means). Then, after
a warm-up launch of each, times them alternating (megakernel, then each width, round after
round) and reports medians of paths per CPU-second (process time: PoCL's threads run in this
process; cpu/wall below the compute units means the shared machine took cores) and the
prototype / megakernel ratio per round, in CPU and in wall time, and the busiest thread's
share of each launch's CPU (1 / threads when PoCL's threads share the work evenly, 1 when one
thread ran it all). Lane utilisation: the prototype's running lanes per bounce-loop iteration
over the width, and the lanes tracing a shadow ray per NEE step. With path regeneration ("16r")
a work-item traces chunks of --chunk lanes' worth of samples, dealt to work-items by --layout
(front: work-item g runs chunk g; spread: over the whole padded launch; queue: each work-item
takes chunks from a counter), in work-groups of --local-size; a variant can name its own
("16r/c8/l32/spread"). The last work-group that traced tells where the work sat in the launch.
Output: JSON (default bench/results/simd_paths_probe.json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import thread_seconds  # noqa: E402

from clrender.runtime import create_runtime, launch_global_size  # noqa: E402
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels  # noqa: E402
from clrender.scene import load_scene  # noqa: E402
from clrender.trace import PathTracer  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "simd_paths_probe.json"
COUNTERS = (
    "nonfinite",
    "rays",
    "bounce_steps",
    "bounce_lanes",
    "shadow_steps",
    "shadow_lanes",
    "last_group",
    "next_chunk",
)
# simd_paths_regen's ways to deal chunks to work-items (SIMD_LAYOUT in the kernel)
LAYOUTS = {"front": 0, "spread": 1, "queue": 2}


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="mitsuba-cbox")
    parser.add_argument("--size", type=int, default=256, help="image width = height")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument(
        "--variants",
        nargs="+",
        default=["16", "8", "16r", "8r"],
        help="lanes per work-item; a trailing r: with path regeneration (simd_paths_regen); "
        "then optionally /cCHUNK, /lLOCAL_SIZE, /front, /spread or /queue (16r/c8/l64/spread)",
    )
    parser.add_argument(
        "--chunk", type=int, default=32, help="regeneration: lanes' worth of samples a chunk"
    )
    parser.add_argument("--local-size", type=int, default=16, help="prototype work-group size")
    parser.add_argument(
        "--layout",
        choices=sorted(LAYOUTS),
        default="queue",
        help="regeneration: chunks dealt to work-items packed at the launch's front, spread "
        "over the whole launch, or taken from a counter by each work-item in turn",
    )
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument(
        "--define",
        action="append",
        default=[],
        help="a -D for the prototype's build (experiments: SIMD_NO_MIN_VECTOR_WIDTH, ...)",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    return parser.parse_args(argv)


def check_scene(scene) -> None:
    """ValueError naming what the prototype cannot trace in the scene."""
    problems = []
    if len(scene.spheres) or len(scene.triangles):
        problems.append("spheres or triangles (quads only)")
    if len(scene.emitters) != 1 or int(scene.emitters["shape"][0]) != 0:
        problems.append("emitters: exactly one quad")
    if (scene.materials["type"] != 0).any():
        problems.append("materials: diffuse only")
    if problems:
        raise ValueError(f"simd_paths prototype cannot trace this scene: {'; '.join(problems)}")


def parse_variant(variant: str, local_size: int, chunk: int, layout: str) -> dict:
    """A variant's settings: "16" or "8" lanes, a trailing "r" for path regeneration, then
    optionally /cCHUNK, /lLOCAL_SIZE and a layout (/front, /spread, /queue) in place of the
    defaults given."""
    head, *options = variant.split("/")
    regenerate = head.endswith("r")
    settings = {
        "width": head.rstrip("r"),
        "regenerate": regenerate,
        "local_size": local_size,
        "chunk": chunk,
        "layout": layout,
    }
    for option in options:
        if option in LAYOUTS and regenerate:
            settings["layout"] = option
        elif option[:1] == "l" and option[1:].isdigit() and int(option[1:]) > 0:
            settings["local_size"] = int(option[1:])
        elif option[:1] == "c" and option[1:].isdigit() and int(option[1:]) > 0 and regenerate:
            settings["chunk"] = int(option[1:])
        else:
            raise ValueError(
                f"--variants {variant}: option {option!r} is not /cCHUNK (with r), /lLOCAL_SIZE "
                f"or a layout ({', '.join(LAYOUTS)}, with r)"
            )
    if settings["width"] not in ("8", "16"):
        raise ValueError(f"--variants {variant}: lanes must be 8 or 16, not {head!r}")
    settings["width"] = int(settings["width"])
    return settings


class Prototype:
    """kernels/simd_paths_probe.cl at one width (variant "16", or "16r" with path regeneration,
    with launch options: parse_variant), on the tracer's scene buffers."""

    def __init__(
        self, runtime, tracer, variant: str, local_size: int, chunk: int, defines, layout="queue"
    ):
        self.runtime = runtime
        self.tracer = tracer
        settings = parse_variant(variant, local_size, chunk, layout)
        self.regenerate = settings["regenerate"]
        self.width = settings["width"]
        self.local_size = settings["local_size"]
        self.chunk = settings["chunk"] if self.regenerate else None
        self.layout = settings["layout"] if self.regenerate else None
        # samples per work-item (regeneration: per chunk)
        self.per_item = self.width * (self.chunk if self.regenerate else 1)
        build = {"SIMD_WIDTH": self.width} | dict.fromkeys(defines, True)
        if self.regenerate:
            build["SIMD_CHUNK"] = self.chunk
            build["SIMD_LAYOUT"] = LAYOUTS[self.layout]
        name = "simd_paths_regen" if self.regenerate else "simd_paths"
        self.kernel = runtime.kernel("simd_paths_probe.cl", name, build)

    def global_size(self, count: int) -> int:
        """Work-items launched for count traced samples: one per SIMD_WIDTH samples, or per
        chunk with regeneration (the spread layout needs a work-item per chunk at least)."""
        return launch_global_size(-(-count // self.per_item), self.local_size)

    def working_groups(self, count: int) -> list[int] | None:
        """The work-groups that trace samples (None when work-items take chunks from a
        counter: then the threads' first work-items do)."""
        items = -(-count // self.per_item)
        if self.layout == "queue":
            return None
        if self.layout == "spread":
            size = self.global_size(count)
            return sorted({c * size // items // self.local_size for c in range(items)})
        return list(range(-(-items // self.local_size)))

    def trace(self, sets, seed, size, count=None):
        """Launch over the first count (default: all) traced samples of the sets."""
        runtime, tracer = self.runtime, self.tracer
        count = sets.traced_total if count is None else count
        global_size = self.global_size(count)
        radiance = runtime.allocate(12 * count)
        counters = runtime.upload(np.zeros(len(COUNTERS), np.uint32))
        args = tracer.scene_arguments()
        quads, quad_blocks, block_count, materials, emitters = (
            args[0],
            args[1],
            args[3],
            args[6],
            args[7],
        )
        event = self.kernel(
            runtime.queue,
            (global_size,),
            (self.local_size,),
            np.uint32(count),
            np.uint32(sets.pixel_count),
            np.uint32(seed),
            np.uint32(size),
            np.uint32(size),
            np.int32(tracer.max_depth),
            sets.positions,
            sets.offsets_buffer,
            sets.pixels_buffer,
            sets.redraws_buffer,
            tracer.camera_buffer(size, size),
            quads,
            quad_blocks,
            block_count,
            materials,
            emitters,
            radiance,
            counters,
        )
        return event, radiance, counters, count

    def read(self, radiance, counters, count):
        out = np.empty((count, 3), np.float32)
        cl.enqueue_copy(self.runtime.queue, out, radiance)
        c = np.empty(len(COUNTERS), np.uint32)
        cl.enqueue_copy(self.runtime.queue, c, counters)
        return out, dict(zip(COUNTERS, c.astype(np.int64).tolist(), strict=True))


def compare(reference: np.ndarray, other: np.ndarray) -> dict:
    """Per-sample agreement of two radiance arrays (T, 3)."""
    diff = np.abs(reference.astype(np.float64) - other.astype(np.float64))
    scale = np.maximum(np.abs(reference), np.abs(other)).astype(np.float64)
    rel = np.where(scale > 0, diff / np.where(scale > 0, scale, 1.0), 0.0)
    worst = int(np.argmax(rel.max(axis=1)))
    samples_equal = np.all(reference == other, axis=1)
    ref_mean = reference.astype(np.float64).mean(axis=0)
    other_mean = other.astype(np.float64).mean(axis=0)
    stderr = reference.astype(np.float64).std(axis=0) / np.sqrt(len(reference))
    return {
        "samples": len(reference),
        "samples_bit_equal": int(samples_equal.sum()),
        "fraction_bit_equal": float(samples_equal.mean()),
        "max_relative_difference": float(rel.max()),
        "max_absolute_difference": float(diff.max()),
        "worst_sample": worst,
        "worst_values": [reference[worst].tolist(), other[worst].tolist()],
        "samples_rel_diff_above_1e-6": int((rel.max(axis=1) > 1e-6).sum()),
        "mean_megakernel": ref_mean.tolist(),
        "mean_prototype": other_mean.tolist(),
        "mean_difference_in_stderr": ((other_mean - ref_mean) / stderr).tolist(),
    }


def pocl_deals(groups: int, threads: int = 2) -> list[int]:
    """The runs of consecutive work-groups PoCL's pthread device deals, one at a time, to
    whichever of its threads asks first (get_wg_index_range in pthread_scheduler.c, PoCL 3.0
    and 3.1): 256 * threads groups a run while more than 256 * threads**2 remain, then
    32 * threads, never more than an even share of what remains."""
    runs = []
    while groups > 0:
        limit = 256 * threads if groups > 256 * threads**2 else 32 * threads
        run = min(limit, -(-groups // threads))
        runs.append(run)
        groups -= run
    return runs


def deals_holding_work(groups: int, working_groups: list[int], threads: int = 2) -> int:
    """How many of PoCL's runs (pocl_deals) hold at least one of the given groups."""
    ends = np.cumsum(pocl_deals(groups, threads))
    return len(set(np.searchsorted(ends, working_groups, side="right").tolist()))


def timed(launch):
    """(wall s, cpu s, the busiest other thread's cpu s) of one launch, run to completion:
    PoCL's worker threads run the kernel, so busiest / cpu is 1 / threads when they share it
    evenly, 1 when one of them ran it all."""
    threads0 = thread_seconds()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    event = launch()
    event.wait()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    threads1 = thread_seconds()
    threads1.pop(str(threading.get_native_id()), None)
    busiest = max((s - threads0.get(t, 0.0) for t, s in threads1.items()), default=0.0)
    return wall, cpu, busiest


def main(argv=None):
    args = parse_args(argv)
    runtime = create_runtime(args.device)
    scene = load_scene(args.scene)
    check_scene(scene)
    tracer = PathTracer(runtime, scene, max_depth=args.max_depth)
    pixels = rectangle_pixels(args.size, 0, 0, args.size, args.size)
    sets = generate_sample_sets(
        runtime, make_sampler("independent", args.spp), args.seed, pixels, None, (args.size,) * 2
    )
    paths = sets.traced_total
    protos = {
        v: Prototype(runtime, tracer, v, args.local_size, args.chunk, args.define, args.layout)
        for v in args.variants
    }

    # Correctness (and warm-up: the first launch at a local size compiles a work-group function)
    mega = tracer.trace(sets, args.seed, args.size, args.size)
    reference = mega.to_host()
    report_widths = {}
    for w, proto in protos.items():
        event, radiance, counters, count = proto.trace(sets, args.seed, args.size)
        event.wait()
        out, stats = proto.read(radiance, counters, count)
        agreement = compare(reference, out)
        groups = proto.global_size(paths) // proto.local_size
        working = proto.working_groups(paths)
        lanes = {
            "pocl_deals": len(pocl_deals(groups)),
            "pocl_deals_holding_work": None
            if working is None
            else deals_holding_work(groups, working),
            "local_size": proto.local_size,
            "chunk": proto.chunk,
            "layout": proto.layout,
            "global_size": proto.global_size(paths),
            "work_groups": proto.global_size(paths) // proto.local_size,
            "work_groups_that_traced": stats["last_group"],
            "bounce_lane_utilisation": stats["bounce_lanes"]
            / (proto.width * stats["bounce_steps"]),
            "shadow_lane_utilisation": stats["shadow_lanes"]
            / (proto.width * max(stats["shadow_steps"], 1)),
            "rays_megakernel": mega.rays,
            "rays_prototype": stats["rays"],
            "nonfinite_megakernel": mega.nonfinite,
            "nonfinite_prototype": stats["nonfinite"],
        }
        report_widths[w] = {"agreement": agreement, "counters": stats, "lanes": lanes}
        print(
            f"simd{w}: {agreement['fraction_bit_equal'] * 100:.4f} % of samples bit-equal, "
            f"max rel diff {agreement['max_relative_difference']:.3g} "
            f"({agreement['samples_rel_diff_above_1e-6']} samples above 1e-6), means "
            f"{np.round(agreement['mean_megakernel'], 5)} vs "
            f"{np.round(agreement['mean_prototype'], 5)}; rays {mega.rays} vs {stats['rays']}; "
            f"lanes running per bounce {lanes['bounce_lane_utilisation'] * 100:.1f} %, per "
            f"shadow step {lanes['shadow_lane_utilisation'] * 100:.1f} %; groups "
            f"{lanes['work_groups']} of {proto.local_size}, the last that traced: "
            f"{stats['last_group']}, PoCL's runs of groups holding work: "
            f"{lanes['pocl_deals_holding_work']} of {lanes['pocl_deals']}",
            flush=True,
        )

    # Timing: alternate, round after round
    times = {"megakernel": []} | {f"simd{w}": [] for w in protos}
    loads = []
    for _ in range(args.rounds):
        loads.append(os.getloadavg()[0])
        times["megakernel"].append(
            timed(lambda: tracer.trace(sets, args.seed, args.size, args.size).event)
        )
        for w, proto in protos.items():
            times[f"simd{w}"].append(timed(lambda p=proto: p.trace(sets, args.seed, args.size)[0]))
    summary = {}
    for name, runs in times.items():
        cpu = [c for _, c, _ in runs]
        wall = [t for t, _, _ in runs]
        summary[name] = {
            "median_cpu_s": statistics.median(cpu),
            "median_wall_s": statistics.median(wall),
            "paths_per_cpu_s": paths / statistics.median(cpu),
            "paths_per_wall_s": paths / statistics.median(wall),
            "cpu_over_wall": statistics.median(c / t for t, c, _ in runs),
            "busiest_thread_share": statistics.median(b / c for _, c, b in runs),
            # the wall time of a launch on an otherwise idle machine is at least its busiest
            # thread's CPU: this rate holds whatever the load took from the process
            "paths_per_busiest_thread_s": paths / statistics.median(b for _, _, b in runs),
            "busiest_thread_s_all": [b for _, _, b in runs],
            "cpu_s_all": cpu,
            "wall_s_all": wall,
        }
    mega = times["megakernel"]
    for w in protos:
        name = f"simd{w}"
        ratios = [m[1] / r[1] for m, r in zip(mega, times[name], strict=True)]
        wall_ratios = [m[0] / r[0] for m, r in zip(mega, times[name], strict=True)]
        summary[name]["ratio_per_round"] = ratios
        summary[name]["median_ratio_to_megakernel"] = statistics.median(ratios)
        summary[name]["wall_ratio_per_round"] = wall_ratios
        summary[name]["median_wall_ratio_to_megakernel"] = statistics.median(wall_ratios)
    for name, row in summary.items():
        extra = ""
        if "median_ratio_to_megakernel" in row:
            r = row["ratio_per_round"]
            extra = (
                f" | x{row['median_ratio_to_megakernel']:.2f} of the megakernel in CPU "
                f"(rounds {min(r):.2f}-{max(r):.2f}), "
                f"x{row['median_wall_ratio_to_megakernel']:.2f} in wall"
            )
        print(
            f"{name:18s} {row['paths_per_cpu_s'] / 1e6:6.3f} M paths/CPU-s "
            f"{row['paths_per_wall_s'] / 1e6:6.3f} M paths/s wall "
            f"{row['paths_per_busiest_thread_s'] / 1e6:6.3f} per busiest-thread s, cpu/wall "
            f"{row['cpu_over_wall']:.2f}, busiest thread {row['busiest_thread_share']:.2f} of "
            f"the CPU{extra}",
            flush=True,
        )
    report = {
        "device": runtime.describe(),
        "platform": runtime.device.platform.version,
        "scene": args.scene,
        "size": args.size,
        "spp": args.spp,
        "max_depth": args.max_depth,
        "paths": paths,
        "rounds": args.rounds,
        "local_size": args.local_size,
        "chunk": args.chunk,
        "layout": args.layout,
        "defines": args.define,
        "loadavg_per_round": loads,
        "variants": report_widths,
        "timing": summary,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
