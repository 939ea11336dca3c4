"""Every bench number labelled and every chart honest, for bench/stability_study.py and
bench/voronoi_speed.py (bench/analytic_study.py: tests/test_bench_smoke.py test_05): the JSON
records the machine's load, each row its own repeat count, every option has a help text; a
count or std of 0 is never drawn as a measured value on a log axis, log tick labels are plain
numbers and the baseline is named as everywhere else."""

import json
import os
import re
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

pytest.importorskip("matplotlib")
stability_study = pytest.importorskip("stability_study")
plt = pytest.importorskip("matplotlib.pyplot")


@pytest.fixture
def kept_figures(monkeypatch):
    """The figures the study's chart functions make, kept unsaved (and closed afterwards)."""
    figures = []

    def keep(fig, out, name, tight=True):
        figures.append(fig)
        return name

    monkeypatch.setattr(stability_study, "save", keep)
    yield figures
    for fig in figures:
        plt.close(fig)


def zero_count_bound(trials: int) -> float:
    """The one-sided 95 % upper bound of a proportion with 0 of `trials`: 1 - 0.05^(1/trials)
    (the Clopper-Pearson bound in closed form)."""
    return 1.0 - 0.05 ** (1.0 / trials)


def plotted(ax) -> list:
    """(x, y, marker, filled) of every line of an axes."""
    return [
        (
            np.asarray(line.get_xdata(), float),
            np.asarray(line.get_ydata(), float),
            line.get_marker(),
            line.get_markerfacecolor() != "none",
        )
        for line in ax.get_lines()
    ]


def assert_machine(record: dict) -> None:
    assert len(record["load_1_5_15"]) == 3 and record["cpus"] == os.cpu_count()
    assert "load average" in record["uptime"]


def test_zero_rejection_counts_sit_at_their_upper_bound_not_on_the_data(kept_figures):
    counts = {0.9: 30, 0.3: 0, 0.1: 3, 0.01: 0, 0.001: 0}
    rows = [
        {
            "n": 4,
            "alpha": alpha,
            "bound": alpha,
            "pixels": 1200 if alpha == 0.001 else 300,
            "rejected": k,
            "frequency": k / (1200 if alpha == 0.001 else 300),
            "upper_95": stability_study.upper_95(k, 1200 if alpha == 0.001 else 300),
        }
        for alpha, k in counts.items()
    ]
    stability_study.plot_rejection(rows, Path("unused"))
    (fig,) = kept_figures
    left, right = fig.axes
    lines = plotted(left)
    measured = [y for x, y, marker, filled in lines if marker == "o"]
    (series,) = measured
    # Zeros break the line (NaN), never a value on the log axis
    np.testing.assert_array_equal(series, [0.1, np.nan, 0.01, np.nan, np.nan])
    hollow = [(x, y) for x, y, marker, filled in lines if marker == "v" and not filled and len(x)]
    ((x, y),) = hollow
    np.testing.assert_array_equal(x, [0.3, 0.01, 0.001])
    np.testing.assert_allclose(y, [zero_count_bound(300)] * 2 + [zero_count_bound(1200)])
    # At the default eps: no measured dot for 0 of 1200, its bound, and the count written out
    assert not [line for line in plotted(right) if line[2] == "o"]
    assert "0 of 1200" in [text.get_text() for text in right.texts]


def test_small_n_draws_empty_counts_at_their_bound_and_names_the_baseline(kept_figures):
    estimators = {"bias": 0.0, "se": 0.01, "rmse_ratio": 1.0}
    rows = [
        {
            "n": n,
            "pixels": 300,
            "p_empty": p0,
            "p_empty_poisson": float(np.exp(-n)),
            "p_N1": 0.2,
            "p_N2": 0.1,
            "p_N3": p3,
            "estimators": dict.fromkeys(stability_study.ROW_NAMES, estimators),
        }
        for n, p0, p3 in ((1, 0.36, 0.06), (16, 0.0, 0.0), (64, 0.0, 0.01))
    ]
    stability_study.plot_small_n({"rows": rows}, Path("unused"))
    (fig,) = kept_figures
    counts, _, ratios = fig.axes
    for x, y, marker, filled in plotted(counts):
        if marker == "v" and not filled and len(x):  # zero counts: at the bound of 0 of 300
            np.testing.assert_allclose(y, zero_count_bound(300))
        elif marker in "o.":  # measured: no placeholder in place of a zero
            assert np.all(np.isnan(y) | (y >= 0.01)), y
    assert ratios.get_ylabel() == "RMSE / RMSE(mc/independent)"


def test_flat_pixel_puts_exact_zeros_in_their_own_strip(kept_figures):
    def row(n, zero_names):
        return {
            "n": n,
            "estimators": {
                name: {"std": 0.0 if name in zero_names else 0.5 / n}
                for name in [*stability_study.ROW_NAMES, "baseline"]
            },
        }

    flat = [row(1, {"baseline"}), row(16, {"baseline", "vor_sn"})]
    stability_study.plot_flat(flat, Path("unused"))
    (fig,) = kept_figures
    log_axes, strip = fig.axes
    for _, y, _, _ in plotted(log_axes):
        assert np.all(np.isnan(y) | (y > 1e-3)), y
    names = [label.get_text() for label in strip.get_yticklabels()]
    assert names == ["vor_sn/sppp", "mc/independent"]
    drawn = {y[0]: x.tolist() for x, y, _, _ in plotted(strip)}
    assert drawn == {0: [16.0], 1: [1.0, 16.0]}


