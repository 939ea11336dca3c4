"""The pixel-level studies on the executor (bench/pixel_study.py, bench/stability_study.py,
bench/image_tessellation_study.py): a slice of each gives exactly the same numbers in this
process, with another split into tasks, and on a Dask LocalCluster of 2 workers."""

import dataclasses
import math
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clrender.cluster import LocalExecutor

pytest.importorskip("distributed")

BENCH = Path(__file__).resolve().parents[1] / "bench"
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

pytest.importorskip("matplotlib")
TIMES = ("seconds", "seconds_by_n", "us_per_pixel")


def assert_same(a, b, where="results"):
    """a and b hold the same numbers, bit for bit (NaN equal to NaN), times aside."""
    if dataclasses.is_dataclass(a):
        assert type(b) is type(a), where
        assert_same(vars(a), vars(b), where)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for key in a:
            if key not in TIMES:
                assert_same(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for index, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{index}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), where
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where


@pytest.mark.device  # the workers open the device PYOPENCL_CTX names
def test_pixel_study_slice_is_the_same_on_any_split_and_executor(runtime, cluster):
    import pixel_study

    from clrender.probes import light_edge_pixel, trace_pixel_runs
    from clrender.sampling import make_sampler
    from clrender.scene import load_scene
    from clrender.trace import PathTracer

    scene = load_scene("cornell-box")
    size, runs = 32, 40
    pixel = light_edge_pixel(scene, size, size).pixel
    args = SimpleNamespace(seed=7, size=size, timing_runs=20)
    independent = pixel_study.point_of(pixel_study.GROUPS[0], 16, pixel, args)
    sppp = pixel_study.point_of(pixel_study.GROUPS[-2], 16, pixel, args)
    # eps 0.15 (against the default 0.52) makes the Voronoi estimators reject about half the
    # runs: several rounds of redraws, each cut into tasks
    storm = replace(sppp, sampler=make_sampler("sppp", 16, eps=0.15))
    points = [independent, sppp, storm]
    local = pixel_study.gather_runs(LocalExecutor(), scene, points, runs, 64)
    split = pixel_study.gather_runs(LocalExecutor(), scene, points, runs, 16)
    remote = pixel_study.gather_runs(cluster, cluster.share(scene), points, runs, 32)
    assert local[2].drawn > runs + 4 and local[2].accepted >= runs  # redraw rounds happened
    for ours, others in ((local, split), (local, remote)):
        for point, other in zip(ours, others, strict=True):
            assert_same(point.values, other.values)
            assert (point.drawn, point.accepted) == (other.drawn, other.accepted)
            assert_same(point.timing, other.timing)
    for point in local:
        assert all(len(values) == runs for values in point.values.values())
        assert point.timing[0].pixel_count == 20
    # Run r is redraw r of the point's stream: mc over independent samples is the mean of
    # the radiance (RGB mean) of run r's samples traced in one launch
    tracer = PathTracer(runtime, scene, max_depth=pixel_study.MAX_DEPTH)
    launch = trace_pixel_runs(runtime, tracer, independent.sampler, 7 + 11, pixel, runs, size, size)
    sums = np.add.reduceat(launch.radiance.mean(axis=1), launch.sets.offsets[:-1])
    np.testing.assert_allclose(local[0].values["mc"], sums / 16, rtol=1e-12)


def test_stability_study_slice_is_the_same_on_any_split_and_executor(cluster, monkeypatch):
    import stability_study as study

    # Blocks of 600 points: several per measurement, so that the splits differ
    monkeypatch.setattr(study, "BLOCK_POINTS", 600)
    cfg = study.Config(
        True, 5, (2, 16), {2: 300, 16: 120}, (4,), 200, (4,), 150, 12, discontinuity_ns=(16,)
    )
    assert len(study.sppp_blocks(16, 120, (5, 1, 16))) > 3
    local = study.measure(cfg)
    assert_same(local, study.measure(cfg, None, 3))
    assert_same(local, study.measure(cfg, cluster, 2))
    measured, all_runs = local
    assert [row["pixels"] for row in measured["fvor_empty"]] == [150]
    assert sum(row["pixels"] for row in measured["rejection"]) == sum(
        cfg.rejection_pixels_for(4, alpha) for alpha in study.REJECTION_BOUNDS
    )
    # f == 1: vor_sn's weights sum to 1, so it is exact wherever a pixel drew a point
    runs = all_runs[16]
    flat = runs.estimates["vor_sn"][:, study.col("flat")]
    assert len(flat) == 120 and np.allclose(flat[runs.counts > 0], 1.0, rtol=0, atol=1e-12)


def test_image_tessellation_slice_is_the_same_on_any_split_and_executor(cluster):
    import image_tessellation_study as study

    local = study.study_ns(4, 3, 11, None, 1, ns=(16, 64))
    assert_same(local, study.study_ns(4, 3, 11, None, 2, ns=(16, 64)))
    assert_same(local, study.study_ns(4, 3, 11, cluster, 1, ns=(16, 64)))
    assert list(local) == ["16", "64"]
    # Another seed draws other points
    other = study.study_ns(4, 3, 12, None, 3, ns=(16,))
    assert other["16"]["estimators"]["mc"]["std"] != local["16"]["estimators"]["mc"]["std"]


def test_the_studies_refuse_a_bad_split(capsys):
    import image_tessellation_study
    import pixel_study
    import stability_study

    for main, argv, message in (
        (pixel_study.parse_args, ["--batch-runs", "20"], "positive multiple of 16, got 20"),
        (stability_study.parse_args, ["--task-blocks", "0"], "positive integer, got 0"),
        (image_tessellation_study.main, ["--runs-per-task", "0"], "positive integer, got 0"),
    ):
        with pytest.raises(SystemExit):
            main(argv)
        assert message in capsys.readouterr().err
