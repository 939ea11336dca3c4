"""Summaries, charts and report of the efficiency study (bench/efficiency_study.py writes the
renders; this module only reads its rows).

Per (configuration, spp): MSE as mean +- standard error over the seeds (the MSE of a render is
the mean over pixels and RGB channels of the squared error against its renderer's reference,
less that reference's own measured variance), median wall time of the call and median CPU time.
Time to a target MSE: the (median wall, mean MSE) points of a configuration joined on log-log
axes; where two consecutive spp bracket the target, the crossing of that segment
(interpolated); else the line through the two points nearest it, extended (extrapolated, said
so). The targets on mitsuba-cbox (clrender at most Mitsuba's MSE, and sooner to MSE 1e-4) are
checked in wall time (the clock they were set in) and in CPU time.

The clock of a scene's table and conclusions: wall time when its renders ran in the study's
process; CPU time when they ran on a Dask cluster (the entry's executor record), where the
workers render different configurations at once and a render's wall time includes waiting for
the cores the others use.

    python bench/efficiency_report.py DIR    # summaries, targets, charts, report.md of
                                             # DIR/results.json again, from its rows
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from bootstrap import ratio_interval  # noqa: E402
from common import MAX_DEPTH, VORONOI_ESTIMATORS, markdown_table, write_json  # noqa: E402
from figures import (  # noqa: E402
    caption,
    decade_log_axis,
    draw_caption,
    legend_beside,
    report_caption,
    save_figure,
    spread,
)

TARGET_MSE = 1e-4
# The names of the clocks of times_to_target, as the report writes them
CLOCK_NAMES = {"wall": "wall", "cpu": "CPU"}
# The table the targets were set from (an earlier run, quoted for comparison, never used as a
# result of this one): mitsuba-cbox 256 x 256, MSE against a 4096-spp reference less its
# variance, box filter.
EARLIER_TABLE = {
    "mitsuba/multijitter": {64: 1.04e-4, 256: 2.02e-5},
    "mitsuba/ldsampler": {64: 1.07e-4, 256: 2.49e-5},
    "mc/independent (as mc/uniform)": {64: 5.70e-4, 256: 1.37e-4},
    "vor_sn/sppp": {64: 4.11e-4, 256: 8.09e-5},
}
MARKERS = "osD^vP*Xh<>"
BOOTSTRAP = 2000  # resamples of a ratio's interval


def label_of(row: dict) -> str:
    return f"{row['estimator']}/{row['sampler']}"


def summarise(rows: list[dict]) -> list[dict]:
    """One point per (label, spp), in the order the rows first name them."""
    groups: dict[tuple[str, int], list[dict]] = {}
    for row in rows:
        groups.setdefault((label_of(row), row["spp"]), []).append(row)
    points = []
    for (label, spp), rs in groups.items():
        mse = spread([r["mse_minus_ref_noise"] for r in rs])
        points.append(
            {
                "label": label,
                "renderer": rs[0].get("renderer", "clrender"),
                "spp": spp,
                "seeds": mse["count"],
                "seed_list": [r["seed"] for r in rs],
                "mse": mse["mean"],
                "mse_se": mse["se"],
                "mse_per_seed": mse["values"],
                "mse_raw": statistics.fmean(r["mse"] for r in rs),
                "wall_s": statistics.median(r["call_s"] for r in rs),
                "cpu_s": statistics.median(r["cpu_s"] for r in rs),
                "unresolved_pixels": sum(r.get("unresolved_pixels", 0) for r in rs),
            }
        )
    return points


def series(points: list[dict], label: str) -> list[dict]:
    return sorted((p for p in points if p["label"] == label), key=lambda p: p["spp"])


def labels(points: list[dict], renderer: str | None = None) -> list[str]:
    return list(dict.fromkeys(p["label"] for p in points if renderer in (None, p["renderer"])))


def time_to_mse(pts: list[dict], target: float = TARGET_MSE, key: str = "wall_s") -> dict:
    """{"seconds", "how"}: log-log interpolation of (time, MSE) at the target (see module)."""
    pts = [p for p in pts if p["mse"] > 0 and p[key] > 0]
    if len(pts) < 2:
        return {"seconds": None, "how": "fewer than two points"}
    pairs = list(zip(pts, pts[1:], strict=False))
    bracket = [(a, b) for a, b in pairs if (a["mse"] - target) * (b["mse"] - target) <= 0]
    if bracket:
        a, b = bracket[0]
        how = f"interpolated {a['spp']}-{b['spp']} spp"
    else:
        a, b = pairs[-1] if pts[-1]["mse"] > target else pairs[0]
        how = f"extrapolated from {a['spp']}-{b['spp']} spp"
    la, lb = math.log(a["mse"]), math.log(b["mse"])
    if la == lb:
        return {"seconds": None, "how": "flat"}
    f = (math.log(target) - la) / (lb - la)
    seconds = math.exp(math.log(a[key]) + f * (math.log(b[key]) - math.log(a[key])))
    return {"seconds": seconds, "how": how}


def times_to_target(points: list[dict]) -> dict:
    return {
        label: {
            "wall": time_to_mse(series(points, label), key="wall_s"),
            "cpu": time_to_mse(series(points, label), key="cpu_s"),
        }
        for label in labels(points)
    }


def best(points: list[dict], spp: int, renderer: str) -> dict | None:
    cands = [p for p in points if p["spp"] == spp and p["renderer"] == renderer]
    return min(cands, key=lambda p: p["mse"]) if cands else None


def fastest(ttt: dict, points: list[dict], renderer: str, clock: str = "wall") -> tuple:
    """(label, entry) with the least time to the target MSE among a renderer's labels."""
    cands = [
        (label, t[clock])
        for label, t in ttt.items()
        if t[clock]["seconds"] and label in labels(points, renderer)
    ]
    return min(cands, key=lambda c: c[1]["seconds"]) if cands else (None, None)