def test_firefly_charts_label_log_ticks_plainly_and_name_every_bar(kept_figures):
    gains = [1, 10, 100]
    by_n = {
        n: {
            name: {
                "rmse_by_gain": [1.0, 1.2, 1.1],
                "n_weight_rms": 1.0 + i / 8,
                "n_weight_max": 1.2 + i / 3,
            }
            for i, name in enumerate([*stability_study.ROW_NAMES, "baseline"])
        }
        for n in (16, 64)
    }
    stability_study.plot_fireflies({"gains": gains, "by_n": by_n}, Path("unused"))
    (fig,) = kept_figures
    fig.canvas.draw()
    weights = fig.axes[-1]
    labels = [t.get_text() for t in weights.get_yticklabels(which="both") if t.get_text()]
    assert {"1", "2", "3"} <= set(labels) and not any("times" in t or "$" in t for t in labels)
    bars = [t.get_text() for t in weights.get_xticklabels()]
    assert bars == stability_study.displayed([*stability_study.ROW_NAMES, "baseline"])
    assert bars[-1] == "mc/independent"


def test_stability_study_records_the_machine(tmp_path, monkeypatch, kept_figures):
    monkeypatch.setattr(stability_study, "BOOT_REPS", 20)
    tiny = stability_study.Config(
        True,
        5,
        (2, 16),
        {2: 40, 16: 40},
        (4,),
        40,
        (4,),
        20,
        8,
        discontinuity_ns=(16,),
        firefly_ns=(16,),
    )
    monkeypatch.setattr(stability_study, "make_config", lambda quick, seed: tiny)
    stability_study.main(["--quick", "--out", str(tmp_path)])
    results = json.loads((tmp_path / "results.json").read_text())
    assert_machine(results["machine_before"])
    assert_machine(results["machine_after"])


def options_without_help(help_text: str) -> list[str]:
    """The options of an argparse --help whose entry has no text beside or under it."""
    lines = help_text.split("options:", 1)[1].splitlines()
    bare = []
    for i, line in enumerate(lines):
        entry = re.match(r"  (-\S.*?)(?:\s{2,}(\S.*))?$", line)
        if entry is None:
            continue
        following = lines[i + 1] if i + 1 < len(lines) else ""
        if entry.group(2) is None and not re.match(r"\s{8,}\S", following):
            bare.append(entry.group(1))
    return bare


@pytest.mark.parametrize("script", ["analytic_study", "stability_study", "voronoi_speed"])
def test_every_option_has_a_help_text(script, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [script, "--help"])
    with pytest.raises(SystemExit):
        runpy.run_path(str(BENCH / f"{script}.py"), run_name="__main__")
    text = capsys.readouterr().out
    assert "--out" in text and options_without_help(text) == []


def test_voronoi_speed_writes_results_into_a_folder_with_each_rows_repeats(tmp_path):
    import voronoi_speed

    voronoi_speed.main(["--quick", "--no-device", "--repeats", "1", "--out", str(tmp_path)])
    results = json.loads((tmp_path / "results.json").read_text())
    # Each row's count is the number of timings it took, per function
    for row in results["rows"]:
        for times in row["cpu_seconds"].values():
            assert len(times) == row["repeats"]
    assert [row["repeats"] for row in results["rows"]][:2] == [3, 1]
    assert "repeats" not in results and results["clock"] == "process_time"
    assert_machine(results["machine_before"])
    assert_machine(results["machine_after"])


def test_throughput_scripts_record_the_machine(tmp_path, monkeypatch):
    """primitive_scaling.py, sample_throughput.py (and bvh_scaling.py: tests/test_bvh.py) write
    the load before and after their timings beside them."""
    import primitive_scaling
    import sample_throughput

    primitive_scaling.main(
        ["--counts", "18", "--size", "8", "--spp", "2", "--repeats", "1"]
        + ["--output", str(tmp_path / "primitives.json")]
    )
    arguments = ["--res", "8", "--n", "4", "--samplers", "independent", "--repeats", "1"]
    monkeypatch.setattr(
        sys, "argv", ["sample_throughput", *arguments, "--out", str(tmp_path / "s")]
    )
    sample_throughput.main()
    for name in ("primitives.json", "s"):
        results = json.loads((tmp_path / name).read_text())
        assert results["results"] and "device" in results
        assert_machine(results["machine_before"])
        assert_machine(results["machine_after"])


def test_placement_rounds_alternate_their_order_and_check_every_image(monkeypatch, runtime):
    """cluster_scaling.py --cases placement: the two placements take turns going first (a fixed
    order would charge the first one whatever the machine does first), every render is checked
    against the local image, and the paired ratios are reported."""
    pytest.importorskip("distributed")
    import cluster_scaling

    from clrender.cluster import LocalExecutor

    order = []

    class RecordingExecutor(LocalExecutor):
        def __init__(self, workers=None):
            pass

        def __setattr__(self, name, value):
            if name == "spread_shared":
                order.append("spread" if value else "scheduler")
            object.__setattr__(self, name, value)

    monkeypatch.setattr(cluster_scaling, "DaskExecutor", RecordingExecutor)
    result = cluster_scaling.placement_case(4, 8, 2)
    assert order == ["scheduler", "spread", "spread", "scheduler"] * 2
    assert result["identical"] is True
    rows = result["rows"]
    assert len(rows["spread"]["runs"]) == len(rows["scheduler"]["runs"]) == 4
    assert rows["first_render_spread_over_scheduler"] > 0
    assert rows["second_render_spread_over_scheduler"] > 0
