"""Rays leave a surface by a bound on that hit point's own float rounding, not by a fraction of
the scene's extent: an object far away changes nothing near the camera.

Before: the offset was 1e-5 x the scene's diagonal, so a radius-1 sphere at y = 1e8 pushed
every secondary ray of the Cornell box about 1000 units off its surface (22 % darker)."""

from pathlib import Path

import numpy as np
import pytest

from clrender.pipeline import RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.sampling import make_sampler
from clrender.scene import SceneWarning, load_scene, scenes_dir
from clrender.trace import PathTracer

SIZE = 24


def cornell_with(tmp_path: Path, extra: str) -> Path:
    text = (scenes_dir() / "cornell-box.toml").read_text() + extra
    path = tmp_path / "cornell-plus.toml"
    path.write_text(text)
    return path


def render_scene(runtime, scene) -> np.ndarray:
    source = PathTracerSource(PathTracer(runtime, scene, max_depth=4), SIZE, SIZE)
    settings = RenderSettings(SIZE, SIZE, make_sampler("independent", 4), "mc", seed=2)
    return render(runtime, source, settings).film.image()


FAR_SPHERE = """
[[shapes]]
name = "far ball"
type = "sphere"
center = [278.0, {height}, 278.0]
radius = 1.0
material = "white"
"""


@pytest.mark.parametrize("height", [1e6, 1e8])
def test_a_far_sphere_changes_no_pixel(runtime, tmp_path, height):
    reference = render_scene(runtime, load_scene("cornell-box"))
    with pytest.warns(SceneWarning, match="float32 steps"):  # the far ball itself is noise
        far = load_scene(cornell_with(tmp_path, FAR_SPHERE.format(height=height)))
    assert np.array_equal(render_scene(runtime, far), reference)


# A black ground quad 2e9 wide under the box: rays that leave through the open front end on it
# instead of in the void, which changes nothing; nothing inside the box may move
BLACK_GROUND = """
[materials.black]
type = "diffuse"
albedo = [0.0, 0.0, 0.0]

[[shapes]]
name = "ground"
type = "quad"
corner = [-1e9, -10.0, 1e9]
edge1 = [2e9, 0.0, 0.0]
edge2 = [0.0, 0.0, -2e9]
material = "black"
"""


def test_a_huge_black_ground_quad_changes_no_pixel(runtime, tmp_path):
    reference = render_scene(runtime, load_scene("cornell-box"))
    grounded = load_scene(cornell_with(tmp_path, BLACK_GROUND))
    assert np.array_equal(render_scene(runtime, grounded), reference)  # before: 20 % darker
