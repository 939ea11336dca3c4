"""Errors of an image against a reference (clrender.compare) and `python -m clrender compare`:
known answers, the reference-noise subtraction (exact and statistical), one-line errors."""

import json
import math
import re
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from clrender import cli, imageio
from clrender.compare import (
    RAMP_DISPLAY,
    ComparisonInputError,
    ImageErrors,
    error_map,
    image_errors,
    read_image,
    read_reference,
)
from clrender.errors import ClrenderError, ParameterError
from clrender.imageio import read_exr, read_png, write_exr

DICT_KEYS = [
    "mse",
    "rel_mse",
    "mse_r",
    "mse_g",
    "mse_b",
    "pixels",
    "reference_noise",
    "mse_minus_noise",
]


def run_cli(capsys, *argv):
    """(exit status, stdout, stderr) of an in-process run."""
    try:
        status = cli.main([str(arg) for arg in argv])
    except SystemExit as exit_:  # argparse's own errors
        status = exit_.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def dyadic_image(seed, shape=(4, 5, 3)):
    """Values k/1024: sums with 0.25 and their squares are exact in float64."""
    return np.random.default_rng(seed).integers(0, 1024, shape) / 1024.0


def write_pair(tmp_path, image, reference, reference_metadata=None, image_metadata=None):
    write_exr(tmp_path / "image.exr", image, image_metadata)
    write_exr(tmp_path / "reference.exr", reference, reference_metadata)
    return tmp_path / "image.exr", tmp_path / "reference.exr"


# --- the errors of arrays --------------------------------------------------------------------


def test_an_offset_everywhere_gives_its_square_as_mse():
    reference = dyadic_image(1)
    errors = image_errors(reference + 0.25, reference)
    assert errors.mse == 0.0625 and errors.mse_per_channel == (0.0625, 0.0625, 0.0625)
    assert errors.pixels == 20
    assert image_errors(reference + 0.1, reference).mse == pytest.approx(0.01, rel=1e-12)


def test_relative_mse_by_hand_on_a_two_by_two_image():
    # (a - r)^2 / (|r| + 0.01)^2 per value: |r| + 0.01 is 0.1, 1, 0.01, 0.2
    reference = np.array([[0.09, 0.99], [0.0, -0.19]])[..., None].repeat(3, axis=-1)
    difference = np.array([[0.1, 0.5], [0.001, 0.2]])[..., None].repeat(3, axis=-1)
    errors = image_errors(reference + difference, reference)
    assert errors.rel_mse == pytest.approx((1.0 + 0.25 + 0.01 + 1.0) / 4, rel=1e-12)
    assert errors.mse == pytest.approx((0.01 + 0.25 + 1e-6 + 0.04) / 4, rel=1e-12)


def test_per_channel_errors_and_their_mean():
    reference = dyadic_image(2)
    errors = image_errors(reference + np.array([0.125, 0.25, 0.5]), reference)
    assert errors.mse_per_channel == (0.015625, 0.0625, 0.25)
    assert errors.mse == pytest.approx((0.015625 + 0.0625 + 0.25) / 3, rel=1e-15)
    # float32 inputs are compared in float64
    single = image_errors(np.float32(0.5) + np.zeros((2, 2, 3), np.float32), np.zeros((2, 2, 3)))
    assert single.mse == 0.25 and isinstance(single.mse, float)


def test_noise_subtraction_and_the_plain_dict():
    reference = dyadic_image(3)
    errors = image_errors(reference + 0.25, reference, reference_noise=0.0125)
    assert errors.reference_noise == 0.0125
    assert errors.mse_minus_noise == pytest.approx(0.0625 - 0.0125, rel=1e-15)
    as_dict = errors.as_dict()
    assert list(as_dict) == DICT_KEYS
    assert as_dict["mse_r"] == as_dict["mse_g"] == as_dict["mse_b"] == 0.0625
    assert all(type(value) in (float, int) for value in as_dict.values())
    assert json.loads(json.dumps(as_dict)) == as_dict
    unknown = image_errors(reference + 0.25, reference)
    assert unknown.reference_noise is None and unknown.mse_minus_noise is None
    assert unknown.as_dict()["mse_minus_noise"] is None
    # A reference noisier than the image's error: negative, as the docstring says
    assert image_errors(reference, reference, reference_noise=0.5).mse_minus_noise == -0.5


