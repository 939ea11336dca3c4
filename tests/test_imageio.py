"""Image output: EXR round trip with metadata, PNG through Pillow, atomic writes, path checks."""

from pathlib import Path

import numpy as np
import pytest

from clrender.imageio import (
    MissingChannelsError,
    OutputPathError,
    check_writable,
    exr_header,
    exr_writer,
    read_exr,
    read_png,
    rgb_float32,
    srgb8,
    write_all_atomically,
    write_atomically,
    write_exr,
    write_png,
)


def test_exr_round_trip_keeps_pixels_and_metadata(tmp_path):
    rng = np.random.default_rng(1)
    image = rng.random((5, 7, 3)).astype(np.float32) * 30.0
    image[0, 0] = [0.0, 1e-30, 65504.0 * 4]  # beyond half range: float32 must survive
    metadata = {
        "scene": "cornell-box",
        "spp": 64,
        "seed": 4_000_000_000,
        "partial": True,
        "render_time_s": 1.25,
        "error_mse": 0.019338188512607515,  # no float32: written as a double
        "nonfinite_samples": 0,
    }
    write_exr(tmp_path / "out.exr", image, metadata)
    pixels, meta = read_exr(tmp_path / "out.exr")
    assert pixels.dtype == np.float32 and pixels.shape == (5, 7, 3)
    assert np.array_equal(pixels, image)
    assert meta == {
        "scene": "cornell-box",
        "spp": 64,
        "seed": 4_000_000_000,  # beyond int32: written as digits, read back as an int
        "partial": 1,
        "render_time_s": 1.25,
        "error_mse": 0.019338188512607515,
        "nonfinite_samples": 0,
    }
    assert all(type(meta[key]) is type(metadata[key]) for key in ("seed", "error_mse", "spp"))


def test_exr_writes_non_contiguous_and_float64_images_correctly(tmp_path):
    image = np.arange(4 * 6 * 3, dtype=np.float64).reshape(4, 6, 3)
    flipped = image[::-1, ::2]  # a strided view, the case the bindings get wrong
    write_exr(tmp_path / "view.exr", flipped)
    pixels, _ = read_exr(tmp_path / "view.exr")
    assert np.array_equal(pixels, flipped.astype(np.float32))


@pytest.mark.parametrize(
    "extra",
    [
        {"count": np.uint32, "variance.R": np.float32, "variance.G": np.float32},
        {"A": np.float32},  # the bindings group R, G, B, A into one RGBA array by default
        {"Z": np.float16},
    ],
    ids=["named", "alpha", "half"],
)
def test_exr_rgb_is_read_whatever_other_channels_it_holds(tmp_path, extra):
    import OpenEXR

    rng = np.random.default_rng(2)
    rgb = rng.random((3, 5, 3)).astype(np.float32)
    channels = {name: np.ascontiguousarray(rgb[..., i]) for i, name in enumerate("RGB")}
    channels.update({name: np.ones((3, 5), dtype) for name, dtype in extra.items()})
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header | {"noise_mse": 0.5}, channels) as exr:
        exr.write(str(tmp_path / "extra.exr"))
    pixels, meta = read_exr(tmp_path / "extra.exr")
    assert pixels.dtype == np.float32 and np.array_equal(pixels, rgb)
    assert meta == {"noise_mse": 0.5}


def test_exr_without_rgb_channels_names_what_it_has(tmp_path):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"Y": np.zeros((2, 2), np.float32)}) as exr:
        exr.write(str(tmp_path / "grey.exr"))
    with pytest.raises(
        MissingChannelsError, match=r"^the EXR has no R, G, B channel \(its channels: Y\)$"
    ):
        read_exr(tmp_path / "grey.exr")


def test_srgb_transfer_function_values():
    linear = np.array([-1.0, 0.0, 0.0031308, 0.18, 0.5, 1.0, 7.0, np.nan])
    # 0.18 -> 0.46135 * 255 = 117.6; 0.5 -> 0.73536 * 255 = 187.5 (rounds up); clamped ends.
    assert srgb8(linear).tolist() == [0, 0, 10, 118, 188, 255, 255, 0]


def test_png_decodes_to_the_right_size_and_srgb_values(tmp_path):
    height, width = 3, 5  # not square: a transposed image would fail
    image = np.zeros((height, width, 3), np.float32)
    image[0, 4] = [1.0, 0.5, 0.18]
    image[2, 0] = [0.0031308, 2.0, -0.5]
    write_png(tmp_path / "preview.png", image)
    decoded = read_png(tmp_path / "preview.png")
    assert decoded.shape == (height, width, 3) and decoded.dtype == np.uint8
    assert decoded[0, 4].tolist() == [255, 188, 118]
    assert decoded[2, 0].tolist() == [10, 255, 0]
    assert decoded.sum() == 255 + 188 + 118 + 10 + 255


