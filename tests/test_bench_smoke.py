"""Smoke runs of the study benches at tiny settings, in-process (a few seconds each): every
output file is written and the JSON holds what the report quotes; and the figures read as a
paper's: several seeds (or runs) behind each point with its spread, every parameter in each
caption, no two labels overlapping, baselines named apart, the paper's values labelled with
their own n or spp, and no tracker references in the scripts' help."""

import json
import re
import runpy
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

pytest.importorskip("matplotlib")
common = pytest.importorskip("common")


@pytest.fixture(autouse=True)
def private_references(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "REFERENCE_DIR", tmp_path / "references")


@pytest.mark.device
def test_01_pixel_study(tmp_path):
    import pixel_study

    # A pixel of a Cornell box and one of veach-mis (every probe's finder is tested in
    # test_probes / test_veach_mis; the study's figures take most of this test's time)
    chosen = ["light_edge", "veach_small_on_glossy"]
    pixel_study.main(
        [
            "--quick",
            "--pixels",
            *chosen,
            "--runs",
            "4",
            "--spp",
            "16",
            "--timing-runs",
            "2",
            "--size",
            "64",
            "--out",
            str(tmp_path),
        ]
    )
    results = json.loads((tmp_path / "results.json").read_text())
    assert list(results["pixels"]) == chosen
    assert results["settings"]["executor"] == "this process"
    for name, entry in results["pixels"].items():
        assert entry["scene"] == pixel_study.PROBES[name].scene
        assert (tmp_path / f"fig6_{name}.png").exists() and (tmp_path / f"fig9_{name}.png").exists()
        for point in entry["table"]["16"].values():  # each variance's interval over the runs
            low, high = point["var_ci"]
            assert low <= point["var"] <= high
    report = (tmp_path / "report.md").read_text()
    assert "of cornell-box\n" in report and "of veach-mis\n" in report
    captions = [line for line in report.splitlines() if line.startswith("*Figure 9")]
    assert len(captions) == len(chosen)
    for words in ("of 64 x 64", "spp 16", "R = 4", "seed 7", "device ", "bootstrap"):
        assert all(words in line for line in captions), words


@pytest.mark.device
def test_02_image_study(tmp_path):
    import image_study

    image_study.main(
        ["--quick", "--size", "8", "--spp", "4", "--reference-spp", "16", "--out", str(tmp_path)]
    )
    results = json.loads((tmp_path / "results.json").read_text())
    assert len(results["rows"]) == len(common.RENDER_PAIRS)
    assert len(results["renders"]) == 2 * len(common.RENDER_PAIRS)  # --quick: 2 seeds a pair
    for row in results["rows"]:
        assert row["seeds"] == [1, 2] and len(row["mse_per_seed"]) == 2
        assert row["mse"] == pytest.approx(np.mean(row["mse_per_seed"]))
        assert row["mse_se"] == pytest.approx(np.std(row["mse_per_seed"], ddof=1) / np.sqrt(2))
    for name in ("error_maps.png", "renders.png", "mse.png", "report.md"):
        assert (tmp_path / name).exists()
    report = (tmp_path / "report.md").read_text()
    captions = [line for line in report.splitlines() if line.startswith("*")]
    assert len(captions) == 3  # mse, renders, error maps
    for words in ("cornell-box", "8 x 8", "spp 4", "device ", "reference mc/sobol, 16 spp"):
        assert all(words in line for line in captions), words
    assert "seeds 2 per pair (1, 2)" in captions[0] and "standard error" in captions[0]
    # The paper's MSE is at 256 spp: its column says so, and the text that this run is not
    assert "paper MSE (256 spp)" in report and "this run is at 4 spp" in report
    assert re.search(r"vor_sn/sppp = \d+\.\d+ \[-?\d+\.\d+, \d+\.\d+\]", report)


