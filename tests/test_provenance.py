"""Provenance in an image's metadata: the scene as the device got it (a file edited under the
same name is told apart, a comment is not), the kernel sources, the Voronoi backend and the
device's precision; a reference of an edited scene is warned about."""

import shutil

import pytest

from clrender import cli
from clrender.compare import reference_warnings
from clrender.imageio import read_exr
from clrender.provenance import kernels_fingerprint, scene_fingerprint, sources_fingerprint
from clrender.runtime import kernels_dir
from clrender.scene import load_scene

FAST = ("--res", "12x8", "--spp", "4")


def copies(tmp_path):
    """cornell-box.toml copied as is, with a comment added, and with its light halved."""
    text = load_scene("cornell-box").path.read_text()
    assert text.count("emission = [24.0, 24.0, 24.0]") == 1
    folders = {}
    for name, edited in (
        ("same", text),
        ("comment", "# a comment\n" + text),
        ("dimmer", text.replace("emission = [24.0, 24.0, 24.0]", "emission = [12.0, 12.0, 12.0]")),
    ):
        folder = tmp_path / name
        folder.mkdir()
        (folder / "cornell-box.toml").write_text(edited)
        folders[name] = folder / "cornell-box.toml"
    return folders


def test_the_scene_fingerprint_follows_what_the_device_gets(tmp_path):
    files = copies(tmp_path)
    shipped = scene_fingerprint(load_scene("cornell-box"))
    assert len(shipped) == 16 and int(shipped, 16) >= 0
    assert scene_fingerprint(load_scene(str(files["same"]))) == shipped
    assert scene_fingerprint(load_scene(str(files["comment"]))) == shipped
    assert scene_fingerprint(load_scene(str(files["dimmer"]))) != shipped
    assert scene_fingerprint(load_scene("mitsuba-cbox")) != shipped


def test_the_kernels_fingerprint_follows_their_sources(tmp_path, monkeypatch):
    shipped = kernels_fingerprint()
    copy = tmp_path / "kernels"
    shutil.copytree(kernels_dir(), copy)
    monkeypatch.setenv("CLRENDER_KERNELS_DIR", str(copy))
    assert kernels_fingerprint() == shipped
    (copy / "geometry_test.cl").write_text("// test kernels are not rendered with\n")
    assert kernels_fingerprint() == shipped
    probe = copy / "simd_paths_probe.cl"  # a research probe: bench scripts build it, not renders
    probe.write_text(probe.read_text() + "// edited\n")
    assert kernels_fingerprint() == shipped
    header = copy / "geometry.h"
    header.write_text(header.read_text() + "\n")
    assert kernels_fingerprint() != shipped


def test_the_kernels_fingerprint_is_of_the_sources_the_process_built(
    runtime, tmp_path, monkeypatch
):
    # Programs are built once per process: a source edited after the builds is not what its
    # renders run, so the fingerprint stays that of the sources built; a later build that finds
    # the files changed adds its own (the programs then come from both)
    copy = tmp_path / "kernels"
    shutil.copytree(kernels_dir(), copy)
    monkeypatch.setenv("CLRENDER_KERNELS_DIR", str(copy))
    header = copy / "geometry.h"
    header.write_text(header.read_text() + "// first\n")
    first = kernels_fingerprint()  # nothing built from the copy yet: its sources now
    runtime.build("selfcheck.cl", {"CLRENDER_FINGERPRINT_TEST": 1})
    header.write_text(header.read_text() + "// edited after the build\n")
    edited = sources_fingerprint(copy)
    assert edited != first and kernels_fingerprint() == first
    runtime.build("selfcheck.cl", {"CLRENDER_FINGERPRINT_TEST": 2})  # a build of the edited ones
    assert kernels_fingerprint() == f"{first}+{edited}"
    runtime.build("selfcheck.cl", {"CLRENDER_FINGERPRINT_TEST": 3})  # the same sources again
    assert kernels_fingerprint() == f"{first}+{edited}"


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize("backend", ["device", "qhull"])
def test_a_render_records_its_provenance(capsys, tmp_path, backend):
    out = tmp_path / "out.exr"
    argv = ["render", "cornell-box", *FAST, "--estimator", "vor_sn", "-o", str(out)]
    assert cli.main([*argv, "--voronoi-backend", backend, "--quiet"]) == 0
    metadata = read_exr(out)[1]
    assert metadata["scene"] == "cornell-box"
    assert metadata["scene_file"] == str(load_scene("cornell-box").path.resolve())
    assert metadata["scene_sha256"] == scene_fingerprint(load_scene("cornell-box"))
    assert metadata["kernels_sha256"] == kernels_fingerprint()
    assert metadata["voronoi_backend"] == backend
    assert metadata["device_precision"] in ("mixed", "single")


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_a_reference_of_an_edited_scene_of_the_same_name_is_warned_about(capsys, tmp_path):
    files = copies(tmp_path)
    reference = tmp_path / "reference.exr"
    argv = ["render", str(files["dimmer"]), *FAST, "--seed", "1", "-o", str(reference)]
    assert cli.main([*argv, "--quiet"]) == 0
    capsys.readouterr()
    for name in ("same", "comment", "dimmer"):
        image = tmp_path / f"{name}.exr"
        argv = ["render", str(files[name]), *FAST, "--reference", str(reference)]
        assert cli.main([*argv, "-o", str(image), "--quiet"]) == 0
        edited = name != "dimmer"  # the reference's scene is the dimmer one
        err = capsys.readouterr().err
        assert ("another scene of the same name 'cornell-box'" in err) == edited, (name, err)
        # compare reads the same from the two files' metadata
        words = reference_warnings(read_exr(image)[1], read_exr(reference)[1], reference)
        assert any("another scene of the same name" in word for word in words) == edited