def test_summary_line():
    errors = ImageErrors(1.234e-4, 5.6e-3, (1e-4, 1.5e-4, 1.2e-4), 64, 2.0e-5)
    assert errors.summary_line() == (
        "MSE 1.234e-04 (R 1.00e-04 G 1.50e-04 B 1.20e-04), relMSE 5.600e-03, 64 pixels; "
        "reference noise 2.000e-05: MSE minus noise 1.034e-04"
    )
    unknown = ImageErrors(1.234e-4, 5.6e-3, (1e-4, 1.5e-4, 1.2e-4), 64)
    assert unknown.summary_line().endswith("64 pixels; reference noise not known")


@pytest.mark.parametrize(
    ("image", "reference", "message"),
    [
        (np.zeros((2, 3, 3)), np.zeros((3, 2, 3)), r"shape \(2, 3, 3\) .* \(3, 2, 3\)"),
        (np.zeros((2, 3)), np.zeros((2, 3)), r"image must be an \(H, W, 3\) .* \(2, 3\)"),
        (np.zeros((2, 3, 3)), np.zeros((2, 3, 4)), r"reference must be .* \(2, 3, 4\)"),
        (np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), "no pixels"),
    ],
    ids=["shapes", "ndim", "channels", "empty"],
)
def test_unfit_arrays_are_one_line_parameter_errors(image, reference, message):
    for compute in (image_errors, error_map):
        with pytest.raises(ParameterError, match=message) as raised:
            compute(image, reference)
        assert isinstance(raised.value, ClrenderError) and "\n" not in str(raised.value)


def test_nonfinite_values_are_counted_by_pixel():
    image, reference = np.zeros((3, 4, 3)), np.zeros((3, 4, 3))
    image[0, 0] = np.nan  # one pixel, three bad channels
    image[2, 1, 2] = np.inf
    with pytest.raises(ParameterError, match="^the image has 2 pixels with NaN or infinite"):
        image_errors(image, reference)
    reference[1, 1, 0] = -np.inf
    with pytest.raises(ParameterError, match="^the reference has 1 pixels with NaN"):
        image_errors(np.zeros((3, 4, 3)), reference)


@pytest.mark.parametrize("noise", [-1e-3, math.nan, math.inf])
def test_a_reference_noise_must_be_finite_and_not_negative(noise):
    with pytest.raises(ParameterError, match="reference noise must be finite and >= 0"):
        image_errors(np.zeros((1, 1, 3)), np.zeros((1, 1, 3)), reference_noise=noise)


def test_error_map_is_the_squared_error_in_float32():
    reference = dyadic_image(4)
    offset = np.array([0.125, 0.25, 0.5])
    squared = error_map(reference + offset, reference)
    assert squared.dtype == np.float32 and squared.shape == (4, 5, 3)
    assert np.array_equal(squared, np.broadcast_to(np.float32(offset**2), (4, 5, 3)))


