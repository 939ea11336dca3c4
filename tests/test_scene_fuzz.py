"""Seeded mutations of the shipped scenes: each either loads and renders a finite image, or is
refused with one line (ClrenderError: SceneError, ParameterError); never another exception.

A mutation replaces one number with an extreme or wrong-typed value, deletes or duplicates a
line, or misspells a key. Rendered at 4 x 4, 1 spp, depth 2 (every loadable mutation is
rendered, so that values the loader accepts are shown to be safe on the device)."""

import re

import numpy as np
import pytest

from clrender.errors import ClrenderError
from clrender.pipeline import RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.sampling import make_sampler
from clrender.scene import list_scenes, load_scene, scenes_dir
from clrender.trace import PathTracer

MUTATIONS_PER_SCENE = 75
NUMBER = re.compile(r"(?<![\w.])-?\d+(\.\d+)?([eE][-+]?\d+)?(?![\w.])")
REPLACEMENTS = [
    "0", "-1", "0.5", "1e-40", "1e-30", "1e39", "1e308", "-1e18", "1e17", "nan", "inf",
    '"x"', "true", "[]", "[1.0, 2.0]", "{}", "65536", "-0.0", "1e18", "-1e-37", "3e-38",
]  # fmt: skip


def mutate(text: str, rng: np.random.Generator) -> str:
    lines = text.splitlines()
    kind = rng.integers(4)
    if kind == 0:  # one number replaced
        spots = list(NUMBER.finditer(text))
        spot = spots[rng.integers(len(spots))]
        value = REPLACEMENTS[rng.integers(len(REPLACEMENTS))]
        return text[: spot.start()] + value + text[spot.end() :]
    line = int(rng.integers(len(lines)))
    if kind == 1:  # a line deleted
        return "\n".join(lines[:line] + lines[line + 1 :])
    if kind == 2:  # a line duplicated
        return "\n".join(lines[: line + 1] + lines[line:])
    keys = [i for i, entry in enumerate(lines) if re.match(r"^\w+ = ", entry)]
    line = keys[rng.integers(len(keys))]
    return "\n".join(lines[:line] + [lines[line][:-1] + "x" + lines[line][-1:]] + lines[line + 1 :])


def render_tiny(runtime, scene) -> np.ndarray:
    source = PathTracerSource(PathTracer(runtime, scene, max_depth=2), 4, 4)
    settings = RenderSettings(4, 4, make_sampler("independent", 1), "mc", seed=1)
    return render(runtime, source, settings).film.image()


# NumPy's RuntimeWarnings (overflow, invalid value) would leak onto a user's stderr and, worse,
# precede a misleading error (1e308 edges overflowed and were called "degenerate quad").
@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("name", list_scenes())
def test_mutated_scenes_render_finite_or_fail_in_one_line(runtime, tmp_path, name):
    text = (scenes_dir() / f"{name}.toml").read_text()
    rng = np.random.default_rng(sum(map(ord, name)))
    outcomes = {"rendered": 0, "refused": 0}
    for k in range(MUTATIONS_PER_SCENE):
        path = tmp_path / f"{name}-{k}.toml"
        path.write_text(mutate(text, rng))
        try:
            image = render_tiny(runtime, load_scene(path))
        except ClrenderError as err:
            message = str(err)
            assert message and "\n" not in message and "Traceback" not in message, message
            outcomes["refused"] += 1
            continue
        assert np.isfinite(image).all(), path.read_text()
        outcomes["rendered"] += 1
    assert outcomes["rendered"] > 5 and outcomes["refused"] > 5, outcomes
