"""Adversarial inputs run against a chosen checkout of clrender as a user would run it.

The catalog of bench/adversarial_catalog.py (bad scene files, command-line values, Python API
misuse, signals, a full disk), each case's outcome classified, tables before and after.

    python bench/adversarial_inputs.py                          # this repository, every kind
    python bench/adversarial_inputs.py --checkout /work/wt-before --label before
    python bench/adversarial_inputs.py --kinds scene cli --limit 20 --jobs 1
    python bench/adversarial_inputs.py --list                   # the catalog, nothing run
    python bench/adversarial_inputs.py --compare before.json after.json

Every case runs in its own subprocess (`python -m clrender ...`, or `python -c SNIPPET` for the
Python API), in its own scratch directory, with PYTHONPATH=CHECKOUT and
CLRENDER_KERNELS_DIR=CHECKOUT/kernels and no other inherited CLRENDER_* setting, a timeout
(--timeout, default 45 s) and an address-space limit (--memory-gb, default 6: a checkout that
allocates an image it cannot hold fails instead of taking the shared machine's memory). Images
are read with the OpenEXR package, never with the checkout under test. Signal and disk cases
run one at a time after the others (--jobs applies to the rest); disk cases need root and a
tmpfs mount and are skipped with the reason otherwise (mounts are always unmounted).

Outcome classes (`classify`, a pure function of the exit status, stderr and file facts):
- ok: exit 0, the image written and finite, nothing on stderr;
- clean error: non-zero exit, exactly one non-empty stderr line and no traceback, the previous
  output intact (a signal case: exit 128 + signal with its finished pixels written, partial=1,
  or nothing written when no tile was finished yet);
- warning: exit 0, a finite image, warning lines (or any other lines) on stderr;
- traceback: "Traceback (most recent call last)" on stderr, more than one line of error output
  on a failing exit, or a failing exit with no message at all (a crash);
- wrong image: exit 0 and the image has non-finite pixels, is unreadable or missing, is all
  black where the unchanged scene's is not (not judged for camera and emitter-geometry
  mutations, which can legitimately leave nothing in view, nor when a warning was printed), or
  (scale cases) differs from the unchanged scene's image by more than noise; or exit 0 where
  the correct outcome is an error, or silently where a warning is due;
- data lost: the previous good output (a marked EXR and PNG placed before the run) is missing,
  empty or unreadable afterwards, or changed by a failing run; a temporary file (.NAME.*.tmp)
  left beside it; a signal case whose render had finished pixels and wrote none;
- hang: the timeout.

Scale cases (SAME_IMAGE): the case and the unchanged scene render at 16 x 16, 16 spp, depth 3,
independent sampler, seed 1, and the unchanged scene again at seed 2. With the same seed every
random number is the same, so a scale-invariant renderer traces the same paths up to float32
rounding. The case differs by more than noise when more than CHANGED_SHARE (5 %) of its pixels
differ from the same-seed image by more than PIXEL_TOLERANCE (1e-3) of (the pixel's brightest
channel + the image mean), or when d(case, seed 1) > SCALE_NOISE_SHARE (1/4) x d(seed 2,
seed 1), d(a, b) = mean |a - b| / mean |b| (a quarter of what independent noise gives).
Measured on Cornell box and Mitsuba's box: scalings by 1e-5, 1e-3, 7.3, 1e3, 1e6 and every far
shape at HEAD change 0 pixels (d = 0); at 3cd3e81 a sphere at y = 1e6 changes 98 % of the
pixels (d = 0.016, mean within 0.2 %), at 1e8 or a 2e9 ground quad 100 % (d = 0.16-0.37),
against an independent-seed noise d of 0.23-0.30 (0.025 for the furnace).

Output: bench/results/adversarial_inputs/<label>.json (every case: id, kind, description,
expected outcome, outcome, reason, exit status, seconds, stderr, file facts) and <label>.md
(tables per kind and in total, then the cases in the bad classes with the stderr line that
says what happened: the first, or a traceback's last); --label defaults to the checkout's
short commit.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import fcntl
import json
import os
import pty
import re
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
import zlib
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR
from adversarial_catalog import (
    ANY,
    ERROR,
    ERROR_OR_WARNING,
    FAST_EDGE,
    KINDS,
    PARTIAL,
    REPO,
    SAME_IMAGE,
    SCALE_ARGS,
    SCENE_ARGS,
    SCENE_SEED,
    WARNING,
    Case,
    catalog,
    select,
    shipped_scenes,
)
from common import RESULTS, command_line, machine, markdown_table, write_json

OUT_DIR = RESULTS / "adversarial_inputs"
OUTCOMES = ("ok", "clean error", "warning", "traceback", "wrong image", "data lost", "hang")
BAD_OUTCOMES = ("traceback", "wrong image", "data lost", "hang")
HARNESS_ERROR = "harness error"  # the harness failed to run the case (not an outcome of clrender)
TIMEOUT = 45.0
MEMORY_GB = 6.0
SCALE_NOISE_SHARE = 0.25
CHANGED_SHARE = 0.05
PIXEL_TOLERANCE = 1e-3
TRACEBACK = "Traceback (most recent call last)"
PRIOR_MARK = "adversarial_prior"
# Hidden temporary files of a writer beside OUT: .OUT.<anything>.tmp (clrender's pattern).
TEMP_FILE = re.compile(r"^\..+\.tmp$")


# ---------------------------------------------------------------------------------------------
# Classification


@dataclass
class Facts:
    """What a run left behind, as the classifier needs it.

    image: the new image's state ("finite", "nonfinite", "unreadable", "empty") or None when
    the run wrote none; black: it is all zeros; base_black: the unchanged scene's image is all
    zeros (None: no base); partial: its EXR says partial=1; prior: the previous good output's
    state after the run (None: none placed; "intact", "replaced", "missing", "empty",
    "corrupt"); stale: temporary files left beside the output; differs: the scale comparison
    (None: not compared); started: a signal case's render had finished pixels when the signal
    was sent (None: not a signal case)."""

    image: str | None = None
    black: bool = False
    base_black: bool | None = None
    partial: bool = False
    prior: str | None = None
    stale: list[str] = field(default_factory=list)
    differs: bool | None = None
    started: bool | None = None
    notes: dict = field(default_factory=dict)


# A drawing of the progress bar: clrender's own ("... elapsed, ETA ...") or tqdm's
# ("label:  12%|##  | 8192/65536 [00:01<00:08, 5000px/s]", "label: 0px [00:00, ?px/s]").
TQDM_BAR = re.compile(r"(\d+/\d+|\d+px) \[\d\d:\d\d[<,]")


def is_progress_bar(text: str) -> bool:
    return "elapsed, ETA" in text or TQDM_BAR.search(text) is not None


def stderr_lines(stderr: str) -> list[str]:
    """The non-empty lines of stderr, progress bar redraws removed (a pseudo-terminal's)."""
    lines = []
    for line in stderr.replace("\r\n", "\n").split("\n"):
        kept = [part for part in line.split("\r") if not is_progress_bar(part)]
        text = "".join(kept).strip()
        if text:
            lines.append(text)
    return lines


def message(lines: list[str]) -> str:
    """The line that says what happened: the first, or a traceback's last (the exception)."""
    if not lines:
        return ""
    return lines[-1] if lines[0].startswith(TRACEBACK) else lines[0]


def is_warning(line: str) -> bool:
    return "warning" in line.lower()


def classify(
    exit_code: int | None,
    stderr: str,
    facts: Facts,
    expect: str = ANY,
    needs_image: bool = True,
    black_ok: bool = False,
) -> tuple[str, str]:
    """(outcome, reason) of one run. exit_code: the status (negative: killed by that signal,
    as subprocess reports it), None after the timeout."""
    if exit_code is None:
        return "hang", "no exit before the timeout"
    lines = stderr_lines(stderr)
    failed = exit_code != 0
    if facts.stale:
        return "data lost", f"temporary file left beside the output: {facts.stale[0]}"
    if facts.prior in ("missing", "empty", "corrupt"):
        return "data lost", f"the previous good output is {facts.prior}"
    if failed and facts.prior == "replaced":
        return "data lost", "a failing run replaced the previous good output"
    if expect == PARTIAL and failed and facts.image is None and facts.started:
        return "data lost", "interrupted after pixels were finished and nothing written"
    if TRACEBACK in stderr:
        return "traceback", "a traceback on stderr"
    if failed:
        return classify_failure(exit_code, lines, facts, expect)
    return classify_success(lines, facts, expect, needs_image, black_ok)


def classify_failure(exit_code: int, lines: list[str], facts: Facts, expect: str):
    status = 128 - exit_code if exit_code < 0 else exit_code
    if len(lines) > 1:
        return "traceback", f"{len(lines)} lines of error output (exit {status})"
    if not lines:
        if expect == PARTIAL and exit_code < 0 and not facts.started:
            return "clean error", "ended by the signal before any pixel was finished"
        killed = f"killed by signal {-exit_code}" if exit_code < 0 else f"exit {status}"
        return "traceback", f"{killed} without a message"
    if expect == PARTIAL and facts.image is not None and not facts.partial:
        return "clean error", f"exit {status}; the image written is not marked partial"
    return "clean error", f"exit {status}"


def classify_success(lines: list[str], facts: Facts, expect: str, needs_image: bool, black_ok):
    warned = any(is_warning(line) for line in lines)
    if expect == ERROR:
        return "wrong image", "exit 0 where the correct outcome is an error"
    if needs_image and facts.image is None:
        return "wrong image", "exit 0 without writing the image"
    if facts.image not in (None, "finite"):
        return "wrong image", f"exit 0 and the image is {facts.image}"
    if expect == SAME_IMAGE and facts.differs:
        return "wrong image", "differs from the unchanged scene's image by more than noise"
    if facts.black and facts.base_black is False and not black_ok and not warned:
        return "wrong image", "all black where the unchanged scene is not"
    if expect in (WARNING, ERROR_OR_WARNING) and not warned:
        return "wrong image", "exit 0 without the warning this input calls for"
    if lines:
        return "warning", "warning on stderr" if warned else "other output on stderr"
    return "ok", "exit 0"


# ---------------------------------------------------------------------------------------------
# Running


def checkout_env(checkout: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CLRENDER_")}
    env["PYTHONPATH"] = str(checkout)
    env["CLRENDER_KERNELS_DIR"] = str(checkout / "kernels")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def git_revision(checkout: Path) -> dict:
    def git(*args: str) -> str:
        run = subprocess.run(["git", "-C", str(checkout), *args], capture_output=True, text=True)
        return run.stdout.strip()

    return {
        "commit": git("rev-parse", "HEAD"),
        "short": git("rev-parse", "--short", "HEAD"),
        "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
        "subject": git("log", "-1", "--format=%s"),
    }


@dataclass
class Run:
    exit_code: int | None  # None: timeout
    stdout: str
    stderr: str
    seconds: float
    started: bool | None = None
    notes: dict = field(default_factory=dict)


class Runner:
    """Runs cases against one checkout: subprocesses, scratch directories, baselines."""

    def __init__(self, checkout: Path, scratch: Path, timeout: float, memory_gb: float):
        self.checkout = checkout
        self.scratch = scratch
        self.timeout = timeout
        self.memory = int(memory_gb * 2**30)
        self.env = checkout_env(checkout)
        self.bases: dict[tuple, np.ndarray | None] = {}
        self.base_locks: dict[tuple, threading.Lock] = {}
        self.lock = threading.Lock()

    # -- processes
    def start(self, case: Case, cwd: Path, **streams) -> subprocess.Popen:
        env = {**self.env, **{k: v for k, v in case.env.items() if v is not None}}
        for key in [k for k, v in case.env.items() if v is None]:
            env.pop(key, None)
        streams.setdefault("stdout", subprocess.PIPE)
        streams.setdefault("stderr", subprocess.PIPE)
        child = subprocess.Popen(
            [sys.executable, *case.argv],
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=default_signals,
            **streams,
        )
        with contextlib.suppress(OSError):  # the address-space limit (the child is starting up)
            resource.prlimit(child.pid, resource.RLIMIT_AS, (self.memory, self.memory))
        return child

    def finish(self, child: subprocess.Popen, timeout: float) -> tuple[int | None, str, str]:
        try:
            out, err = child.communicate(timeout=timeout)
            code = child.returncode
        except subprocess.TimeoutExpired:
            kill_group(child)
            out, err = child.communicate()
            code = None
        decode = lambda data: (data or b"").decode("utf-8", "replace")  # noqa: E731
        return code, decode(out), decode(err)

    def run_process(self, case: Case, cwd: Path) -> Run:
        start = time.perf_counter()
        child = self.start(case, cwd)
        code, out, err = self.finish(child, case.timeout or self.timeout)
        return Run(code, out, err, time.perf_counter() - start)

    # -- baselines
    def base_image(self, scene: str, args: tuple[str, ...], seed: int) -> np.ndarray | None:
        """The unchanged shipped scene (this repository's text) rendered by the checkout."""
        key = (scene, args, seed)
        with self.lock:
            lock = self.base_locks.setdefault(key, threading.Lock())
        with lock:
            if key not in self.bases:
                where = Path(tempfile.mkdtemp(prefix=f"base-{scene}.", dir=self.scratch))
                (where / "scene.toml").write_text(shipped_scenes()[scene])
                argv = ["-m", "clrender", "render", "scene.toml", *args, "--seed", str(seed)]
                case = Case("base", "scene", "", [*argv, "-o", "base.exr"])
                run = self.run_process(case, where)
                pixels = read_exr(where / "base.exr")[0] if run.exit_code == 0 else None
                self.bases[key] = pixels
                shutil.rmtree(where, ignore_errors=True)
            return self.bases[key]

    # -- one case
    def run(self, case: Case) -> dict:
        where = Path(tempfile.mkdtemp(prefix=f"{case.id[:60]}.", dir=self.scratch))
        existed = {path: os.path.lexists(path) for path in case.outside}
        try:
            for name, data in case.files.items():
                (where / name).write_bytes(data)
            if case.setup is not None:
                case.setup(where)
            if case.runner == "disk":
                run, facts = run_disk(self, case, where)
            else:
                prior = place_prior(where / case.output) if case.prior and case.output else None
                before = file_times(where)
                if case.runner == "signal":
                    run = run_signal(self, case, where)
                else:
                    run = self.run_process(case, where)
                facts = self.facts(case, where, run, prior, before)
            outcome, reason = classify(
                run.exit_code, run.stderr, facts, case.expect, case.needs_image, case.black_ok
            )
        finally:
            for path, was in existed.items():
                if not was and os.path.lexists(path):
                    with contextlib.suppress(OSError):
                        os.unlink(path)
            remove_tree(where)
        lines = stderr_lines(run.stderr)
        return {
            "id": case.id,
            "kind": case.kind,
            "description": case.description,
            "expect": case.expect,
            "outcome": outcome,
            "reason": reason,
            "exit": run.exit_code,
            "seconds": round(run.seconds, 3),
            "stderr_first": lines[0][:300] if lines else "",
            "message": message(lines)[:300],
            "stderr": run.stderr[-4000:],
            "facts": asdict(facts),
            "command": case.command()[:400] if case.kind != "api" else "python -c SNIPPET",
            **case.params,
        }

    def facts(
        self, case: Case, where: Path, run: Run, prior: dict | None, before: dict | None = None
    ) -> Facts:
        """What the run left in `where` (before: the files there before it, as file_times)."""
        facts = Facts(started=run.started, notes=dict(run.notes))
        output = where / case.output if case.output else None
        if prior is not None:
            facts.prior = prior_state(prior)
        image_path = None
        if output is not None and output.exists() and (prior is None or not prior_unchanged(prior)):
            image_path = output
        elif run.exit_code == 0:
            image_path = newest_image(where, before)
        if image_path is not None:
            facts.notes["image"] = image_path.name
            pixels, header, state = image_facts(image_path)
            facts.image = state
            facts.partial = str(header.get("partial", "0")) == "1"
            if pixels is not None:
                facts.black = bool(np.all(pixels == 0))
        facts.stale = stale_files(output.parent if output is not None else where)
        if case.base and run.exit_code == 0 and facts.image == "finite":
            self.compare_with_base(case, facts, pixels)
        return facts

    def compare_with_base(self, case: Case, facts: Facts, pixels: np.ndarray) -> None:
        args = SCALE_ARGS if case.expect == SAME_IMAGE else SCENE_ARGS
        base = self.base_image(case.base, args, SCENE_SEED)
        if base is None:
            facts.notes["base"] = "the unchanged scene failed to render"
            return
        facts.base_black = bool(np.all(base == 0))
        if case.expect != SAME_IMAGE:
            return
        other = self.base_image(case.base, args, SCENE_SEED + 1)
        if other is None or other.shape != base.shape or pixels.shape != base.shape:
            facts.notes["base"] = "no comparable second base"
            return
        noise = relative_difference(other, base)
        diff = relative_difference(pixels, base)
        changed = changed_share(pixels, base)
        facts.differs = bool(changed > CHANGED_SHARE or diff > SCALE_NOISE_SHARE * noise)
        facts.notes.update(
            changed_pixels=round(changed, 4),
            difference=round(diff, 6),
            noise=round(noise, 6),
            mean_ratio=round(float(pixels.mean() / max(base.mean(), 1e-30)), 6),
        )


def kill_group(child: subprocess.Popen) -> None:
    """SIGKILL the process group the harness started for this case."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(child.pid, signal.SIGKILL)


def remove_tree(where: Path) -> None:
    """Remove a case directory, whatever modes the case set on it."""
    for root, dirs, _ in os.walk(where):
        for name in dirs:
            with contextlib.suppress(OSError):
                os.chmod(os.path.join(root, name), 0o755)
    shutil.rmtree(where, ignore_errors=True)


def changed_share(image: np.ndarray, base: np.ndarray) -> float:
    """The share of pixels whose any channel differs from the base's by more than
    PIXEL_TOLERANCE x (that pixel's brightest base channel + the base image's mean)."""
    scale = np.abs(base).max(axis=2) + np.abs(base).mean()
    delta = np.abs(image.astype(np.float64) - base).max(axis=2)
    return float((delta > PIXEL_TOLERANCE * scale).mean())


def relative_difference(image: np.ndarray, base: np.ndarray) -> float:
    """mean |image - base| / mean |base| over pixels and channels."""
    scale = max(float(np.abs(base).mean()), 1e-30)
    return float(np.abs(image.astype(np.float64) - base).mean() / scale)


# --- images and files --------------------------------------------------------------------------


def read_exr(path: Path) -> tuple[np.ndarray, dict]:
    """(H, W, 3) float32 pixels and the header of an EXR (the OpenEXR package alone)."""
    with OpenEXR.File(str(path)) as exr:
        header = {k: v for k, v in exr.header().items()}
        channels = exr.channels()
        if "RGB" in channels:
            pixels = np.array(channels["RGB"].pixels, np.float32)
        else:
            pixels = np.stack([np.array(channels[c].pixels) for c in "RGB"], -1)
    return pixels.astype(np.float32), header


def image_facts(path: Path) -> tuple[np.ndarray | None, dict, str]:
    """(pixels, header, state) of an image the run wrote: an EXR or an API case's .npy."""
    if path.stat().st_size == 0:
        return None, {}, "empty"
    try:
        if path.suffix == ".npy":
            pixels, header = np.load(path).astype(np.float64), {}
        else:
            pixels, header = read_exr(path)
    except Exception:  # noqa: BLE001 - whatever the file is, it is not a readable image
        return None, {}, "unreadable"
    return pixels, header, "finite" if np.isfinite(pixels).all() else "nonfinite"


def file_times(where: Path) -> dict[Path, int]:
    """Every regular file under `where` and its modification time (ns)."""
    return {p: p.stat().st_mtime_ns for p in where.rglob("*") if p.is_file()}


def newest_image(where: Path, before: dict | None = None) -> Path | None:
    """The newest image a successful run wrote or changed somewhere other than asked (e.g.
    SCENE.exr for -o '')."""
    before = before or {}
    found = [
        (time_ns, p)
        for p, time_ns in file_times(where).items()
        if p.suffix.lower() in (".exr", ".npy") and before.get(p) != time_ns
    ]
    return max(found)[1] if found else None


def stale_files(directory: Path) -> list[str]:
    """Temporary files of a writer left in the directory (.NAME.*.tmp)."""
    try:
        return sorted(p.name for p in directory.iterdir() if TEMP_FILE.match(p.name))
    except OSError:
        return []


def encode_png(rgb8: np.ndarray) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    height, width, _ = rgb8.shape
    rows = b"".join(b"\0" + rgb8[y].tobytes() for y in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


def place_prior(exr: Path) -> dict:
    """A previous good output at exr (and its PNG preview), marked; their bytes."""
    pixels = np.full((4, 4, 3), 0.25, np.float32)
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        PRIOR_MARK: "1",
    }
    with OpenEXR.File(header, {"RGB": pixels}) as image:
        image.write(str(exr))
    png = exr.with_suffix(".png")
    png.write_bytes(encode_png(np.full((4, 4, 3), 137, np.uint8)))
    return {exr: exr.read_bytes(), png: png.read_bytes()}


def prior_unchanged(prior: dict) -> bool:
    return all(path.exists() and path.read_bytes() == data for path, data in prior.items())


def prior_state(prior: dict) -> str:
    """The previous good output after the run: intact, replaced (by a readable file), or lost
    (missing, empty, corrupt: the worst of the EXR and its PNG)."""
    states = []
    for path, data in prior.items():
        if not path.exists():
            states.append("missing")
        elif path.stat().st_size == 0:
            states.append("empty")
        elif path.read_bytes() == data:
            states.append("intact")
        elif path.suffix == ".exr":
            states.append("replaced" if image_facts(path)[2] != "unreadable" else "corrupt")
        else:
            states.append("replaced" if path.read_bytes().startswith(b"\x89PNG") else "corrupt")
    for state in ("missing", "empty", "corrupt", "replaced"):
        if state in states:
            return state
    return "intact"


def default_signals() -> None:
    """In a case's child: the default actions of SIGINT, SIGTERM and SIGHUP, as for a command
    typed at a terminal, whatever the harness was started with (`&` ignores SIGINT, `nohup`
    SIGHUP, and a child inherits both)."""
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)


# --- signal cases --------------------------------------------------------------------------------


# A progress bar with finished pixels: clrender's own bar until 2026-11 ("... elapsed"), then
# tqdm's (" 12%|##  | 8192/65536 [00:01<00:08, ...]", a count above 0).
TQDM_PROGRESS = re.compile(rb"(?<![\d/])[1-9]\d*/\d+ \[")


def shows_progress(data: bytes) -> bool:
    """Whether a chunk of the terminal shows pixels finished."""
    return b"elapsed" in data or TQDM_PROGRESS.search(data) is not None


def run_signal(runner: Runner, case: Case, where: Path) -> Run:
    """The render with stderr on a pseudo-terminal (the progress bar shows when a tile is
    finished), the signal sent at the case's moment."""
    signum = getattr(signal, case.params["signal"])
    controller, terminal = pty.openpty()
    # 80 columns: tqdm draws nothing on a terminal 0 wide, as a new pseudo-terminal is
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    start = time.perf_counter()
    child = runner.start(case, where, stderr=terminal)
    os.close(terminal)
    chunks: list[tuple[float, bytes]] = []

    def read_terminal() -> None:
        while True:
            try:
                data = os.read(controller, 4096)
            except OSError:  # EIO: every writer closed its side
                return
            if not data:
                return
            chunks.append((time.perf_counter(), data))

    reader = threading.Thread(target=read_terminal, daemon=True)
    reader.start()
    moment = case.params["moment"]
    if moment == "tile":
        deadline = start + runner.timeout
        while time.perf_counter() < deadline and child.poll() is None:
            if any(shows_progress(data) for _, data in chunks):
                break
            time.sleep(0.01)
        time.sleep(0.3)
    else:
        time.sleep(max(0.0, start + float(moment.removesuffix("s")) - time.perf_counter()))
    sent = time.perf_counter()
    notes = {
        "signal_at_s": round(sent - start, 3),
        "exited_before_signal": child.poll() is not None,
    }
    if child.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(child.pid, signum)
    code, out, _ = runner.finish(child, runner.timeout)
    reader.join(timeout=5)
    os.close(controller)
    started = any(shows_progress(data) for t, data in chunks if t <= sent)
    stderr = b"".join(data for _, data in chunks).decode("utf-8", "replace")
    return Run(code, out, stderr, time.perf_counter() - start, started, notes)


# --- disk cases ----------------------------------------------------------------------------------


def mount_tmpfs(where: Path, size: str, options: str = "") -> None:
    where.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}{options}", "tmpfs", str(where)],
        check=True,
        capture_output=True,
    )


