"""The researcher's workflow on the command line: several estimators from one trace, errors
against a reference, per-pixel layers in the EXR, JSON and quiet output, the scenes list and
the warning for a poor estimator/sampler pair."""

import json

import numpy as np
import pytest

from clrender import cli
from clrender.compare import image_errors
from clrender.imageio import read_exr, read_exr_channels, write_exr
from clrender.scene import list_scenes

FAST = ("--res", "24x16", "--spp", "16", "--seed", "4")


def run_cli(capsys, *argv):
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_several_estimators_write_one_pair_each_from_one_trace(capsys, tmp_path):
    out = tmp_path / "many.exr"
    status, stdout, _ = run_cli(
        capsys, "render", "analytic:mix", *FAST, "--estimator", "mc_n,vor_sn,fvor", "-o", str(out)
    )
    assert status == 0
    images = {}
    for name in ("mc_n", "vor_sn", "fvor"):
        pixels, metadata = read_exr(tmp_path / f"many.{name}.exr")
        assert (tmp_path / f"many.{name}.png").is_file()
        assert metadata["estimator"] == name and metadata["estimators"] == "mc_n,vor_sn,fvor"
        assert f"wrote {tmp_path / f'many.{name}.exr'}" in stdout
        images[name] = pixels
    assert not out.exists()
    # Each equals the single-estimator render of the same seed (no pixel redrew here)
    for name in ("vor_sn", "mc_n"):
        single = tmp_path / f"{name}.exr"
        run_cli(capsys, "render", "analytic:mix", *FAST, "--estimator", name, "-o", str(single))
        assert read_exr(single)[0].tobytes() == images[name].tobytes(), name


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_layers_beside_rgb_hold_counts_redraws_flags_and_variance(capsys, tmp_path):
    out = tmp_path / "layers.exr"
    status, _, _ = run_cli(
        capsys, "render", "analytic:mix", *FAST, "--sampler", "stratified", "-o", str(out)
    )
    assert status == 0
    channels = read_exr_channels(out)
    assert set(channels) == {"RGB", "samples", "redraws", "flagged", "mc_variance"}
    assert (channels["samples"] == 16).all() and channels["samples"].dtype == np.uint32
    assert not channels["redraws"].any() and not channels["flagged"].any()
    variance = channels["mc_variance"]
    assert variance.shape == (16, 24, 3) and (variance >= 0).all() and variance.max() > 0
    # Stratified samples: no unbiased variance of their own, so no noise_mse in the metadata
    assert "noise_mse" not in read_exr(out)[1]


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_a_reference_gives_errors_in_summary_metadata_and_json(capsys, tmp_path):
    # A reference rendered with mc over independent samples carries its own noise
    reference = tmp_path / "ref.exr"
    status, _, _ = run_cli(
        capsys,
        "render",
        "analytic:smooth",
        "--res",
        "24x16",
        "--spp",
        "64",
        "--sampler",
        "independent",
        "--seed",
        "9",
        "-o",
        str(reference),
    )
    ref_pixels, ref_meta = read_exr(reference)
    assert status == 0 and ref_meta["noise_mse"] > 0
    out = tmp_path / "test.exr"
    status, stdout, _ = run_cli(
        capsys,
        "render",
        "analytic:smooth",
        *FAST,
        "--sampler",
        "sobol",
        "--reference",
        str(reference),
        "--json",
        "-o",
        str(out),
    )
    assert status == 0
    summary = json.loads(stdout)  # nothing but the JSON on stdout
    pixels, metadata = read_exr(out)
    expected = image_errors(pixels, ref_pixels, ref_meta["noise_mse"])
    errors = summary["images"]["mc"]["errors"]
    assert errors["mse"] == pytest.approx(expected.mse, rel=1e-12)
    assert errors["mse_minus_noise"] == pytest.approx(expected.mse - ref_meta["noise_mse"])
    assert metadata["error_mse"] == pytest.approx(expected.mse, rel=1e-6)
    assert metadata["error_reference"] == str(reference)
    assert summary["reference"] == str(reference)
    timings = summary["timings"]
    stages = ("sample_sets_s", "tracing_s", "voronoi_s", "readback_s")
    assert set(stages) <= set(timings) and timings["estimators_s"].keys() == {"mc"}
    assert summary["images"]["mc"]["metadata"]["spp"] == 16


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_one_sample_per_pixel_writes_no_noise_and_valid_json(capsys, tmp_path):
    # The variance of one sample is unknown (NaN layer): no noise_mse, and JSON stays strict
    out = tmp_path / "one.exr"
    status, stdout, _ = run_cli(
        capsys,
        "render",
        "analytic:smooth",
        "--res",
        "24x16",
        "--spp",
        "1",
        "--sampler",
        "independent",
        "--estimator",
        "mc,mc_n",
        "--json",
        "-o",
        str(out),
    )
    assert status == 0
    summary = json.loads(stdout, parse_constant=lambda name: pytest.fail(name))
    assert "noise_mse" not in summary["images"]["mc"]["metadata"]
    assert "noise_mse" not in read_exr(tmp_path / "one.mc.exr")[1]