@pytest.mark.device
def test_03_efficiency_study_and_perf_ratio(tmp_path):
    import efficiency_study

    efficiency_study.main(
        [
            "--quick",
            "--size",
            "8",
            "--spp",
            "4",
            "--reference-spp",
            "16",
            "--scenes",
            "cornell-box",
            "--out",
            str(tmp_path),
        ]
    )
    assert (tmp_path / "efficiency_cornell-box.png").exists()
    results = json.loads((tmp_path / "results.json").read_text())
    entry = results["scenes"]["cornell-box"]
    labels = {p["label"] for p in entry["summary"]}
    assert labels == {common.pair_label(*c) for c in efficiency_study.CONFIGS}
    assert all(p["seeds"] == 2 for p in entry["summary"])  # --quick: 2 seeds per point
    for point in entry["summary"]:  # the spread behind each error bar, and its values
        assert point["seed_list"] == [1, 2] and len(point["mse_per_seed"]) == 2
        assert point["mse"] == pytest.approx(np.mean(point["mse_per_seed"]))
        assert point["mse_se"] == pytest.approx(np.std(point["mse_per_seed"], ddof=1) / np.sqrt(2))
    report = (tmp_path / "report.md").read_text()
    caption = next(line for line in report.splitlines() if line.startswith("*Efficiency on"))
    for words in (
        "cornell-box",
        "resolution 8 x 8",
        "spp 4;",
        "seeds 2 per point",
        "standard error",
        "reference mc/sobol, 16 spp",
        f"device {entry['device']}",
        "Voronoi cells",
    ):
        assert words in caption, words
    assert "issue" not in report.lower()
    assert "Conclusions (from this run" in report
    assert re.search(r"the best baseline, mc(_n)?/\S+ \(", report) or "no ratio" in report
    efficiency_study.main(
        ["--perf-ratio", "--quick", "--size", "8", "--spp", "4", "--out", str(tmp_path)]
    )
    ratio = json.loads((tmp_path / "perf_ratio.json").read_text())
    assert ratio["ratio_wall"] > 0 and ratio["repeats"] == 1


@pytest.mark.device
def test_03a_efficiency_study_resumes_after_a_kill(tmp_path, monkeypatch):
    """A run killed mid-study keeps its whole (spp, seed) rounds in results.json; the same
    command then renders only the missing rounds and finishes the entry."""
    import efficiency_report
    import efficiency_study

    argv = ["--quick", "--size", "8", "--spp", "4", "16", "--reference-spp", "16"]
    argv += ["--scenes", "cornell-box", "--configs", "mc/sobol", "mc/stratified"]
    argv += ["--peer", "off", "--out", str(tmp_path)]
    real = efficiency_study.one_render
    calls = []

    def killed_in_third_round(*args, **kwargs):
        calls.append(args[6])  # spp
        if len(calls) == 5:  # rounds of 2 renders: the third round dies midway
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(efficiency_study, "one_render", killed_in_third_round)
    with pytest.raises(KeyboardInterrupt):
        efficiency_study.main(argv)
    entry = json.loads((tmp_path / "results.json").read_text())["scenes"]["cornell-box"]
    assert entry["complete"] is False
    kept = {(r["spp"], r["seed"]) for r in entry["rows"]}
    assert kept == {(4, 1), (4, 2)} and len(entry["rows"]) == 4
    assert "interrupted after 2" in efficiency_report.report(
        json.loads((tmp_path / "results.json").read_text())
    )

    calls.clear()
    efficiency_study.main(argv)
    assert calls == [16, 16, 16, 16]  # only the two rounds at 16 spp rendered again
    final = json.loads((tmp_path / "results.json").read_text())["scenes"]["cornell-box"]
    assert final["complete"] is True and len(final["runs"]) == 2
    assert final["rows"][:4] == entry["rows"]
    assert {p["label"] for p in final["summary"]} == {"mc/sobol", "mc/stratified"}