def unmount(where: Path) -> None:
    if subprocess.run(["umount", str(where)], capture_output=True).returncode != 0:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def tmpfs_unavailable(scratch: Path) -> str | None:
    """Why the disk kind cannot run here (None: it can: a tmpfs mounts)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "not root: cannot mount a tmpfs"
    probe = scratch / "mount-probe"
    try:
        mount_tmpfs(probe, "64k")
    except (OSError, subprocess.CalledProcessError) as err:
        detail = getattr(err, "stderr", b"") or b""
        return f"mount -t tmpfs failed: {detail.decode(errors='replace').strip() or err}"
    unmount(probe)
    return None


def fill(directory: Path, free_kb: int) -> None:
    """Fill the file system of `directory` (unbuffered writes until ENOSPC), then free
    `free_kb` KB again."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        for size in (65536, 4096, 512, 1):
            block = b"\0" * size
            try:
                while True:
                    os.write(fd, block)
            except OSError as err:
                if err.errno != errno.ENOSPC:
                    raise
    finally:
        os.close(fd)
    if free_kb:
        os.truncate(filler, max(0, filler.stat().st_size - free_kb * 1024))


def run_disk(runner: Runner, case: Case, where: Path) -> tuple[Run, Facts]:
    mount = where / "mnt"
    size = "256m" if case.params.get("kill_during_write") else "1m"
    mount_tmpfs(mount, size)
    try:
        prior = place_prior(mount / "full.exr")
        if case.params.get("kill_during_write"):
            return kill_during_write(runner, case, mount, prior)
        if case.params.get("read_only"):
            subprocess.run(["mount", "-o", "remount,ro", str(mount)], check=True)
        else:
            fill(mount, case.params["free_kb"])
        before = file_times(mount)
        run = runner.run_process(case, mount)
        facts = runner.facts(case, mount, run, prior, before)
        facts.notes["free_kb_after"] = (
            os.statvfs(mount).f_bavail * os.statvfs(mount).f_frsize // 1024
        )
        return run, facts
    finally:
        unmount(mount)