def targets(entry: dict) -> dict:
    """The targets against Mitsuba 3 on mitsuba-cbox, from this run's points."""
    points, ttt = entry["summary"], entry["time_to_target"]
    out = {}
    for spp in (64, 256):
        ours = best(points, spp, "clrender")
        theirs = [p for p in points if p["label"] == "mitsuba/multijitter" and p["spp"] == spp]
        if ours is None:
            continue
        row = {"best_clrender": ours["label"], "mse": ours["mse"], "mse_se": ours["mse_se"]}
        if theirs:
            row["mitsuba_multijitter"] = theirs[0]["mse"]
            row["mitsuba_multijitter_se"] = theirs[0]["mse_se"]
            row["met_vs_this_run"] = ours["mse"] <= theirs[0]["mse"]
        earlier = EARLIER_TABLE["mitsuba/multijitter"].get(spp)
        row["earlier_table_multijitter"] = earlier
        row["met_vs_earlier_table"] = ours["mse"] <= earlier
        out[f"mse_{spp}spp"] = row
    # Wall time is the targets' clock; CPU time beside it, since other work on a shared machine
    # slows the two renderers' threads differently
    for clock, key in (("wall", "time_to_mse_1e-4"), ("cpu", "time_to_mse_1e-4_cpu")):
        ours_label, ours_t = fastest(ttt, points, "clrender", clock)
        theirs_label, theirs_t = fastest(ttt, points, "mitsuba", clock)
        out[key] = {
            "clrender": ours_label,
            "clrender_s": ours_t and ours_t["seconds"],
            "clrender_how": ours_t and ours_t["how"],
            "mitsuba": theirs_label,
            "mitsuba_s": theirs_t and theirs_t["seconds"],
            "mitsuba_how": theirs_t and theirs_t["how"],
            "met": bool(ours_t and theirs_t and ours_t["seconds"] < theirs_t["seconds"]),
        }
    return out


# ---------------------------------------------------------------------------------------------
# Charts