@pytest.mark.device
def test_03b_efficiency_study_peer(tmp_path):
    """mitsuba-cbox with the Mitsuba peer: rendered when mitsuba imports, else the report says
    it was not run."""
    import efficiency_study

    efficiency_study.main(
        ["--quick", "--size", "8", "--spp", "4", "--reference-spp", "16"]
        + ["--scenes", "mitsuba-cbox", "--configs", "mc/sobol", "vor_sn/sppp", "--out"]
        + [str(tmp_path)]
    )
    entry = json.loads((tmp_path / "results.json").read_text())["scenes"]["mitsuba-cbox"]
    report = (tmp_path / "report.md").read_text()
    if entry["peer"]["status"]["available"]:
        labels = {p["label"] for p in entry["summary"]}
        assert {"mitsuba/multijitter", "mitsuba/ldsampler"} <= labels
        assert {"time_to_mse_1e-4", "time_to_mse_1e-4_cpu"} <= set(entry["targets"])
    else:
        assert "Mitsuba peer: not run" in report


@pytest.mark.device
def test_04_cells_figure(tmp_path):
    import cells_figure

    cells_figure.main(["--n", "8", "--size", "64", "--out", str(tmp_path)])
    assert (tmp_path / "cells.png").exists()
    assert len(list(tmp_path.glob("cells_*_n8.png"))) == 3


def test_03c_efficiency_chart_labels_do_not_overlap(tmp_path):
    """The legend sits beside the axes and no two texts overlap, on a quick run's narrow time
    range (0.015 to 0.45 s: the default log axes labelled minor ticks there, and 3x10^-2 ran
    into 4x10^-2) and on a wide one, with every configuration."""
    import efficiency_report
    import efficiency_study
    import figures
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    configs = efficiency_study.CONFIGS
    for low, high in ((0.015, 0.45), (0.3, 400.0)):
        rows = [
            {
                "estimator": estimator,
                "sampler": sampler,
                "spp": spp,
                "seed": seed,
                "mse_minus_ref_noise": 0.05 / spp * (1 + 0.1 * rng.random()),
                "mse": 0.05 / spp,
                "call_s": low * (high / low) ** (k / len(configs)) * (1.3 if spp == 64 else 1),
                "cpu_s": low * (high / low) ** (k / len(configs)) * 1.5,
            }
            for k, (estimator, sampler) in enumerate(configs)
            for spp in (16, 64)
            for seed in (1, 2)
        ]
        summary = efficiency_report.summarise(rows)
        entry = {
            "settings": {"size": 8, "spp": [16, 64], "seeds": 2, "first_seed": 1},
            "reference": {"sampler": "sobol", "spp": 64, "parts": 4},
            "summary": summary,
            "time_to_target": efficiency_report.times_to_target(summary),
            "device": "test device",
        }
        fig = efficiency_report.scene_figure("cornell-box", entry)
        assert figures.overlapping_texts(fig) == []  # a draw: the layout is final
        (legend,) = fig.legends
        box = legend.get_window_extent()
        assert not any(box.overlaps(ax.get_window_extent()) for ax in fig.axes)
        plt.close(fig)


def test_03d_figure_helpers():
    """overlapping_texts finds two texts drawn on one another, and not hidden ones; spread is
    the mean and standard error of the values it keeps."""
    import figures
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.text(0.5, 0.5, "one label")
    ax.text(0.5, 0.5, "another label")
    ax.text(0.1, 0.9, "hidden", visible=False)
    ax.text(0.1, 0.9, "not hidden")
    assert figures.overlapping_texts(fig) == [("one label", "another label")]
    plt.close(fig)
    result = figures.spread([1.0, 2.0, 4.0])
    assert result["mean"] == pytest.approx(7 / 3) and result["values"] == [1.0, 2.0, 4.0]
    assert result["se"] == pytest.approx(np.std([1, 2, 4], ddof=1) / np.sqrt(3))


