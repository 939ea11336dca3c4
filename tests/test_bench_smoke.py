"""Smoke runs of the study benches at tiny settings, in-process (a few seconds each): every
output file is written and the JSON holds what the report quotes."""

import json
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

pytest.importorskip("matplotlib")
common = pytest.importorskip("common")


@pytest.fixture(autouse=True)
def private_references(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "REFERENCE_DIR", tmp_path / "references")


def test_01_pixel_study(tmp_path):
    import pixel_study

    pixel_study.main(
        [
            "--quick",
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
    assert list(results["pixels"]) == list(pixel_study.PROBES)
    for name, entry in results["pixels"].items():
        assert entry["scene"] == pixel_study.PROBES[name].scene
        assert (tmp_path / f"fig6_{name}.png").exists() and (tmp_path / f"fig9_{name}.png").exists()
    assert "of cornell-box-glossy" in (tmp_path / "report.md").read_text()


def test_02_image_study(tmp_path):
    import image_study

    image_study.main(
        ["--quick", "--size", "8", "--spp", "4", "--reference-spp", "16", "--out", str(tmp_path)]
    )
    results = json.loads((tmp_path / "results.json").read_text())
    assert len(results["rows"]) == len(common.RENDER_PAIRS)
    assert (tmp_path / "error_maps.png").exists() and (tmp_path / "report.md").exists()


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
    efficiency_study.main(
        ["--perf-ratio", "--quick", "--size", "8", "--spp", "4", "--out", str(tmp_path)]
    )
    ratio = json.loads((tmp_path / "perf_ratio.json").read_text())
    assert ratio["ratio_wall"] > 0 and ratio["repeats"] == 1


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


def test_04_cells_figure(tmp_path):
    import cells_figure

    cells_figure.main(["--n", "8", "--size", "64", "--out", str(tmp_path)])
    assert (tmp_path / "cells.png").exists()
    assert len(list(tmp_path.glob("cells_*_n8.png"))) == 3
