"""Bad input at the command line: one-line errors (no traceback) with a non-zero exit status,
one-line warnings with status 0; determinism across runs and tilings; peak memory bounded by
the tile size, not the image size.

Cases already covered elsewhere are not repeated here: bad --spp, --sampler, --estimator,
estimator/sampler mismatches, non-square stratified spp, --res, --seed, --max-depth and a
missing output directory (tests/test_render_cli.py), each scene error's wording
(tests/test_scene.py), the runtime's errors in process (tests/test_runtime.py) and
determinism across tilings in process (tests/test_render_pipeline.py).
"""

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from scene_texts import MINIMAL_SCENE

from clrender import api, cli
from clrender.imageio import read_exr

SCENE = MINIMAL_SCENE

BOX = """
[[shapes]]
name = "crate"
type = "box"
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 1.0]
rotate_y = 30.0
translate = [0.0, 0.0, 5.5]
material = "white"
"""

FAST = ["--res", "4", "--spp", "1", "--sampler", "independent", "--max-depth", "1"]


def run_cli(capsys, *argv):
    """(exit status, stdout, stderr) of an in-process run."""
    try:
        status = cli.main(list(argv))
    except SystemExit as exit_:
        status = exit_.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def run_child(*argv, env=None, cwd=None):
    """A `python -m clrender` subprocess, environment changes applied."""
    environment = {**os.environ, **(env or {})}
    environment = {k: v for k, v in environment.items() if v is not None}
    return subprocess.run(
        [sys.executable, "-m", "clrender", *argv],
        capture_output=True,
        text=True,
        env=environment,
        cwd=cwd,
    )