def test_mse_minus_noise_estimates_the_mse_against_the_truth(tmp_path):
    """truth + independent noise: the reference's of known per-pixel variance s_i^2 (recorded
    as noise_mse = mean s_i^2), the image's of variance v. E[(a - r)^2] = v + s_i^2 per value,
    so mse_minus_noise estimates v, with standard error sqrt(sum_i 2 (v + s_i^2)^2) / n (a
    squared normal's variance is twice its mean squared); tolerance 5 standard errors, while
    the plain MSE is off by mean s_i^2, over 100 of them."""
    truth = np.random.default_rng(10).random((120, 160, 3))
    reference_variance = 0.002 * (0.5 + truth)  # noisier where brighter, as a render
    image_variance = 1e-3
    reference = truth + np.random.default_rng(11).normal(size=truth.shape) * np.sqrt(
        reference_variance
    )
    image = truth + np.random.default_rng(12).normal(size=truth.shape) * math.sqrt(image_variance)
    noise = float(reference_variance.mean())
    image_path, reference_path = write_pair(tmp_path, image, reference, {"noise_mse": noise})
    pixels, recorded_noise = read_reference(reference_path)
    assert recorded_noise == pytest.approx(noise, rel=1e-7)  # a single-precision attribute
    errors = image_errors(read_exr(image_path)[0], pixels, recorded_noise)
    standard_error = math.sqrt(np.sum(2 * (image_variance + reference_variance) ** 2)) / truth.size
    assert abs(errors.mse_minus_noise - image_variance) < 5 * standard_error
    assert abs(errors.mse - image_variance) > 100 * standard_error


# --- reading ---------------------------------------------------------------------------------


def test_read_reference_returns_its_noise_or_none(tmp_path):
    image = dyadic_image(5)
    write_exr(tmp_path / "noisy.exr", image, {"noise_mse": 0.25, "spp": 64})
    write_exr(tmp_path / "plain.exr", image, {"spp": 64})
    pixels, noise = read_reference(tmp_path / "noisy.exr")
    assert np.array_equal(pixels, image.astype(np.float32)) and noise == 0.25
    assert read_reference(tmp_path / "plain.exr")[1] is None
    assert read_reference(tmp_path / "plain.exr", expected_shape=(4, 5, 3))[1] is None


def test_read_reference_returns_rgb_beside_other_channels(tmp_path):
    # The renderer's planned extra channels (count, variance.R, ...) beside R, G, B
    rgb = dyadic_image(6, (3, 4, 3)).astype(np.float32)
    channels = {"RGB": rgb, "count": np.full((3, 4), 7, np.uint32)}
    channels |= {f"variance.{name}": np.full((3, 4), 0.5, np.float32) for name in "RGB"}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header | {"noise_mse": 0.5}, channels) as exr:
        exr.write(str(tmp_path / "channels.exr"))
    pixels, noise = read_reference(tmp_path / "channels.exr", expected_shape=(3, 4))
    assert np.array_equal(pixels, rgb) and noise == 0.5


@pytest.mark.parametrize("value", ["lots", -0.5, "nan"])
def test_an_unusable_noise_attribute_is_one_line(tmp_path, value):
    write_exr(tmp_path / "ref.exr", np.zeros((2, 2, 3)), {"noise_mse": value})
    with pytest.raises(ComparisonInputError, match=r"ref.exr: its noise_mse metadata .* is not"):
        read_reference(tmp_path / "ref.exr")


def make_bad_input(tmp_path, kind):
    """The path of an unreadable reference of this kind, and the message expected."""
    path = tmp_path / f"{kind}.exr"
    if kind == "missing":
        return path, r"^cannot read reference \S*missing.exr: no such file$"
    if kind == "directory":
        path.mkdir()
        return path, r"^cannot read reference \S*directory.exr: it is a directory$"
    if kind == "text":
        path.write_text("not an image\n")
        return path, r"^cannot read reference \S*text.exr: not an OpenEXR file$"
    if kind == "empty":
        path.write_bytes(b"")
        return path, r"^cannot read reference \S*empty.exr: not an OpenEXR file$"
    if kind == "truncated":
        write_exr(path, np.random.default_rng(0).random((300, 200, 3)))
        path.write_bytes(path.read_bytes()[:40_000])
        return path, r"^cannot read reference \S*truncated.exr: a damaged or truncated EXR"
    if kind == "grey":
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, {"Y": np.zeros((4, 5), np.float32)}) as exr:
            exr.write(str(path))
        return path, r"^cannot read reference \S*grey.exr: the EXR has no R, G, B channel"
    if kind == "size":
        write_exr(path, np.zeros((5, 4, 3)))
        return path, r"^reference \S*size.exr is 4x5, the image compared is 5x4: images must"
    if kind == "nan":
        pixels = np.zeros((4, 5, 3))
        pixels[1, 2, 0] = np.nan
        pixels[3, 3] = np.inf
        write_exr(path, pixels)
        return path, r"^reference \S*nan.exr has 2 pixels with NaN or infinite values$"
    raise AssertionError(kind)


