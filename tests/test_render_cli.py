"""`python -m clrender render`: outputs and metadata, one-line errors and exit codes, Ctrl-C."""

import fcntl
import functools
import io
import os
import pty
import signal
import struct
import subprocess
import sys
import termios
from pathlib import Path

import numpy as np
import pytest

from clrender import api, cli, interrupts
from clrender.errors import ParameterError
from clrender.estimators import ESTIMATORS
from clrender.film import Film
from clrender.imageio import read_exr, read_png, srgb8
from clrender.pipeline import RenderResult, RenderStats
from clrender.sampling import make_sampler

ROOT = Path(__file__).resolve().parents[1]  # a child run here imports this tree's clrender


def run_cli(capsys, *argv):
    """(exit status, stdout, stderr) of an in-process run."""
    try:
        status = cli.main(list(argv))
    except SystemExit as exit_:  # argparse's own errors
        status = exit_.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_analytic_render_writes_exr_with_metadata_and_matching_png(capsys, tmp_path):
    out = tmp_path / "mix.exr"
    status, stdout, _ = run_cli(
        capsys,
        "render",
        "analytic:mix",
        "--res",
        "24x16",
        "--spp",
        "16",
        "--seed",
        "7",
        "-o",
        str(out),
    )
    assert status == 0
    assert "done: 384/384 pixels" in stdout and "host estimators" in stdout
    pixels, meta = read_exr(out)
    assert pixels.shape == (16, 24, 3) and np.isfinite(pixels).all() and pixels.min() > 0
    assert meta["scene"] == "analytic:mix" and meta["spp"] == 16 and meta["seed"] == 7
    assert (meta["sampler"], meta["estimator"]) == ("sppp", "vor_sn")
    assert meta["partial"] == 0 and meta["rendered_pixels"] == 384
    assert meta["nonfinite_samples"] == 0 and meta["flagged_pixels"] == 0
    assert meta["render_time_s"] > 0 and "device" in meta
    png = read_png(out.with_suffix(".png"))
    assert np.array_equal(png, srgb8(pixels))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mix.exr", "mix.png"]


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_default_output_name_is_the_scene_name_in_the_current_directory(
    capsys, tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    status, _, _ = run_cli(capsys, "render", "analytic:edge", "--res", "8", "--spp", "4")
    assert status == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["analytic-edge.exr", "analytic-edge.png"]


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize("estimator", list(ESTIMATORS))
def test_every_estimator_renders_over_sppp(capsys, tmp_path, estimator):
    out = tmp_path / "e.exr"
    status, _, err = run_cli(
        capsys,
        "render",
        "analytic",
        "--res",
        "8",
        "--spp",
        "9",
        "--estimator",
        estimator,
        "-o",
        str(out),
    )
    assert status == 0, err
    assert read_exr(out)[1]["estimator"] == estimator


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize("sampler", ["independent", "stratified"])
def test_mc_over_uniform_and_stratified_samples(capsys, tmp_path, sampler):
    out = tmp_path / "s.exr"
    status, _, _ = run_cli(
        capsys,
        "render",
        "analytic",
        "--res",
        "8",
        "--spp",
        "9",
        "--sampler",
        sampler,
        "-o",
        str(out),
    )
    assert status == 0
    assert (read_exr(out)[1]["sampler"], read_exr(out)[1]["estimator"]) == (sampler, "mc")


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--spp", "0"], "--spp must be a positive integer, got 0"),
        (["--spp", "-3"], "--spp must be a positive integer"),
        (["--sampler", "halton"], "unknown sampler 'halton'; accepted: independent, stratified"),
        (["--sampler", "uniform"], "the 'uniform' sampler is now called 'independent'"),
        (["--sampler", "zsobol", "--spp", "12"], "power of two"),
        (["--estimator", "median"], "unknown estimator 'median'; accepted: mc, mc_n, vor"),
        (
            ["--sampler", "independent", "--estimator", "vor"],
            "estimator 'vor' needs the auxiliary nuclei of an SPPP sampler, and the 'independent' "
            "sampler draws none: use --sampler sppp or sppp-sobol",
        ),
        (["--sampler", "stratified", "--estimator", "fvor"], "'fvor' needs the auxiliary"),
        (["--sampler", "stratified", "--spp", "10"], "perfect square"),
        (["--res", "0x4"], "--res must be WxH"),
        (["--res", "wide"], "--res must be WxH"),
        (["--seed", "-1"], "seed must be an integer in [0, 2^32)"),
        (["--tile-samples", "0"], "--tile-samples must be a positive integer"),
        (["--max-depth", "-2"], "--max-depth must be an integer in [0, 1024]"),
        (["--max-depth", "1025"], "--max-depth must be an integer in [0, 1024], got 1025"),
        (["analytic", "--max-depth", "3"], "--max-depth needs a path-traced scene: analytic is"),
        (["analytic:plaid"], "unknown analytic scene 'analytic:plaid'; accepted:"),
        (["no-such-scene"], "no shipped scene of that name"),
        (["-o", "picture.png"], "-o/--output must name an .exr file"),
        (["--spp", "many"], "argument --spp: invalid int value: 'many'"),
        (["--frobnicate"], "unrecognized arguments: --frobnicate"),
    ],
)
def test_bad_arguments_give_one_line_errors_and_status_2(capsys, tmp_path, argv, message):
    status, _, err = run_cli(capsys, "render", *argv)
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("clrender: error: ")
    assert message in err
    assert "Traceback" not in err


