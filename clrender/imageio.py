"""Image output: linear float32 OpenEXR with render metadata, and an 8-bit sRGB PNG preview
(encoded by Pillow).

Both writers are atomic and checked: the bytes go to a temporary file in the destination's
directory (".<name>.<pid>.<random>.tmp"), which is read back (an EXR's float32 pixels and a
PNG's 8-bit ones must come back exactly: a full disk can leave a short file without any error
from the OpenEXR library), flushed to disk (fsync), and only then replaces the requested name
with os.replace, and the directory entry is flushed too. A reader never sees a half-written
file under that name; a failed write leaves the old file and raises OutputPathError naming the
path. `write_all_atomically` does this for several files at once: every file is written and
checked before the first one replaces its old version (an image and its preview stay a pair).
A writer killed before its rename leaves its temporary file; the next write to that name
removes the ones whose process is gone. `check_writable` validates an output path up front,
before any rendering starts.

EXR attributes: the standard ones plus one per metadata entry. OpenEXR's int attribute is
32-bit and its float attribute single precision, so integers outside the int32 range (seeds up
to 2^32, ray counts) are stored as decimal strings, and floats lose digits beyond ~7.
"""

from __future__ import annotations

import glob
import os
import re
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image, PngImagePlugin

from clrender.errors import ClrenderError

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
LONG_INTEGER = re.compile(r"-?[1-9][0-9]{9,}")  # the digits of an integer beyond int32
NAME_MAX = 255  # bytes in one file name (Linux, macOS, Windows alike)
PATH_MAX = 4096  # bytes in a whole path (Linux; longer ones fail with ENAMETOOLONG)
SRGB_PERCEPTUAL = 0  # the sRGB chunk's rendering intent
SRGB_BLOCK = 1 << 18  # values per block of the sRGB encoding (2 MB float64 temporaries)
# Attributes every scanline EXR carries; read_exr leaves them out of the metadata it returns.
STANDARD_EXR_ATTRIBUTES = {
    "channels",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "pixelAspectRatio",
    "screenWindowCenter",
    "screenWindowWidth",
    "type",
}


class OutputPathError(ClrenderError):
    """An output file cannot be written where requested."""


def check_writable(path: str | os.PathLike) -> Path:
    """Fail early with a one-line error if `path` cannot be created or replaced. Missing
    folders are fine when the nearest existing one is writable: the writers create them."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    too_long = [part for part in path.parts if len(os.fsencode(part)) > NAME_MAX]
    if too_long:
        raise OutputPathError(
            f"cannot write {str(path)[:60]}...: a name in the path is over {NAME_MAX} bytes"
        )
    if len(os.fsencode(str(path.absolute()))) >= PATH_MAX:
        raise OutputPathError(
            f"cannot write {str(path)[:60]}...: the path is over {PATH_MAX} bytes in all"
        )
    if path.exists() and not path.is_file() and not path.is_dir():
        raise OutputPathError(f"cannot write {path}: it is not a regular file (a device or FIFO)")
    if path.is_dir():
        raise OutputPathError(f"cannot write {path}: it is a directory")
    existing = nearest_existing(directory)
    if not existing.is_dir():
        raise OutputPathError(f"cannot write {path}: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK) or not can_create_in(existing):
        raise OutputPathError(f"cannot write {path}: directory {existing} is not writable")
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputPathError(f"cannot write {path}: the existing file is read-only")
    return path


def nearest_existing(directory: Path) -> Path:
    """directory, or its nearest ancestor that exists (a file there is reported by the caller)."""
    while not directory.exists() and directory != directory.parent:
        directory = directory.parent
    return directory


def can_create_in(directory: Path) -> bool:
    """Whether a file can be created in `directory`, tried for real: os.access says yes to
    root on a read-only directory, and knows nothing of read-only mounts."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".clrender-probe.", suffix=".tmp")
    except OSError:
        return False
    os.close(fd)
    os.unlink(name)
    return True