@pytest.mark.device
def test_a_partial_image_gets_no_error_against_the_reference(capsys, tmp_path, monkeypatch):
    # ivor records a tile at once, vor_sn after its redraws: an interrupt in a redraw leaves
    # ivor complete and vor_sn partial; only the complete image is compared
    from clrender import pipeline

    original = pipeline.TilePipeline.redraw

    def interrupted_redraw(self, pixels, redraws):
        if self.films["ivor"].complete:  # the last tile's redraws
            raise KeyboardInterrupt
        return original(self, pixels, redraws)

    monkeypatch.setattr(pipeline.TilePipeline, "redraw", interrupted_redraw)
    monkeypatch.setattr(cli, "settings_from_args", narrow_eps(cli.settings_from_args))
    status, stdout, _ = run_cli(
        capsys,
        "render",
        "analytic:mix",
        "--res",
        "32x24",
        "--spp",
        "16",
        "--estimator",
        "ivor,vor_sn",
        "--json",
        "-o",
        str(tmp_path / "p.exr"),
    )
    summary = json.loads(stdout)
    assert status == 130 and summary["status"] == "interrupted"
    assert summary["images"]["ivor"]["errors"]["mse"] > 0
    assert summary["images"]["vor_sn"]["errors"] is None
    assert summary["images"]["vor_sn"]["metadata"]["partial"] == 1


def narrow_eps(make_settings):
    """settings_from_args with eps = 0.05: most pixels reject their first draw."""
    from dataclasses import replace

    from clrender.sampling import make_sampler

    def made(args, width, height):
        settings = make_settings(args, width, height)
        sampler = make_sampler(args.sampler, args.spp, eps=0.05)
        return replace(settings, sampler=sampler)

    return made


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_analytic_images_report_their_error_against_the_exact_integrals(capsys, tmp_path):
    out = tmp_path / "exact.exr"
    status, stdout, _ = run_cli(capsys, "render", "analytic:edge", *FAST, "-o", str(out))
    assert status == 0
    assert "vor_sn against exact pixel integrals: MSE" in stdout
    pixels, metadata = read_exr(out)
    assert metadata["error_reference"] == "exact pixel integrals"
    assert metadata["error_mse"] > 0 and metadata["error_reference_noise"] == 0.0


@pytest.mark.device
def test_a_reference_of_another_size_is_refused_before_rendering(capsys, tmp_path):
    reference = tmp_path / "small.exr"
    write_exr(reference, np.zeros((8, 8, 3), np.float32))
    status, _, err = run_cli(
        capsys,
        "render",
        "analytic:mix",
        *FAST,
        "--reference",
        str(reference),
        "-o",
        str(tmp_path / "o.exr"),
    )
    assert status == 2 and err.count("\n") == 1 and "8x8" in err and "24x16" in err
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_quiet_prints_nothing_but_warnings(capsys, tmp_path):
    status, stdout, err = run_cli(
        capsys,
        "render",
        "analytic:mix",
        *FAST,
        "--estimator",
        "mc",
        "--quiet",
        "-o",
        str(tmp_path / "q.exr"),
    )
    assert status == 0 and stdout == ""
    # mc over the default sppp sampler: one warning line naming what to use instead
    assert err.count("\n") == 1 and err.startswith("clrender: warning: mc over the sppp")
    assert "mc_n" in err and "--sampler sobol" in err


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_good_pairs_get_no_warning(capsys, tmp_path):
    status, _, err = run_cli(
        capsys,
        "render",
        "analytic:mix",
        *FAST,
        "--sampler",
        "sobol",
        "--quiet",
        "-o",
        str(tmp_path / "g.exr"),
    )
    assert status == 0 and err == ""


@pytest.mark.parametrize(
    "value, fragment",
    [("mc,,vor_sn", "empty name"), ("mc,mc", "twice"), ("mc,nope", "unknown estimator")],
)
def test_bad_estimator_lists_are_one_line_errors(capsys, tmp_path, value, fragment):
    status, _, err = run_cli(
        capsys, "render", "analytic:mix", *FAST, "--estimator", value, "-o", str(tmp_path / "b")
    )
    assert status == 2 and err.count("\n") == 1 and fragment in err


def test_scenes_lists_every_shipped_scene_with_its_description(capsys):
    status, stdout, _ = run_cli(capsys, "scenes")
    assert status == 0
    for name in list_scenes():
        assert f"  {name} " in stdout
    assert "The Cornell box of the paper's authors" in stdout
    assert "analytic[:edge|smooth|disc|bowl|mix]" in stdout


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_the_sizes_the_scenes_list_gives_are_the_ones_rendered(capsys, tmp_path):
    stdout = run_cli(capsys, "scenes")[1]
    listed = stdout.split("(own size ")[1].split(")")[0]
    assert f"{cli.DEFAULT_WIDTH} pixels wide unless --res says otherwise" in stdout
    for res, size in (("scene", listed), (None, f"{cli.DEFAULT_WIDTH}x{cli.DEFAULT_WIDTH}")):
        out = tmp_path / f"{res}.exr"
        argv = ["render", "analytic:disc", "--spp", "8", "-o", str(out), "--quiet"]
        assert run_cli(capsys, *argv, *(["--res", res] if res else []))[0] == 0
        height, width = read_exr(out)[0].shape[:2]
        assert f"{width}x{height}" == size


@pytest.mark.parametrize(
    ("reference_name", "output", "estimators"),
    [("ref.exr", "ref.exr", "mc"), ("ref.exr", "ref", "mc"), ("out.vor.exr", "out", "mc,vor")],
)
def test_a_render_never_overwrites_its_reference(
    capsys, tmp_path, reference_name, output, estimators
):
    reference = tmp_path / reference_name
    write_exr(reference, np.full((16, 24, 3), 0.5, np.float32), {"spp": 64})
    before = reference.read_bytes()
    status, stdout, err = run_cli(
        capsys,
        "render",
        "analytic:smooth",
        *FAST,
        "--estimator",
        estimators,
        "--reference",
        str(reference),
        "-o",
        str(tmp_path / output),
    )
    assert status == 2 and stdout == ""
    assert err.startswith("clrender: error: -o/--output ") and err.count("\n") == 1
    assert f"would overwrite {reference}, the --reference image" in err
    assert reference.read_bytes() == before