BAD_INPUTS = ["missing", "directory", "text", "empty", "truncated", "grey", "size", "nan"]


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_an_unusable_reference_is_one_line_naming_it(tmp_path, kind):
    path, message = make_bad_input(tmp_path, kind)
    with pytest.raises(ComparisonInputError, match=message) as raised:
        read_reference(path, expected_shape=(4, 5, 3))
    assert isinstance(raised.value, ClrenderError) and "\n" not in str(raised.value)


def test_read_image_names_its_role(tmp_path):
    with pytest.raises(ComparisonInputError, match=r"^cannot read image \S*none.exr: no such"):
        read_image(tmp_path / "none.exr")


# --- the command -----------------------------------------------------------------------------


def test_compare_prints_one_summary_line(capsys, tmp_path):
    reference = dyadic_image(7)
    paths = write_pair(tmp_path, reference + 0.25, reference, {"noise_mse": 0.0078125})
    status, out, err = run_cli(capsys, "compare", *paths)
    assert (status, err) == (0, "")
    expected = image_errors(reference + 0.25, reference, 0.0078125)
    assert out == expected.summary_line() + "\n"
    assert out.startswith("MSE 6.250e-02 ") and "MSE minus noise 5.469e-02" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["image.exr", "reference.exr"]


def test_compare_json_matches_image_errors(capsys, tmp_path):
    rng = np.random.default_rng(8)
    reference = rng.random((6, 7, 3))
    image = reference + rng.normal(0, 0.05, reference.shape)
    image_path, reference_path = write_pair(tmp_path, image, reference, {"noise_mse": 1e-3})
    status, out, err = run_cli(capsys, "compare", image_path, reference_path, "--json")
    assert (status, err) == (0, "")
    record = json.loads(out)
    assert out.count("\n") == 1
    pixels, noise = read_reference(reference_path)
    expected = image_errors(read_exr(image_path)[0], pixels, noise).as_dict()
    assert record == {"image": str(image_path), "reference": str(reference_path)} | expected


def test_compare_map_writes_the_squared_error_and_a_false_colour_preview(capsys, tmp_path):
    reference = np.full((8, 10, 3), 0.5)
    image = reference.copy()
    image[2, 3] += 0.51  # relative squared error 1: the top colour
    image[5, 6] += 0.051  # 1e-2: half way up a scale of four decades
    image_path, reference_path = write_pair(tmp_path, image, reference)
    out_path = tmp_path / "maps" / "errors.exr"  # a missing folder is created
    status, out, err = run_cli(capsys, "compare", image_path, reference_path, "--map", out_path)
    assert (status, err) == (0, "")
    first, second = out.splitlines()
    assert first == image_errors(read_exr(image_path)[0], reference).summary_line()
    assert second.startswith(f"wrote {out_path} (squared error) and {out_path.with_suffix('.png')}")
    assert "log scale from 1e-04 (black) to 1e+00 (pale yellow)" in second
    squared, metadata = read_exr(out_path)
    assert np.array_equal(squared, error_map(read_exr(image_path)[0], reference))
    assert metadata["image"] == str(image_path) and metadata["reference"] == str(reference_path)
    assert metadata["mse"] == pytest.approx(float(squared.astype(np.float64).mean()), rel=1e-6)
    assert metadata["pixels"] == 80 and "reference_noise" not in metadata
    assert "1e-04 (black) to 1e+00" in metadata["preview_scale"]
    preview = read_png(out_path.with_suffix(".png"))
    ramp_codes = np.floor(RAMP_DISPLAY * 255 + 0.5)
    assert preview.shape == (8, 10, 3)
    assert np.abs(preview[0, 0] - ramp_codes[0]).max() <= 1  # no error: the bottom colour
    assert np.abs(preview[2, 3] - ramp_codes[-1]).max() <= 1
    assert np.abs(preview[5, 6] - ramp_codes[2]).max() <= 1