def test_03d_save_figure_draws_once_what_savefig_draws(tmp_path):
    """save_figure writes savefig's PNG pixel for pixel (a caption, log axes, the legend beside
    them, at a dpi other than the figure's) from one draw of the figure instead of two."""
    from unittest.mock import patch

    import figures
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure
    from PIL import Image

    def chart():
        fig, axes = plt.subplots(1, 2, figsize=(6, 3), layout="constrained")
        for ax in axes:
            ax.loglog([1, 10, 100], [3, 2, 1], label="a series")
            ax.set_title("a panel")
        figures.legend_beside(fig, axes)
        figures.draw_caption(fig, figures.caption("A chart", {"runs": 4, "seed": 7}), width=40)
        return fig

    fig = chart()
    fig.savefig(tmp_path / "savefig.png", dpi=90)
    plt.close(fig)
    draws = []
    draw = Figure.draw

    def counted(figure, renderer):
        draws.append(figure)
        return draw(figure, renderer)

    fig = chart()
    with patch.object(Figure, "draw", counted):
        figures.save_figure(fig, tmp_path / "once.png", dpi=90)
    plt.close(fig)
    assert len(draws) == 1
    once, reference = (np.asarray(Image.open(tmp_path / n)) for n in ("once.png", "savefig.png"))
    assert once.shape == reference.shape and np.array_equal(once, reference)


def test_03e_statistic_interval_covers_the_std():
    from bootstrap import statistic_interval

    rng = np.random.default_rng(1)
    runs = rng.normal(scale=[1.0, 3.0], size=(2000, 2))  # two columns, two known stds

    def std(a, axis=0):
        return np.std(a, axis=axis, ddof=1)

    low, high = statistic_interval(runs, std, rng, resamples=500)
    assert (low < [1.0, 3.0]).all() and (high > [1.0, 3.0]).all()
    assert (high - low < [0.15, 0.45]).all()


def test_04a_cells_stand_out_from_the_background():
    """The light's cells (radiance clamped to white) are hatched and drawn over a background
    far from white, so they do not vanish into it."""
    import cells_figure
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb

    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring = 0.9 * np.column_stack([np.cos(angles), np.sin(angles)])
    traced = np.array([[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3], [0.0, 0.0]])
    radiance = np.array([[5.0, 5.0, 5.0], [2.0, 1.5, 1.2], [0.2, 0.2, 0.2], [0.0] * 3, [0.5] * 3])
    runs = SimpleNamespace(sets=SimpleNamespace(traced=traced, aux=ring), radiance=radiance)
    fig, ax = plt.subplots()
    cells_figure.draw_cells(ax, runs, SimpleNamespace(eps=0.5), {"mc": 1.0, "vor_sn": 1.0}, "t")
    background = np.array(to_rgb(ax.get_facecolor()))
    assert np.linalg.norm(background - 1.0) > 0.5  # far from the light's white
    assert np.linalg.norm(background) > 0.5  # and from black shadow
    filled = [c for c in ax.collections if len(c.get_facecolors()) == len(traced)]
    (cells,) = filled
    for colour in cells.get_facecolors()[:2]:  # the two light cells: white, unlike the ground
        assert np.allclose(colour[:3], 1.0)
        assert np.linalg.norm(colour[:3] - background) > 0.5
    hatched = [c for c in ax.collections if c.get_hatch()]
    assert len(hatched) == 1 and len(hatched[0].get_paths()) == 2  # exactly the clamped cells
    plt.close(fig)


