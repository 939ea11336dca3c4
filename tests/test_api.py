"""The public front door (clrender.load_scene, clrender.render) and the registry's promise that
a new estimator is one entry plus its formula."""

import re
from pathlib import Path

import numpy as np
import pytest

import clrender
from clrender.estimators import registry
from clrender.estimators.registry import Estimator, PixelSums

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example_runs(capsys):
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Python") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    exec(compile(code, "README.md (Python section)", "exec"), {})
    assert capsys.readouterr().out.startswith("(32, 32, 3) float32 ")


def test_render_returns_the_image_as_float32_array():
    result = clrender.render("analytic:edge", spp=4, sampler="independent", resolution=(8, 6))
    assert result.image.shape == (6, 8, 3)
    assert result.image.dtype == np.float32
    assert result.settings.estimator.name == "mc"
    assert result.film.complete


def test_render_equals_the_pipeline_with_the_same_settings(runtime):
    from clrender.analytic import AnalyticSource
    from clrender.pipeline import RenderSettings
    from clrender.pipeline import render as render_pipeline
    from clrender.sampling import make_sampler

    front = clrender.render("analytic:mix", spp=16, estimator="fvor", resolution=(12, 8), seed=5)
    source = AnalyticSource.for_scene("analytic:mix", runtime.queue, 12, 8)
    settings = RenderSettings(12, 8, make_sampler("sppp", 16), "fvor", seed=5)
    direct = render_pipeline(runtime, source, settings)
    assert np.array_equal(front.image, direct.image)


@pytest.mark.parametrize(
    "arguments, message",
    [
        ({"spp": 0}, "spp must be a positive integer"),
        ({"sampler": "halton"}, "unknown sampler"),
        ({"estimator": "voronoi"}, "unknown estimator"),
        ({"sampler": "independent", "estimator": "vor_sn"}, "needs the auxiliary nuclei"),
        ({"sampler": "uniform"}, "now called 'independent'"),
        ({"sampler": "zsobol", "spp": 12}, "power of two"),
        ({"sampler": "stratified", "spp": 12}, "perfect square"),
        ({"sampler": "zsobol", "spp": 2**20, "resolution": 4096}, "at most 256 samples"),
        ({"sampler": "zsobol", "spp": 1, "resolution": (70000, 1)}, "largest side 65536"),
        ({"sampler": "stratified", "spp": 2**22}, "at most 1048576 samples"),
        ({"resolution": (8, 0)}, "resolution must be"),
        ({"resolution": "big"}, "resolution must be"),
    ],
)
def test_bad_arguments_are_one_line_errors(arguments, message):
    with pytest.raises(clrender.ClrenderError, match=message) as info:
        clrender.render("analytic:edge", **{"spp": 4, **arguments})
    assert "\n" not in str(info.value)


def test_load_scene_names_shipped_scenes_and_analytic_images():
    scene = clrender.load_scene("cornell-box")
    assert scene.resolution
    assert clrender.load_scene("analytic:disc") == "analytic:disc"
    with pytest.raises(clrender.ClrenderError, match="no-such-scene"):
        clrender.load_scene("no-such-scene")


def half_self_normalised(sums: PixelSums) -> np.ndarray:
    return 0.5 * registry.self_normalised(sums)


def test_a_new_estimator_is_one_registry_entry(monkeypatch):
    """An entry and its formula are all a new estimator needs: the command line's validation,
    the sampler check, the device sums and the redraws all follow from the entry."""
    entry = Estimator(
        "half_vor_sn",
        "half of vor_sn (a test entry)",
        half_self_normalised,
        cells="sppp",
        needs_aux=True,
        device_sums=True,
    )
    monkeypatch.setitem(registry.ESTIMATORS, entry.name, entry)
    options = {"spp": 16, "resolution": (12, 8), "seed": 2}
    for backend in ("device", "qhull"):
        options["voronoi_backend"] = backend
        new = clrender.render("analytic:mix", estimator="half_vor_sn", **options)
        old = clrender.render("analytic:mix", estimator="vor_sn", **options)
        assert np.array_equal(new.image, 0.5 * old.image)
    with pytest.raises(clrender.ClrenderError, match="half_vor_sn.*auxiliary nuclei"):
        clrender.render("analytic:mix", sampler="independent", estimator="half_vor_sn", spp=4)