def plot_scene(axes, entry: dict) -> None:
    points = entry["summary"]
    names = labels(points)
    cmap = plt.get_cmap("tab20")
    for ax, key, what in zip(axes, ("wall_s", "cpu_s"), ("wall", "CPU"), strict=True):
        for i, label in enumerate(names):
            pts = series(points, label)
            mitsuba = pts[0]["renderer"] == "mitsuba"
            y = [p["mse"] for p in pts]
            se = [0.0 if math.isnan(p["mse_se"]) else p["mse_se"] for p in pts]
            lower = [min(s, 0.999 * v) if v > 0 else 0 for s, v in zip(se, y, strict=True)]
            ax.errorbar(
                [p[key] for p in pts],
                y,
                yerr=[lower, se],
                ls=":" if mitsuba else ("--" if label.startswith("mc") else "-"),
                marker=MARKERS[i % len(MARKERS)],
                ms=4,
                lw=1.6 if mitsuba else 1.0,
                capsize=2,
                color=cmap(i % 20),
                label=label,
            )
        ax.axhline(TARGET_MSE, color="0.5", lw=0.6, ls="-.", label=f"target MSE {TARGET_MSE:g}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        positive = [p["mse"] for p in points if p["mse"] > 0] + [TARGET_MSE]
        decade_log_axis(ax.xaxis, min(p[key] for p in points), max(p[key] for p in points))
        decade_log_axis(ax.yaxis, min(positive), max(positive))
        ax.grid(which="major", color="0.9", lw=0.6)
        ax.set(
            xlabel=f"{what} seconds per render (median over seeds)",
            ylabel="MSE - reference variance",
            title=f"MSE against {what} time",
        )


def figure_caption(scene: str, entry: dict) -> str:
    """Every parameter of a scene's chart: scene, resolution, spp, seeds, what the points and
    error bars are, the reference, device and Voronoi backend."""
    s, ref = entry["settings"], entry["reference"]
    peer = entry.get("peer", {}).get("status", {})
    return caption(
        f"Efficiency on {scene}: whole-image MSE against time per render",
        {
            "resolution": f"{s['size']} x {s['size']}",
            "spp": ", ".join(str(v) for v in s["spp"]),
            "seeds": f"{s['seeds']} per point (seeds {s['first_seed']} to "
            f"{s['first_seed'] + s['seeds'] - 1})",
            "points": "mean MSE over the seeds less the reference's variance, median time",
            "error bars": "+- 1 standard error of the mean over the seeds",
            "labels": "estimator/sampler (mc/independent: plain Monte Carlo over uniform "
            "samples, the paper's MC baseline; dashed: mc over other samplers; mitsuba/"
            "<sampler>: Mitsuba 3 against its own reference, dotted)",
            "reference": f"mc/{ref['sampler']}, {ref['spp']} spp in {ref['parts']} parts",
            "max depth": MAX_DEPTH,
            "device": entry.get("device", "not recorded"),
            "Voronoi cells": s.get("backend") or "not recorded",
            "Mitsuba": (
                f"{peer.get('version')} {peer.get('variant')}" if peer.get("available") else None
            ),
        },
    )


def scene_figure(scene: str, entry: dict):
    """The chart of one scene's finished entry: MSE against wall and CPU time."""
    fig, axes = plt.subplots(1, 2, figsize=(14, 6.5), layout="constrained")
    plot_scene(axes, entry)
    legend_beside(fig, axes)
    draw_caption(fig, figure_caption(scene, entry))
    return fig


def finished(results: dict) -> dict:
    """The scene entries whose run completed (an interrupted one has rows but no summary)."""
    return {k: e for k, e in results["scenes"].items() if e.get("complete", True)}


def plot_all(results: dict, out: Path) -> None:
    for scene, entry in finished(results).items():
        fig = scene_figure(scene, entry)
        save_figure(fig, out / f"efficiency_{scene}.png", dpi=100)
        plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Report


def fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.{digits}g}"


def clock_of(entry: dict) -> str:
    """The efficiency's clock of a scene's entry: "wall", or "cpu" for renders on a cluster."""
    return entry.get("executor", {}).get("clock", "wall")


def scene_table(entry: dict) -> str:
    points = entry["summary"]
    clock = clock_of(entry)
    spps = sorted({p["spp"] for p in points})
    header = ["config"]
    for spp in spps:
        header += [f"MSE {spp}", f"wall s {spp}", f"CPU s {spp}"]
    header += [f"t(1e-4) {CLOCK_NAMES[clock]} s", "how"]
    rows = []
    for label in labels(points):
        by = {p["spp"]: p for p in series(points, label)}
        row = [label]
        for spp in spps:
            p = by.get(spp)
            row += (
                [f"{fmt(p['mse'])} +- {fmt(p['mse_se'], 2)}", fmt(p["wall_s"]), fmt(p["cpu_s"])]
                if p
                else ["", "", ""]
            )
        t = entry["time_to_target"][label][clock]
        row += [fmt(t["seconds"]), t["how"]]
        rows.append(row)
    return markdown_table(header, rows)


