"""Previews for notebooks: a render's images tone-mapped to 8-bit sRGB, as Pillow images
(Jupyter shows a PIL image returned by a cell; `RenderResult` shows itself the same way).

    clrender.preview(result)                    # every estimator's image, side by side, named
    clrender.preview(result.image, exposure=1)  # one image, twice as bright

Tone mapping: linear values times 2^exposure, clamped to [0, 1] and sRGB-encoded
(clrender.imageio.srgb8, the PNG preview's own transfer function). Small renders are enlarged
by an integer factor (nearest neighbour: every pixel stays a visible square) so that each image
is at least MIN_PREVIEW_SIDE pixels high, or by `scale`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from PIL import Image, ImageDraw

from clrender.compare import is_render_result
from clrender.errors import ParameterError
from clrender.imageio import srgb8

MIN_PREVIEW_SIDE = 192
MAX_PREVIEW_PIXELS = 2**26  # 64 M pixels (192 MB of RGB): a larger preview is refused
LABEL_HEIGHT = 14  # pixels above each named image for its name
GAP = 6  # pixels between images


def tone_map(image: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """(H, W, 3) uint8 sRGB of a linear RGB image scaled by 2^exposure."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        raise ParameterError(
            f"preview takes a non-empty (H, W, 3) RGB image, got shape {image.shape}"
        )
    if image.dtype.kind not in "biuf":
        raise ParameterError(f"preview takes an image of numbers, got dtype {image.dtype}")
    if (
        isinstance(exposure, bool)
        or not isinstance(exposure, int | float | np.integer | np.floating)
        or not np.isfinite(exposure)
    ):
        raise ParameterError(f"exposure must be a finite number of stops, got {exposure!r}")
    return srgb8(np.asarray(image, np.float64) * 2.0**exposure)


def preview(
    images: np.ndarray | Mapping[str, np.ndarray] | object,
    exposure: float = 0.0,
    scale: int | None = None,
) -> Image.Image:
    """A PIL image of one linear RGB image, of several ({name: image}, side by side with their
    names above), or of a RenderResult (all its estimators' images)."""
    if is_render_result(images):
        images = images.images
    named = dict(images) if isinstance(images, Mapping) else {"": images}
    if not named:
        raise ParameterError("preview has no image to show")
    tiles = {name: tone_map(image, exposure) for name, image in named.items()}
    height, width = next(iter(tiles.values())).shape[:2]
    if any(tile.shape[:2] != (height, width) for tile in tiles.values()):
        raise ParameterError("preview's images differ in size: show them one at a time")
    factor = max(1, -(-MIN_PREVIEW_SIDE // height)) if scale is None else scale
    if isinstance(factor, bool) or not isinstance(factor, int) or factor < 1:
        raise ParameterError(f"scale must be a positive integer, got {scale!r}")
    label = LABEL_HEIGHT if any(named) else 0
    side_w, side_h = width * factor, height * factor
    canvas_pixels = (len(tiles) * (side_w + GAP) - GAP) * (side_h + label)
    if canvas_pixels > MAX_PREVIEW_PIXELS:
        raise ParameterError(
            f"a preview at scale {factor} would be {canvas_pixels:,} pixels, more than "
            f"{MAX_PREVIEW_PIXELS:,}: use a smaller scale"
        )
    canvas = Image.new("RGB", (len(tiles) * (side_w + GAP) - GAP, side_h + label), "white")
    draw = ImageDraw.Draw(canvas)
    for index, (name, tile) in enumerate(tiles.items()):
        left = index * (side_w + GAP)
        enlarged = Image.fromarray(tile).resize((side_w, side_h), Image.Resampling.NEAREST)
        canvas.paste(enlarged, (left, label))
        if name:
            draw.text((left + 2, 1), name, fill="black")
    return canvas