def kill_during_write(runner: Runner, case: Case, mount: Path, prior: dict) -> tuple[Run, Facts]:
    """SIGKILL as soon as a temporary file of full.exr shows (up to 3 tries), then a second
    render to that name; the facts: the old file after the kill, temporary files after the
    second write."""
    caught = False
    for _ in range(3):
        child = runner.start(case, mount)
        while child.poll() is None and not caught:
            caught = any(TEMP_FILE.match(p.name) and "full" in p.name for p in mount.iterdir())
            if not caught:
                time.sleep(0.002)
        if caught:
            time.sleep(0.02)
            kill_group(child)
        child.communicate()
        if caught:
            break
        place_prior(mount / "full.exr")
    after_kill = prior_state(prior)
    left = stale_files(mount)
    again = Case(case.id, case.kind, "", [*case.argv[:3], *FAST_EDGE, "-o", "full.exr"])
    run = runner.run_process(again, mount)
    facts = Facts(prior=after_kill if after_kill != "replaced" else "intact")
    facts.notes.update(caught_in_write=caught, left_by_kill=left, prior_after_kill=after_kill)
    if after_kill == "replaced":  # the kill came after the rename: nothing to judge there
        facts.notes["kill"] = "after the rename"
    facts.stale = stale_files(mount)
    if run.exit_code == 0 and (mount / "full.exr").exists():
        facts.image = image_facts(mount / "full.exr")[2]
    return run, facts