def scene_section(scene: str, entry: dict) -> list[str]:
    s, ref = entry["settings"], entry["reference"]
    lines = [
        f"## {scene}",
        "",
        f"Command: `{s['command']}`",
        "",
        f"{s['size']} x {s['size']}, spp {s['spp']}, seeds {s['seeds']} per point, clrender "
        f"max depth 8. Reference: {ref['parts']} parts of mc/{ref['sampler']}, {ref['spp']} spp "
        f"in all, measured variance {fmt(entry['reference_noise'])} per pixel channel "
        "(subtracted from every MSE). Load average before/after: "
        f"{entry['machine_before']['load_1_5_15'][0]:.2f} / "
        f"{entry['machine_after']['load_1_5_15'][0]:.2f}.",
        "",
    ]
    where = entry.get("executor")
    if where is not None:
        clock = CLOCK_NAMES[clock_of(entry)]
        lines += [
            f"Renders ran in {where['where']}, each timed {where['timed']}; the times to "
            f"target and the conclusions are in {clock} time"
            + (
                " (the workers render at once and share the cores: wall time includes waiting "
                "for the others; Mitsuba's peer renders ran in the study's process, between "
                "rounds)."
                if where["clock"] == "cpu"
                else "."
            ),
            "",
        ]
    peer = entry.get("peer")
    if peer is not None:
        lines += peer_lines(peer)
    lines += [
        "MSE (mean +- standard error over seeds), median wall (whole call) and CPU seconds per "
        "render; t(1e-4): time to MSE 1e-4 on log-log axes (efficiency_report.time_to_mse):",
        "",
        scene_table(entry),
        "",
    ]
    ours = {spp: best(entry["summary"], spp, "clrender") for spp in s["spp"]}
    lines += [
        "Best clrender configuration per spp: "
        + ", ".join(
            f"{spp}: {p['label']} {fmt(p['mse'])} +- {fmt(p['mse_se'], 2)}"
            for spp, p in ours.items()
            if p
        ),
        "",
    ]
    for skip in entry.get("skipped", []):
        lines.append(
            f"- Not rendered at {skip['spp']} spp and above: {skip['config']} (predicted "
            f"{skip['predicted_s']:.3g} s per render from its {skip['from']}, over --max-seconds)"
        )
    if entry.get("skipped"):
        lines.append("")
    if "targets" in entry:
        lines += target_lines(entry["targets"])
    lines += conclusions(entry)
    lines += [
        f"![{scene}](efficiency_{scene}.png)",
        "",
        report_caption(figure_caption(scene, entry)),
        "",
    ]
    return lines


def is_voronoi(label: str) -> bool:
    return label.split("/")[0] in VORONOI_ESTIMATORS


def mse_ratio(a: dict, b: dict, rng) -> dict:
    """MSE(a) / MSE(b) of two points (means over their seeds) and its 95 % percentile bootstrap
    interval over the seeds (bench/bootstrap.py; independent draws, each resampled on its own;
    no interval under two seeds a point)."""
    x, y = (np.asarray(p.get("mse_per_seed", [p["mse"]])) for p in (a, b))
    if a["mse"] <= 0 or b["mse"] <= 0:
        return {"ratio": None, "why": "an MSE at or below the reference's variance"}
    if min(len(x), len(y)) < 2:
        return {"ratio": a["mse"] / b["mse"], "lo": None, "hi": None}
    ratio, lo, hi = ratio_interval(x, y, np.mean, rng, paired=False, resamples=BOOTSTRAP)
    return {"ratio": ratio, "lo": lo, "hi": hi}


