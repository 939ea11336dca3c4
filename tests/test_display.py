"""Notebook previews: tone mapping against the PNG preview's transfer function, layout of
several named images, a RenderResult's own rich display, one-line errors."""

import io

import numpy as np
import PIL.Image
import pytest

import clrender
from clrender.display import GAP, LABEL_HEIGHT, MIN_PREVIEW_SIDE, preview, tone_map
from clrender.errors import ParameterError
from clrender.imageio import srgb8


def test_exposure_scales_linear_values_by_powers_of_two():
    image = np.linspace(0, 0.4, 4 * 5 * 3).reshape(4, 5, 3)
    np.testing.assert_array_equal(tone_map(image, exposure=1.0), srgb8(image * 2))
    np.testing.assert_array_equal(tone_map(image), srgb8(image))


def test_one_image_is_enlarged_by_whole_pixels():
    image = np.zeros((6, 8, 3))
    image[0, 0] = 1.0
    shown = preview(image)
    factor = -(-MIN_PREVIEW_SIDE // 6)
    assert shown.size == (8 * factor, 6 * factor)
    pixels = np.asarray(shown)
    assert (pixels[:factor, :factor] == 255).all() and (pixels[factor:, factor:] == 0).all()


def test_named_images_sit_side_by_side_under_their_names():
    images = {"a": np.zeros((4, 4, 3)), "b": np.ones((4, 4, 3))}
    shown = preview(images, scale=10)
    assert shown.size == (2 * 40 + GAP, 40 + LABEL_HEIGHT)
    pixels = np.asarray(shown)
    assert (pixels[LABEL_HEIGHT:, :40] == 0).all() and (
        pixels[LABEL_HEIGHT:, 40 + GAP :] == 255
    ).all()
    assert (pixels[:LABEL_HEIGHT, :40] < 255).any()  # the name is drawn


@pytest.mark.device
def test_a_render_result_displays_itself_in_a_notebook():
    result = clrender.render("analytic:mix", spp=4, estimators=["mc_n", "vor_sn"], resolution=8)
    png = PIL.Image.open(io.BytesIO(result._repr_png_()))
    assert png.size == preview(result).size and png.width > 2 * (png.height - LABEL_HEIGHT)


@pytest.mark.parametrize(
    "images, options, message",
    [
        (np.zeros((4, 4)), {}, "RGB image"),
        ({"a": np.zeros((4, 4, 3)), "b": np.zeros((5, 4, 3))}, {}, "differ in size"),
        (np.zeros((4, 4, 3)), {"exposure": float("nan")}, "exposure"),
        (np.zeros((4, 4, 3)), {"exposure": "1"}, "exposure"),
        (np.zeros((4, 4, 3)), {"exposure": None}, "exposure"),
        (np.full((4, 4, 3), "a"), {}, "image of numbers"),
        (np.zeros((4, 4, 3)), {"scale": 0}, "scale"),
        ({}, {}, "no image"),
        (np.zeros((0, 0, 3)), {}, "non-empty"),
        (np.zeros((16, 16, 3)), {"scale": 100_000}, "use a smaller scale"),  # 2.6e11 pixels
    ],
)
def test_bad_previews_are_one_line_errors(images, options, message):
    with pytest.raises(ParameterError, match=message):
        preview(images, **options)