# ---------------------------------------------------------------------------------------------
# Reports


def summary(results: list[dict]) -> dict[str, dict[str, int]]:
    """{kind and "total": {outcome: count, "tried": n}}."""
    table: dict[str, Counter] = {}
    for result in results:
        if result["outcome"] == HARNESS_ERROR:
            continue
        for key in (result["kind"], "total"):
            table.setdefault(key, Counter())[result["outcome"]] += 1
            table[key]["tried"] += 1
    order = [k for k in KINDS if k in table] + (["total"] if "total" in table else [])
    return {k: {o: table[k][o] for o in ("tried", *OUTCOMES)} for k in order}


def summary_markdown(results: list[dict]) -> str:
    rows = [[kind, *counts.values()] for kind, counts in summary(results).items()]
    return markdown_table(["kind", "tried", *OUTCOMES], rows)


def bad_cases_markdown(results: list[dict]) -> str:
    bad = [r for r in results if r["outcome"] in BAD_OUTCOMES]
    if not bad:
        return "No case in the bad classes."
    rows = [
        [r["outcome"], r["id"], r["description"][:90], r["reason"][:70], r["message"][:120]]
        for r in sorted(bad, key=lambda r: (BAD_OUTCOMES.index(r["outcome"]), r["id"]))
    ]
    header = ["outcome", "id", "description", "reason", "stderr (a traceback's: its last line)"]
    return markdown_table(header, rows)