def ratio_words(r: dict, what: str) -> str:
    """'0.81x [0.72, 0.9] the MSE of X (lower)' from mse_ratio's result."""
    if r["ratio"] is None:
        return f"no ratio to {what} ({r['why']})"
    if r["lo"] is None:
        return f"{fmt(r['ratio'])}x the MSE of {what} (one seed: no interval)"
    verdict = "lower" if r["hi"] < 1 else "higher" if r["lo"] > 1 else "not significantly different"
    return f"{fmt(r['ratio'])}x [{fmt(r['lo'])}, {fmt(r['hi'])}] the MSE of {what} ({verdict})"


def fastest_to_target(
    ttt: dict, points: list[dict], voronoi: bool, clock: str = "wall"
) -> tuple[str, float] | None:
    """(label, seconds to the target MSE on the clock) of the fastest Voronoi (or baseline)
    label."""
    times = [
        (label, ttt[label][clock]["seconds"])
        for label in labels(points)
        if is_voronoi(label) == voronoi and ttt[label][clock]["seconds"]
    ]
    return min(times, key=lambda t: t[1]) if times else None


def conclusions(entry: dict) -> list[str]:
    """What the scene's run shows, as ratios of this run's points: at the highest spp every
    family rendered, the best Voronoi configuration against the best Monte Carlo one and against
    mc/independent (plain Monte Carlo over uniform samples, the paper's MC), and the fastest of
    each family to MSE 1e-4."""
    points = [p for p in entry["summary"] if p["renderer"] == "clrender"]
    spps = [
        spp
        for spp in sorted({p["spp"] for p in points}, reverse=True)
        if any(is_voronoi(p["label"]) for p in points if p["spp"] == spp)
        and any(not is_voronoi(p["label"]) for p in points if p["spp"] == spp)
    ]
    if not spps:
        return []
    top = spps[0]
    at_top = [p for p in points if p["spp"] == top]
    vor = min((p for p in at_top if is_voronoi(p["label"])), key=lambda p: p["mse"])
    mc = min((p for p in at_top if not is_voronoi(p["label"])), key=lambda p: p["mse"])
    rng = np.random.default_rng(0)
    lines = [
        "Conclusions (from this run; ratios of mean MSE over the seeds with 95 % bootstrap "
        "intervals over the seeds; baselines are the Monte Carlo configurations mc/<sampler> "
        "and mc_n/<sampler>, mc/independent being the paper's MC):",
        "",
        f"- At {top} spp the lowest-MSE Voronoi configuration, {vor['label']}, has "
        + ratio_words(mse_ratio(vor, mc, rng), f"the best baseline, {mc['label']}")
        + ".",
    ]
    plain = next((p for p in at_top if p["label"] == "mc/independent"), None)
    if plain is not None and plain is not mc:
        lines.append(
            f"- {vor['label']} has "
            + ratio_words(mse_ratio(vor, plain, rng), "mc/independent")
            + f"; {mc['label']} has "
            + ratio_words(mse_ratio(mc, plain, rng), "mc/independent")
            + "."
        )
    clock = clock_of(entry)
    fastest_vor = fastest_to_target(entry["time_to_target"], points, True, clock)
    fastest_mc = fastest_to_target(entry["time_to_target"], points, False, clock)
    if fastest_vor and fastest_mc:
        (vor_label, t_vor), (mc_label, t_mc) = fastest_vor, fastest_mc
        faster = "the Voronoi configuration" if t_vor < t_mc else "the baseline"
        lines.append(
            f"- Fastest to MSE {TARGET_MSE:g} in {CLOCK_NAMES[clock]} time: {vor_label} "
            f"{fmt(t_vor)} s among the "
            f"Voronoi configurations, {mc_label} {fmt(t_mc)} s among the baselines, a ratio of "
            f"{fmt(t_vor / t_mc)} ({faster} is faster; each time interpolated or extrapolated as "
            "the table says)."
        )
    return lines + [""]