def test_05_analytic_study(tmp_path):
    """Table 2 and the sweep carry bootstrap intervals over the runs; a run at n = 64 labels the
    paper's columns n = 4096 and says the two differ; every figure has its caption."""
    import analytic_study

    argv = ["--quick", "--runs", "16", "--sweep-runs", "8", "--n", "64", "--sweep-n", "32", "64"]
    analytic_study.main(argv + ["--out", str(tmp_path)])
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["timing"]["clock"] == "wall" and results["machine_after"]["cpus"] >= 1
    row = results["table2"]["holder_1"]["vor_sn"]
    assert row["std_ci"][0] <= row["std"] <= row["std_ci"][1]
    for summary in results["sweep"]["summaries"]:
        low, high = np.array(summary["mc"]["rmse_ci"]).T
        assert (low <= np.array(summary["mc"]["rmse"]) + 1e-15).all()
        assert (np.array(summary["mc"]["rmse"]) <= high + 1e-15).all()
    report = (tmp_path / "report.md").read_text()
    assert "paper std (n = 4096)" in report and "paper ms (n = 4096)" in report
    assert "This run is at n = 64 (16 runs); the paper's columns are at n = 4096" in report
    captions = [line for line in report.splitlines() if re.match(r"\*(Table|Figure)", line)]
    assert len(captions) == 1 + 2 * len(analytic_study.FUNCTIONS)
    for words in ("runs", "seed 2025", "device host", "sampler SPPP", "bootstrap"):
        assert all(words in line for line in captions), words
    assert "20 at n = 64" not in captions[0] and "16 at n = 64" in captions[0]
    assert all((tmp_path / f"fig3_{f}.png").exists() for f in analytic_study.FUNCTIONS)


def test_06_stability_atlas_names_its_baseline_apart():
    """The atlas's first column is mc over SPPP draws and its baseline mc over n uniform
    points: each named with its samples, never both "mc"; the figure's texts do not overlap
    and its caption gives the runs, seed and bootstrap."""
    import figures
    import matplotlib.pyplot as plt
    import stability_study

    cell = {"ratio": 2.0, "lo": 1.5, "hi": 2.5, "verdict": "worse", "value": 2.0, "baseline": 1}
    atlas = [
        {
            "situation": f"smooth, n = {n}",
            "n": n,
            "metric": "RMSE",
            "cells": dict.fromkeys(stability_study.ROW_NAMES, cell),
        }
        for n in (2, 16)
    ]
    header = stability_study.atlas_markdown(atlas)[0]
    assert "| mc/sppp |" in header and "| mc |" not in header
    assert stability_study.BASELINE == "mc/independent" and "| mc/independent |" not in header
    config = {"runs": {2: 300, 16: 300}, "seed": 2026}
    figures_made = []
    real_save = stability_study.save

    def keep(fig, out, name, tight=True):
        fig.canvas.draw()
        figures_made.append(fig)
        return name

    stability_study.save = keep
    try:
        stability_study.plot_atlas(atlas, Path("unused"), config)
    finally:
        stability_study.save = real_save
    (fig,) = figures_made
    ax = fig.axes[0]
    columns = [t.get_text().replace("\n", "") for t in ax.get_xticklabels()]
    assert columns[0] == "mc/sppp" and "mc/independent" not in columns
    assert "mc/independent" in ax.get_title()
    assert figures.overlapping_texts(fig) == []
    caption = fig._suptitle.get_text().replace("\n", " ")
    for words in ("300 at n = 2", "seed 2026", "baseline mc/independent", "bootstrap"):
        assert words in caption, words
    plt.close(fig)


def test_07_help_texts_name_no_tracker_issue(monkeypatch, capsys):
    """Every bench script's --help says what it does, not which tracker issue asked for it."""
    scripts = [p for p in sorted(BENCH.glob("*.py")) if "ArgumentParser" in p.read_text()]
    assert len(scripts) >= 10
    for script in scripts:
        monkeypatch.setattr(sys, "argv", [str(script), "--help"])
        with pytest.raises(SystemExit) as exit_:
            runpy.run_path(str(script), run_name="__main__")
        assert exit_.value.code == 0, script.name
        text = capsys.readouterr().out
        assert text.startswith("usage:"), script.name
        assert not re.search(r"\bissues?\b|#\d+", text, re.IGNORECASE), (script.name, text)