def report_markdown(data: dict) -> str:
    results = data["cases"]
    seconds = Counter()
    for r in results:
        seconds[r["kind"]] += r["seconds"]
    per_kind = ", ".join(
        f"{kind} {seconds[kind] / n:.1f} s"
        for kind, n in Counter(r["kind"] for r in results).items()
    )
    checkout = data["checkout"]
    lines = [
        f"# Adversarial inputs: {data['label']}",
        "",
        f"Checkout {checkout['path']} at {checkout['commit']}"
        + (" (uncommitted changes)" if checkout["dirty"] else "")
        + f": {checkout['subject']}",
        f"Command: `{data['command']}`; {len(results)} cases in {data['wall_s']:.0f} s "
        f"(mean seconds a case: {per_kind}).",
    ]
    for kind, reason in data.get("skipped", {}).items():
        lines.append(f"Skipped {kind}: {reason}.")
    for r in results:
        if r["outcome"] == HARNESS_ERROR:
            lines.append(f"Not run (harness error, not counted): {r['id']}: {r['reason']}")
    lines += ["", summary_markdown(results), "", "## Cases in the bad classes", ""]
    lines.append(bad_cases_markdown(results))
    return "\n".join(lines) + "\n"


def compare_markdown(before: dict, after: dict) -> str:
    """The two summaries side by side (before -> after), then the cases whose outcome moved."""
    a, b = summary(before["cases"]), summary(after["cases"])
    rows = []
    for kind in [k for k in (*KINDS, "total") if k in a or k in b]:
        cells = [f"{a.get(kind, {}).get(o, 0)} -> {b.get(kind, {}).get(o, 0)}" for o in
                 ("tried", *OUTCOMES)]  # fmt: skip
        rows.append([kind, *cells])
    moved = Counter()
    outcome_a = {r["id"]: r["outcome"] for r in before["cases"]}
    changes = []
    for r in after["cases"]:
        old = outcome_a.get(r["id"])
        if old is not None and old != r["outcome"]:
            moved[(old, r["outcome"])] += 1
            changes.append((r["id"], old, r["outcome"]))
    lines = [
        f"# Adversarial inputs: {before['label']} -> {after['label']}",
        "",
        f"before: {before['checkout']['commit']} ({before['checkout']['subject'][:70]})",
        f"after:  {after['checkout']['commit']} ({after['checkout']['subject'][:70]})",
        "",
        markdown_table(["kind", "tried", *OUTCOMES], rows),
        "",
        "Outcome moves (cases run in both):",
        "",
        markdown_table(
            ["before", "after", "cases"],
            [[old, new, n] for (old, new), n in sorted(moved.items(), key=lambda kv: -kv[1])],
        ),
        "",
        "## Cases in the bad classes after",
        "",
        bad_cases_markdown(after["cases"]),
    ]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Command line


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkout", type=Path, default=REPO, help="clrender checkout to test")
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--limit", type=int, default=None, help="at most N cases of each kind")
    parser.add_argument("--ids", nargs="+", default=None, help="only ids matching these globs")
    parser.add_argument("--jobs", type=int, default=1, help="cases run at once (not signal/disk)")
    parser.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds a case")
    parser.add_argument("--memory-gb", type=float, default=MEMORY_GB, help="address space a case")
    parser.add_argument("--label", default=None, help="output name (default: short commit)")
    parser.add_argument("--out", type=Path, default=OUT_DIR)
    parser.add_argument("--list", action="store_true", help="print the catalog and exit")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    return parser.parse_args(argv)


