"""Provenance in an image's metadata: the scene as the device got it (a file edited under the
same name is told apart, a comment is not), the kernel sources, clrender's Python code, the
Voronoi backend and the device's precision; a reference of an edited scene is warned about."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import clrender
from clrender import cli
from clrender.code_sources import python_sources_fingerprint
from clrender.compare import reference_warnings
from clrender.imageio import read_exr
from clrender.provenance import (
    KernelsWarning,
    ProvenanceWarning,
    code_fingerprint,
    kernels_fingerprint,
    provenance_warning,
    scene_fingerprint,
    sources_fingerprint,
)
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


def package_copy(tmp_path) -> Path:
    """clrender's package folder copied into tmp_path/copy/clrender, without bytecode caches."""
    copy = tmp_path / "copy" / "clrender"
    shutil.copytree(Path(clrender.__file__).parent, copy, ignore=shutil.ignore_patterns("*.pyc"))
    return copy


def imported_from(copy: Path, code: str) -> str:
    """What `code` prints in a child process that imports clrender from the copy."""
    # The copy holds the Python package alone: its kernels are ours (an installed package
    # finds them inside it, a checkout beside it, and the copy has neither)
    env = {**os.environ, "PYTHONPATH": str(copy.parent), "PYTHONDONTWRITEBYTECODE": "1"}
    env["CLRENDER_KERNELS_DIR"] = str(kernels_dir())
    child = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=copy.parent
    )
    assert child.returncode == 0, child.stderr
    return child.stdout


def test_the_code_fingerprint_follows_the_python_sources(tmp_path):
    ours = code_fingerprint()
    assert len(ours) == 16 and int(ours, 16) >= 0 and ours == clrender.CODE_SHA256
    copy = package_copy(tmp_path)
    # the same sources anywhere: the same fingerprint, also as the copy's own import takes it
    assert python_sources_fingerprint(copy) == ours
    assert imported_from(copy, "import clrender; print(clrender.CODE_SHA256)").strip() == ours
    # bytecode, kernels and other files do not count
    (copy / "__pycache__").mkdir(exist_ok=True)
    (copy / "__pycache__" / "stale.py").write_text("x = 1\n")
    (copy / "kernels").mkdir()
    (copy / "kernels" / "rng.cl").write_text("// kernels have their own fingerprint\n")
    (copy / "notes.txt").write_text("not code\n")
    assert python_sources_fingerprint(copy) == ours
    # an edited module (in a subpackage), an added one and a moved one each change it
    fingerprints = {ours}
    registry = copy / "estimators" / "registry.py"
    text = registry.read_text()
    assert text.count("np.maximum(counts, 1.0)") == 1
    registry.write_text(text.replace("np.maximum(counts, 1.0)", "np.maximum(counts, 2.0)"))
    fingerprints.add(python_sources_fingerprint(copy))
    (copy / "extra.py").write_text("")
    fingerprints.add(python_sources_fingerprint(copy))
    (copy / "extra.py").rename(copy / "estimators" / "extra.py")
    fingerprints.add(python_sources_fingerprint(copy))
    assert len(fingerprints) == 4


def test_the_code_fingerprint_says_when_the_sources_changed_after_the_import(tmp_path):
    # clrender imports most modules when first used, so a module edited after the import (in
    # a notebook's session) may run: the fingerprint then names both versions; the next
    # process imports and fingerprints the edit alone
    copy = package_copy(tmp_path)
    api = copy / "api.py"
    script = (
        "import pathlib, clrender\n"
        "from clrender.provenance import code_fingerprint\n"
        "before = code_fingerprint()\n"
        f"path = pathlib.Path({str(api)!r})\n"
        "path.write_text(path.read_text() + '# edited after the import\\n')\n"
        "print(before, code_fingerprint())\n"
    )
    before, after = imported_from(copy, script).split()
    edited = python_sources_fingerprint(copy)
    assert before == code_fingerprint() and edited != before  # (the copy was ours)
    assert after == f"{before}+{edited}"
    assert imported_from(copy, "import clrender; print(clrender.CODE_SHA256)").strip() == edited