def test_compare_map_with_json_adds_the_map_paths(capsys, tmp_path):
    reference = dyadic_image(9)
    paths = write_pair(tmp_path, reference + 0.25, reference)
    status, out, _ = run_cli(capsys, "compare", *paths, "--json", "--map", tmp_path / "e")
    record = json.loads(out)
    assert status == 0 and record["map"] == str(tmp_path / "e.exr")
    assert record["preview"] == str(tmp_path / "e.png") and len(record["preview_scale"]) == 2
    assert (tmp_path / "e.exr").is_file() and (tmp_path / "e.png").is_file()


@pytest.mark.parametrize("blocked", ["exr", "png"])
def test_a_map_path_that_cannot_be_written_exits_2_and_writes_nothing(capsys, tmp_path, blocked):
    reference = dyadic_image(10)
    paths = write_pair(tmp_path, reference + 0.25, reference)
    (tmp_path / f"errors.{blocked}").mkdir()
    status, out, err = run_cli(capsys, "compare", *paths, "--map", tmp_path / "errors.exr")
    assert (status, out) == (2, "")
    assert err == f"clrender: error: cannot write {tmp_path}/errors.{blocked}: it is a directory\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["image.exr", "reference.exr", f"errors.{blocked}"]
    )


def test_a_failed_map_write_keeps_the_old_files(capsys, tmp_path, monkeypatch):
    reference = dyadic_image(11)
    paths = write_pair(tmp_path, reference + 0.25, reference)
    (tmp_path / "errors.exr").write_bytes(b"old map")

    def full_disk_writer(image):
        def write(temp):
            raise OSError(28, "No space left on device")

        return write

    monkeypatch.setattr(imageio, "png_writer", full_disk_writer)
    status, out, err = run_cli(capsys, "compare", *paths, "--map", tmp_path / "errors.exr")
    assert (status, out) == (2, "")
    assert err == f"clrender: error: cannot write {tmp_path}/errors.png: No space left on device\n"
    assert (tmp_path / "errors.exr").read_bytes() == b"old map"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "errors.exr",
        "image.exr",
        "reference.exr",
    ]


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_an_unusable_reference_exits_2_in_one_line(capsys, tmp_path, kind):
    write_exr(tmp_path / "image.exr", np.zeros((4, 5, 3)))
    path, message = make_bad_input(tmp_path, kind)
    status, out, err = run_cli(capsys, "compare", tmp_path / "image.exr", path)
    assert (status, out) == (2, "")
    assert err.count("\n") == 1 and err.startswith("clrender: error: ")
    assert re.match(message, err.removeprefix("clrender: error: ").removesuffix("\n"))


def test_an_unusable_image_or_map_name_exits_2_in_one_line(capsys, tmp_path):
    write_exr(tmp_path / "reference.exr", np.zeros((4, 5, 3)))
    status, _, err = run_cli(capsys, "compare", tmp_path / "none.exr", tmp_path / "reference.exr")
    assert (
        status == 2
        and err == f"clrender: error: cannot read image {tmp_path}/none.exr: no such file\n"
    )
    status, _, err = run_cli(
        capsys, "compare", tmp_path / "reference.exr", tmp_path / "reference.exr", "--map", "a.png"
    )
    assert status == 2 and err == "clrender: error: --map must name an .exr file, got 'a.png'\n"
    status, _, err = run_cli(capsys, "compare", tmp_path / "reference.exr")
    assert status == 2 and err.startswith("clrender: error: the following arguments are required")