@pytest.mark.device
def test_08_render_throughput_splits_the_render_and_compares_in_one_run(tmp_path):
    import render_throughput

    render_throughput.main(
        ["--size", "16", "--spp", "4", "--repeats", "2", "--output", str(tmp_path)]
        + ["--configs", "independent/mc", "sppp/vor_sn"]
    )
    data = json.loads((tmp_path / "results.json").read_text())
    points = data["summary"]["4"]
    for config in ("independent/mc", "sppp/vor_sn"):
        point = points[config]
        assert point["repeats"] == 2 and point["paths"] > 0
        assert point["render_over_tracing"] >= 1.0 and point["tracing_s"] > 0
        if "mitsuba/independent" in points:
            mitsuba = points["mitsuba/independent"]["wall_paths_per_s"]
            assert point["wall_ratio_to_mitsuba"] == pytest.approx(
                point["wall_paths_per_s"] / mitsuba
            )
    assert points["sppp/vor_sn"]["voronoi_s"] > 0 and points["independent/mc"]["voronoi_s"] == 0
    renders = [row for row in data["renders"] if row["renderer"] == "clrender"]
    assert len(renders) == 4 and data["command"].startswith("python bench/render_throughput.py")


@pytest.mark.device
def test_08_render_throughput_compares_trace_kernels_in_one_run(tmp_path, capsys):
    import render_throughput

    configs = ["independent/mc@megakernel", "independent/mc@simd"]
    render_throughput.main(
        ["--size", "8", "--spp", "2", "--repeats", "1", "--no-mitsuba"]
        + ["--output", str(tmp_path), "--configs", *configs]
    )
    data = json.loads((tmp_path / "results.json").read_text())
    assert sorted(data["summary"]["2"]) == sorted(configs)
    ran = {row["config"]: row["trace_kernel"] for row in data["renders"]}
    assert ran == {configs[0]: "megakernel", configs[1]: "simd"}
    with pytest.raises(SystemExit):
        render_throughput.parse_args(["--configs", "independent/mc@fastest"])
    assert "expected sampler/estimator[@kernel]" in capsys.readouterr().err


@pytest.mark.device
def test_08_render_throughput_compares_trees_in_new_processes(tmp_path):
    import render_throughput

    tree = Path(render_throughput.__file__).resolve().parents[1]
    render_throughput.main(
        ["--size", "8", "--spp", "2", "--repeats", "1", "--output", str(tmp_path)]
        + ["--configs", "sppp/mc_n", "sppp/vor_sn", "--trees", str(tree), str(tree)]
    )
    data = json.loads((tmp_path / "trees.json").read_text())
    assert data["trees"] == [str(tree)] * 2
    points = data["summary"][str(tree)]["2"]
    assert points["sppp/mc_n"]["wall_ratio_to_first"] == 1.0
    assert points["sppp/vor_sn"]["repeats"] == 2 and points["sppp/vor_sn"]["voronoi_s"] > 0
    assert points["sppp/vor_sn"]["cpu_ratio_to_first"] > 0


def test_09_cold_start_times_the_command_line_in_new_processes(tmp_path):
    import cold_start

    data = cold_start.main(
        ["--repeats", "1", "--kinds", "warm", "help", "--args", "render --res 8 --spp 2"]
        + ["--user-cache", "--output", str(tmp_path)]
    )
    warm = data["summary"]["warm"]
    assert warm["runs"] == 1 and 0 < warm["render_wall_s"] < warm["wall_s"] <= warm["cpu_s"] * 50
    assert 0 < warm["outside_render_s"] < warm["wall_s"] - warm["render_wall_s"]
    assert data["summary"]["help"]["wall_s"] > 0
    assert json.loads((tmp_path / "results.json").read_text())["clrender_args"][-1] == "--json"


