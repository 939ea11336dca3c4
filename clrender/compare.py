"""Comparing images: the error of a rendered image against a reference, and the `compare`
command (`python -m clrender compare IMAGE.exr REFERENCE.exr [--map OUT.exr] [--json]`).

The errors, over every pixel and the three RGB channels, computed in float64 (a image,
r reference):

- MSE: the mean of (a - r)^2, also per channel.
- relMSE: the mean of (a - r)^2 / (|r| + 0.01)^2. This is pbrt-v4's relative error, the "MRSE"
  of `imgtool diff --metric MRSE` and `imgtool error` (Image::MRSE in src/pbrt/util/image.cpp
  of github.com/mmp/pbrt-v4: Sqr(v - vref) / Sqr(vref + 0.01), per channel, averaged over
  pixels): the squared error relative to the reference value, the 0.01 keeping black pixels
  from dominating. |r| instead of r: the same for r >= 0, and no division by zero at a negative
  reference value (pbrt's is infinite at r = -0.01, and skipped). Other papers divide by
  r^2 + eps instead (Rousselle et al.'s relMSE form, eps small): their numbers are not
  interchangeable with these for dark pixels.
- Reference noise: a reference rendered with an unbiased estimate of its own variance carries
  `noise_mse` in its EXR metadata, the mean over pixels and channels of the per-pixel variance
  of its estimator. For an image a independent of an unbiased reference r,
  E[(a - r)^2] = E[(a - truth)^2] + Var(r), so MSE minus that noise estimates the image's MSE
  against the truth; being a difference of noisy numbers it can come out negative when the
  image is about as close to the truth as the reference is.

`compare --map OUT.exr` writes the squared-error map (linear float32, the inputs and the MSE in
its metadata) and OUT.png, a false-colour preview of the per-pixel relative squared error (the
mean over channels of the relMSE terms) on a log scale of MAP_DECADES decades ending at the
decade above its largest value, through a black-purple-orange-yellow ramp.

Only NumPy is imported at module level: the command line builds its parser (which calls
add_compare_parser) for every command, and OpenEXR is loaded by clrender.imageio only when an
image is read or written.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clrender.errors import ClrenderError, ParameterError

RELATIVE_OFFSET = 0.01  # the relMSE denominator's (|r| + 0.01)^2, pbrt-v4's
NOISE_ATTRIBUTE = "noise_mse"  # the reference's own noise, in its EXR metadata
ERROR_BLOCK_VALUES = 1 << 18  # values per block of the error sums (2 MB float64 temporaries)
MAP_DECADES = 4  # the preview's log scale spans this many decades of relative squared error
EXR_MAGIC = b"\x76\x2f\x31\x01"  # the first four bytes of every OpenEXR file
# The preview's colour ramp (a black-purple-orange-yellow heat scale): display (sRGB-encoded)
# colours at evenly spaced points from the scale's bottom to its top.
RAMP_DISPLAY = np.array(
    [
        [0.00, 0.00, 0.02],
        [0.34, 0.06, 0.43],
        [0.73, 0.21, 0.33],
        [0.98, 0.55, 0.04],
        [0.99, 1.00, 0.64],
    ]
)


class ComparisonInputError(ClrenderError):
    """An image to compare cannot be read, or does not match the other one."""


@dataclass(frozen=True)
class ImageErrors:
    """The errors of an image against a reference (see the module docstring for the metrics)."""

    mse: float
    rel_mse: float
    mse_per_channel: tuple[float, float, float]
    pixels: int
    reference_noise: float | None = None

    @property
    def mse_minus_noise(self) -> float | None:
        """MSE minus the reference's own noise: the expected MSE against the truth (None when
        the reference noise is not known; can be negative by noise)."""
        return None if self.reference_noise is None else self.mse - self.reference_noise

    def as_dict(self) -> dict:
        """The errors as plain floats, ints and None, for JSON."""
        red, green, blue = self.mse_per_channel
        return {
            "mse": self.mse,
            "rel_mse": self.rel_mse,
            "mse_r": red,
            "mse_g": green,
            "mse_b": blue,
            "pixels": self.pixels,
            "reference_noise": self.reference_noise,
            "mse_minus_noise": self.mse_minus_noise,
        }

    def summary_line(self) -> str:
        """The errors in one line for a terminal."""
        red, green, blue = self.mse_per_channel
        line = (
            f"MSE {self.mse:.3e} (R {red:.2e} G {green:.2e} B {blue:.2e}), "
            f"relMSE {self.rel_mse:.3e}, {self.pixels} pixels"
        )
        if self.reference_noise is None:
            return line + "; reference noise not known"
        return (
            f"{line}; reference noise {self.reference_noise:.3e}: "
            f"MSE minus noise {self.mse_minus_noise:.3e}"
        )


# --- errors of arrays ------------------------------------------------------------------------


def checked_pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both arrays as float64, checked (see checked_arrays)."""
    image, reference = checked_arrays(image, reference)
    return image.astype(np.float64), reference.astype(np.float64)


