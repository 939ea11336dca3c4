"""Command line: `python -m clrender [COMMAND] ...`.

With no command it lists the OpenCL platforms and devices and runs a self-check kernel on
the selected device; `render` renders a scene to a linear EXR and an sRGB PNG preview. Errors
the user can fix print as one line (no traceback unless --debug) and exit with status 2;
an interrupted render (Ctrl-C, SIGTERM, SIGHUP) writes what it has and exits with status
128 + the signal number (130, 143, 129). Warnings (a scene with
no emitter, a camera inside a solid shape) print one line each on stderr and do not change
the exit status.
"""

from __future__ import annotations

import argparse
import signal
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import pyopencl as cl

from clrender import interrupts
from clrender.errors import ClrenderError, ParameterError
from clrender.runtime import create_runtime, describe_device, list_devices

EXIT_USAGE = 2
EXIT_STRICT = 3

DEFAULT_SCENE = "cornell-box"
DEFAULT_SPP = 64
DEFAULT_WIDTH = 128
DEFAULT_SAMPLER = "sppp"

RENDER_EPILOG = """\
defaults: the authors' Cornell box at 128x128, 64 spp, the sppp sampler with the vor_sn
estimator: the paper's Voronoi weights, self-normalised (the README's "What the measurements
say" compares the estimators and samplers).
--estimator defaults to vor_sn with the SPPP samplers and mc with the others.

samplers (spp each takes):
{samplers}

estimators:
{estimators}

SCENE is a shipped scene name, a .toml path, or analytic[:edge|smooth|disc|bowl|mix]
(images with exact pixel integrals).
exit status: 0 done, 2 bad arguments, 3 --strict and non-finite radiance, 128 + signal when
interrupted (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP: the pixels done so far are written, with
partial=1 in the EXR metadata)."""


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"clrender: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="python -m clrender", description=__doc__.split("\n")[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    commands = parser.add_subparsers(dest="command", parser_class=OneLineErrorParser)
    devices = commands.add_parser("devices", help="list OpenCL devices and run a self-check")
    add_device_option(devices)
    render = commands.add_parser(
        "render",
        help="render a scene to OUT.exr (linear float) and OUT.png (sRGB preview)",
        description="Render a scene to a linear float32 EXR and an sRGB 8-bit PNG preview.",
        epilog=render_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_render_options(render)
    from clrender.compare import add_compare_parser

    add_compare_parser(commands)
    return parser


def render_epilog() -> str:
    """The render help's closing text, its estimator list from the registry."""
    import textwrap

    from clrender.estimators import ESTIMATORS
    from clrender.sampling import SAMPLERS

    samplers = [
        textwrap.fill(
            f"  {name:16s} {kind.description} (spp: {kind.counts})", 92, subsequent_indent=" " * 19
        )
        for name, kind in SAMPLERS.items()
    ]
    lines = []
    for name, entry in ESTIMATORS.items():
        mark = "*" if entry.needs_sppp else " "
        text = f"{mark} {name:8s} {entry.description}"
        lines.append(textwrap.fill(text, 92, subsequent_indent=" " * 11))
    lines.append(
        "  * needs an SPPP sampler: sppp or sppp-sobol (auxiliary nuclei or Poisson counts)"
    )
    return RENDER_EPILOG.format(samplers="\n".join(samplers), estimators="\n".join(lines))


def add_device_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--device",
        default=None,
        help="OpenCL device: index in the list, or a name substring "
        "(default: PYOPENCL_CTX, else the first device)",
    )


def add_render_options(parser: argparse.ArgumentParser) -> None:
    from clrender.estimators import ESTIMATORS

    add = parser.add_argument
    add(
        "scene",
        nargs="?",
        default=DEFAULT_SCENE,
        help=f"scene name, .toml file or analytic[:KIND] (default: {DEFAULT_SCENE})",
    )
    add(
        "-o",
        "--output",
        default=None,
        metavar="OUT.exr",
        help="output EXR; the PNG preview goes beside it (default: SCENE.exr here)",
    )
    add(
        "--spp",
        type=int,
        default=DEFAULT_SPP,
        help=f"samples per pixel (the SPPP intensity n) (default: {DEFAULT_SPP})",
    )
    add(
        "--res",
        default=str(DEFAULT_WIDTH),
        metavar="WxH|N|scene",
        help=f"image size: WxH, a width N (scene's aspect ratio), or 'scene' for the scene "
        f"file's own size (default: {DEFAULT_WIDTH})",
    )
    add(
        "--sampler",
        default=DEFAULT_SAMPLER,
        metavar="NAME",
        help=f"sample positions and path dimensions, listed below (default: {DEFAULT_SAMPLER})",
    )
    add(
        "--estimator",
        default=None,
        metavar="NAME",
        help=f"pixel estimator: {', '.join(ESTIMATORS)} (default: vor_sn with sppp, mc otherwise)",
    )
    add("--seed", type=int, default=0, help="random seed, 0 <= S < 2^32 (default: 0)")
    add(
        "--max-depth",
        type=int,
        default=8,
        metavar="D",
        help="scattering vertices per path (default: 8)",
    )
    add(
        "--tile-samples",
        type=int,
        default=None,
        metavar="N",
        help="samples per tile (traced + auxiliary): bounds memory whatever the image size, "
        "about 600 MB at the default 4000000",
    )
    add(
        "--no-overlap",
        action="store_true",
        help="run the host estimator after each tile instead of during the next one",
    )
    add(
        "--voronoi-backend",
        default="device",
        metavar="NAME",
        help="where vor, vor_sn, fvor and pvor get their Voronoi cells: device (an OpenCL "
        "kernel, exact, default) or qhull (SciPy's Qhull on the host)",
    )
    add(
        "--strict",
        action="store_true",
        help="exit with status 3 if any sample's radiance was NaN or infinite",
    )
    # SUPPRESS: without a default here, `--debug render` keeps the top-level flag's value.
    add("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks on errors")
    add_device_option(parser)


