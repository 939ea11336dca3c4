"""Voronoi cells of single pixels coloured by traced radiance: the paper's Figure 8.

    python bench/cells_figure.py [--quick] [--n 64 256] [--out DIR]

Pixels found from the scenes' geometry (clrender.probes): the light-edge pixel and the diffuse
back-wall pixel of the authors' Cornell box, and a glossy highlight of cornell-box-glossy (the
brightest pixel of a short render among pixels seeing the glossy box). For each pixel and n:
one SPPP sample set (redrawn while a W nucleus has an unbounded cell, as the renderer does),
traced; Voronoi cells of W + auxiliary nuclei from scipy.spatial.Voronoi, clipped to W' for
display; each W nucleus' cell filled with its sample's radiance (sRGB of RGB clamped to
[0, 1]) and outlined in black, cells whose radiance was clamped (brighter than display white,
such as the light's) hatched as well; auxiliary cells outlined in white only, over a blue
background (BACKGROUND) that no radiance colour of white or grey takes, so the light's white
cells stand out from it; auxiliary nuclei in navy, the pixel border W in red and W' dashed. The
title gives the pixel's mc and vor_sn estimates (RGB mean); the caption every parameter.
Outputs (default bench/results/cells_figure/): cells_<pixel>_n<n>.png, cells.png (all).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import MAX_DEPTH, RESULTS, make_source, make_tracer, timed_render  # noqa: E402
from figures import caption, draw_caption, save_figure  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402
from scipy.spatial import Voronoi  # noqa: E402

from clrender.estimators import estimate_all  # noqa: E402
from clrender.imageio import srgb_encode  # noqa: E402
from clrender.probes import (  # noqa: E402
    clip_to_box,
    diffuse_wall_pixel,
    glossy_highlight_pixel,
    light_edge_pixel,
    trace_pixel_runs,
)
from clrender.runtime import create_runtime  # noqa: E402
from clrender.samples import SampleSets  # noqa: E402
from clrender.sampling import make_sampler  # noqa: E402

MAX_REDRAWS = 20
# Behind the cells: a mid blue, far from the white of the light's cells and from the black and
# greys of unlit ones.
BACKGROUND = "#8fb0d0"
CLAMPED_HATCH = "////"


def find_pixels(runtime, size: int) -> list[tuple[str, str, object]]:
    """(name, scene, ProbePixel) of the three pixels."""
    tracer = make_tracer(runtime, "cornell-box")
    glossy_source = make_source(runtime, "cornell-box-glossy", size, size)
    short, _ = timed_render(runtime, glossy_source, "mc", "stratified", 64, 3)
    scene = tracer.scene
    return [
        ("light_edge", "cornell-box", light_edge_pixel(scene, size, size)),
        ("diffuse_wall", "cornell-box", diffuse_wall_pixel(scene, size, size)),
        (
            "glossy_highlight",
            "cornell-box-glossy",
            glossy_highlight_pixel(glossy_source.tracer.scene, short),
        ),
    ]


def draw_accepted(runtime, tracer, n: int, pixel: int, size: int, seed: int):
    """(runs, sampler, estimates): the first draw whose W cells are all bounded."""
    sampler = make_sampler("sppp", n)
    for redraw in range(MAX_REDRAWS):
        runs = trace_pixel_runs(runtime, tracer, sampler, seed, pixel, 1, size, size, redraw)
        sets = runs.sets
        samples = SampleSets(
            sets.traced.astype(np.float64),
            sets.offsets,
            float(n),
            sets.aux.astype(np.float64),
            sets.aux_offsets,
            sampler.eps,
        )
        result = estimate_all(["mc", "vor_sn"], samples, runs.radiance.mean(axis=1))
        if not result["vor_sn"].needs_redraw[0]:
            return runs, sampler, {k: float(r.estimates[0]) for k, r in result.items()}
    raise RuntimeError(f"pixel {pixel}: every one of {MAX_REDRAWS} draws was rejected")


def cell_polygons(points: np.ndarray, box: float) -> list[np.ndarray | None]:
    """Each point's Voronoi cell clipped to [-box, box]^2 (None where unbounded)."""
    vor = Voronoi(points)
    polygons = []
    for region_index in vor.point_region:
        region = vor.regions[region_index]
        if -1 in region or not region:
            polygons.append(None)
        else:
            polygons.append(clip_to_box(vor.vertices[region], (-box, -box), (box, box)))
    return polygons


