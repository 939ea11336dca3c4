"""The render studies of bench/ on a Dask LocalCluster (--scheduler of one module-wide
cluster): every image and error the same as the run in this process, bit for bit; only the
timings differ, and they are there (positive, taken on the worker that rendered, named in the
row); a reference rendered over the cluster is the local one, bit for bit."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

pytest.importorskip("distributed")
pytest.importorskip("matplotlib")
common = pytest.importorskip("common")

from clrender.imageio import read_exr  # noqa: E402

pytestmark = pytest.mark.device  # the workers open the device PYOPENCL_CTX names

# The fields of a render's row that depend on where and when it ran
TIMING_FIELDS = {
    "wall_s",
    "run_s",
    "call_s",
    "device_s",
    "host_s",
    "tracing_s",
    "compile_s",
    "cpu_s",
    "load_1min",
    "worker",
    "workers",
}


def run_here_and_there(tmp_path, monkeypatch, cluster, main, argv) -> tuple[Path, Path]:
    """(output folder of the run in this process, that of the run on the cluster): each with
    its own reference folder, so that each renders its reference."""
    outs = []
    for where, extra in (("local", []), ("cluster", ["--scheduler", cluster_address(cluster)])):
        out = tmp_path / where
        monkeypatch.setattr(common, "REFERENCE_DIR", out / "references")
        main([*argv(out), *extra])
        outs.append(out)
    return outs[0], outs[1]


def cluster_address(cluster) -> str:
    return cluster.client.scheduler.address


def without_timings(row: dict) -> dict:
    return {key: value for key, value in row.items() if key not in TIMING_FIELDS}


def assert_timed_where_they_ran(local_rows: list[dict], cluster_rows: list[dict], keys) -> None:
    """The timing fields are there and positive; the rows name the process that rendered."""
    for row in local_rows + cluster_rows:
        for key in keys:
            assert row[key] > 0, key
    assert {row["worker"] for row in local_rows} == {"this process"}
    assert all(row["worker"].startswith("tcp://") for row in cluster_rows)
    assert {row["workers"] for row in local_rows} == {1}
    assert {row["workers"] for row in cluster_rows} == {2}


def assert_same_references(local: Path, remote: Path) -> None:
    names = sorted(path.name for path in local.glob("*.exr"))
    assert names and names == sorted(path.name for path in remote.glob("*.exr"))
    for name in names:
        assert np.array_equal(read_exr(local / name)[0], read_exr(remote / name)[0]), name


def test_01_image_study_same_images_and_errors_on_the_cluster(tmp_path, monkeypatch, cluster):
    import image_study

    pairs = [("mc", "independent"), ("vor_sn", "sppp"), ("vor", "sppp")]  # the report's three
    monkeypatch.setattr(image_study, "RENDER_PAIRS", pairs)
    local, remote = run_here_and_there(
        tmp_path,
        monkeypatch,
        cluster,
        image_study.main,
        lambda out: (
            ["--quick", "--size", "16", "--spp", "4", "--reference-spp", "16"] + ["--out", str(out)]
        ),
    )
    here, there = (json.loads((out / "results.json").read_text()) for out in (local, remote))
    assert len(here["renders"]) == 6  # 3 pairs, 2 seeds
    assert [without_timings(r) for r in there["renders"]] == [
        without_timings(r) for r in here["renders"]
    ]
    assert_timed_where_they_ran(here["renders"], there["renders"], ("wall_s", "cpu_s"))
    for name in ("render_mc_independent.exr", "render_vor_sn_sppp.exr", "render_vor_sppp.exr"):
        assert np.array_equal(read_exr(local / name)[0], read_exr(remote / name)[0]), name
    assert_same_references(local / "references", remote / "references")
    assert here["executor"]["where"] == "this process" and here["executor"]["clock"] == "wall"
    assert there["executor"]["where"].startswith("Dask cluster at tcp://")
    assert "Renders ran in Dask cluster at" in (remote / "report.md").read_text()


def test_02_efficiency_study_same_errors_on_the_cluster_timed_in_cpu(
    tmp_path, monkeypatch, cluster
):
    import efficiency_study

    local, remote = run_here_and_there(
        tmp_path,
        monkeypatch,
        cluster,
        efficiency_study.main,
        lambda out: (
            ["--quick", "--size", "16", "--spp", "4", "--reference-spp", "16"]
            + ["--scenes", "cornell-box", "--configs", "mc/sobol", "vor_sn/sppp", "--peer", "off"]
            + ["--out", str(out)]
        ),
    )
    here, there = (
        json.loads((out / "results.json").read_text())["scenes"]["cornell-box"]
        for out in (local, remote)
    )
    assert len(here["rows"]) == 4  # 2 configurations, 2 seeds
    assert [without_timings(r) for r in there["rows"]] == [without_timings(r) for r in here["rows"]]
    assert_timed_where_they_ran(here["rows"], there["rows"], ("call_s", "cpu_s"))
    for mine, theirs in zip(here["summary"], there["summary"], strict=True):
        assert (mine["label"], mine["mse_per_seed"]) == (theirs["label"], theirs["mse_per_seed"])
    assert here["executor"]["clock"] == "wall" and there["executor"]["clock"] == "cpu"
    assert there["executor"]["workers"] == 2
    report = (remote / "report.md").read_text()
    assert "t(1e-4) CPU s" in report and "are in CPU time" in report
    assert "t(1e-4) wall s" in (local / "report.md").read_text()


def test_03_roulette_study_same_errors_on_the_cluster(tmp_path, monkeypatch, cluster):
    import roulette_study

    monkeypatch.setattr(roulette_study, "CONFIGS", [("mc", "independent"), ("vor_sn", "sppp")])
    local, remote = run_here_and_there(
        tmp_path,
        monkeypatch,
        cluster,
        roulette_study.main,
        lambda out: ["--quick", "--spp", "4", "--variants", "off", "rr", "--out", str(out)],
    )
    here, there = (
        json.loads((out / "results.json").read_text())["scenes"]["cornell-box"]
        for out in (local, remote)
    )
    assert len(here["rows"]) == 8  # 2 configurations, 2 variants, 2 seeds
    assert [without_timings(r) for r in there["rows"]] == [without_timings(r) for r in here["rows"]]
    assert_timed_where_they_ran(here["rows"], there["rows"], ("wall_s", "cpu_s"))
    # the variants differ (roulette changes the image), so the comparison above has teeth
    by_variant = {r["variant"]: r["mse_raw"] for r in here["rows"] if r["estimator"] == "mc"}
    assert by_variant["off"] != by_variant["rr"]
    assert_same_references(local / "references", remote / "references")


def test_04_veach_study_same_region_errors_on_the_cluster(tmp_path, monkeypatch, cluster):
    import veach_study

    local, remote = run_here_and_there(
        tmp_path,
        monkeypatch,
        cluster,
        veach_study.main,
        lambda out: ["--quick", "--out", str(out)],
    )
    here, there = (json.loads((out / "results.json").read_text()) for out in (local, remote))
    assert len(here["renders"]) == 2 * 6  # 2 seeds, 6 pairs from 4 renders
    assert [without_timings(r) for r in there["renders"]] == [
        without_timings(r) for r in here["renders"]
    ]
    assert_timed_where_they_ran(here["renders"], there["renders"], ("wall_s", "cpu_s"))
    assert_same_references(local / "references", remote / "references")


def test_05_render_estimators_same_errors_on_the_cluster(tmp_path, monkeypatch, cluster):
    import render_estimators

    monkeypatch.setattr(render_estimators, "PAIRS", [("mc", "stratified"), ("fvor", "sppp")])
    local, remote = run_here_and_there(
        tmp_path,
        monkeypatch,
        cluster,
        render_estimators.main,
        lambda out: (
            ["--size", "16", "--spp", "4", "--reference-spp", "16", "--seeds", "1", "2"]
            + ["--output", str(out / "render_estimators.json")]
        ),
    )
    here, there = (
        json.loads((out / "render_estimators.json").read_text()) for out in (local, remote)
    )
    assert [r["mse_per_seed"] for r in there["rows"]] == [r["mse_per_seed"] for r in here["rows"]]
    assert all(len(r["mse_per_seed"]) == 2 and r["host_s"] > 0 for r in here["rows"])
    assert {w for r in there["rows"] for w in r["workers"]} <= set(cluster.client.nthreads())
    assert_same_references(local / "references", remote / "references")


def test_06_render_task_is_the_local_render(runtime):
    """A task renders what clrender.pipeline.render gives for the same settings (an
    independent path: the render called here on a source built here)."""
    from clrender.pipeline import render

    task = common.RenderTask("cornell-box", (12, 8), ("mc_n", "vor_sn"), "sppp", 4, 3)
    images, row = common.render_task(task)
    source = common.make_source(runtime, "cornell-box", 12, 8)
    settings = common.render_settings((12, 8), ["mc_n", "vor_sn"], "sppp", 4, 3)
    result = render(runtime, source, settings)
    for name in ("mc_n", "vor_sn"):
        assert np.array_equal(images[name], result.films[name].image()), name
    assert row["worker"] == "this process" and row["spp"] == 4 and row["seed"] == 3


def test_07_perf_ratio_refuses_a_cluster(capsys):
    import efficiency_study

    with pytest.raises(SystemExit):
        efficiency_study.main(["--perf-ratio", "--workers", "2"])
    assert "--perf-ratio times its renders in this process" in capsys.readouterr().err