def test_output_under_a_file_fails_before_any_device_work(capsys, tmp_path, monkeypatch):
    def no_device(*args, **kwargs):
        raise AssertionError("a runtime was created before the output path was checked")

    monkeypatch.setattr(api, "runtime_for", no_device)
    (tmp_path / "notes.txt").write_text("x")
    target = tmp_path / "notes.txt" / "deeper" / "out.exr"
    status, _, err = run_cli(capsys, "render", "-o", str(target))
    assert status == 2
    assert (
        err
        == f"clrender: error: cannot write {target}: {tmp_path / 'notes.txt'} is not a directory\n"
    )


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
def test_missing_output_folders_are_created(capsys, tmp_path):
    """The README's `-o out/cbox.exr` on a fresh clone: before, 'directory out does not exist'."""
    target = tmp_path / "out" / "deeper" / "cbox.exr"
    status, out, err = run_cli(
        capsys, "render", "analytic:edge", "--res", "4", "--spp", "8", "-o", str(target)
    )
    assert status == 0, err
    assert target.is_file() and target.with_suffix(".png").is_file()
    assert read_exr(target)[0].shape == (4, 4, 3)


@pytest.mark.parametrize("argv", [["--debug", "render"], ["render", "--debug"]])
def test_debug_shows_the_traceback(argv):
    with pytest.raises(ParameterError, match="--spp must be a positive integer"):
        cli.main([*argv, "--spp", "0"])


def fake_result(
    nonfinite: int, flagged: int, interrupted: bool = False, pixels: int | None = None
) -> RenderResult:
    """A 4 x 2 render's result; an interrupted one holds 5 pixels unless `pixels` says."""
    film = Film(4, 2)
    done = (5 if interrupted else 8) if pixels is None else pixels
    film.record(np.arange(done), np.ones((done, 3)), np.arange(done) < flagged)
    stats = RenderStats(nonfinite_samples=nonfinite, interrupted=interrupted)
    settings = cli.settings_from_args(cli.build_parser().parse_args(["render"]), 4, 2)
    assert settings.sampler == make_sampler("sppp", 64)
    return RenderResult(film, stats, settings)