@pytest.mark.device
def test_09a_host_wait_times_every_way_of_waiting(tmp_path, capsys):
    import host_wait

    host_wait.main(["--tiles", "2", "--repeats", "1", "--steps", "1000", "--output", str(tmp_path)])
    data = json.loads((tmp_path / "results.json").read_text())
    assert list(data["ways"]) == list(host_wait.WAYS)
    for way in data["ways"].values():
        assert way["wall_s"] > 0 and way["cpu_s"] >= 0
    assert data["command"].startswith("python bench/host_wait.py --tiles 2")
    printed = capsys.readouterr().out
    assert all(f"  {way} " in printed for way in host_wait.WAYS), printed


@pytest.mark.device
def test_09b_vor_bias_measures_each_estimator_against_the_exact_mean(tmp_path, capsys):
    import vor_bias

    import clrender
    from clrender.analytic import analytic_image

    vor_bias.main(
        ["--n", "4", "--kinds", "smooth", "--seeds", "3", "--size", "8"] + ["--out", str(tmp_path)]
    )
    data = json.loads((tmp_path / "results.json").read_text())
    assert (
        data["command"]
        == f"python bench/vor_bias.py --n 4 --kinds smooth --seeds 3 --size 8 --out {tmp_path}"
    )
    row = data["results"]["smooth n=4"]
    # The same three renders, measured here: mean over seeds of image mean / exact mean - 1
    exact = analytic_image("analytic:smooth", 8, 8).pixel_integrals(8, 8)[..., 0].mean()
    for name in vor_bias.ESTIMATORS:
        ratios = [
            clrender.render("analytic:smooth", spp=4, estimator=name, resolution=8, seed=seed)
            .image[..., 0]
            .astype(np.float64)
            .mean()
            / exact
            - 1.0
            for seed in range(3)
        ]
        assert row[name]["bias"] == pytest.approx(np.mean(ratios), rel=1e-12, abs=1e-15)
        assert row[name]["standard_error"] == pytest.approx(
            np.std(ratios, ddof=1) / np.sqrt(3), rel=1e-12
        )
    assert "| smooth | 4 |" in capsys.readouterr().out
    # The construction simulated apart from clrender: f = 1, so E_V - 1 is at most a few
    # percent on average, far from the -1 of a sum that lost its cells
    vor_bias.main(
        [
            "--n",
            "16",
            "--kinds",
            "smooth",
            "--seeds",
            "2",
            "--size",
            "4",
            "--simulate",
            "200",
            "--out",
            str(tmp_path),
        ]
    )
    simulated = json.loads((tmp_path / "results.json").read_text())["simulated"]["16"]
    assert simulated["trials"] == 200 and abs(simulated["bias"]) < 0.05
    assert 0 < simulated["standard_error"] < 0.05


def test_10_kernel_structure_compares_megakernel_and_wavefront(tmp_path):
    import kernel_structure

    kernel_structure.main(
        ["--devices", "0", "--cases", "cornell-box:1", "--size", "16", "--repeats", "1"]
        + ["--sweep-repeats", "1", "--local-sizes", "64", "--wave-sizes", "4096"]
        + ["--lane-spp", "1", "--no-vectorizer", "--out", str(tmp_path)]
    )
    text = (tmp_path / "results.json").read_text()
    data = json.loads(text)
    assert "conclusion" in text and data