def command_devices(args: argparse.Namespace) -> int:
    from clrender.selfcheck import run_self_check

    devices = list_devices()
    print("OpenCL devices:")
    for index, device in enumerate(devices):
        print(f"  [{index}] {describe_device(device)}, {device.max_compute_units} compute units")
    runtime = create_runtime(args.device)
    print(f"selected: {runtime.describe()}")
    ok, message = run_self_check(runtime)
    print(f"self-check: {message}: {'ok' if ok else 'FAILED'}")
    return 0 if ok else 1


# --- render --------------------------------------------------------------------------------


@dataclass(frozen=True)
class OutputPaths:
    exr: Path
    png: Path


def output_paths(output: str | None, scene_label: str) -> OutputPaths:
    """OUT.exr and OUT.png, both checked writable before anything renders."""
    from clrender.imageio import check_writable

    if output is not None and not output.strip():
        raise ParameterError("-o/--output is empty: give a file name such as out.exr")
    exr = Path(output) if output else Path(scene_label.replace(":", "-") + ".exr")
    if exr.name.lower() in (".exr", ".png"):
        raise ParameterError(f"-o/--output {str(exr)!r} has no file name before {exr.name}")
    if output and exr.suffix == "" and exr.exists() and not exr.is_file():
        raise ParameterError(
            f"-o/--output {str(exr)!r} is not a file name (a directory or device): clrender "
            "writes OUT.exr and OUT.png, give OUT"
        )
    if exr.suffix.lower() != ".exr":
        if exr.suffix:
            raise ParameterError(f"-o/--output must name an .exr file, got {str(exr)!r}")
        exr = exr.with_suffix(".exr")
    png = exr.with_suffix(".png")
    return OutputPaths(check_writable(exr), check_writable(png))


def parse_resolution(text: str) -> tuple[int, int] | int | None:
    """(width, height) from 'WxH', the width N from 'N', None from 'scene'."""
    if text == "scene":
        return None
    parts = text.lower().split("x")
    try:
        sizes = [int(part) for part in parts]
    except ValueError:
        sizes = []
    if len(sizes) not in (1, 2) or min(sizes) <= 0:
        raise ParameterError(
            f"--res must be WxH, N or 'scene' with positive integers, got {text!r}"
        )
    return (sizes[0], sizes[1]) if len(sizes) == 2 else sizes[0]


def scene_label(scene: str) -> str:
    from clrender.analytic import analytic_image, is_analytic_scene

    if is_analytic_scene(scene):
        return analytic_image(scene, 1, 1).name
    return Path(scene).stem if scene.endswith(".toml") else scene


def settings_from_args(args: argparse.Namespace, width: int, height: int):
    from clrender.api import default_estimator
    from clrender.estimators import check_compatible
    from clrender.pipeline import DEFAULT_TILE_SAMPLES, RenderSettings
    from clrender.sampling import make_sampler, sampler_kind

    if args.spp <= 0:
        raise ParameterError(f"--spp must be a positive integer, got {args.spp}")
    sampler_kind(args.sampler)
    estimator = check_compatible(args.estimator or default_estimator(args.sampler), args.sampler)
    tile_samples = DEFAULT_TILE_SAMPLES if args.tile_samples is None else args.tile_samples
    if tile_samples <= 0:
        raise ParameterError(f"--tile-samples must be a positive integer, got {tile_samples}")
    return RenderSettings(
        width,
        height,
        make_sampler(args.sampler, args.spp),
        estimator,
        args.seed,
        tile_samples,
        not args.no_overlap,
        args.voronoi_backend,
    )


def check_render_args(args: argparse.Namespace) -> None:
    """Everything checkable without a device, so mistakes fail fast."""
    from clrender.film import check_image_memory
    from clrender.sampling import check_seed

    settings_from_args(args, 1, 1)
    check_seed(args.seed)
    size = parse_resolution(args.res)
    if isinstance(size, tuple):  # else known only with the scene: checked by RenderSettings
        check_image_memory(*size)
    if args.max_depth < 0:
        raise ParameterError(f"--max-depth must be a non-negative integer, got {args.max_depth}")


