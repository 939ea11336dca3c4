"""Image output: linear float32 OpenEXR with render metadata, and an 8-bit sRGB PNG preview.

Both writers are atomic: the bytes go to a temporary file in the destination's directory,
which then replaces the requested name with os.replace, so a reader never sees a half-written
file under that name (an interrupted or failed write leaves the old file, or none).
`check_writable` validates an output path up front, before any rendering starts.

EXR attributes: the standard ones plus one per metadata entry. OpenEXR's int attribute is
32-bit and its float attribute single precision, so integers outside the int32 range (seeds up
to 2^32, ray counts) are stored as decimal strings, and floats lose digits beyond ~7.
"""

from __future__ import annotations

import contextlib
import os
import struct
import tempfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import OpenEXR

from clrender.errors import ClrenderError

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
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
    """Fail early with a one-line error if `path` cannot be created or replaced."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise OutputPathError(f"cannot write {path}: it is a directory")
    if not directory.is_dir():
        raise OutputPathError(f"cannot write {path}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK) or not can_create_in(directory):
        raise OutputPathError(f"cannot write {path}: directory {directory} is not writable")
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputPathError(f"cannot write {path}: the existing file is read-only")
    return path


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


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it replaces `path`, on any error
    (including KeyboardInterrupt) it is removed."""
    path = Path(path)
    fd, temp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    temp = Path(temp_name)
    temp.chmod(0o666 & ~current_umask())  # mkstemp's 0600 would outlive the rename
    try:
        yield temp
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def write_atomically(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Run write(temp_path), then move the result onto `path`; errors name the path."""
    path = check_writable(path)
    try:
        with atomic_path(path) as temp:
            write(temp)
    except OSError as err:
        raise OutputPathError(f"cannot write {path}: {err.strerror or err}") from err
    return path


# --- OpenEXR ---------------------------------------------------------------------------------


def exr_attribute(value: object) -> int | float | str:
    """A metadata value as an EXR attribute (int32, float or string)."""
    if isinstance(value, bool | np.bool_):
        return int(value)
    if isinstance(value, int | np.integer):
        value = int(value)
        return value if INT32_MIN <= value <= INT32_MAX else str(value)
    if isinstance(value, float | np.floating):
        return float(value)
    return str(value)


def rgb_float32(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32, C-contiguous: the only layout the OpenEXR bindings write correctly."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {image.shape}")
    return np.ascontiguousarray(image, np.float32)


def write_exr(path: str | os.PathLike, image: np.ndarray, metadata: dict | None = None) -> Path:
    """Write a linear RGB float32 EXR (ZIP compression) with metadata attributes."""
    pixels = rgb_float32(image)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (metadata or {}).items():
        if key in STANDARD_EXR_ATTRIBUTES:
            raise ValueError(f"metadata key {key!r} clashes with a standard EXR attribute")
        header[key] = exr_attribute(value)

    def write(temp: Path) -> None:
        with OpenEXR.File(header, {"RGB": pixels}) as exr:
            exr.write(str(temp))

    return write_atomically(path, write)


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """The (H, W, 3) float32 RGB pixels of an EXR and its non-standard attributes."""
    with OpenEXR.File(str(path)) as exr:
        # Copy inside the block: the bindings empty the header dict when the file closes.
        header = exr.header()
        metadata = {k: v for k, v in header.items() if k not in STANDARD_EXR_ATTRIBUTES}
        channels = exr.channels()
        if "RGB" in channels:
            pixels = np.array(channels["RGB"].pixels, np.float32)
        else:
            pixels = np.stack([channels[c].pixels for c in "RGB"], axis=-1).astype(np.float32)
    return pixels, metadata


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


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def encode_png(rgb8: np.ndarray) -> bytes:
    """An 8-bit RGB PNG (filter 0 on every row) carrying an sRGB chunk."""
    height, width, _ = rgb8.shape
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    rows = np.zeros((height, 1 + 3 * width), np.uint8)  # leading 0 = filter type None
    rows[:, 1:] = np.ascontiguousarray(rgb8, np.uint8).reshape(height, 3 * width)
    return b"".join(
        [
            PNG_SIGNATURE,
            png_chunk(b"IHDR", header),
            png_chunk(b"sRGB", b"\x00"),  # rendering intent: perceptual
            png_chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)),
            png_chunk(b"IEND", b""),
        ]
    )


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write the sRGB-encoded, clamped 8-bit preview of a linear RGB image."""
    data = encode_png(srgb8(rgb_float32(image)))
    return write_atomically(path, lambda temp: temp.write_bytes(data))


def png_chunks(data: bytes) -> Iterator[tuple[bytes, bytes]]:
    """(kind, body) of each chunk of a PNG file, CRCs checked."""
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError("not a PNG file")
    pos = len(PNG_SIGNATURE)
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        if zlib.crc32(kind + body) != crc:
            raise ValueError(f"PNG chunk {kind!r} has a bad CRC")
        yield kind, body
        pos += 12 + length


def decode_png(data: bytes) -> np.ndarray:
    """Decode the PNGs encode_png writes (8-bit RGB, filter 0): for tests and tools."""
    chunks: dict[bytes, bytes] = {}
    for kind, body in png_chunks(data):
        chunks[kind] = chunks.get(kind, b"") + body
    width, height, depth, color_type = struct.unpack(">IIBB", chunks[b"IHDR"][:10])
    if (depth, color_type) != (8, 2):
        raise ValueError("only 8-bit RGB PNGs are supported")
    rows = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(height, -1)
    if np.any(rows[:, 0] != 0):
        raise ValueError("only PNG filter type 0 is supported")
    return rows[:, 1:].reshape(height, width, 3).copy()
