"""Sample-generation throughput: samples per second for each sampler and n over an image.

    python bench/sample_throughput.py [--res 256] [--n 64 256 1024 4096] [--repeats 5]
                                      [--device D] [--out bench/results/sample_throughput.json]

Each configuration draws every pixel's sample set tile by tile (about --tile-samples traced
samples per launch, buffers released between tiles), waiting for the device after each tile.
Reported: median over repeats of the whole image's time, traced samples per second, and all
samples (traced + auxiliary nuclei) per second. One warm-up pass per sampler builds the
program and JIT-compiles the work-group function first.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from common import machine

from clrender.runtime import create_runtime
from clrender.sampling import SAMPLERS, generate_sample_sets, make_sampler, rectangle_pixels


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--res", type=int, default=256, help="image width = height (pixels)")
    parser.add_argument("--n", type=int, nargs="+", default=[64, 256, 1024, 4096])
    parser.add_argument("--samplers", nargs="+", default=list(SAMPLERS))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tile-samples", type=int, default=1 << 22)
    parser.add_argument("--device", default=None)
    parser.add_argument("--out", type=Path, default=Path("bench/results/sample_throughput.json"))
    return parser.parse_args()


def image_rows_per_tile(res: int, n: int, tile_samples: int) -> int:
    return max(1, min(res, tile_samples // (n * res)))


def draw_image(runtime, config, res: int, rows: int, seed: int) -> tuple[int, int]:
    """Draw every pixel's set, tile by tile; returns (traced, auxiliary) sample counts."""
    traced = aux = 0
    for y0 in range(0, res, rows):
        pixels = rectangle_pixels(res, 0, y0, res, min(rows, res - y0))
        sets = generate_sample_sets(runtime, config, seed, pixels, None, (res, res))
        runtime.queue.finish()
        traced += sets.traced_total
        aux += sets.aux_total
        sets.positions.release()
    return traced, aux


def measure(runtime, sampler: str, n: int, args) -> dict:
    config = make_sampler(sampler, n)
    rows = image_rows_per_tile(args.res, n, args.tile_samples)
    times = []
    for repeat in range(args.repeats):
        start = time.perf_counter()
        traced, aux = draw_image(runtime, config, args.res, rows, seed=repeat)
        times.append(time.perf_counter() - start)
    median = statistics.median(times)
    return {
        "sampler": sampler,
        "n": n,
        "resolution": args.res,
        "tile_rows": rows,
        "traced_samples": traced,
        "auxiliary_nuclei": aux,
        "median_seconds": median,
        "seconds": times,
        "traced_samples_per_second": traced / median,
        "all_samples_per_second": (traced + aux) / median,
    }


def format_row(row: dict) -> str:
    return (
        f"{row['sampler']:>10} n={row['n']:>5}: {row['median_seconds']:7.3f} s, "
        f"{row['traced_samples_per_second'] / 1e6:8.1f} M traced samples/s, "
        f"{row['all_samples_per_second'] / 1e6:8.1f} M samples/s incl. auxiliary"
    )


def main() -> None:
    args = parse_args()
    runtime = create_runtime(args.device)
    before = machine()
    results = []
    for sampler in args.samplers:
        draw_image(runtime, make_sampler(sampler, 16), 16, 16, seed=0)  # warm-up (16: any sampler)
        for n in args.n:
            row = measure(runtime, sampler, n, args)
            results.append(row)
            print(format_row(row))
    report = {
        "device": runtime.describe(),
        "machine_before": before,
        "machine_after": machine(),
        "repeats": args.repeats,
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(json.dumps(report))


if __name__ == "__main__":
    main()
