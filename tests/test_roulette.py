"""Russian roulette as a user option (clrender.render(russian_roulette=...), --russian-roulette):
unbiased on a shipped scene with glass, fewer rays, off by default and then without effect,
recorded in the metadata, refused for analytic images; and a smoke run of its study.

Statistics: independent samples, so every traced sample is an independent draw of its pixel's
radiance and a mean over samples has standard error std / sqrt(count). Seeds are fixed.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import clrender
from clrender import cli
from clrender.errors import ParameterError
from clrender.imageio import read_exr
from clrender.probes import glass_shapes, pixel_hits
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.trace import PathTracer

SIZE = 32  # the authors' Cornell box at 32 x 32: the glass ball covers about 34 pixels
SPP = 128
SEED = 11
# A difference of means beyond this many standard errors fails (two-sided p about 6e-5 for
# one comparison; six comparisons per test: RGB of the whole image and of the glass pixels).
Z_BOUND = 4.0


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell-box")


def trace_samples(runtime, tracer, seed=SEED, size=SIZE, spp=SPP):
    """(per-sample radiance (P * spp, 3) float64, each sample's pixel, the trace's counters)."""
    pixels = rectangle_pixels(size, 0, 0, size, size)
    sets = generate_sample_sets(
        runtime, make_sampler("independent", spp), seed, pixels, None, (size, size)
    )
    result = tracer.trace(sets, seed, size, size)
    radiance = result.to_host().astype(np.float64)
    owner = np.repeat(sets.pixels, np.diff(sets.traced_offsets))
    return radiance, owner, result


def mean_and_se(values):
    return values.mean(axis=0), values.std(axis=0, ddof=1) / math.sqrt(len(values))


def glass_pixel_mask(scene, size):
    """Pixels every probe ray of which sees the glass ball (found from the geometry)."""
    shape, _ = pixel_hits(scene, size, size)
    return np.isin(shape, glass_shapes(scene)).all(axis=-1).ravel()


def test_roulette_is_unbiased_on_the_cornell_box(runtime, cornell):
    """The authors' Cornell box (diffuse walls, a glass ball, a small bright light), depth 8:
    the mean radiance with roulette equals the one without, over the whole image and over
    the pixels that see the glass ball (paths refracted into it, the case the eta'^2 scaling
    of the roulette's throughput is for), within Z_BOUND standard errors per channel. Different
    seeds: the two estimates are independent."""
    plain, owner, _ = trace_samples(runtime, PathTracer(runtime, cornell, 8), seed=SEED)
    rr, owner_rr, _ = trace_samples(
        runtime, PathTracer(runtime, cornell, 8, russian_roulette=True), seed=SEED + 1
    )
    assert np.array_equal(owner, owner_rr)
    glass = glass_pixel_mask(cornell, SIZE)[owner]
    assert glass.sum() >= 20 * SPP  # the region holds enough pixels to mean something
    for where in (slice(None), glass):
        mean_plain, se_plain = mean_and_se(plain[where])
        mean_rr, se_rr = mean_and_se(rr[where])
        z = (mean_rr - mean_plain) / np.hypot(se_plain, se_rr)
        assert np.all(np.abs(z) < Z_BOUND), (mean_plain, mean_rr, z)
        # and the check has power: the standard errors are a few % of the means
        assert np.all(np.hypot(se_plain, se_rr) < 0.05 * mean_plain), (se_plain, se_rr)


def test_roulette_traces_fewer_rays_and_tracks_refractions(runtime, cornell):
    """Roulette ends paths early: fewer rays (the kernel's counter) than without, by at least
    a quarter at depth 8 on this box (about 45 % fewer measured). With the eta'^2 scaling a
    path inside the glass is not culled for the 1 / eta'^2 of its refraction: more rays than the
    roulette on beta alone (a build of the kernel for bench/roulette_study.py)."""
    counts = {}
    for name, rr, defines in (
        ("plain", False, None),
        ("rr", True, None),
        ("rr beta alone", True, {"RUSSIAN_ROULETTE_ETA_SCALE": 0}),
    ):
        tracer = PathTracer(runtime, cornell, 8, russian_roulette=rr, profile_defines=defines)
        _, _, result = trace_samples(runtime, tracer, spp=32)
        counts[name] = result.rays
    assert counts["rr"] < 0.75 * counts["plain"], counts
    assert counts["rr beta alone"] < counts["rr"], counts


def test_roulette_off_by_default_and_without_effect_where_it_never_applies(runtime):
    """Default off: render() equals render(russian_roulette=False) bit for bit. And roulette
    draws its own dimension of each bounce, so switching it on changes nothing where it never
    applies: at max_depth 1 (it starts after the second vertex's BSDF sample) the images are
    bit-identical, with any sampler."""
    common = {"spp": 8, "resolution": 12, "seed": 3}
    default = clrender.render("mitsuba-cbox", sampler="sobol", **common)
    off = clrender.render("mitsuba-cbox", sampler="sobol", russian_roulette=False, **common)
    on = clrender.render("mitsuba-cbox", sampler="sobol", russian_roulette=True, **common)
    assert np.array_equal(default.image, off.image) and default.stats.rays == off.stats.rays
    assert not np.array_equal(on.image, off.image) and on.stats.rays < off.stats.rays
    for sampler in ("independent", "sobol", "sppp"):
        shallow = {**common, "sampler": sampler, "max_depth": 1}
        plain = clrender.render("mitsuba-cbox", **shallow)
        rr = clrender.render("mitsuba-cbox", russian_roulette=True, **shallow)
        assert np.array_equal(plain.image, rr.image), sampler
        assert plain.stats.rays == rr.stats.rays, sampler


def run_cli(capsys, *argv):
    """(exit status, stdout, stderr) of an in-process run."""
    try:
        status = cli.main(list(argv))
    except SystemExit as exit_:
        status = exit_.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.usefixtures("shared_cli_runtime")
def test_cli_flag_reaches_the_render_the_metadata_and_the_json(capsys, tmp_path):
    args = ["render", "mitsuba-cbox", "--res", "12", "--spp", "8", "--sampler", "sobol"]
    summaries, images = {}, {}
    for name, extra in (("off", []), ("on", ["--russian-roulette"])):
        out = tmp_path / f"{name}.exr"
        status, stdout, err = run_cli(capsys, *args, *extra, "-o", str(out), "--json")
        assert status == 0, err
        summaries[name] = json.loads(stdout)
        images[name] = read_exr(out)
    assert images["off"][1]["russian_roulette"] == 0
    assert images["on"][1]["russian_roulette"] == 1
    assert summaries["on"]["images"]["mc"]["metadata"]["russian_roulette"] == 1
    assert summaries["off"]["images"]["mc"]["metadata"]["russian_roulette"] == 0
    assert images["on"][1]["rays"] < images["off"][1]["rays"]
    assert not np.array_equal(images["on"][0], images["off"][0])
    # the same render through the Python API, bit for bit
    api = clrender.render(
        "mitsuba-cbox", spp=8, sampler="sobol", resolution=12, russian_roulette=True
    )
    assert np.array_equal(api.image, images["on"][0])
    # no paths, no key
    out = tmp_path / "a.exr"
    status, _, _ = run_cli(
        capsys, "render", "analytic:disc", "--res", "8", "--spp", "4", "-o", str(out)
    )
    assert status == 0 and "russian_roulette" not in read_exr(out)[1]


def test_roulette_is_refused_where_there_are_no_paths(capsys, tmp_path):
    out = tmp_path / "x.exr"
    status, stdout, err = run_cli(
        capsys, "render", "analytic:disc", "--russian-roulette", "-o", str(out)
    )
    assert status == 2 and stdout == ""
    assert err.count("\n") == 1 and "--russian-roulette needs a path-traced scene" in err
    assert not out.exists()
    with pytest.raises(ParameterError, match="needs a path-traced scene: analytic:disc"):
        clrender.render("analytic:disc", spp=4, russian_roulette=True)
    for bad in ("yes", 1, None):
        with pytest.raises(ParameterError, match="russian_roulette must be True or False"):
            clrender.render("furnace", spp=4, resolution=4, russian_roulette=bad)


def test_roulette_study_smoke(tmp_path, monkeypatch):
    """bench/roulette_study.py at tiny settings: every output written, one efficiency ratio
    with its interval per scene, configuration, variant and spp, and a conclusion."""
    pytest.importorskip("matplotlib")
    bench = Path(__file__).resolve().parents[1] / "bench"
    monkeypatch.syspath_prepend(str(bench))
    sys.modules.pop("roulette_study", None)
    import roulette_study

    roulette_study.main(["--quick", "--out", str(tmp_path)])
    results = json.loads((tmp_path / "results.json").read_text())
    for name in ("report.md", "efficiency.png", "results.json"):
        assert (tmp_path / name).exists(), name
    assert results["references"] and all(r["roulette"] is False for r in results["references"])
    for row in results["summary"]:
        low, high = row["efficiency_ratio_ci"]
        assert low <= row["efficiency_ratio"] <= high
        assert row["rays_per_path"] > 0
    assert results["conclusion"]