def current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class MissingChannelsError(ValueError):
    """An EXR has no R, G or B channel (the bindings raise ValueError for a damaged file too)."""


class IncompleteWrite(OSError):
    """A file came back from disk other than it was written (a full disk, a failing device)."""


# Writes the file at a temporary path (and raises OSError, or IncompleteWrite after reading it
# back, if it is not all there).
FileWriter = Callable[[Path], None]


def temp_prefix(path: Path) -> str:
    """Temporary files of `path` are named <prefix><random>.tmp; the prefix holds the writer's
    process id, so that a stale one (its writer killed) can be told from one being written."""
    return f".{path.name}.{os.getpid()}."


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def remove_stale_temps(path: Path) -> list[Path]:
    """Remove the temporary files of `path` whose writing process is gone; the removed ones."""
    removed = []
    for temp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        owner = temp.name[len(path.name) + 2 :].split(".", 1)[0]
        if owner.isdigit() and int(owner) > 0 and not process_alive(int(owner)):
            temp.unlink(missing_ok=True)
            removed.append(temp)
    return removed


def flush_to_disk(path: Path) -> None:
    """fsync a file: its data must be on the device before it replaces the old file."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def flush_directory(directory: Path) -> None:
    """fsync a directory (the renames in it), where the file system allows it."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems cannot fsync a directory: the rename still happened
        pass
    finally:
        os.close(fd)


def make_temp(path: Path) -> Path:
    fd, temp_name = tempfile.mkstemp(dir=path.parent, prefix=temp_prefix(path), suffix=".tmp")
    os.close(fd)
    temp = Path(temp_name)
    temp.chmod(0o666 & ~current_umask())  # mkstemp's 0600 would outlive the rename
    return temp


def write_all_atomically(jobs: Sequence[tuple[str | os.PathLike, FileWriter]]) -> list[Path]:
    """For each (path, write): write(temp) to a temporary file beside path (its missing folders
    created), each checked by its writer and flushed to disk; then every temporary file
    replaces its path. On any error (KeyboardInterrupt included) every temporary file is
    removed and every old file stays; OutputPathError names the path whose write failed."""
    paths = [check_writable(path) for path, _ in jobs]
    temps: list[Path] = []
    try:
        for path, (_, write) in zip(paths, jobs, strict=True):
            temp = None
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                remove_stale_temps(path)
                temp = make_temp(path)
                temps.append(temp)
                write(temp)
                flush_to_disk(temp)
            except (OSError, RuntimeError) as err:  # RuntimeError: the OpenEXR library's
                reason = getattr(err, "strerror", None) or str(err) or type(err).__name__
                # OpenEXR names the file: 'Failed to write ... to image file "<temp>". No space
                # left on device.'; the user knows the path, not the temporary file
                reason = reason.replace(f'image file "{temp}"', "its temporary file")
                reason = reason.replace(f'"{temp}"', "its temporary file")
                raise OutputPathError(f"cannot write {path}: {reason}") from err
        for path, temp in zip(paths, temps, strict=True):
            os.replace(temp, path)
    except BaseException:
        for temp in temps:
            temp.unlink(missing_ok=True)
        raise
    for directory in {path.parent for path in paths}:
        flush_directory(directory)
    return paths


def write_atomically(path: str | os.PathLike, write: FileWriter) -> Path:
    """write_all_atomically of one file."""
    return write_all_atomically([(path, write)])[0]


def incomplete(temp: Path, detail: str) -> IncompleteWrite:
    free = os.statvfs(temp.parent).f_bavail if hasattr(os, "statvfs") else None
    hint = "; the disk is full" if free == 0 else " (a full disk?)"
    return IncompleteWrite(0, f"the written file is incomplete: {detail}{hint}")


# --- OpenEXR ---------------------------------------------------------------------------------