@pytest.mark.parametrize(
    "strict, nonfinite, flagged, interrupted, status",
    [
        (False, 0, 0, False, 0),
        (False, 5, 2, False, 0),
        (True, 5, 2, False, 3),
        (True, 0, 0, False, 0),
        (True, 5, 2, True, 130),
    ],
)
def test_exit_status(capsys, strict, nonfinite, flagged, interrupted, status):
    args = cli.build_parser().parse_args(["render"] + (["--strict"] if strict else []))
    result = fake_result(nonfinite, flagged, interrupted)
    assert cli.exit_status(args, result, held_signals=[]) == status
    err = capsys.readouterr().err
    if nonfinite and not interrupted:
        assert "5 samples had NaN or infinite radiance; 2 pixels flagged" in err


def test_a_signal_held_while_writing_gives_its_own_status(capsys, monkeypatch):
    args = cli.build_parser().parse_args(["render"])
    held = [int(signal.SIGTERM)]
    assert cli.exit_status(args, fake_result(0, 0, False), held_signals=held) == 143
    # The render was complete: so are its images (not "partial")
    assert "after the last pixel: the images are complete" in capsys.readouterr().err
    # An interrupted render: the status is the interrupting signal's (Python's own Ctrl-C
    # here, none recorded), not the later one's
    monkeypatch.setattr(interrupts, "_received", [])
    assert cli.exit_status(args, fake_result(0, 0, True), held_signals=held) == 130
    assert "interrupted: the image holds" in capsys.readouterr().err
    monkeypatch.setattr(interrupts, "_received", [int(signal.SIGHUP), int(signal.SIGTERM)])
    assert cli.exit_status(args, fake_result(0, 0, True), held_signals=held) == 129


def test_an_interrupt_after_the_last_pixel_leaves_complete_images(capsys, monkeypatch):
    # The signal came between the last tile's recording and the end of the render: the
    # images are whole, and said to be; the status is still the signal's
    args = cli.build_parser().parse_args(["render"])
    monkeypatch.setattr(interrupts, "_received", [int(signal.SIGTERM)])
    assert cli.exit_status(args, fake_result(0, 0, True, pixels=8), held_signals=[]) == 143
    err = capsys.readouterr().err
    assert err == "clrender: interrupted (SIGTERM) after the last pixel: the images are complete\n"
    assert cli.exit_status(args, fake_result(0, 0, True, pixels=7), held_signals=[]) == 143
    assert "the image holds 7 of 8 pixels (partial=1)" in capsys.readouterr().err


def read_until(fd: int, marker: bytes) -> bytes:
    """Read a pty until `marker` shows up or the writer is gone."""
    seen = b""
    while marker not in seen:
        try:
            chunk = os.read(fd, 4096)
        except OSError:  # EIO: the child closed its side
            break
        if not chunk:
            break
        seen += chunk
    return seen


def default_signals() -> None:
    """In a child: the default action of Ctrl-C, SIGTERM and SIGHUP, as at a terminal. A test
    run started in the background (`pytest &`) ignores SIGINT, under `nohup` SIGHUP, and a
    child inherits that: it would render on through the test's signal."""
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)


def ignored_sighup() -> None:
    """In a child: SIGHUP ignored, as `nohup` starts a command."""
    default_signals()
    signal.signal(signal.SIGHUP, signal.SIG_IGN)


def slow_render_on_a_terminal(tmp_path, preexec) -> tuple[subprocess.Popen, int]:
    """A ~10 s render with stderr on an 80-column pseudo-terminal (tqdm draws nothing on a
    terminal 0 wide, as a new one is): the child and the terminal's controlling side."""
    controller, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    command = [sys.executable, "-m", "clrender", "render", "analytic", "--res", "256"]
    command += ["--spp", "64", "-o", str(tmp_path / "slow.exr")]
    child = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=terminal, cwd=tmp_path, preexec_fn=preexec
    )
    os.close(terminal)
    return child, controller