def assert_one_line_error(status, err, *fragments):
    assert status == 2, err
    assert err.startswith("clrender: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in err, err


def write_scene(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# --- scene files -------------------------------------------------------------------------

SCENE_ERRORS = [
    # (replace this, with this, message fragments)
    ("fov = 40.0", "fov = = 40.0", ["TOML syntax error", "line 5"]),
    ("fov = 40.0\n", "", ["[camera], field 'fov': missing (required)"]),
    ("radius = 1.0", "radius = 1.0\nradious = 2.0", ["'radious'", "did you mean 'radius'"]),
    ("radius = 1.0", 'radius = "big"', ["shapes[1] ('ball'), field 'radius'", "a string"]),
    ('type = "sphere"', 'type = "cone"', ["unknown shape type 'cone'", "quad, box, sphere"]),
    ('type = "diffuse"', 'type = "glass"', ["unknown material type 'glass'", "dielectric"]),
    (
        "radius = 1.0",
        "radius = 1.0\nemission = [1.0, -1.0, 1.0]",
        ["'ball'), field 'emission'", "expected"],
    ),
    (
        "emission = [1.0, 1.0, 1.0]",
        'emitter = { type = "area", radiance = [1.0, 1.0, 1.0] }',
        ["shapes[0] ('lamp'), field 'emitter'", "no emitter types", "`emission = [r, g, b]`"],
    ),
    (
        "[materials.white]",
        '[[emitters]]\ntype = "area"\n\n[materials.white]',
        [
            "top level, field 'emitters'",
            "an emitter is a [[shapes]] quad, sphere or mesh with an `emission`",
        ],
    ),
    ("radius = 1.0", "radius = -0.5", ["field 'radius'", "> 0, got -0.5"]),
    ("radius = 1.0", "radius = nan", ["field 'radius'", "finite", "nan"]),
    ("radius = 1.0", "radius = inf", ["field 'radius'", "finite", "inf"]),
    ("edge2 = [0.0, 2.0, 0.0]", "edge2 = [-inf, 2.0, 0.0]", ["'edge2'", "non-finite"]),
    (
        "edge2 = [0.0, 2.0, 0.0]",
        "edge2 = [3.0, 0.0, 0.0]",
        ["shapes[0] ('lamp')", "degenerate quad"],
    ),
    (
        'type = "sphere"\ncenter = [0.0, 0.0, -2.0]\nradius = 1.0',
        'type = "box"\nmin = [0.0, 0.0, 0.0]\nmax = [1.0, -1.0, 1.0]',
        [
            "shapes[1] ('ball'), field 'max'",
            "max > min on every axis",
            "got min [0.0, 0.0, 0.0], max [1.0, -1.0, 1.0]",
        ],
    ),
    (  # the lamp without its light: it needs a material, and the message says why
        "emission = [1.0, 1.0, 1.0]",
        "emission = [0.0, 0.0, 0.0]",
        ["shapes[0] ('lamp'), field 'material'", "unless it emits", "[0, 0, 0] emits nothing"],
    ),
    (  # before: a numpy overflow warning, then "degenerate quad"
        "edge2 = [0.0, 2.0, 0.0]",
        "edge2 = [0.0, 1e308, 0.0]",
        ["shapes[0] ('lamp'), field 'edge2'", "too large for the device's float32"],
    ),
]
SCENE_ERROR_IDS = [
    "toml-syntax",
    "missing-field",
    "misspelt-field",
    "wrong-type",
    "unknown-shape",
    "unknown-material",
    "emitter-on-sphere",
    "emitter-type",
    "emitters-table",
    "negative-radius",
    "nan-radius",
    "inf-radius",
    "inf-vector",
    "degenerate-quad",
    "negative-box-size",
    "dark-emitter-without-material",
    "overflowing-edge",
]


@pytest.mark.parametrize(("old", "new", "fragments"), SCENE_ERRORS, ids=SCENE_ERROR_IDS)
def test_scene_errors_are_one_line_naming_the_file(capsys, tmp_path, old, new, fragments):
    assert old in SCENE
    path = write_scene(tmp_path, SCENE.replace(old, new, 1))
    status, _, err = run_cli(capsys, "render", str(path), *FAST, "-o", str(tmp_path / "o.exr"))
    assert_one_line_error(status, err, f"{path}: ", *fragments)
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize(
    "text, message",
    [
        (
            SCENE.replace("emission = [1.0, 1.0, 1.0]", 'material = "white"'),
            "the scene has no emitter (no shape with emission): it renders black",
        ),
        (
            SCENE.replace("radius = 1.0", "radius = 8.0"),
            "[camera] look_from [0.0, 0.0, 5.0] is inside shapes[1] ('ball') (a sphere)",
        ),
        (SCENE + BOX, "[camera] look_from [0.0, 0.0, 5.0] is inside shapes[2] ('crate') (a box)"),
        (
            SCENE.replace("radius = 1.0", "radius = 7.0"),
            "[camera] look_from [0.0, 0.0, 5.0] lies on shapes[1] ('ball'): camera rays start",
        ),
        (
            SCENE.replace("radius = 1.0", "radius = 1e-17"),
            "shapes[1] ('ball'): its radius 1e-17 spans under 16 float32 steps",
        ),
    ],
    ids=["no-emitter", "camera-in-sphere", "camera-in-rotated-box", "camera-on-sphere", "tiny"],
)
def test_scene_warnings_print_once_and_exit_0(capsys, tmp_path, text, message):
    path = write_scene(tmp_path, text)
    out = tmp_path / "o.exr"
    status, stdout, err = run_cli(capsys, "render", str(path), *FAST, "-o", str(out))
    assert status == 0, err
    assert err.startswith(f"clrender: warning: {path}: {message}"), err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert out.exists() and "wrote" in stdout


# --- output paths ------------------------------------------------------------------------


def no_device(*args, **kwargs):
    raise AssertionError("a runtime was created before the output path was checked")


def test_read_only_output_directory_fails_before_rendering(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(api, "runtime_for", no_device)
    directory = tmp_path / "read-only"
    directory.mkdir()
    directory.chmod(0o555)
    if os.geteuid() == 0:  # root writes into a 0555 directory: use one nobody can write
        directory = Path("/sys")
    target = directory / "out.exr"
    try:
        status, _, err = run_cli(capsys, "render", "analytic", "-o", str(target))
    finally:
        (tmp_path / "read-only").chmod(0o755)
    assert_one_line_error(status, err)
    assert err == f"clrender: error: cannot write {target}: directory {directory} is not writable\n"
    assert not target.exists()


def test_output_path_that_is_a_directory_fails_before_rendering(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(api, "runtime_for", no_device)
    target = tmp_path / "image.exr"
    target.mkdir()
    status, _, err = run_cli(capsys, "render", "analytic", "-o", str(target))
    assert_one_line_error(status, err, f"cannot write {target}: it is a directory")


# --- OpenCL: no device, a kernel that does not build -----------------------------------


@pytest.mark.parametrize("command", [["render", "analytic", "--res", "4"], []])
def test_no_opencl_platform_says_what_to_install(tmp_path, command):
    # Both ICD loaders (ocl-icd, bundled in the pyopencl wheel, and Khronos') read the vendor
    # files of OCL_ICD_VENDORS; a folder that does not exist leaves them no platform at all.
    missing = tmp_path / "no-vendors"
    env = {"OCL_ICD_VENDORS": str(missing), "PYOPENCL_CTX": None}
    child = run_child(*command, env=env, cwd=tmp_path)
    assert_one_line_error(
        child.returncode,
        child.stderr,
        "no OpenCL platform found: install",
        'pip install "pyopencl[pocl]"',
        "pocl-opencl-icd",
    )
    assert child.stdout == ""
    assert list(tmp_path.iterdir()) == []


def test_pyopencl_ctx_naming_a_missing_platform(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("PYOPENCL_CTX", "no-such-platform")
    status, _, err = run_cli(capsys, "render", "analytic", "-o", str(tmp_path / "o.exr"))
    assert_one_line_error(
        status, err, "PYOPENCL_CTX platform 'no-such-platform' matches nothing; accepted: 0: "
    )


BROKEN_KERNEL = """// sampling.cl with an error on line 3
__kernel void fill_traced(__global float *out) {
    out[0] = undefined_symbol;
}
"""


@pytest.mark.device
def test_kernel_build_failure_shows_the_compiler_log_without_traceback(tmp_path):
    kernels = tmp_path / "kernels"
    kernels.mkdir()
    (kernels / "sampling.cl").write_text(BROKEN_KERNEL)
    out = tmp_path / "o.exr"
    env = {"CLRENDER_KERNELS_DIR": str(kernels)}
    argv = ["render", "analytic", "--res", "4", "-o", str(out)]
    with ThreadPoolExecutor(max_workers=2) as pool:  # without and with --debug, at once
        child, debug = pool.map(lambda first: run_child(*first, *argv, env=env), [[], ["--debug"]])
    assert child.returncode == 2, child.stderr
    # The compiler itself may print a line or two ("1 error generated.") before ours; our
    # message is the rest of stderr and may span lines: it carries the compiler log.
    err = child.stderr
    assert "Traceback" not in err
    message = err[err.index("clrender: error: ") :]
    assert message.startswith(f"clrender: error: OpenCL build of {kernels / 'sampling.cl'} failed")
    assert f"{kernels / 'sampling.cl'}:3:" in message and "undefined_symbol" in message
    assert not out.exists()
    assert debug.returncode != 0 and "Traceback" in debug.stderr
    assert "KernelBuildError" in debug.stderr


@pytest.mark.device
def test_kernels_dir_override_must_be_a_directory(tmp_path):
    env = {"CLRENDER_KERNELS_DIR": str(tmp_path / "nowhere")}
    child = run_child("render", "analytic", "--res", "4", "-o", str(tmp_path / "o.exr"), env=env)
    message = f"CLRENDER_KERNELS_DIR={tmp_path / 'nowhere'} is not a directory"
    assert_one_line_error(child.returncode, child.stderr, message)


# --- determinism -------------------------------------------------------------------------


@pytest.mark.device
def test_two_runs_give_byte_identical_pixels_whatever_the_tile_size(tmp_path):
    """Path-traced Cornell box, separate processes: pixels equal bit for bit across runs and
    tilings (with and without overlap); the render time in the metadata differs."""
    common = ["render", "cornell-box", "--res", "16", "--spp", "9", "--seed", "11"]
    runs = {
        "a": [],
        "b": ["--tile-samples", "500", "--no-overlap"],
        "c": ["--tile-samples", "37"],
        "other-seed": ["--seed", "12"],
    }

    def render(name: str) -> tuple:
        out = tmp_path / f"{name}.exr"
        child = run_child(*common, *runs[name], "-o", str(out))
        assert child.returncode == 0, child.stderr
        return read_exr(out)

    with ThreadPoolExecutor(max_workers=2) as pool:  # two processes at a time
        images = dict(zip(runs, pool.map(render, runs), strict=True))
    reference, meta = images["a"]
    assert reference.std() > 0  # a lit image, not all black
    for name in ("b", "c"):
        pixels, other_meta = images[name]
        assert pixels.tobytes() == reference.tobytes(), name
        assert other_meta["seed"] == meta["seed"] == 11
    assert images["other-seed"][0].tobytes() != reference.tobytes()


# --- memory ------------------------------------------------------------------------------

PEAK_SCRIPT = """
import sys
from clrender import cli
status = cli.main(sys.argv[1:])
peak_kb = next(line for line in open("/proc/self/status") if line.startswith("VmHWM"))
print("peak_kb", int(peak_kb.split()[1]), file=sys.stderr)
sys.exit(status)
"""
# Measured here (pip PoCL 3.0 and Debian PoCL 3.1 CPU, 2 cores, warm kernel cache),
# 4096-sample tiles: 196 MB for a 16 x 16 render, the baseline (Python, NumPy, every registered
# OpenCL platform's libraries, whichever device renders: 87 MB more with Intel's CPU runtime
# registered; and the program builds), 232 MB at 512^2 and 336 MB at 1024^2 with the per-pixel
# layers and the error against the exact pixel integrals: 140 MB above the baseline at 1024^2.
RENDER_BOUND_MB = 200
# Per pixel: the film's float32 RGB and two flags (14 B), the layers (samples, redraws, RGB
# variance: 20 B), the EXR's channels as the bindings copy them to write and read them back
# (2 x 36 B) and the flags as a uint32 channel (4 B), the PNG rows and their compressed copy
# (about 7 B), the exact pixel integrals (float64 RGB, 24 B): 144 B per pixel is the allowance.
BYTES_PER_PIXEL = 144
SLACK_MB = 16  # allocator and thread-arena noise between two processes


def peak_rss_mb(tmp_path: Path, width: int, tile_samples: int) -> float:
    """Peak resident memory (VmHWM) of one render of analytic:edge, measured in the child."""
    out = tmp_path / f"peak-{width}.exr"
    argv = [
        "render",
        "analytic:edge",
        "--res",
        str(width),
        "--spp",
        "4",
        "--sampler",
        "independent",
        "--tile-samples",
        str(tile_samples),
        "-o",
        str(out),
    ]
    child = subprocess.run(
        [sys.executable, "-c", PEAK_SCRIPT, *argv], capture_output=True, text=True
    )
    assert child.returncode == 0, child.stderr
    line = next(x for x in child.stderr.splitlines() if x.startswith("peak_kb"))
    return int(line.split()[1]) / 1024


@pytest.mark.device
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_peak_memory_is_bounded_by_the_tile_not_the_image(tmp_path):
    tile_samples = 4096
    small = peak_rss_mb(tmp_path, 512, tile_samples)  # builds the kernels if the cache is cold
    with ThreadPoolExecutor(max_workers=2) as pool:  # then two processes at a time
        large, baseline = pool.map(peak_rss_mb, [tmp_path] * 2, [1024, 16], [tile_samples] * 2)
    extra_pixels = 1024 * 1024 - 512 * 512
    allowance = extra_pixels * BYTES_PER_PIXEL / 2**20 + SLACK_MB
    assert large - baseline < RENDER_BOUND_MB, (baseline, small, large)
    assert large - small < allowance, (small, large, allowance)


# --- files that are not what a scene or an output must be: one line, before any device ---------


def deeply_nested(depth: int) -> bytes:
    return ("a = " + "[" * depth + "]" * depth + "\n").encode()


@pytest.mark.parametrize(
    "content, fragment",
    [
        ("a = 1\n".encode("utf-16"), "not UTF-8 text (byte 0xff at offset 0)"),
        (bytes(range(128, 256)), "not UTF-8 text (byte 0x80 at offset 0)"),
        (deeply_nested(3000), "arrays or tables nested too deeply"),
    ],
)
def test_unreadable_scene_files_are_one_line(capsys, tmp_path, monkeypatch, content, fragment):
    monkeypatch.setattr(api, "runtime_for", no_device)
    scene = tmp_path / "bad.toml"
    scene.write_bytes(content)
    status, _, err = run_cli(capsys, "render", str(scene), *FAST, "-o", str(tmp_path / "o"))
    assert_one_line_error(status, err, f"{scene}: {fragment}")


def test_a_scene_argument_that_is_no_regular_file(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(api, "runtime_for", no_device)
    os.mkfifo(tmp_path / "pipe.toml")
    (tmp_path / "folder.toml").mkdir()
    out = str(tmp_path / "o")
    for name, what in [("pipe.toml", "not a regular file"), ("folder.toml", "is a directory")]:
        status, _, err = run_cli(capsys, "render", str(tmp_path / name), *FAST, "-o", out)
        assert_one_line_error(status, err, what)
    status, _, err = run_cli(capsys, "render", "x" * 300 + ".toml", *FAST, "-o", out)
    assert_one_line_error(status, err, "name too long")


@pytest.mark.parametrize(
    "output, fragment",
    [
        ("", "-o/--output is empty"),
        ("d/.exr", "has no file name before .exr"),
        ("/dev/null", "is not a file name (a directory or device)"),
        ("y" * 300 + ".exr", "over 255 bytes"),
        ("/".join(["z" * 200] * 25) + "/o.exr", "the path is over 4096 bytes in all"),
    ],
)
def test_output_names_that_cannot_be_written_are_one_line(
    capsys, tmp_path, monkeypatch, output, fragment
):
    monkeypatch.setattr(api, "runtime_for", no_device)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "d").mkdir()
    status, _, err = run_cli(capsys, "render", "analytic", *FAST[:-2], "-o", output)
    assert_one_line_error(status, err, fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"] and not list(
        (tmp_path / "d").iterdir()
    )


def test_a_resolution_beyond_the_machine_is_refused_before_any_device(capsys, monkeypatch):
    monkeypatch.setattr(api, "runtime_for", no_device)
    status, _, err = run_cli(capsys, "render", "analytic", "--res", "65536x65536")
    assert_one_line_error(status, err, "a 65536x65536 image needs about 468.0 GiB")


def test_a_pixel_whose_samples_cannot_fit_is_refused_before_any_device(
    capsys, tmp_path, monkeypatch
):
    import clrender.pipeline as pipeline

    monkeypatch.setattr(api, "runtime_for", no_device)
    monkeypatch.setattr(pipeline, "physical_memory", lambda: 2**30)
    # 60 M samples of one pixel at >= 20 B each: 1.1 GiB, over the 1 GiB given
    argv = ["render", "analytic", "--res", "1x1", "--sampler", "independent"]
    status, _, err = run_cli(capsys, *argv, "--spp", "60000000")
    assert_one_line_error(
        status, err, "a tile of 60,000,000 samples", "at least 1.1 GiB", "this machine's 1.0 GiB"
    )
    # 50 M fit (0.93 GiB): refused later only for the missing device, not for memory
    with pytest.raises(AssertionError, match="runtime was created"):
        cli.main([*argv, "--spp", "50000000", "-o", str(tmp_path / "o.exr")])


def test_tile_memory_counts_the_pixels_of_a_tile_and_their_auxiliary_nuclei():
    from clrender.errors import ParameterError
    from clrender.pipeline import (
        MIN_BYTES_PER_TILE_SAMPLE,
        RenderSettings,
        check_tile_memory,
        pixels_per_tile,
    )
    from clrender.sampling import make_sampler

    settings = RenderSettings(64, 64, make_sampler("sppp", 256), "vor_sn", tile_samples=10**5)
    per_pixel = 256 + settings.sampler.n_aux
    assert settings.sampler.n_aux > 0
    need = pixels_per_tile(settings) * per_pixel * MIN_BYTES_PER_TILE_SAMPLE
    check_tile_memory(settings, memory=need)
    with pytest.raises(ParameterError, match=f"{per_pixel:,} a pixel"):
        check_tile_memory(settings, memory=need - 1)
    # A 1x1 image: its tile is the one pixel, not the 256 pixels of a minimum tile
    one = RenderSettings(1, 1, make_sampler("independent", 1000), "mc")
    check_tile_memory(one, memory=1000 * MIN_BYTES_PER_TILE_SAMPLE)


def test_running_out_of_host_memory_is_one_line(capsys, monkeypatch):
    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 3.20 GiB for an array")

    monkeypatch.setattr(api, "runtime_for", exhausted)
    status, _, err = run_cli(capsys, "render", "analytic", *FAST[:-2], "-o", "unused.exr")
    assert_one_line_error(status, err, "out of host memory (Unable to allocate 3.20 GiB")


# --- the Python API checks its arguments with the same one-line messages -----------------------


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"width": -1}, "width must be a positive integer, got -1"),
        ({"height": "8"}, "height must be a positive integer, got '8'"),
        ({"sampler": "sobol"}, "sampler must be a SamplerConfig"),
        ({"estimator": "vornoi"}, "unknown estimator 'vornoi'"),
        ({"seed": -1}, "seed must be an integer in [0, 2^32), got -1"),
        ({"tile_samples": 0}, "tile_samples must be a positive integer, got 0"),
    ],
)
def test_render_settings_refuse_bad_values(change, fragment):
    from clrender.errors import ParameterError
    from clrender.pipeline import RenderSettings
    from clrender.sampling import make_sampler

    arguments = {"width": 8, "height": 8, "sampler": make_sampler("independent", 4)}
    arguments.update({"estimator": "mc", **change})
    with pytest.raises(ParameterError) as raised:
        RenderSettings(**arguments)
    assert fragment in str(raised.value) and "\n" not in str(raised.value)


def test_api_loaders_refuse_what_they_cannot_use():
    import clrender
    from clrender.sampling import make_sampler

    with pytest.raises(clrender.ParameterError, match="takes a scene name or a path"):
        clrender.load_scene(None)
    with pytest.raises(clrender.ClrenderError, match=r"no scene given \(an empty name\)"):
        clrender.load_scene("")  # before: "scene file '' is a directory"
    for scene in (None, 42):  # before: AttributeError: ... has no attribute 'quads'
        with pytest.raises(clrender.ParameterError, match="render takes a Scene"):
            clrender.render(scene, spp=1, sampler="independent", resolution=4)
    with pytest.raises(clrender.ParameterError, match=r"must be in \(0, 4\], got 1000000.0"):
        make_sampler("sppp", 16, eps=1e6)
