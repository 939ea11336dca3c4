"""Command line: `python -m clrender [COMMAND] ...`.

With no command it lists the OpenCL platforms and devices and runs a self-check kernel on
the selected device; `render` renders a scene to a linear EXR and an sRGB PNG preview (one
pair per estimator, all from one trace, with `--estimator mc,vor_sn,fvor`); `compare` gives the
error of an image against a reference; `scenes` lists the shipped scenes. Errors
the user can fix print as one line (no traceback unless --debug) and exit with status 2;
an interrupted render (Ctrl-C, SIGTERM, SIGHUP) writes what it has and exits with status
128 + the signal number (130, 143, 129). Warnings (a scene with
no emitter, a camera inside a solid shape) print one line each on stderr and do not change
the exit status, as does one for a poor estimator/sampler pair (mc over SPPP samples).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import pyopencl as cl

from clrender import __version__, interrupts
from clrender.errors import ClrenderError, ParameterError
from clrender.runtime import describe_device, list_devices
from clrender.trace import DEFAULT_MAX_DEPTH, MAX_DEPTH_LIMIT

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

SCENE is a shipped scene name, a .toml or pbrt-v4 .pbrt path, or
analytic[:edge|smooth|disc|bowl|mix] (images with exact pixel integrals).
exit status: 0 done, 2 bad arguments, 3 --strict and non-finite radiance, 128 + signal when
interrupted (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP: the pixels done so far are written, with
partial=1 in the EXR metadata), 141 when stdout's reader left (`... | head`)."""


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"clrender: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="python -m clrender", description=__doc__.split("\n")[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"clrender {__version__}")
    commands = parser.add_subparsers(dest="command", parser_class=OneLineErrorParser)
    devices = commands.add_parser("devices", help="list OpenCL devices and run a self-check")
    add_device_option(devices)
    commands.add_parser("scenes", help="list the shipped scenes and the analytic images")
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
        help="OpenCL device: index in the list, its whole name, or a part of its description "
        "(name, platform, version) no other device shares (default: PYOPENCL_CTX, else the "
        "first device)",
    )