def peer_lines(peer: dict) -> list[str]:
    status = peer["status"]
    if not status["available"]:
        return [f"**Mitsuba peer: not run** -- {status['why']}.", ""]
    lines = [
        f"Mitsuba peer: Mitsuba {status['version']}, variant {status['variant']} "
        f"(libLLVM: {status.get('libllvm')}), max_depth {status['max_depth']}, box filter, "
        "alternated with clrender's renders, one untimed warm-up render per sampler and spp. "
        f"Its reference: {peer['reference']['parts']} parts of {peer['reference']['sampler']}, "
        f"{peer['reference']['spp']} spp in all, measured variance "
        f"{fmt(peer['reference_noise'])}. MSE between the two renderers' references "
        f"(less both variances): {fmt(peer['reference_mse_between'])} "
        f"(raw {fmt(peer['reference_mse_between_raw'])}).",
        "",
    ]
    if not status["comparable_timings"]:
        lines += [
            "**Mitsuba ran on its scalar variant (no LLVM): its timings are not comparable.**",
            "",
        ]
    return lines


def target_lines(t: dict) -> list[str]:
    lines = [
        "Targets against Mitsuba 3 (clrender's best MSE at most Mitsuba multijitter's at 64 and "
        "256 spp; clrender sooner to MSE 1e-4 than Mitsuba's fastest sampler):",
        "",
    ]
    for spp in (64, 256):
        row = t.get(f"mse_{spp}spp")
        if not row:
            continue
        lines.append(
            f"- MSE at {spp} spp: best clrender {row['best_clrender']} {fmt(row['mse'])} +- "
            f"{fmt(row['mse_se'], 2)}; Mitsuba multijitter in this run "
            f"{fmt(row.get('mitsuba_multijitter'))} +- {fmt(row.get('mitsuba_multijitter_se'), 2)}"
            f" -> {'met' if row.get('met_vs_this_run') else 'NOT met'}; the earlier run's "
            f"table {fmt(row['earlier_table_multijitter'])} -> "
            f"{'met' if row['met_vs_earlier_table'] else 'NOT met'}."
        )
    for clock, key in (("wall", "time_to_mse_1e-4"), ("CPU", "time_to_mse_1e-4_cpu")):
        tt = t.get(key)
        if tt is None:  # results from before CPU time was a target
            continue
        lines.append(
            f"- Time to MSE 1e-4 ({clock}): clrender's fastest {tt['clrender']} "
            f"{fmt(tt['clrender_s'])} s ({tt['clrender_how']}); Mitsuba's fastest "
            f"{tt['mitsuba']} {fmt(tt['mitsuba_s'])} s ({tt['mitsuba_how']}) -> "
            f"{'met' if tt['met'] else 'NOT met'}."
        )
    return lines + [""]


def report(results: dict) -> str:
    lines = [
        "# Efficiency study: image MSE against time",
        "",
        "Every render is scored against its own renderer's reference (mean of parts, variance "
        "measured from their spread), as MSE - reference variance: an unbiased estimate of the "
        "error against the true image. Wall time: the whole render call to the image in hand; "
        "CPU time: the process's (OpenCL's PoCL threads and Dr.Jit's run in-process).",
        "",
        "The table the Mitsuba targets were set from (an earlier run on mitsuba-cbox, 256 x "
        "256, for comparison only): "
        + "; ".join(
            f"{k} {', '.join(f'{s} spp {fmt(v)}' for s, v in d.items())}"
            for k, d in EARLIER_TABLE.items()
        ),
        "",
    ]
    for scene, entry in results["scenes"].items():
        if entry.get("complete", True):
            lines += scene_section(scene, entry)
        else:
            rounds = len({(r["spp"], r["seed"]) for r in entry["rows"]})
            lines += [
                f"## {scene}: interrupted after {rounds} (spp, seed) rounds",
                "",
                f"Resume with the same command: `{entry['settings']['command']}`",
                "",
            ]
    return "\n".join(lines)


def rebuild(out: Path) -> None:
    """Summaries, targets, charts and report.md of out/results.json recomputed from its rows
    (after a change to this module; the renders are not run again)."""
    path = out / "results.json"
    results = json.loads(path.read_text())
    for entry in finished(results).values():
        entry["summary"] = summarise(entry["rows"])
        entry["time_to_target"] = times_to_target(entry["summary"])
        if "targets" in entry:
            entry["targets"] = targets(entry)
    write_json(path, results)
    plot_all(results, out)
    (out / "report.md").write_text(report(results) + "\n")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=rebuild.__doc__.split("\n")[0])
    parser.add_argument("out", type=Path, help="a study's output folder (holds results.json)")
    rebuild(parser.parse_args().out)