def test_editor_files_and_unreadable_sources_do_not_stop_the_import(tmp_path):
    # Emacs' lock file of an edited api.py is a dangling symlink named .#api.py (before:
    # open() failed inside `import clrender`); an unreadable module counts as such
    copy = package_copy(tmp_path)
    shipped = python_sources_fingerprint(copy)
    (copy / ".#api.py").symlink_to("root@host.1234:1700000000")
    (copy / "api.py~").write_text("backup")
    assert python_sources_fingerprint(copy) == shipped
    assert imported_from(copy, "import clrender; print(clrender.CODE_SHA256)").strip() == shipped
    (copy / "estimators" / "extra.py").symlink_to(tmp_path / "missing.py")
    unreadable = python_sources_fingerprint(copy)
    assert unreadable != shipped
    assert imported_from(copy, "import clrender; print(clrender.CODE_SHA256)").strip() == (
        unreadable
    )


def test_the_provenance_warning_names_what_differs():
    ours = {"code_sha256": "c" * 16, "kernels_sha256": "k" * 16}
    assert provenance_warning({"code_sha256": None, "kernels_sha256": None}, ours) is None
    assert provenance_warning(dict(ours), ours) is None
    code = provenance_warning({**ours, "code_sha256": "0" * 16}, ours)
    assert type(code) is ProvenanceWarning  # the kernels agree: not a KernelsWarning
    assert str(code) == (
        f"the workers ran other clrender code (code {'0' * 16}) than this clrender "
        f"({'c' * 16}); the images record the workers' values"
    )
    both = provenance_warning({"code_sha256": "0" * 16, "kernels_sha256": "1" * 16}, ours)
    assert isinstance(both, KernelsWarning) and isinstance(both, ProvenanceWarning)
    assert "ran other clrender code" in str(both) and "built other OpenCL sources" in str(both)
    older = f"{'c' * 16}; unknown (an older worker)"
    unknown = provenance_warning({"code_sha256": older, "kernels_sha256": "k" * 16}, ours)
    assert type(unknown) is ProvenanceWarning
    assert str(unknown).startswith(
        f"a worker could not tell which clrender code it ran (code {older})"
    )
    mixed = provenance_warning({"code_sha256": older, "kernels_sha256": "1" * 16}, ours)
    assert type(mixed) is KernelsWarning and str(mixed).count("\n") == 0
    assert "built other OpenCL sources" in str(mixed)
    assert "a worker could not tell which clrender code it ran" in str(mixed)
    client = {"code_sha256": "c" * 16, "kernels_sha256": None}  # a client without kernels
    assert "than this clrender (no kernels folder here)" in str(provenance_warning(ours, client))


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_a_render_of_other_code_records_another_fingerprint(tmp_path, capsys):
    # The reviewer's case: a host-side estimator edited in a copy of the package halves the
    # image, and the image's metadata says it was made by other code
    copy = package_copy(tmp_path)
    registry = copy / "estimators" / "registry.py"
    registry.write_text(
        registry.read_text().replace("np.maximum(counts, 1.0)", "np.maximum(counts, 2.0)")
    )
    argv = ["render", "analytic:mix", "--res", "8x4", "--spp", "1", "--sampler", "independent"]
    argv += ["--estimator", "mc_n", "--seed", "2", "--quiet", "--json"]
    ours, theirs = tmp_path / "ours.exr", tmp_path / "theirs.exr"
    assert cli.main([*argv, "-o", str(ours)]) == 0
    (image,) = json.loads(capsys.readouterr().out)["images"].values()
    assert image["metadata"]["code_sha256"] == code_fingerprint()
    run = f"from clrender.cli import main; raise SystemExit(main({[*argv, '-o', str(theirs)]!r}))"
    imported_from(copy, run)
    (ours_pixels, ours_metadata), (their_pixels, their_metadata) = (
        read_exr(path)[:2] for path in (ours, theirs)
    )
    assert np.array_equal(their_pixels * 2, ours_pixels)
    assert ours_metadata["code_sha256"] == code_fingerprint()
    assert their_metadata["code_sha256"] == python_sources_fingerprint(copy) != code_fingerprint()
    differ = {
        key
        for key in ours_metadata.keys() | their_metadata.keys()
        if ours_metadata.get(key) != their_metadata.get(key) and not key.endswith("time_s")
    }
    # (the errors against the analytic image's exact integrals follow the pixels)
    assert {key for key in differ if not key.startswith("error_")} == {"code_sha256"}


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
    assert metadata["code_sha256"] == code_fingerprint()
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