def add_render_options(parser: argparse.ArgumentParser) -> None:
    from clrender.estimators import ESTIMATORS

    add = parser.add_argument
    add(
        "scene",
        nargs="?",
        default=DEFAULT_SCENE,
        help=f"scene name, .toml or .pbrt file or analytic[:KIND] (default: {DEFAULT_SCENE})",
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
        metavar="NAME[,NAME...]",
        help=f"pixel estimator, or several separated by commas, all from one trace (one output "
        f"pair each, OUT.NAME.exr and OUT.NAME.png): {', '.join(ESTIMATORS)} (default: vor_sn "
        "with sppp, mc otherwise)",
    )
    add(
        "--reference",
        default=None,
        metavar="REF.exr",
        help="report each image's error against this EXR (MSE, relMSE, and MSE minus the "
        "reference's own noise when its metadata carries noise_mse); analytic images are "
        "compared with their exact pixel integrals without it",
    )
    add(
        "--json",
        action="store_true",
        help="print the closing summary as one JSON object on stdout (and nothing else there)",
    )
    add(
        "--quiet",
        action="store_true",
        help="no progress bar and no summary: warnings and errors only",
    )
    add("--seed", type=int, default=0, help="random seed, 0 <= S < 2^32 (default: 0)")
    add(
        "--max-depth",
        type=int,
        default=None,
        metavar="D",
        help=f"scattering vertices per path, 0 <= D <= {MAX_DEPTH_LIMIT} (default: "
        f"{DEFAULT_MAX_DEPTH}; not for analytic images)",
    )
    add(
        "--russian-roulette",
        action="store_true",
        help="end paths at random from their second vertex on, continuing with probability "
        "max(throughput) (pbrt-v4's rule; unbiased, fewer rays per path; default: off, as in "
        "the paper; not for analytic images)",
    )
    add(
        "--trace-kernel",
        choices=("auto", "megakernel", "simd"),
        default="auto",
        help="the path-tracing kernel: the same image to the bit, at different speeds; auto "
        "(default): simd (paths in vector lanes) on a CPU device for a scene without "
        "triangles, BVH or emitters other than quads, megakernel otherwise",
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
        help="where vor, vor_sn, fvor, cvor, pvor, ivor and ivor_sn get their Voronoi cells: "
        "device (an OpenCL kernel, exact, default) or qhull (SciPy's Qhull on the host)",
    )
    add(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="render on a Dask LocalCluster of N worker processes on this machine (needs "
        "pip install 'dask[distributed]'); the image is bit-identical to a local render",
    )
    add(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="render on the existing Dask cluster whose scheduler is at ADDRESS (e.g. "
        "tcp://host:8786); each worker uses --device, else its own PYOPENCL_CTX; this machine "
        "needs no OpenCL device",
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
    from clrender.api import runtime_for

    runtime = runtime_for(args.device)
    print(f"selected: {runtime.describe()}")
    ok, message = run_self_check(runtime)
    print(f"self-check: {message}: {'ok' if ok else 'FAILED'}")
    return 0 if ok else 1


# --- render --------------------------------------------------------------------------------


def estimator_names(text: str | None, sampler: str) -> list[str]:
    """The estimators of --estimator NAME[,NAME...], each checked against the sampler (the
    sampler's default estimator without the option; a name given twice is refused by
    RenderSettings)."""
    from clrender.api import default_estimator
    from clrender.estimators import check_compatible

    if text is None:
        return [check_compatible(default_estimator(sampler), sampler).name]
    names = [name.strip() for name in text.split(",")]
    if not all(names):
        raise ParameterError(f"--estimator {text!r} has an empty name: give NAME[,NAME...]")
    return [check_compatible(name, sampler).name for name in names]


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
    return Path(scene).stem if scene.lower().endswith((".toml", ".pbrt")) else scene


def settings_from_args(args: argparse.Namespace, width: int, height: int):
    from clrender.pipeline import DEFAULT_TILE_SAMPLES, RenderSettings
    from clrender.sampling import make_sampler, sampler_kind

    if args.spp <= 0:
        raise ParameterError(f"--spp must be a positive integer, got {args.spp}")
    sampler_kind(args.sampler)
    estimators = estimator_names(args.estimator, args.sampler)
    tile_samples = DEFAULT_TILE_SAMPLES if args.tile_samples is None else args.tile_samples
    if tile_samples <= 0:
        raise ParameterError(f"--tile-samples must be a positive integer, got {tile_samples}")
    return RenderSettings(
        width,
        height,
        make_sampler(args.sampler, args.spp),
        estimators,
        args.seed,
        tile_samples,
        not args.no_overlap,
        args.voronoi_backend,
    )


def check_render_args(args: argparse.Namespace) -> None:
    """Everything checkable without a device, so mistakes fail fast."""
    from clrender.analytic import is_analytic_scene
    from clrender.film import check_image_memory
    from clrender.sampling import check_seed

    settings_from_args(args, 1, 1)
    check_seed(args.seed)
    size = parse_resolution(args.res)
    if isinstance(size, tuple):  # else known only with the scene: checked by RenderSettings
        check_image_memory(*size)
    if args.max_depth is not None and not 0 <= args.max_depth <= MAX_DEPTH_LIMIT:
        raise ParameterError(
            f"--max-depth must be an integer in [0, {MAX_DEPTH_LIMIT}], got {args.max_depth}"
        )
    if args.max_depth is not None and is_analytic_scene(args.scene):
        raise ParameterError(
            f"--max-depth needs a path-traced scene: {args.scene} is an analytic image "
            "without paths"
        )
    if args.workers is not None and args.workers <= 0:
        raise ParameterError(f"--workers must be a positive integer, got {args.workers}")
    if args.workers is not None and args.scheduler is not None:
        raise ParameterError("give --workers or --scheduler, not both")
    if args.russian_roulette and is_analytic_scene(args.scene):
        raise ParameterError(
            f"--russian-roulette needs a path-traced scene: {args.scene} is an analytic image "
            "without paths"
        )


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
        if "/" in args.scene or args.scene.lower().endswith((".toml", ".pbrt")):  # a file
            raise
        raise ParameterError(f"{err}; or analytic[:{'|'.join(ANALYTIC_KINDS)}]") from None
    for note in scene.warnings:
        print(f"clrender: warning: {note}", file=sys.stderr)
    return scene


def make_source(args: argparse.Namespace, runtime, scene):
    """The radiance source of the scene (of the analytic image named by the argument when scene
    is None) at the requested size."""
    from clrender.api import radiance_source

    size = parse_resolution(args.res)
    return radiance_source(
        runtime,
        scene or args.scene,
        size,
        path_depth(args),
        args.russian_roulette,
        args.trace_kernel,
    )


def path_depth(args: argparse.Namespace) -> int:
    """--max-depth, or the default depth when it was not given."""
    return DEFAULT_MAX_DEPTH if args.max_depth is None else args.max_depth


@dataclass(frozen=True)
class Reference:
    """What the images are compared with: a reference EXR, or an analytic image's exact
    pixel integrals."""

    label: str
    pixels: object  # (H, W, 3) array
    noise: float | None


def load_reference(args: argparse.Namespace, settings, labels) -> Reference | None:
    """--reference (checked against the render's size before it starts; what makes its errors
    untrustworthy printed as warnings), else the exact pixel integrals of an analytic image
    (computed here, without a device), else None."""
    from clrender.analytic import analytic_image, is_analytic_scene
    from clrender.compare import noise_from_metadata, read_image, reference_warnings

    if args.reference:
        shape = (settings.height, settings.width)
        pixels, metadata = read_image(args.reference, "reference", shape)
        noise = noise_from_metadata(metadata, args.reference)
        rendered = {"scene": labels.scene, "seed": settings.seed}
        if labels.scene_sha256 is not None:
            rendered["scene_sha256"] = labels.scene_sha256
        for warning in reference_warnings(rendered, metadata, args.reference):
            print(f"clrender: warning: {warning}", file=sys.stderr)
        return Reference(args.reference, pixels, noise)
    if is_analytic_scene(args.scene):
        width, height = settings.width, settings.height
        integrals = analytic_image(args.scene, width, height).pixel_integrals(width, height)
        return Reference("exact pixel integrals", integrals, 0.0)
    return None


def reference_errors(result, reference: Reference | None) -> dict[str, dict]:
    """{estimator: errors as a dict, with the reference's label} for a complete render."""
    from clrender.compare import image_errors

    if reference is None:
        return {}
    errors = {}
    for name, film in result.films.items():
        if not film.complete:  # no error of a partial image: its missing pixels are 0
            continue
        measured = image_errors(film.image(), reference.pixels, reference.noise)
        errors[name] = {**measured.as_dict(), "reference": reference.label}
        errors[name]["summary"] = measured.summary_line()
    return errors


def error_lines(errors: dict[str, dict], result, reference: Reference | None) -> list[str]:
    if reference is None:
        return []
    return [
        f"{name} against {reference.label}: {errors[name]['summary']}"
        if name in errors
        else f"{name}: no error against {reference.label}: its image is partial"
        for name in result.films
    ]


def command_render(args: argparse.Namespace) -> int:
    args.outputs_written = False  # an interrupt that escapes says whether the files were written
    with interrupts.signals_blocked():  # SciPy and OpenEXR initialise whole
        import clrender.report  # noqa: F401 (for finish_render)
        from clrender.estimators import pairing_advice
        from clrender.outputs import output_paths, render_labels
        from clrender.pipeline import render
        from clrender.progress import ProgressBar
        from clrender.runtime import thread_build_seconds

    # Set-up with the ending signals blocked: one that comes is acted on when it is done, not
    # inside a library's initialisation or the OpenCL compiler (clrender.interrupts)
    with interrupts.signals_blocked():
        check_render_args(args)
        label = scene_label(args.scene)
        names = estimator_names(args.estimator, args.sampler)
        paths = output_paths(args.output, label, names)
        if args.reference:
            from clrender.compare import check_outputs_spare_inputs

            written = [path for pair in paths.values() for path in (pair.exr, pair.png)]
            check_outputs_spare_inputs(
                written, [args.reference], "-o/--output", "the --reference image or its preview"
            )
        scene = load_scene_arg(args)
        for name in names:
            advice = pairing_advice(name, args.sampler, args.spp)
            if advice:
                print(f"clrender: warning: {advice}", file=sys.stderr)
        cluster = args.workers is not None or args.scheduler is not None
        if cluster:  # the workers choose the device and build the source: none is needed here
            from clrender.api import image_size

            size = image_size(scene or args.scene, parse_resolution(args.res))
        else:
            from clrender.api import runtime_for

            runtime = runtime_for(args.device)  # one per process: its programs build once
            built = thread_build_seconds()
            source = make_source(args, runtime, scene)
            setup_compile = thread_build_seconds() - built
            size = source.width, source.height
        max_depth, roulette = (
            (None, None) if scene is None else (path_depth(args), args.russian_roulette)
        )
        settings = settings_from_args(args, *size)
        labels = render_labels(label, scene, max_depth, roulette)
        reference = load_reference(args, settings, labels)
    # From the end of the render's work to the command's end a signal is held (the render
    # calls interrupts.work_done): the finished pixels are written and the summary printed,
    # and the status reports it
    with interrupts.held_once_done() as held:
        progress = ProgressBar(
            f"{label} {settings.width}x{settings.height}", enabled=False if args.quiet else None
        )
        try:
            if not cluster:
                result = render(runtime, source, settings, progress)
                result.stats.setup_compile_seconds = setup_compile
            else:  # its workers' devices and source builds (clrender.cluster), not this one's
                result = render_on_cluster(args, scene, settings, max_depth, roulette, progress)
        finally:
            progress.close()
        return finish_render(args, result, labels, paths, reference, held)


def finish_render(args: argparse.Namespace, result, labels, paths, reference, held) -> int:
    """Write a render's images and print its summary; the command's status. `held`: the
    ending signals held since the render's work was done (more come in while writing)."""
    from clrender.outputs import write_outputs
    from clrender.provenance import provenance_warning, reported
    from clrender.report import json_ready, summary_json, summary_lines

    # the device, precision, kernels and code that rendered it: a cluster's, its workers'
    workers = reported(result)
    warning = provenance_warning(workers, reported(labels))
    if warning is not None:
        print(f"clrender: warning: {warning}", file=sys.stderr)
    labels = dataclasses.replace(
        labels,
        device=result.device,
        device_precision=result.device_precision,
        **{key: value or getattr(labels, key) for key, value in workers.items()},
    )
    # Every signal is held until the finished pixels are written (or found to be none), also
    # where none was asked to be held (in-process runs)
    with interrupts.signals_held(held):
        rendered = max(film.rendered_count for film in result.films.values())
        if result.stats.interrupted and rendered == 0:
            # Nothing to save: an all-black partial image would replace the previous one
            signum = interrupts.interrupting_signal()
            print(
                f"clrender: interrupted ({signal.Signals(signum).name}) before any pixel was "
                "finished: nothing written (a previous image there is kept)",
                file=sys.stderr,
            )
            if args.json:
                summary = summary_json(result, labels, {}, {}, reference and reference.label)
                print(json.dumps(json_ready(summary), indent=1, allow_nan=False))
            return interrupts.exit_status(signum)
        errors = reference_errors(result, reference)
        write_outputs(result, labels, paths, errors)
    args.outputs_written = True
    outputs = {name: pair for name, pair in zip(result.films, paths.values(), strict=True)}
    if args.json:
        summary = summary_json(result, labels, outputs, errors, reference and reference.label)
        print(json.dumps(json_ready(summary), indent=1, allow_nan=False))
    elif not args.quiet:
        print("\n".join(summary_lines(result, labels) + error_lines(errors, result, reference)))
        for pair in outputs.values():
            print(f"wrote {pair.exr} and {pair.png}")
    return exit_status(args, result, interrupts.take_held(held))


def render_on_cluster(args: argparse.Namespace, scene, settings, max_depth, roulette, progress):
    """The render on the Dask cluster of --workers / --scheduler (clrender.cluster): the same
    image as a local render. Its workers choose the device (--device, else their own
    PYOPENCL_CTX) and report one they lack; this process needs no OpenCL device."""
    from clrender.cluster import RenderJob, make_executor, render_on

    with interrupts.signals_blocked():
        executor = make_executor(args.workers, args.scheduler)
    try:
        job = RenderJob.of(
            scene or args.scene,
            settings,
            max_depth or 0,
            bool(roulette),
            args.device,
            args.trace_kernel,
        )
        return render_on(executor, job, progress)
    finally:
        with interrupts.signals_blocked():
            executor.close()


def command_scenes(args: argparse.Namespace) -> int:
    """The shipped scenes (name, size, the first sentence of their description) and the
    analytic images."""
    import textwrap

    from clrender.analytic import ANALYTIC_KINDS, DEFAULT_RESOLUTION
    from clrender.scene import list_scenes, load_scene

    print(
        f"shipped scenes (python -m clrender render NAME: {DEFAULT_WIDTH} pixels wide unless "
        "--res says otherwise; --res scene for the size below):"
    )
    for name in list_scenes():
        scene = load_scene(name)
        width, height = scene.camera.resolution
        text = " ".join(scene.description.split())
        first = text.split(". ")[0].rstrip(".") + "." if text else "(no description)"
        line = f"  {name:20s} {f'{width}x{height}':9s} {first}"
        print(textwrap.fill(line, 100, subsequent_indent=" " * 33))
    kinds = "|".join(ANALYTIC_KINDS)
    width, height = DEFAULT_RESOLUTION
    print(
        f"analytic images with exact pixel integrals: analytic[:{kinds}] "
        f"(own size {width}x{height})"
    )
    return 0


def exit_status(args: argparse.Namespace, result, held_signals: list[int]) -> int:
    """The command's status; held_signals: the signals that came once the render's work was
    done (the render itself reports an interrupt in its stats)."""
    interrupted = result.stats.interrupted
    if interrupted or held_signals:
        # The signal that interrupted the render; else the one held while writing
        signum = interrupts.interrupting_signal() if interrupted else held_signals[-1]
        # An interrupt after the last pixel was recorded (held, or between the last tile and
        # the end of the render) leaves complete images: they are not partial
        if not interrupted or all(film.complete for film in result.films.values()):
            print(
                f"clrender: interrupted ({signal.Signals(signum).name}) after the last "
                "pixel: the images are complete",
                file=sys.stderr,
            )
        else:
            counts = sorted({film.rendered_count for film in result.films.values()})
            held = " to ".join(str(count) for count in (counts[0], counts[-1])[: len(counts)])
            print(
                "clrender: interrupted: the "
                f"image{'s hold' if len(result.films) > 1 else ' holds'} "
                f"{held} of {result.film.pixel_count} pixels (partial=1)",
                file=sys.stderr,
            )
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
    "scenes": command_scenes,
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
    except MemoryError as err:
        if args.debug:
            raise
        detail = f" ({err})" if str(err) else ""
        print(
            f"clrender: error: out of host memory{detail}: render fewer pixels or samples per "
            "pixel, or lower --tile-samples",
            file=sys.stderr,
        )
        return EXIT_USAGE
    except KeyboardInterrupt as interrupt:
        if args.debug:
            raise
        return interrupts.report(interrupt, getattr(args, "outputs_written", None))