def test_png_is_marked_srgb_and_its_rows_are_filtered(tmp_path):
    # Pillow's encoder filters rows (the hand-written one wrote them unfiltered, 26-32 % larger)
    import zlib

    from PIL import Image

    y, x = np.mgrid[0:64, 0:96] / 96.0
    image = np.stack([x, y, 0.5 * (x + y)], axis=-1) ** 2.2  # smooth gradients, as renders
    write_png(tmp_path / "p.png", image)
    with Image.open(tmp_path / "p.png") as png:
        assert (png.format, png.mode, png.size) == ("PNG", "RGB", (96, 64))
        assert png.info["srgb"] == 0  # sRGB chunk, perceptual intent
    rows = np.zeros((64, 1 + 3 * 96), np.uint8)
    rows[:, 1:] = srgb8(image).reshape(64, -1)
    unfiltered = len(zlib.compress(rows.tobytes(), 6))
    assert (tmp_path / "p.png").stat().st_size < 0.8 * unfiltered


def test_a_preview_over_pillows_decompression_bomb_limit_is_written(tmp_path, monkeypatch):
    # Image.open warns above 89 M pixels and refuses above 179 M: a large render's preview
    import warnings

    from PIL import Image

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # stands in for a 10k x 10k render
    image = np.random.default_rng(2).random((20, 30, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_png(tmp_path / "large.png", image)
        assert np.array_equal(read_png(tmp_path / "large.png"), srgb8(image))


def test_failed_write_leaves_no_file_under_the_requested_name(tmp_path):
    target = tmp_path / "out.png"

    def half_write_then_fail(temp):
        temp.write_bytes(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputPathError, match="out.png"):
        write_atomically(target, half_write_then_fail)
    assert list(tmp_path.iterdir()) == []


def test_interrupted_write_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.exr"
    write_exr(target, np.ones((2, 2, 3)))

    def interrupted(temp):
        temp.write_bytes(b"partial bytes")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomically(target, interrupted)
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]
    assert np.array_equal(read_exr(target)[0], np.ones((2, 2, 3), np.float32))


@pytest.mark.parametrize("relative", ["a-file/out.exr", "a-file/deeper/out.exr", "."])
def test_unwritable_paths_fail_with_the_path_named(tmp_path, relative):
    (tmp_path / "a-file").write_text("not a directory")
    path = tmp_path / relative
    with pytest.raises(OutputPathError, match="cannot write"):
        check_writable(path)
    with pytest.raises(OutputPathError, match=str(path.parent.name)):
        write_png(path, np.zeros((1, 1, 3)))


def test_writable_path_in_an_existing_directory(tmp_path):
    assert check_writable(tmp_path / "new.exr") == tmp_path / "new.exr"


def test_missing_folders_are_created_by_the_writers(tmp_path):
    path = tmp_path / "missing" / "deeper" / "out.png"
    assert check_writable(path) == path and not path.parent.exists()
    write_png(path, np.zeros((1, 1, 3)))
    assert path.is_file()


# --- a full disk, a killed writer (issue: no data lost) ---------------------------------------


def test_a_short_exr_never_replaces_the_previous_one(tmp_path, monkeypatch):
    # A full disk: the OpenEXR library writes a short file without raising (seen on tmpfs)
    import OpenEXR

    target = tmp_path / "out.exr"
    write_exr(target, np.ones((4, 4, 3)))

    def write_short(self, name):
        with open(name, "wb") as f:
            f.write(b"\x76\x2f\x31\x01")  # the EXR magic number, then nothing

    monkeypatch.setattr(OpenEXR.File, "write", write_short)
    with pytest.raises(OutputPathError, match=r"cannot write .*out.exr: the written file is"):
        write_exr(target, np.zeros((4, 4, 3)))
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]
    assert np.array_equal(read_exr(target)[0], np.ones((4, 4, 3), np.float32))