@pytest.mark.device
def test_11_veach_study_errors_by_region_from_the_geometry(tmp_path):
    import veach_study

    from clrender.probes import glossy_reflection_pixel, sphere_light_edge_pixel
    from clrender.scene import load_scene

    veach_study.main(["--quick", "--out", str(tmp_path)])
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["size"] == [32, 18] and data["seeds"] == [1, 2]
    # each region comes from the geometry: it holds what the probes find independently
    scene = load_scene("veach-mis")
    masks = veach_study.regions(scene, 32, 18)
    lights = veach_study.light_names(scene)
    for e in (0, 1):  # the small light's outline hides inside one pixel here
        edge = sphere_light_edge_pixel(scene, 32, 18, emitter=e)
        assert masks[f"outline {lights[e]}"][edge.y, edge.x]
    spot = glossy_reflection_pixel(scene, 32, 18, emitter=1, material="Glossy")
    assert masks[f"{lights[1]} on Glossy"][spot.y, spot.x]
    assert not (masks[f"{lights[1]} on Glossy"] & masks["rest of Glossy"]).any()
    assert data["region_pixels"]["whole image"] == 32 * 18
    assert data["region_reference_noise"]["whole image"] == pytest.approx(data["reference_noise"])
    # every pair, mean and standard error over the seeds, ratios with their verdicts
    pairs = {f"{e}/{s}" for estimators, s in veach_study.RENDERS for e in estimators}
    assert set(data["table"]) == pairs and len(data["renders"]) == 2 * len(pairs)
    for entry in data["table"].values():
        assert entry["wall_s"] > 0 and entry["cpu_s"] > 0
        cell = entry["regions"]["whole image"]
        assert cell["mse"] == pytest.approx(np.mean(cell["mse_per_seed"]))
        assert cell["mse_se"] == pytest.approx(np.std(cell["mse_per_seed"], ddof=1) / np.sqrt(2))
        for base in veach_study.BASELINES:
            r = cell[f"vs {base}"]
            if r["ratio"] is not None:
                assert r["low"] <= r["ratio"] <= r["high"]
                want = "win" if r["high"] < 1 else "loss" if r["low"] > 1 else "tie"
                assert r["verdict"] == want
    # the region MSE against a NumPy computation, and the ratio on known numbers
    rng = np.random.default_rng(3)
    ref, image = rng.random((2, 4, 5, 3))
    var = np.full((4, 5, 3), 0.01)
    mask = np.zeros((4, 5), bool)
    mask[1:3, 2:4] = True
    got = veach_study.region_mse(image, ref, var, {"r": mask})["r"]
    assert got == pytest.approx(((image - ref)[1:3, 2:4] ** 2).mean() - 0.01)
    twice = veach_study.ratio_interval(np.array([2.0, 4.0, 6.0]), np.array([1.0, 2.0, 3.0]))
    assert twice["ratio"] == pytest.approx(2.0) and twice["verdict"] == "loss"
    mixed = veach_study.ratio_interval(np.array([1.0, 4.0]), np.array([2.0, 2.0]))
    assert mixed["ratio"] == pytest.approx(1.0) and mixed["verdict"] == "tie"
    report = (tmp_path / "report.md").read_text()
    assert "python bench/veach_study.py --quick" in report and "outline light r=1" in report


def test_12_cached_references_follow_the_scene_and_the_kernels(tmp_path, monkeypatch):
    """A cached reference serves the same scene and kernels only: an edited scene or a changed
    kernel source renders it anew (a test kernel does not)."""
    import shutil

    from clrender.runtime import kernels_dir

    renders = []

    def fake_render(runtime, scene, size, spp, log, executor):
        renders.append(scene)
        return np.full((*size[::-1], 3), 0.5), np.full((*size[::-1], 3), 1e-4), 1.0

    monkeypatch.setattr(common, "render_reference", fake_render)
    kernels = tmp_path / "kernels"
    shutil.copytree(kernels_dir(), kernels)
    monkeypatch.setenv("CLRENDER_KERNELS_DIR", str(kernels))

    def fetch():
        return common.reference(None, "cornell-box", (8, 4), 16, log=lambda _: None)[2]

    assert not fetch()["cached"] and fetch()["cached"] and len(renders) == 1
    (kernels / "bsdf_test.cl").write_text((kernels / "bsdf_test.cl").read_text() + "\n")
    assert fetch()["cached"]
    (kernels / "bsdf.h").write_text((kernels / "bsdf.h").read_text() + "\n// changed\n")
    assert not fetch()["cached"] and fetch()["cached"] and len(renders) == 2
    real_load = common.load_scene

    def edited(name):
        scene = real_load(name)
        scene.materials["albedo"][0] *= 0.5
        return scene

    monkeypatch.setattr(common, "load_scene", edited)
    assert not fetch()["cached"] and len(renders) == 3