def checked_arrays(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both arrays, checked: (H, W, 3) RGB, the same shape, finite, not empty; ParameterError
    otherwise."""
    arrays = []
    for role, array in (("image", image), ("reference", reference)):
        if hasattr(array, "images") and hasattr(array, "film"):  # a RenderResult
            raise ParameterError(
                f"the {role} must be an (H, W, 3) RGB array: pass a render result's .image "
                "(or .images[name])"
            )
        array = np.asarray(array)
        if array.ndim != 3 or array.shape[2] != 3:
            raise ParameterError(
                f"the {role} must be an (H, W, 3) RGB array, got shape {array.shape}"
            )
        arrays.append(array)
    image, reference = arrays
    if image.shape != reference.shape:
        raise ParameterError(
            f"the image's shape {image.shape} differs from the reference's {reference.shape}"
        )
    if image.shape[0] * image.shape[1] == 0:
        raise ParameterError(f"the images have no pixels (shape {image.shape})")
    for role, array in (("image", image), ("reference", reference)):
        bad = nonfinite_pixels(array)
        if bad:
            raise ParameterError(f"the {role} has {bad} pixels with NaN or infinite values")
    return image, reference


def nonfinite_pixels(pixels: np.ndarray) -> int:
    """How many pixels have a NaN or infinite channel."""
    return int(np.count_nonzero(~np.isfinite(pixels).all(axis=-1)))


def squared_errors(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(a - r)^2 per pixel and channel, float64, of checked float64 arrays."""
    return np.square(image - reference)


def relative_squared_errors(squared: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(a - r)^2 / (|r| + RELATIVE_OFFSET)^2 per pixel and channel, from the squared errors."""
    return squared / np.square(np.abs(reference) + RELATIVE_OFFSET)


class ReferenceWarning(UserWarning):
    """Errors against this reference are not to be trusted as they are (reference_warnings)."""


def image_errors(image, reference, reference_noise: float | None = None) -> ImageErrors:
    """The errors of an (H, W, 3) image against an (H, W, 3) reference, in float64.
    reference_noise: the reference's own noise (the mean per-pixel variance of its estimator),
    if known. Either may be a RenderResult (clrender.render's; its first estimator's image):
    a reference result gives its own noise when reference_noise is None (as the command line's
    noise_mse: clrender.report.own_noise, None where its variance layer is not its estimator's
    unbiased variance), a partial one is refused, and a reference of another scene or of the
    image's seed warns (ReferenceWarning), as `compare` does. ParameterError on a wrong shape,
    differing shapes or NaN/infinite values."""
    if is_render_result(reference) and reference_noise is None:
        from clrender.report import own_noise

        reference_noise = own_noise(reference, reference.settings.estimator.name)
    if is_render_result(image) or is_render_result(reference):
        for text in reference_warnings(
            result_metadata(image), result_metadata(reference), "(a RenderResult)"
        ):
            warnings.warn(text, ReferenceWarning, stacklevel=2)
    image, reference = result_image(image, "image"), result_image(reference, "reference")
    image, reference = checked_arrays(image, reference)
    if reference_noise is not None:
        reference_noise = checked_noise(reference_noise)
    # Sums over blocks of rows: float64 temporaries of a block, not of the whole image
    squared_sum, relative_sum = np.zeros(3), 0.0
    rows = max(1, ERROR_BLOCK_VALUES // (3 * image.shape[1]))
    for top in range(0, image.shape[0], rows):
        block = np.asarray(reference[top : top + rows], np.float64)
        squared = squared_errors(np.asarray(image[top : top + rows], np.float64), block)
        squared_sum += squared.sum(axis=(0, 1))
        relative_sum += float(relative_squared_errors(squared, block).sum())
    pixels = image.shape[0] * image.shape[1]
    per_channel = squared_sum / pixels
    return ImageErrors(
        mse=float(per_channel.mean()),
        rel_mse=relative_sum / (3 * pixels),
        mse_per_channel=(float(per_channel[0]), float(per_channel[1]), float(per_channel[2])),
        pixels=pixels,
        reference_noise=reference_noise,
    )


def is_render_result(value: object) -> bool:
    """Whether value is a RenderResult (told by its attributes: this module imports no more
    than NumPy)."""
    return hasattr(value, "films") and hasattr(value, "settings")


def result_image(value, role: str):
    """A RenderResult's first image (ParameterError if partial); anything else as it is."""
    if not is_render_result(value):
        return value
    film = value.film
    if not film.complete:
        raise ParameterError(
            f"the {role} is a partial render ({film.rendered_count} of {film.pixel_count} "
            "pixels): its unfinished pixels are black, so it has no error"
        )
    return value.image


def result_metadata(value) -> dict:
    """What reference_warnings reads (scene, scene_sha256, seed) of a RenderResult made by
    clrender.render; {} for an array (nothing known)."""
    if not is_render_result(value):
        return {}
    labels = getattr(value, "labels", None)
    metadata = {"seed": value.settings.seed}
    if labels is not None:
        metadata.update(scene=labels.scene, scene_sha256=labels.scene_sha256)
    return metadata


def checked_noise(value: float) -> float:
    """A reference noise as a float; ParameterError unless finite and non-negative."""
    noise = float(value)
    if not math.isfinite(noise) or noise < 0:
        raise ParameterError(f"the reference noise must be finite and >= 0, got {value!r}")
    return noise


def error_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The (H, W, 3) float32 squared error (a - r)^2 per pixel and channel (computed in
    float64). ParameterError as image_errors."""
    image, reference = checked_pair(image, reference)
    return squared_errors(image, reference).astype(np.float32)


# --- reading ---------------------------------------------------------------------------------


def read_image(
    path: str | os.PathLike, role: str = "image", expected_shape: tuple[int, ...] | None = None
) -> tuple[np.ndarray, dict]:
    """The (H, W, 3) float32 RGB pixels of an EXR to compare and its metadata attributes.
    ComparisonInputError, one line naming the file as the `role` ("image", "reference"), if
    it is missing, not an EXR, unreadable, without RGB channels, of another width and height
    than expected_shape's (H, W, ...), or has NaN or infinite pixels."""
    from clrender.imageio import MissingChannelsError, read_exr

    path = Path(path)
    prefix = f"cannot read {role} {path}"
    if not path.exists():
        raise ComparisonInputError(f"{prefix}: no such file")
    if path.is_dir():
        raise ComparisonInputError(f"{prefix}: it is a directory")
    try:
        with open(path, "rb") as file:
            magic = file.read(len(EXR_MAGIC))
    except OSError as err:
        raise ComparisonInputError(f"{prefix}: {err.strerror or err}") from None
    if magic != EXR_MAGIC:  # checked here: the library's message says only "Unable to open"
        raise ComparisonInputError(f"{prefix}: not an OpenEXR file")
    # The bindings print warnings on sys.stdout, and the C library its errors on file
    # descriptor 2: both kept apart, so that a damaged file gives one line
    library_output = io.StringIO()
    try:
        with contextlib.redirect_stdout(library_output), library_stderr() as library_errors:
            pixels, metadata = read_exr(path)
    except MissingChannelsError as err:
        raise ComparisonInputError(f"{prefix}: {err}") from None
    except (RuntimeError, ValueError, OSError) as err:  # ValueError: one cut in its pixel data
        first = (library_errors or [""])[0].strip().splitlines()
        reason = first[0].removeprefix(f"{path}: ") if first else str(err)
        reason = " ".join(reason.split()) or type(err).__name__
        raise ComparisonInputError(
            f"{prefix}: a damaged or truncated EXR (OpenEXR: {reason})"
        ) from None
    # stdout is for the errors (--json) only
    sys.stderr.write(library_output.getvalue() + "".join(library_errors))
    if expected_shape is not None and pixels.shape[:2] != tuple(expected_shape[:2]):
        height, width = expected_shape[:2]
        raise ComparisonInputError(
            f"{role} {path} is {pixels.shape[1]}x{pixels.shape[0]}, the image compared is "
            f"{width}x{height}: images must be the same size"
        )
    bad = nonfinite_pixels(pixels)
    if bad:
        raise ComparisonInputError(f"{role} {path} has {bad} pixels with NaN or infinite values")
    return pixels, metadata


@contextlib.contextmanager
def library_stderr():
    """File descriptor 2 sent to a temporary file while the block runs; yields a list that
    gets the text written there (by C libraries, which bypass sys.stderr) when it ends."""
    import tempfile

    sys.stderr.flush()
    saved = os.dup(2)
    captured: list[str] = []
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode(errors="replace")
            if text:
                captured.append(text)


def reference_warnings(
    image: dict, reference: dict, reference_path: str | os.PathLike
) -> list[str]:
    """What makes errors against a reference untrustworthy, from the two images' metadata (a
    render's EXR attributes, or those of the image being rendered): a partial reference, a
    reference of another scene, or one rendered from the same seed (the image's samples are
    then the reference's, or correlated with them, and its errors come out too low)."""
    found = []
    if reference.get("partial") == 1:
        found.append(partial_warning("reference", reference_path))
    image_scene, reference_scene = image.get("scene"), reference.get("scene")
    if image_scene is not None and reference_scene is not None:
        if image_scene != reference_scene:
            found.append(
                f"the reference {reference_path} is of scene {reference_scene!r}, the image of "
                f"{image_scene!r}"
            )
        elif _differ(image.get("scene_sha256"), reference.get("scene_sha256")):
            found.append(
                f"the reference {reference_path} is of another scene of the same name "
                f"{image_scene!r}: the scene the device got differs (scene_sha256 "
                f"{reference['scene_sha256']} against the image's {image['scene_sha256']})"
            )
        elif "seed" in image and image.get("seed") == reference.get("seed"):
            found.append(
                f"the image and the reference {reference_path} were rendered from the same seed "
                f"({image['seed']}): the image's samples are the reference's or correlated with "
                "them, so its errors come out too low; render the reference with another seed "
                "(--seed, seed=)"
            )
    return found


def _differ(a: object, b: object) -> bool:
    """Whether two recorded values are both there and differ."""
    return a is not None and b is not None and a != b


def partial_warning(role: str, path: str | os.PathLike) -> str:
    """The warning about an input that is an interrupted render (partial=1)."""
    return f"the {role} {path} is partial (an interrupted render: its unfinished pixels are black)"


def read_reference(
    path: str | os.PathLike, expected_shape: tuple[int, ...] | None = None
) -> tuple[np.ndarray, float | None]:
    """The (H, W, 3) float32 RGB pixels of a reference EXR and its own noise (its `noise_mse`
    metadata attribute, None without one). Errors as read_image, and ComparisonInputError if
    noise_mse is not a finite non-negative number."""
    pixels, metadata = read_image(path, "reference", expected_shape)
    return pixels, noise_from_metadata(metadata, path)


def noise_from_metadata(metadata: dict, path: str | os.PathLike) -> float | None:
    """The reference noise recorded in EXR metadata (None without one)."""
    if NOISE_ATTRIBUTE not in metadata:
        return None
    value = metadata[NOISE_ATTRIBUTE]
    try:
        if isinstance(value, bool):
            raise ValueError
        return checked_noise(value)
    except (TypeError, ValueError):
        raise ComparisonInputError(
            f"reference {path}: its {NOISE_ATTRIBUTE} metadata {value!r} is not a finite "
            "non-negative number"
        ) from None


# --- the error map and its preview ---------------------------------------------------------


@dataclass(frozen=True)
class PreviewScale:
    """The preview's log scale: relative squared errors from `bottom` (the ramp's first colour,
    and below) to `top` (its last)."""

    bottom: float
    top: float

    def describe(self) -> str:
        """The scale in words, for metadata and the printed line."""
        return (
            f"relative squared error (a - r)^2 / (|r| + {RELATIVE_OFFSET})^2, mean of R, G, B; "
            f"log scale from {self.bottom:.0e} (black) to {self.top:.0e} (pale yellow)"
        )


def preview_scale(relative: np.ndarray) -> PreviewScale:
    """MAP_DECADES decades ending at the power of ten at or above the largest value (1 for an
    all-zero map)."""
    largest = float(relative.max())
    top_exponent = math.ceil(math.log10(largest)) if largest > 0 else 0
    return PreviewScale(10.0 ** (top_exponent - MAP_DECADES), 10.0**top_exponent)


def false_colour(relative: np.ndarray, scale: PreviewScale) -> np.ndarray:
    """(H, W, 3) linear RGB of (H, W) relative errors through the colour ramp, log-scaled."""
    with np.errstate(divide="ignore"):  # log10(0) = -inf: the bottom colour
        logs = np.log10(relative)
    low, high = math.log10(scale.bottom), math.log10(scale.top)
    position = np.clip((logs - low) / (high - low), 0.0, 1.0)
    stops = np.linspace(0.0, 1.0, len(RAMP_DISPLAY))
    display = np.stack(
        [np.interp(position, stops, RAMP_DISPLAY[:, channel]) for channel in range(3)], axis=-1
    )
    return srgb_decode(display)


def srgb_decode(display: np.ndarray) -> np.ndarray:
    """Linear values of sRGB-encoded ones in [0, 1] (the inverse of imageio.srgb_encode): the
    PNG writer encodes them back, so the ramp's colours show as written."""
    return np.where(display <= 0.04045, display / 12.92, ((display + 0.055) / 1.055) ** 2.4)


def map_paths(output: str | os.PathLike) -> tuple[Path, Path]:
    """OUT.exr and OUT.png of --map OUT.exr (OUT alone gets .exr), both checked writable."""
    from clrender.imageio import check_writable

    exr = Path(output)
    if not str(output).strip() or exr.name.lower() in (".exr", ".png"):
        raise ParameterError(f"--map needs a file name such as errors.exr, got {str(output)!r}")
    if exr.suffix == "":
        exr = exr.with_suffix(".exr")
    elif exr.suffix.lower() != ".exr":
        raise ParameterError(f"--map must name an .exr file, got {str(output)!r}")
    return check_writable(exr), check_writable(exr.with_suffix(".png"))


def check_outputs_spare_inputs(
    outputs: Iterable[Path], inputs: Iterable[str], option: str, role: str
) -> None:
    """ParameterError if an output would replace an input or an input's PNG preview (a render
    wrote IMAGE.png beside IMAGE.exr); option names the outputs, role the inputs."""
    spared = [Path(name) for name in inputs]
    spared += [name.with_suffix(".png") for name in spared]
    for written in outputs:
        for other in spared:
            if os.path.realpath(written) == os.path.realpath(other):
                raise ParameterError(
                    f"{option} {written} would overwrite {other}, {role}: choose another name"
                )


def write_error_map(
    paths: tuple[Path, Path],
    image: np.ndarray,
    reference: np.ndarray,
    labels: dict,
) -> PreviewScale:
    """Write the squared-error map EXR (labels: its metadata, naming the inputs and the errors)
    and its false-colour PNG, both or neither (atomically); the preview's scale."""
    from clrender.imageio import exr_header, exr_writer, png_writer, write_all_atomically

    image, reference = checked_pair(image, reference)
    squared = squared_errors(image, reference)
    relative = relative_squared_errors(squared, reference).mean(axis=-1)
    scale = preview_scale(relative)
    header = exr_header(
        labels
        | {
            "content": "squared error (image - reference)^2 per pixel and channel",
            "preview_scale": scale.describe(),
        }
    )
    exr_path, png_path = paths
    write_all_atomically(
        [
            (exr_path, exr_writer(squared.astype(np.float32), header)),
            (png_path, png_writer(false_colour(relative, scale))),
        ]
    )
    return scale


# --- the command -------------------------------------------------------------------------------


def add_compare_parser(commands: argparse._SubParsersAction) -> None:
    """The `compare` subcommand's parser, added to the command line's subparsers."""
    parser = commands.add_parser(
        "compare",
        help="errors of an image against a reference (MSE, relMSE, minus the reference noise)",
        description="Print the errors of IMAGE.exr against REFERENCE.exr: MSE (per channel "
        "too), relMSE (a - r)^2 / (|r| + 0.01)^2 as pbrt-v4's imgtool, and, when the "
        f"reference's metadata holds its own noise ({NOISE_ATTRIBUTE}), MSE minus that noise: "
        "the expected MSE against the truth.",
        epilog="exit status: 0 done, 2 bad input (one line on stderr).",
    )
    parser.add_argument("image", metavar="IMAGE.exr", help="the image to measure")
    parser.add_argument("reference", metavar="REFERENCE.exr", help="the reference image")
    parser.add_argument(
        "--map",
        default=None,
        metavar="OUT.exr",
        help="also write the squared-error map to OUT.exr (linear float32) and a false-colour "
        "preview of the per-pixel relative error, log-scaled, to OUT.png",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object instead of the summary line"
    )
    # SUPPRESS: without a default here, `--debug compare` keeps the top-level flag's value.
    parser.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks"
    )


def run_compare(args: argparse.Namespace) -> int:
    """The `compare` command: print the errors of args.image against args.reference, and
    write the error map if args.map; 0 when done (bad input raises a ClrenderError)."""
    paths = map_paths(args.map) if args.map is not None else None
    if paths is not None:
        check_outputs_spare_inputs(
            paths, (args.image, args.reference), "--map", "an input or its preview"
        )
    image, image_metadata = read_image(args.image, "image")
    reference, reference_metadata = read_image(args.reference, "reference", image.shape)
    errors = image_errors(image, reference, noise_from_metadata(reference_metadata, args.reference))
    warnings = reference_warnings(image_metadata, reference_metadata, args.reference)
    if image_metadata.get("partial") == 1:
        warnings.insert(0, partial_warning("image", args.image))
    for warning in warnings:
        print(f"clrender: warning: {warning}", file=sys.stderr)
    scale = None
    if paths is not None:
        labels = {"image": str(args.image), "reference": str(args.reference)}
        labels |= {key: value for key, value in errors.as_dict().items() if value is not None}
        scale = write_error_map(paths, image, reference, labels)
    if args.json:
        record = {"image": str(args.image), "reference": str(args.reference)}
        record |= errors.as_dict()
        if paths is not None:
            record |= {"map": str(paths[0]), "preview": str(paths[1])}
            record |= {"preview_scale": [scale.bottom, scale.top]}
        print(json.dumps(record))
        return 0
    print(errors.summary_line())
    if paths is not None:
        print(f"wrote {paths[0]} (squared error) and {paths[1]} ({scale.describe()})")
    return 0