def exr_attribute(value: object) -> int | np.ndarray | str:
    """A metadata value as an EXR attribute: int32 for an integer that fits, double for a
    float (a 0-d float64 array: the bindings write a Python float as a 32-bit float), string
    otherwise (an integer beyond int32 as its decimal digits: metadata_value reads it back)."""
    if isinstance(value, bool | np.bool_):
        return int(value)
    if isinstance(value, int | np.integer):
        value = int(value)
        return value if INT32_MIN <= value <= INT32_MAX else str(value)
    if isinstance(value, float | np.floating):
        return np.array(float(value), np.float64)
    return str(value)


def metadata_value(value: object) -> object:
    """An EXR attribute as exr_attribute was given it: a double as a float, an integer beyond
    int32 (written as its digits) as an int; other values as the bindings read them."""
    if isinstance(value, np.ndarray) and value.dtype == np.float64 and value.size == 1:
        return float(value.reshape(()))
    if isinstance(value, str) and LONG_INTEGER.fullmatch(value):
        number = int(value)
        if not INT32_MIN <= number <= INT32_MAX:
            return number
    return value


def rgb_float32(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32, C-contiguous: the only layout the OpenEXR bindings write correctly."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {image.shape}")
    return np.ascontiguousarray(image, np.float32)


def write_exr(
    path: str | os.PathLike,
    image: np.ndarray,
    metadata: dict | None = None,
    layers: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write a linear RGB float32 EXR (ZIP compression) with metadata attributes and optional
    named layers beside RGB (see exr_writer)."""
    pixels = rgb_float32(image)
    header = exr_header(metadata)
    return write_atomically(path, exr_writer(pixels, header, layers))


def exr_header(metadata: dict | None) -> dict:
    """The EXR header of an RGB float32 image with these metadata attributes."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (metadata or {}).items():
        if key in STANDARD_EXR_ATTRIBUTES:
            raise ValueError(f"metadata key {key!r} clashes with a standard EXR attribute")
        header[key] = exr_attribute(value)
    return header


def exr_layer(name: str, values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A layer as the bindings write it: (H, W) uint32 or float32 (one channel `name`), or
    (H, W, 3) float32 (channels name.R, name.G, name.B), C-contiguous."""
    values = np.asarray(values)
    if values.shape[:2] != shape or values.ndim not in (2, 3) or values.shape[2:] not in ((), (3,)):
        raise ValueError(
            f"layer {name!r}: shape {values.shape}, expected {shape} or {shape + (3,)}"
        )
    dtype = (
        np.uint32 if np.issubdtype(values.dtype, np.integer) or values.dtype == bool else np.float32
    )
    return np.ascontiguousarray(values, dtype)


def exr_writer(
    pixels: np.ndarray, header: dict, layers: dict[str, np.ndarray] | None = None
) -> FileWriter:
    """Writes the EXR (RGB, then each named layer: integer ones as UINT channels, the others as
    FLOAT, three-channel ones as name.R, name.G, name.B), then reads it back: every channel must
    come back bit for bit (the library can leave a short file on a full disk without an
    error)."""
    shape = pixels.shape[:2]
    channels = {"RGB": pixels}
    for name, values in (layers or {}).items():
        if name in ("RGB", "R", "G", "B"):
            raise ValueError(f"layer name {name!r} clashes with the image's own channels")
        channels[name] = exr_layer(name, values, shape)

    def write(temp: Path) -> None:
        with OpenEXR.File(dict(header), dict(channels)) as exr:  # the bindings edit both
            exr.write(str(temp))
        try:
            back = read_exr_channels(temp)
        except (RuntimeError, ValueError) as err:  # ValueError: a file cut in its pixel data
            raise incomplete(temp, f"{temp.stat().st_size} bytes that do not read back") from err
        for name, values in channels.items():
            got = back.get(name)
            if got is None or got.shape != values.shape or got.tobytes() != values.tobytes():
                raise incomplete(temp, f"its {name} pixels read back differently")

    return write


def read_exr_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every channel group of an EXR as the bindings read it: "RGB" (H, W, 3), a layer written
    as name.R/G/B as (H, W, 3), single channels as (H, W)."""
    with OpenEXR.File(str(path)) as exr:
        return {name: np.array(channel.pixels) for name, channel in exr.channels().items()}


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """The (H, W, 3) float32 RGB pixels of an EXR and its non-standard attributes. The R, G
    and B channels are read by name, whatever other channels the file holds (an A channel, or
    named ones such as count or variance.R); MissingChannelsError if one of the three is
    missing."""
    # separate_channels: by default the bindings group R, G, B with A into one "RGBA" array
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        # Copy inside the block: the bindings empty the header dict when the file closes.
        header = exr.header()
        metadata = {
            k: metadata_value(v) for k, v in header.items() if k not in STANDARD_EXR_ATTRIBUTES
        }
        channels = exr.channels()
        missing = [name for name in "RGB" if name not in channels]
        if missing:
            raise MissingChannelsError(
                f"the EXR has no {', '.join(missing)} channel (its channels: "
                f"{', '.join(sorted(channels)) or 'none'})"
            )
        pixels = np.stack([channels[name].pixels for name in "RGB"], axis=-1)
    return pixels.astype(np.float32, copy=False), metadata


# --- PNG -------------------------------------------------------------------------------------


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of values clamped to [0, 1]; NaN -> 0."""
    c = np.clip(np.nan_to_num(np.asarray(linear, np.float64), nan=0.0), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def srgb8(linear: np.ndarray) -> np.ndarray:
    """8-bit sRGB code values, rounded to nearest. Computed SRGB_BLOCK values at a time: the
    float64 temporaries of a whole image would be the peak memory of a large render."""
    linear = np.asarray(linear)
    flat = linear.reshape(-1)
    codes = np.empty(flat.shape, np.uint8)
    for start in range(0, flat.size, SRGB_BLOCK):
        block = flat[start : start + SRGB_BLOCK]
        codes[start : start + SRGB_BLOCK] = np.floor(srgb_encode(block) * 255.0 + 0.5).astype(
            np.uint8
        )
    return codes.reshape(linear.shape)


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write the sRGB-encoded, clamped 8-bit preview of a linear RGB image."""
    return write_atomically(path, png_writer(image))


def png_writer(image: np.ndarray) -> FileWriter:
    """Writes the preview PNG of a linear RGB image (Pillow), then reads it back: its pixels
    must come back exactly."""
    codes = srgb8(rgb_float32(image))
    chunks = PngImagePlugin.PngInfo()
    chunks.add(b"sRGB", bytes([SRGB_PERCEPTUAL]))  # the code values are sRGB

    def write(temp: Path) -> None:
        Image.fromarray(codes).save(temp, format="PNG", pnginfo=chunks)
        try:
            back = read_png(temp)
        except (OSError, SyntaxError, ValueError, EOFError) as err:  # Pillow's "broken PNG"
            raise incomplete(temp, f"{temp.stat().st_size} bytes that do not read back") from err
        if back.shape != codes.shape or back.tobytes() != codes.tobytes():
            raise incomplete(temp, "its pixels read back differently")

    return write


def read_png(path: str | os.PathLike) -> np.ndarray:
    """The (H, W, 3) uint8 pixels of an RGB PNG (Pillow), the whole file checked: every chunk's
    CRC, through the end chunk (Pillow decodes the pixels of a file cut after them). Opened
    without Image.open's decompression-bomb limit: it would refuse a large render's preview."""
    with PngImagePlugin.PngImageFile(path) as png:
        png.verify()
    with PngImagePlugin.PngImageFile(path) as png:
        if png.mode != "RGB":
            raise ValueError(f"{path}: a {png.mode} PNG, not RGB")
        return np.asarray(png)