def run_cases(runner: Runner, cases: list[Case], jobs: int, log=print) -> list[dict]:
    """Every case's result in catalog order; signal and disk cases one at a time."""
    results: dict[str, dict] = {}
    total = len(cases)

    def one(case: Case) -> None:
        try:
            result = runner.run(case)
        except Exception as err:  # noqa: BLE001 - the harness's own failure, reported apart
            result = {
                "id": case.id,
                "kind": case.kind,
                "description": case.description,
                "outcome": HARNESS_ERROR,
                "reason": f"{type(err).__name__}: {err}",
                "message": "",
                "seconds": 0.0,
            }
        results[case.id] = result
        log(
            f"[{len(results)}/{total}] {case.id}: {result['outcome']} "
            f"({result['seconds']:.1f} s) {result['message'][:80] or result['reason'][:80]}"
        )

    parallel = [c for c in cases if c.runner == "process"]
    serial = [c for c in cases if c.runner != "process"]
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        list(pool.map(one, parallel))
    for case in serial:
        one(case)
    return [results[c.id] for c in cases]


def main(argv=None) -> dict | None:
    args = parse_args(argv)
    if args.compare:
        before, after = (json.loads(p.read_text()) for p in args.compare)
        print(compare_markdown(before, after))
        return None
    cases = select(catalog(args.kinds), args.limit, args.ids)
    if args.list:
        for case in cases:
            print(f"{case.id}\t{case.expect}\t{case.description}")
        print(dict(Counter(c.kind for c in cases)))
        return None
    checkout = args.checkout.resolve()
    revision = git_revision(checkout)
    label = args.label or revision["short"] or checkout.name
    scratch = Path(tempfile.mkdtemp(prefix="adversarial-"))
    skipped = {}
    try:
        if any(c.kind == "disk" for c in cases):
            reason = tmpfs_unavailable(scratch)
            if reason:
                print(f"skipping the disk cases: {reason}")
                skipped["disk"] = reason
                cases = [c for c in cases if c.kind != "disk"]
        runner = Runner(checkout, scratch, args.timeout, args.memory_gb)
        start = time.perf_counter()
        results = run_cases(runner, cases, args.jobs)
        wall = time.perf_counter() - start
    finally:
        remove_tree(scratch)
    data = {
        "command": command_line("adversarial_inputs.py", argv),
        "label": label,
        "checkout": {"path": str(checkout), **revision},
        "machine": machine(),
        "settings": {
            "kinds": args.kinds,
            "limit": args.limit,
            "ids": args.ids,
            "jobs": args.jobs,
            "timeout_s": args.timeout,
            "memory_gb": args.memory_gb,
            "scale_noise_share": SCALE_NOISE_SHARE,
        },
        "skipped": skipped,
        "wall_s": wall,
        "summary": summary(results),
        "cases": results,
    }
    write_json(args.out / f"{label}.json", data)
    report = report_markdown(data)
    (args.out / f"{label}.md").write_text(report)
    print(report)
    print(f"wrote {args.out / f'{label}.json'} and {args.out / f'{label}.md'}")
    return data


if __name__ == "__main__":
    main()