def test_an_exr_cut_in_its_pixel_data_never_replaces_the_previous_one(tmp_path, monkeypatch):
    # The bindings read such a file with a ValueError (a file cut after its magic number: a
    # RuntimeError); either is a failed write, reported in one line
    import OpenEXR

    target = tmp_path / "out.exr"
    write_exr(target, np.ones((4, 4, 3)))
    write_whole = OpenEXR.File.write

    def write_cut(self, name):
        write_whole(self, name)
        data = Path(name).read_bytes()
        Path(name).write_bytes(data[: len(data) // 2])

    monkeypatch.setattr(OpenEXR.File, "write", write_cut)
    image = np.random.default_rng(0).random((300, 200, 3))  # several chunks: cut between them
    with pytest.raises(OutputPathError, match=r"cannot write .*out.exr: the written file is"):
        write_exr(target, image)
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]
    assert np.array_equal(read_exr(target)[0], np.ones((4, 4, 3), np.float32))


@pytest.mark.parametrize("keep", [0, 8, 40, -30, -12])
def test_a_short_png_never_replaces_the_previous_one(tmp_path, monkeypatch, keep):
    # Cut at the signature, the header, inside the pixel data, before IEND: each is read back
    from PIL import Image

    target = tmp_path / "out.png"
    write_png(target, np.ones((4, 4, 3)))
    old = target.read_bytes()
    real_save = Image.Image.save

    def save_short(self, fp, *args, **kwargs):
        real_save(self, fp, *args, **kwargs)
        data = Path(fp).read_bytes()
        Path(fp).write_bytes(data[:keep])

    monkeypatch.setattr(Image.Image, "save", save_short)
    image = np.random.default_rng(3).random((16, 16, 3))
    with pytest.raises(OutputPathError, match=r"cannot write .*out.png: the written file is"):
        write_png(target, image)
    assert [p.name for p in tmp_path.iterdir()] == ["out.png"]
    assert target.read_bytes() == old


def test_a_png_whose_pixels_read_back_differently_is_refused(tmp_path, monkeypatch):
    from PIL import Image

    real_save = Image.Image.save

    def save_other(self, fp, *args, **kwargs):
        real_save(Image.new("RGB", self.size, (1, 2, 3)), fp, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "save", save_other)
    with pytest.raises(OutputPathError, match="out.png: .*pixels read back differently"):
        write_png(tmp_path / "out.png", np.zeros((2, 3, 3)))
    assert list(tmp_path.iterdir()) == []


def test_an_exr_library_error_is_one_line_naming_the_file(tmp_path, monkeypatch):
    import OpenEXR

    def fail(self, name):
        raise RuntimeError("Cannot write image file: No space left on device")

    monkeypatch.setattr(OpenEXR.File, "write", fail)
    with pytest.raises(OutputPathError, match="cannot write .*a.exr: Cannot write image file"):
        write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    assert list(tmp_path.iterdir()) == []


def test_the_temporary_file_the_exr_library_names_is_not_shown(tmp_path, monkeypatch):
    """OpenEXR's message names the temporary file: before, 'Failed to write pixel data to
    image file its temporary file.'"""
    import OpenEXR

    def fail(self, name):
        raise RuntimeError(
            f'Failed to write pixel data to image file "{name}". No space left on device.'
        )

    monkeypatch.setattr(OpenEXR.File, "write", fail)
    with pytest.raises(OutputPathError) as err:
        write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    assert str(err.value) == (
        f"cannot write {tmp_path / 'a.exr'}: Failed to write pixel data to its temporary file. "
        "No space left on device."
    )


def test_a_pair_is_replaced_only_when_both_files_are_written(tmp_path):
    exr, png = tmp_path / "out.exr", tmp_path / "out.png"
    write_exr(exr, np.ones((2, 2, 3)))
    write_png(png, np.ones((2, 2, 3)))
    old_png = png.read_bytes()

    def no_space(temp):
        raise OSError(28, "No space left on device")

    writers = [(exr, exr_writer(rgb_float32(np.zeros((2, 2, 3))), exr_header({}))), (png, no_space)]
    with pytest.raises(OutputPathError, match="out.png: No space left on device"):
        write_all_atomically(writers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr", "out.png"]
    assert np.array_equal(read_exr(exr)[0], np.ones((2, 2, 3), np.float32))
    assert png.read_bytes() == old_png


def test_temp_files_of_a_killed_writer_are_removed_by_the_next_write(tmp_path):
    import os
    import subprocess
    import sys

    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    stale = tmp_path / f".out.exr.{int(gone.stdout)}.k9x2a7.tmp"
    live = tmp_path / f".out.exr.{os.getppid()}.b3c4d5.tmp"  # a running process's
    other = tmp_path / f".other.exr.{int(gone.stdout)}.k9x2a7.tmp"  # another file's
    for path in (stale, live, other):
        path.write_bytes(b"")
    write_exr(tmp_path / "out.exr", np.ones((2, 2, 3)))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out.exr", live.name, other.name])


def test_a_full_disk_keeps_the_previous_image(tmp_path):
    # A real full file system where one can be mounted (root in a container), else skipped
    import subprocess

    mount = tmp_path / "small"
    mount.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)], capture_output=True
    )
    if made.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here")
    try:
        target = mount / "full.exr"
        image = np.random.default_rng(0).random((64, 64, 3))
        write_exr(target, image)
        with open(mount / "filler", "wb", buffering=0) as filler, pytest.raises(OSError):
            while True:
                filler.write(b"\0" * 4096)
        # A small image: the library leaves a short file silently; a larger one: it raises
        for scale in (2, 8):
            bigger = np.tile(image * scale, (scale, 1, 1))
            with pytest.raises(OutputPathError, match="full.exr: .*(incomplete|No space left)"):
                write_exr(target, bigger)
        assert np.array_equal(read_exr(target)[0], image.astype(np.float32))
        assert sorted(p.name for p in mount.iterdir()) == ["filler", "full.exr"]
    finally:
        subprocess.run(["umount", str(mount)], check=False)