def test_a_partial_input_is_warned_about(capsys, tmp_path):
    reference = dyadic_image(12)
    paths = write_pair(tmp_path, reference, reference, {"partial": 1}, {"partial": 0})
    status, out, err = run_cli(capsys, "compare", *paths)
    assert status == 0 and out.startswith("MSE 0.000e+00")
    assert err == (
        f"clrender: warning: the reference {paths[1]} is partial (an interrupted render: its "
        "unfinished pixels are black)\n"
    )


def test_the_parser_does_not_load_openexr():
    # build_parser runs for every command, outside the signal-blocked library loading
    code = (
        "import sys; from clrender import cli; cli.build_parser(); print('OpenEXR' in sys.modules)"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout == "False\n"


def test_a_damaged_exr_is_one_line_even_where_the_library_prints(capfd, tmp_path):
    # OpenEXR's C library prints its errors on file descriptor 2 itself (sys.stderr is not it)
    write_exr(tmp_path / "image.exr", np.zeros((4, 5, 3)))
    path, _ = make_bad_input(tmp_path, "truncated")
    status = cli.main(["compare", str(tmp_path / "image.exr"), str(path)])
    out, err = capfd.readouterr()
    assert (status, out) == (2, "")
    assert err.count("\n") == 1 and err.startswith("clrender: error: cannot read reference")
    assert "(EXR_ERR_" in err  # the library's reason, in the one line


@pytest.mark.parametrize("name", ["image.exr", "reference", "image"])
def test_a_map_is_never_written_over_an_input(capsys, tmp_path, name):
    reference = dyadic_image(13)
    paths = write_pair(tmp_path, dyadic_image(14), reference)
    (tmp_path / "image.png").write_bytes(b"the render's preview")
    before = {path: path.read_bytes() for path in tmp_path.iterdir()}
    status, out, err = run_cli(capsys, "compare", *paths, "--map", tmp_path / name)
    assert (status, out) == (2, "")
    assert err.startswith(f"clrender: error: --map {tmp_path}/") and "would overwrite" in err
    assert {path: path.read_bytes() for path in tmp_path.iterdir()} == before


@pytest.mark.parametrize(
    "image, reference, warned",
    [
        ({"scene": "cornell-box", "seed": 0}, {"scene": "cornell-box", "seed": 0}, ["same seed"]),
        ({"scene": "cornell-box", "seed": 0}, {"scene": "cornell-box", "seed": 1}, []),
        ({"scene": "cornell-box", "seed": 0}, {"scene": "mitsuba-cbox", "seed": 1}, ["scene"]),
        ({"scene": "cornell-box", "seed": 0}, {}, []),  # another renderer's reference
        ({}, {"scene": "cornell-box", "seed": 0, "partial": 1}, ["partial"]),
    ],
)
def test_what_makes_a_reference_untrustworthy_is_warned_about(image, reference, warned):
    from clrender.compare import reference_warnings

    warnings = reference_warnings(image, reference, "ref.exr")
    assert len(warnings) == len(warned)
    for text, expected in zip(warnings, warned, strict=True):
        assert expected in text and "ref.exr" in text and "\n" not in text


def test_compare_warns_of_a_reference_from_the_same_seed(capsys, tmp_path):
    labels = {"scene": "cornell-box", "seed": 3, "sampler": "independent"}
    paths = write_pair(tmp_path, dyadic_image(15), dyadic_image(16), labels, labels)
    status, out, err = run_cli(capsys, "compare", *paths)
    assert status == 0 and out.startswith("MSE ")
    assert err.startswith("clrender: warning: the image and the reference") and "(3)" in err
