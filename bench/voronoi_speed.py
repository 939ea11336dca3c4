"""Speed of the Voronoi stage against Qhull's bare Delaunay triangulation.

    python bench/voronoi_speed.py [--quick] [--repeats K] [--out FILE]

Prints, as medians over K repeats (the machine is shared): the time of one 4096-sample pixel
estimate (vor: all cell areas + the estimate; target <= 2 ms), the ratio of the whole vor stage
to bare scipy.spatial.Delaunay on the same point arrays (target <= 1.3; measured both on the
arrays the stage hands to Qhull and one pixel per call), and microseconds per sample for
n = 64 ... 4096 and for a batch of 4096 pixels. One thread (Qhull is single-threaded).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.spatial import Delaunay  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from clrender.estimators import PixelSamples, estimate  # noqa: E402
from clrender.sppp import draw_sppp  # noqa: E402
from clrender.voronoi_cells import QHULL_OPTIONS, qhull_point_arrays  # noqa: E402


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def measure(n: int, pixels: int, repeats: int, rng: np.random.Generator) -> dict:
    batch = draw_sppp(rng, n, pixels)
    samples = PixelSamples.from_sppp(batch, np.abs(batch.traced[:, 0] * batch.traced[:, 1]), n)
    arrays = qhull_point_arrays(batch.traced, batch.offsets, batch.aux, batch.aux_offsets)
    per_pixel = [np.concatenate([batch.traced[batch.offsets[p]:batch.offsets[p + 1]],
                                 batch.aux[batch.aux_offsets[p]:batch.aux_offsets[p + 1]]])
                 for p in range(pixels)]

    def bare_same_calls():
        for points in arrays:
            Delaunay(points, qhull_options=QHULL_OPTIONS)

    def bare_per_pixel():
        for points in per_pixel:
            Delaunay(points)

    stage = median_time(lambda: estimate("vor", samples), repeats)
    bare_calls = median_time(bare_same_calls, repeats)
    bare_pixels = median_time(bare_per_pixel, repeats)
    samples_count = len(batch.traced)
    return {"n": n, "pixels": pixels, "samples": samples_count,
            "points": samples_count + len(batch.aux), "qhull_calls": len(arrays),
            "stage_ms_per_pixel": 1e3 * stage / pixels,
            "bare_same_calls_ms_per_pixel": 1e3 * bare_calls / pixels,
            "bare_per_pixel_ms_per_pixel": 1e3 * bare_pixels / pixels,
            "ratio_same_calls": stage / bare_calls, "ratio_per_pixel": stage / bare_pixels,
            "us_per_sample": 1e6 * stage / samples_count}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "voronoi_speed.json")
    args = parser.parse_args(argv)
    repeats = args.repeats or (3 if args.quick else 7)
    rng = np.random.default_rng(7)
    rows = []
    # One 4096-sample pixel, then n = 64 ... 4096 over enough pixels for ~0.2 M samples.
    rows.append(measure(4096, 1, repeats * 3, rng))
    for n in [64, 256, 1024, 4096]:
        pixels = 4 if args.quick else max(2, 200_000 // n)
        rows.append(measure(n, pixels, repeats, rng))
    # A batch of 4096 pixels (n = 64 in quick mode, 256 otherwise).
    rows.append(measure(64 if args.quick else 256, 4096 if not args.quick else 256, 3, rng))
    print("| n | pixels | Qhull calls | stage ms/pixel | bare (same calls) | bare (per pixel) | "
          "stage/bare same | stage/bare per-pixel | us/sample |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['n']} | {r['pixels']} | {r['qhull_calls']} | "
              f"{r['stage_ms_per_pixel']:.3f} | {r['bare_same_calls_ms_per_pixel']:.3f} | "
              f"{r['bare_per_pixel_ms_per_pixel']:.3f} | {r['ratio_same_calls']:.3f} | "
              f"{r['ratio_per_pixel']:.3f} | {r['us_per_sample']:.2f} |")
    single = rows[0]
    print(f"one 4096-sample pixel: {single['stage_ms_per_pixel']:.2f} ms (target <= 2 ms; bare "
          f"Qhull alone on its {single['points']} points: "
          f"{single['bare_same_calls_ms_per_pixel']:.2f} ms)")
    print(f"vor stage / bare Delaunay (same calls), n = 4096: {rows[4]['ratio_same_calls']:.3f} "
          "(target <= 1.3)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"repeats": repeats, "rows": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