def draw_cells(ax, runs, sampler, estimates: dict, title: str) -> None:
    traced = runs.sets.traced.astype(np.float64)
    aux = runs.sets.aux.astype(np.float64)
    box = 0.5 + sampler.eps
    polygons = cell_polygons(np.vstack([traced, aux]), box)
    radiance = np.asarray(runs.radiance, dtype=np.float64)
    colours = srgb_encode(radiance)
    clamped = (radiance > 1.0).any(axis=1)
    traced_cells = polygons[: len(traced)]  # all bounded: the draw was accepted
    ax.set_facecolor(BACKGROUND)
    aux_cells = [p for p in polygons[len(traced) :] if p is not None and len(p) >= 3]
    ax.add_collection(
        PolyCollection(aux_cells, facecolors="none", edgecolors="white", linewidths=0.5)
    )
    ax.add_collection(
        PolyCollection(traced_cells, facecolors=colours, edgecolors="k", linewidths=0.6)
    )
    if clamped.any():
        ax.add_collection(
            PolyCollection(
                [cell for cell, bright in zip(traced_cells, clamped, strict=True) if bright],
                facecolors="none",
                edgecolors="0.45",
                linewidths=0.0,
                hatch=CLAMPED_HATCH,
            )
        )
    ax.plot(traced[:, 0], traced[:, 1], ".", color="k", ms=1.5, label="W nuclei (traced)")
    ax.plot(aux[:, 0], aux[:, 1], ".", color="navy", ms=3, label="auxiliary nuclei")
    ax.add_patch(Rectangle((-0.5, -0.5), 1, 1, fill=False, ec="red", lw=1.5, label="pixel W"))
    ax.add_patch(
        Rectangle((-box, -box), 2 * box, 2 * box, fill=False, ec="0.4", ls="--", lw=0.8, label="W'")
    )
    ax.set_xlim(-box - 0.02, box + 0.02)
    ax.set_ylim(box + 0.02, -box - 0.02)  # image y grows downwards
    ax.set_aspect("equal")
    ax.set(xlabel="pixel-local x", ylabel="pixel-local y (down)")
    ax.set_title(
        f"{title}\nN = {len(traced)}, mc {estimates['mc']:.3f}, vor_sn "
        f"{estimates['vor_sn']:.3f} (RGB mean)",
        fontsize=9,
    )


def legend(ax) -> None:
    """The legend, with the background and the hatching of clamped cells explained."""
    handles, _ = ax.get_legend_handles_labels()
    handles += [
        Patch(facecolor="white", edgecolor="k", hatch=CLAMPED_HATCH, label="radiance > 1, clamped"),
        Patch(facecolor=BACKGROUND, edgecolor="white", label="auxiliary cells (outline)"),
    ]
    ax.legend(handles=handles, fontsize=7, loc="lower right", framealpha=0.9)


def figure_caption(args, device: str) -> str:
    return caption(
        "SPPP Voronoi cells of single pixels coloured by traced radiance (the paper's Figure 8)",
        {
            "resolution": f"{args.size} x {args.size}",
            "n (SPPP intensity)": ", ".join(str(n) for n in args.n),
            "draws": f"one accepted draw per pixel and n (seed {args.seed}, redrawn while a W "
            "cell is unbounded)",
            "sampler": "sppp",
            "estimators in the titles": "mc and vor_sn, RGB mean",
            "colour": "sRGB of the radiance clamped to [0, 1]",
            "max depth": MAX_DEPTH,
            "device": device,
        },
    )


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run: n = 16 only")
    parser.add_argument("--n", type=int, nargs="+", default=None, help="default 64 256")
    parser.add_argument("--size", type=int, default=256, help="image width = height")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS / "cells_figure")
    args = parser.parse_args(argv)
    args.n = args.n or ([16] if args.quick else [64, 256])
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    runtime = create_runtime()
    pixels = find_pixels(runtime, args.size)
    tracers = {scene: make_tracer(runtime, scene) for scene in {p[1] for p in pixels}}
    fig, axes = plt.subplots(
        len(args.n),
        len(pixels),
        figsize=(5 * len(pixels), 5.2 * len(args.n) + 0.6),
        squeeze=False,
        layout="constrained",
    )
    for col, (name, scene, pixel) in enumerate(pixels):
        print(f"{name} ({scene}): {pixel.as_dict()}", flush=True)
        for row, n in enumerate(args.n):
            drawn = draw_accepted(runtime, tracers[scene], n, pixel.pixel, args.size, args.seed)
            title = f"{name} ({pixel.x}, {pixel.y}) of {scene}, n = {n}"
            one, ax = plt.subplots(figsize=(5.5, 5.8))
            draw_cells(ax, *drawn, title)
            legend(ax)
            one.tight_layout()
            one.savefig(args.out / f"cells_{name}_n{n}.png", dpi=110)
            plt.close(one)
            draw_cells(axes[row, col], *drawn, title)
    legend(axes[0, 0])
    draw_caption(fig, figure_caption(args, runtime.describe()), width=130)
    save_figure(fig, args.out / "cells.png", dpi=90)
    plt.close(fig)
    print(f"wrote {args.out}/cells.png and one PNG per pixel and n")


if __name__ == "__main__":
    main()