def load_scene_arg(args: argparse.Namespace):
    """The scene named by the argument (None for an analytic image), loaded before any OpenCL
    work so that a bad scene file is reported without a device; warnings printed once each."""
    from clrender.analytic import ANALYTIC_KINDS, is_analytic_scene
    from clrender.scene import SceneError, SceneWarning, load_scene

    if is_analytic_scene(args.scene):
        return None
    try:
        with warnings.catch_warnings():  # printed below, once each, as one line
            warnings.simplefilter("ignore", SceneWarning)
            scene = load_scene(args.scene)
    except SceneError as err:
        if "/" in args.scene or args.scene.endswith(".toml"):  # a file, not a scene name
            raise
        raise ParameterError(f"{err}; or analytic[:{'|'.join(ANALYTIC_KINDS)}]") from None
    for note in scene.warnings:
        print(f"clrender: warning: {note}", file=sys.stderr)
    return scene


def make_source(args: argparse.Namespace, runtime, scene):
    """(radiance source, max depth or None) for the scene (None: the analytic image named by
    the argument) at the requested size."""
    from clrender.api import radiance_source

    size = parse_resolution(args.res)
    source = radiance_source(runtime, scene or args.scene, size, args.max_depth)
    return source, None if scene is None else args.max_depth


def write_outputs(result, labels, paths: OutputPaths) -> None:
    """Both images, each checked on disk before either replaces its old version."""
    from clrender.imageio import (
        exr_header,
        exr_writer,
        png_writer,
        rgb_float32,
        write_all_atomically,
    )
    from clrender.report import render_metadata

    image = rgb_float32(result.film.image())
    header = exr_header(render_metadata(result, labels))
    write_all_atomically([(paths.exr, exr_writer(image, header)), (paths.png, png_writer(image))])


def command_render(args: argparse.Namespace) -> int:
    with interrupts.signals_blocked():  # SciPy and OpenEXR initialise whole
        from clrender.pipeline import render
        from clrender.progress import ProgressBar
        from clrender.report import RenderLabels, summary_lines

    # Set-up with the ending signals blocked: one that comes is acted on when it is done, not
    # inside a library's initialisation or the OpenCL compiler (clrender.interrupts)
    with interrupts.signals_blocked():
        check_render_args(args)
        label = scene_label(args.scene)
        paths = output_paths(args.output, label)
        scene = load_scene_arg(args)
        runtime = create_runtime(args.device)
        source, max_depth = make_source(args, runtime, scene)
        settings = settings_from_args(args, source.width, source.height)
        labels = RenderLabels(label, runtime.describe(), max_depth)
    progress = ProgressBar(f"{label} {settings.width}x{settings.height}")
    try:
        result = render(runtime, source, settings, progress)
    finally:
        progress.close()
    if result.stats.interrupted and result.film.rendered_count == 0:
        # Nothing to save: an all-black partial image would replace the previous one
        signum = interrupts.last_signal()
        print(
            f"clrender: interrupted ({signal.Signals(signum).name}) before any pixel was "
            "finished: nothing written (a previous image there is kept)",
            file=sys.stderr,
        )
        return interrupts.exit_status(signum)
    with interrupts.signals_held() as held:
        write_outputs(result, labels, paths)
    print("\n".join(summary_lines(result, labels)))
    print(f"wrote {paths.exr} and {paths.png}")
    return exit_status(args, result, held)


def exit_status(args: argparse.Namespace, result, held_signals: list[int]) -> int:
    """The command's status; held_signals: the signals that came while the images were
    written (the render itself reports an interrupt in its stats)."""
    if result.stats.interrupted or held_signals:
        print(
            f"clrender: interrupted: the image holds {result.film.rendered_count} of "
            f"{result.film.pixel_count} pixels (partial=1)",
            file=sys.stderr,
        )
        signum = held_signals[-1] if held_signals else interrupts.last_signal()
        return interrupts.exit_status(signum)
    if result.stats.nonfinite_samples or result.film.flagged_count:
        print(
            f"clrender: warning: {result.stats.nonfinite_samples} samples had NaN or "
            f"infinite radiance; {result.film.flagged_count} pixels flagged and set to 0",
            file=sys.stderr,
        )
        if args.strict:
            return EXIT_STRICT
    return 0


def command_compare(args: argparse.Namespace) -> int:
    from clrender.compare import run_compare

    return run_compare(args)


COMMANDS = {
    "devices": command_devices,
    "render": command_render,
    "compare": command_compare,
    None: command_devices,
}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        args.device = None
    try:
        return COMMANDS[args.command](args)
    except (ClrenderError, cl.Error) as err:
        if args.debug:
            raise
        print(f"clrender: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as interrupt:
        if args.debug:
            raise
        return interrupts.report(interrupt)