@pytest.mark.device
@pytest.mark.parametrize(
    "signum, status",
    [(signal.SIGINT, 130), (signal.SIGTERM, 128 + 15), (signal.SIGHUP, 128 + 1)],
)
def test_an_ending_signal_writes_the_partial_image_and_exits_128_plus_it(tmp_path, signum, status):
    # Ctrl-C, a job scheduler's SIGTERM, a closed terminal's SIGHUP: the same partial image.
    # stderr on a pseudo-terminal, so the progress bar draws: its first line with a percentage
    # says a tile is done, which is when the signal is sent (no timing guesses).
    out = tmp_path / "slow.exr"
    child, controller = slow_render_on_a_terminal(tmp_path, default_signals)
    try:
        progress = read_until(controller, b"%|")
        assert b"/65536 [" in progress, progress
        child.send_signal(signum)
        messages = read_until(controller, b"(partial=1)")
        stdout, _ = child.communicate()
    finally:
        os.close(controller)
        if child.poll() is None:
            child.kill()
    assert child.returncode == status, messages
    assert b"interrupted" in messages and b"interrupted:" in stdout
    pixels, meta = read_exr(out)
    total = 256 * 256
    assert meta["partial"] == 1 and 0 < meta["rendered_pixels"] < total
    # Every channel of the analytic image is positive: rendered pixels are exactly the nonzero.
    assert np.count_nonzero(pixels.max(axis=2)) == meta["rendered_pixels"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["slow.exr", "slow.png"]


@pytest.mark.device
def test_under_nohup_a_closed_terminal_does_not_end_the_render(tmp_path):
    """SIGHUP ignored at start (nohup) stays ignored: the render finishes whole (before: the
    SIGHUP handler replaced nohup's and ended it with a partial image)."""
    child, controller = slow_render_on_a_terminal(tmp_path, ignored_sighup)
    try:
        assert b"/65536 [" in read_until(controller, b"%|")
        child.send_signal(signal.SIGHUP)
        stdout, _ = child.communicate()
    finally:
        os.close(controller)
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, stdout
    assert read_exr(tmp_path / "slow.exr")[1]["partial"] == 0


# The signal arrives while the command still imports its libraries (the moment is made
# exact by sending it from an import): one line, no traceback. From the import of datetime,
# which NumPy's C initialisation makes: before the signals were blocked there, the interrupt
# inside it became "ImportError: PyCapsule_Import could not import module datetime".
INTERRUPT_WHILE_IMPORTING = """
import builtins, os, signal, sys
real_import = builtins.__import__
def interrupting_import(name, *args, **kwargs):
    if name == "{module}" and not sent:
        sent.append(1)
        os.kill(os.getpid(), signal.{signal})
    return real_import(name, *args, **kwargs)
sent = []
builtins.__import__ = interrupting_import
sys.argv = ["clrender", "render", "analytic", "--res", "8", "-o", "never.exr"]
from clrender.__main__ import run
sys.exit(run(exiting=True))
"""


@pytest.mark.parametrize("module", ["clrender.cli", "datetime"])
@pytest.mark.parametrize("name, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_an_interrupt_while_loading_is_one_line(tmp_path, name, status, module):
    child = subprocess.run(
        [sys.executable, "-c", INTERRUPT_WHILE_IMPORTING.format(signal=name, module=module)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        preexec_fn=default_signals,
    )
    assert child.returncode == status, child.stderr
    assert child.stderr == f"clrender: interrupted ({name})\n"
    assert list(tmp_path.iterdir()) == []


# The signal arrives while an OpenCL program builds (the build finishes first: a signal inside
# the compiler's system calls failed it, "1 error generated."), or once rendering has begun but
# before any pixel is finished: one line, and with no pixel to save nothing is written, so the
# previous image stays (before: an all-black partial image replaced it).
INTERRUPT_AT = """
import os, signal, sys
import pyopencl as cl
import clrender.pipeline
def interrupting(real):
    def call(*args, **kwargs):
        if not sent:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGTERM)
        return real(*args, **kwargs)
    return call
sent = []
{patch}
sys.argv = ["clrender", "render", "cornell-box", "--res", "8", "--spp", "8", "-o", "old.exr"]
from clrender.__main__ import run
sys.exit(run(exiting=True))
"""
PATCHES = {
    "building": "cl.Program.build = interrupting(cl.Program.build)",
    "first-tile": "clrender.pipeline.tile_pixels = interrupting(clrender.pipeline.tile_pixels)",
}


@pytest.mark.device
@pytest.mark.parametrize("moment", list(PATCHES))
def test_an_interrupt_before_any_pixel_keeps_the_previous_image(tmp_path, moment):
    (tmp_path / "old.exr").write_bytes(b"a previous image")
    child = subprocess.run(
        [sys.executable, "-c", INTERRUPT_AT.format(patch=PATCHES[moment])],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert child.returncode == 143, child.stderr
    assert child.stderr.count("\n") == 1 and "Traceback" not in child.stderr, child.stderr
    assert child.stderr.startswith("clrender: interrupted (SIGTERM)"), child.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.exr"]
    assert (tmp_path / "old.exr").read_bytes() == b"a previous image"


def run_child(tmp_path, script: str) -> subprocess.CompletedProcess:
    """A Python script in a child with the signals' default actions, as at a terminal."""
    return subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        preexec_fn=default_signals,
    )


def render_at(tmp_path, patch: str) -> subprocess.CompletedProcess:
    return run_child(tmp_path, INTERRUPT_AT.format(patch=patch))


# The moments after the render's last pixel where a signal is sent (the first call of a
# function met there): the estimator thread still joined as the render's thread pool closes,
# the result built, the progress bar closed, the images written (the errors against a
# reference computed), the summary printed
AFTER_THE_LAST_PIXEL = {
    "pool-closing": "class Pool(clrender.pipeline.ThreadPoolExecutor):\n"
    "    __exit__ = interrupting(clrender.pipeline.ThreadPoolExecutor.__exit__)\n"
    "clrender.pipeline.ThreadPoolExecutor = Pool",
    "result": "clrender.pipeline.RenderResult = interrupting(clrender.pipeline.RenderResult)",
    "progress-bar": "import clrender.progress\nclrender.progress.ProgressBar.close = "
    "interrupting(clrender.progress.ProgressBar.close)",
    "writing": "import clrender.cli\n"
    "clrender.cli.reference_errors = interrupting(clrender.cli.reference_errors)",
    "summary": "import clrender.report\n"
    "clrender.report.summary_lines = interrupting(clrender.report.summary_lines)",
}


@pytest.mark.device
@pytest.mark.parametrize("moment", list(AFTER_THE_LAST_PIXEL))
def test_a_signal_after_the_last_pixel_still_writes_the_finished_image(tmp_path, moment):
    # It comes after the render's work is done: held, the complete image is written, the
    # summary printed and the command says so (before: up to the writing, the interrupt ended
    # the command with nothing written, the render lost; in the summary, it cut it short)
    (tmp_path / "old.exr").write_bytes(b"a previous image")
    child = render_at(tmp_path, AFTER_THE_LAST_PIXEL[moment])
    assert child.returncode == 143, child.stderr
    assert (
        child.stderr
        == "clrender: interrupted (SIGTERM) after the last pixel: the images are complete\n"
    )
    assert "wrote old.exr and old.png" in child.stdout
    assert read_exr(tmp_path / "old.exr")[1]["partial"] == 0


@pytest.mark.device
def test_a_signal_as_the_process_exits_ends_it_without_a_traceback(tmp_path):
    # Ctrl-C after the command returned, as the interpreter shuts down (sent from an atexit
    # function): the signal's default action ends the process, which the shell reports as
    # 130 (before: Python's own handler raised a KeyboardInterrupt there, and its traceback
    # was printed)
    patch = "import atexit\natexit.register(os.kill, os.getpid(), signal.SIGINT)"
    child = render_at(tmp_path, patch)
    assert child.returncode == -signal.SIGINT and child.stderr == "", child.stderr
    assert "wrote old.exr and old.png" in child.stdout
    assert read_exr(tmp_path / "old.exr")[1]["partial"] == 0


@pytest.mark.device
def test_a_signal_after_the_status_is_delivered_as_the_command_ends(tmp_path):
    # SIGTERM once the command has taken its status (the held signals reported): it is
    # delivered again as the command ends, the signal's default action ends the process, and
    # the line says the images are complete (before: held and dropped, status 0, no line)
    patch = (
        "import clrender.cli\n"
        "clrender.cli.exit_status = (lambda real: lambda *a: (real(*a), "
        "os.kill(os.getpid(), signal.SIGTERM))[0])(clrender.cli.exit_status)"
    )
    child = render_at(tmp_path, patch)
    assert child.returncode == -signal.SIGTERM, child.stderr
    assert (
        child.stderr
        == "clrender: interrupted (SIGTERM) after the last pixel: the images are complete\n"
    )
    assert read_exr(tmp_path / "old.exr")[1]["partial"] == 0


# The command inside a program that goes on (as IPython's `%run -m clrender`, runpy): its
# handlers come back, and a signal after the command reaches them
RUN_INSIDE_A_PROGRAM = """
import os, signal, sys, time
sys.argv = ["clrender", "render", "analytic", "--res", "8", "--spp", "4", "--json", "-o", "a.exr"]
from clrender.__main__ import run
status = run()
print("handler back:", signal.getsignal(signal.SIGINT) is signal.default_int_handler)
try:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)  # (the handler runs at once: the sleep ends with its KeyboardInterrupt)
except KeyboardInterrupt:
    print("the program caught Ctrl-C after the command, status", status)
"""


def test_the_command_inside_a_program_gives_its_handlers_back(tmp_path):
    child = run_child(tmp_path, RUN_INSIDE_A_PROGRAM)
    assert child.returncode == 0, child.stderr
    assert "handler back: True" in child.stdout
    assert "the program caught Ctrl-C after the command, status 0" in child.stdout


def test_the_output_is_flushed_before_the_signals_take_their_default_action(tmp_path):
    # Ctrl-C right after the command returned, stdout a pipe (block-buffered): the summary is
    # out before the default action can end the process (before: the JSON was lost)
    script = RUN_INSIDE_A_PROGRAM.split("status = run()")[0] + (
        "status = run(exiting=True)\nos.kill(os.getpid(), signal.SIGINT)\n"
    )
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONUNBUFFERED"}
    child = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=environment,
        preexec_fn=default_signals,
    )
    assert child.returncode == -signal.SIGINT, child.stderr
    assert '"partial": 0' in child.stdout or '"partial": false' in child.stdout, child.stdout


@pytest.mark.parametrize(
    "arguments, expected",
    [
        (["python", "-m", "clrender", "render"], True),
        (["python", "-X", "dev", "-mclrender"], True),
        (["python", "/usr/bin/ipython", "-c", "%run -m clrender"], False),
        (["python", "-m", "clrender.__main__"], False),
        (["python", "-c", "import clrender"], False),
    ],
)
def test_the_process_is_python_m_clrender(monkeypatch, arguments, expected):
    from clrender.__main__ import _run_by_python_m

    monkeypatch.setattr(sys, "orig_argv", arguments)
    assert _run_by_python_m() is expected


# A 32 x 32 render of many tiles in a child process whose estimator stage `estimate(self,
# tile)` (defined by the patch, counting its calls in `estimates`) replaces TilePipeline's;
# main_thread_in(name) tells whether the main thread is inside a function of that name.
PATCHED_RENDER = """
import os, signal, sys, threading, time
import clrender.pipeline
TilePipeline = clrender.pipeline.TilePipeline
real_estimate = TilePipeline.estimate
estimates = []
def main_thread_in(name):
    frame = sys._current_frames()[threading.main_thread().ident]
    while frame is not None and frame.f_code.co_name != name:
        frame = frame.f_back
    return frame is not None
{patch}
TilePipeline.estimate = estimate
sys.argv = ["clrender", "render", "cornell-box", "--res", "32", "--spp", "8", "--tile-samples",
            "2048", "-o", "out.exr"]
from clrender.__main__ import run
sys.exit(run(exiting=True))
"""


def render_with_patch(tmp_path, patch: str) -> subprocess.CompletedProcess:
    return run_child(tmp_path, PATCHED_RENDER.format(patch=patch))


@pytest.mark.device
def test_a_second_signal_while_finishing_keeps_the_finished_pixels(tmp_path):
    # Ctrl-C interrupts the render while it waits for tile 1's estimate, still in flight on
    # its thread (finish_in_flight): the estimate is recorded once done (before: dropped from
    # in_flight before the wait, nothing was written). SIGTERM comes while the render still
    # waits for it (before: raised there, it ended the command with nothing written). That
    # estimate sends both once the main thread waits for it and finishes after them, so the
    # second comes after the first was raised and before the writing, whenever each lands.
    child = render_with_patch(
        tmp_path,
        """
def estimate(self, tile):
    estimates.append(1)
    if len(estimates) == 1:
        while not main_thread_in("finish_in_flight"):
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)
    return real_estimate(self, tile)
""",
    )
    assert child.returncode == 130, child.stderr  # the status of the signal that interrupted
    assert "clrender: interrupted again (SIGTERM): still finishing, finished pixels are saved" in (
        child.stderr
    )
    assert "Traceback" not in child.stderr, child.stderr
    pixels, meta = read_exr(tmp_path / "out.exr")
    assert meta["partial"] == 1 and 0 < meta["rendered_pixels"] < 32 * 32, child.stderr


@pytest.mark.device
def test_a_full_disk_keeps_the_previous_image_and_exits_2(capsys, tmp_path, monkeypatch):
    import OpenEXR

    out = tmp_path / "edge.exr"
    argv = ["render", "analytic:edge", "--res", "8", "--spp", "8", "-o", str(out)]
    assert run_cli(capsys, *argv)[0] == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    monkeypatch.setattr(OpenEXR.File, "write", lambda self, name: open(name, "wb").close())
    status, stdout, stderr = run_cli(capsys, *argv, "--seed", "5")
    assert status == 2 and "wrote" not in stdout
    assert stderr.count("\n") == 1 and "edge.exr: the written file is incomplete" in stderr
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize("estimator, drawn", [("vor_sn", True), ("mc", False), ("ivor", False)])
def test_auxiliary_nuclei_are_drawn_only_for_estimators_that_use_them(
    capsys, tmp_path, estimator, drawn
):
    out = tmp_path / "aux.exr"
    argv = ["render", "analytic", "--res", "8", "--spp", "16", "--estimator", estimator]
    status, _, err = run_cli(capsys, *argv, "-o", str(out))
    assert status == 0, err
    metadata = read_exr(out)[1]
    assert (metadata["sppp_aux"] > 0) == drawn
    assert metadata["sppp_eps"] > 0


@pytest.mark.usefixtures("shared_cli_runtime")
@pytest.mark.device
@pytest.mark.parametrize(
    "sampler, estimator, shifted", [("sobol", "pvor", True), ("sobol", "mc", False)]
)
def test_toroidal_shift_is_recorded_when_applied(capsys, tmp_path, sampler, estimator, shifted):
    out = tmp_path / "shift.exr"
    argv = ["render", "analytic", "--res", "8", "--spp", "16", "--sampler", sampler]
    status, summary, err = run_cli(capsys, *argv, "--estimator", estimator, "-o", str(out))
    assert status == 0, err
    assert ("toroidal_shift" in read_exr(out)[1]) == shifted
    assert ("(toroidal shift)" in summary) == shifted


def test_the_command_line_starts_without_importing_scipy():
    """Start-up time: scipy's optimize, spatial and integrate take about 2 s to import together;
    the command line, and the settings of the default (SPPP) render, import none of them."""
    code = (
        "import sys; import clrender.cli, clrender.api; "
        "from clrender.cli import build_parser, settings_from_args; "
        "settings_from_args(build_parser().parse_args(['render']), 8, 8); "
        "print(sorted(m for m in sys.modules if m.split('.')[:2] in "
        "(['scipy', 'spatial'], ['scipy', 'optimize'], ['scipy', 'integrate'])))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_reader_that_leaves_the_pipe_ends_the_command_quietly(tmp_path):
    # `python -m clrender scenes | head -1`: stdout's reader is gone before the command writes
    reader, writer = os.pipe()
    os.close(reader)
    try:
        child = subprocess.run(
            [sys.executable, "-m", "clrender", "scenes"],
            stdout=writer,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
    finally:
        os.close(writer)
    assert child.returncode == 141, child.stderr
    assert child.stderr == ""


@pytest.mark.device
def test_in_process_commands_share_one_runtime(capsys, tmp_path, monkeypatch, runtime):
    # Without the session fixture: a second command in the same process renders on the first
    # one's runtime (clrender.api.runtime_for, one per device request), so its programs are not
    # built again (before: a new context per call, about 0.2 s of builds for a tiny render)
    from clrender import api

    made = []

    def counted(request=None):
        made.append((request, os.environ.get("PYOPENCL_CTX")))
        return runtime

    monkeypatch.setattr(api, "create_runtime", counted)
    monkeypatch.setattr(api, "_runtime_for", functools.cache(api._runtime_for.__wrapped__))
    monkeypatch.setenv("PYOPENCL_CTX", "0")
    for name in ("a", "b"):
        argv = ["render", "analytic", "--res", "4", "--spp", "4", "-o", str(tmp_path / name)]
        assert run_cli(capsys, *argv)[0] == 0
    assert made == [(None, "0")]
    # A changed PYOPENCL_CTX is a new request (its device may be another)
    monkeypatch.setenv("PYOPENCL_CTX", "1")
    assert run_cli(capsys, "render", "analytic", "--res", "4", "-o", str(tmp_path / "c"))[0] == 0
    assert made == [(None, "0"), (None, "1")]


def test_a_second_signal_with_stderr_gone_does_not_raise(monkeypatch):
    # After SIGHUP from a closed terminal, writing to it fails (EIO): the report of a second
    # signal must not raise there, in the middle of saving the finished pixels
    class ClosedTerminal(io.TextIOBase):
        def write(self, text):
            raise OSError(5, "Input/output error")

    monkeypatch.setattr(interrupts, "_received", [int(signal.SIGHUP)])
    monkeypatch.setattr(sys, "stderr", ClosedTerminal())
    interrupts._interrupt_once(int(signal.SIGTERM), None)
    assert interrupts._received == [int(signal.SIGHUP), int(signal.SIGTERM)]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("argv", [["scenes"], ["render", "analytic:edge", "--res", "8", "--json"]])
def test_a_stdout_that_cannot_be_written_is_one_line(tmp_path, argv):
    # `... > file` on a full disk: one line and status 2 (before: an OSError traceback, 1)
    with open("/dev/full", "w") as full:
        child = subprocess.run(
            [
                sys.executable,
                "-m",
                "clrender",
                *argv,
                *(["-o", str(tmp_path / "o.exr")] if argv[0] == "render" else []),
            ],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
    assert child.returncode == 2, child.stderr
    assert child.stderr.endswith(
        "clrender: error: cannot write standard output: No space left on device\n"
    ), child.stderr
    assert "Traceback" not in child.stderr
