"""The public front door (clrender.load_scene, clrender.render) and the registry's promise that
a new estimator is one entry plus its formula."""

import ast
import pickle
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import PIL.Image
import pytest

import clrender
from clrender.estimators import registry
from clrender.estimators.registry import Estimator, EstimatorWarning, PixelSums

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.device
def test_readme_python_example_runs_as_a_notebook_cell(capsys):
    # The README's Python section, run as written; its last line is the cell's value
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Python") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    tree = ast.parse(code)
    last = tree.body.pop()
    assert isinstance(last, ast.Expr)
    namespace: dict = {}
    exec(compile(tree, "README.md (Python section)", "exec"), namespace)
    shown = eval(compile(ast.Expression(last.value), "README.md (last line)", "eval"), namespace)
    lines = capsys.readouterr().out.splitlines()
    mse = {line.split()[0]: float(line.split()[2]) for line in lines}
    assert list(mse) == ["mc_n", "vor_sn", "fvor"]
    # One trace: the Voronoi estimators beat mc_n on these very samples (2.7x here)
    assert mse["vor_sn"] < mse["mc_n"] / 2 and mse["fvor"] < mse["mc_n"] / 2
    assert isinstance(shown, PIL.Image.Image)
    assert shown.width > 3 * shown.height * 0.9  # three images side by side


@pytest.mark.device
def test_a_poor_estimator_sampler_pair_warns_once_with_advice():
    with pytest.warns(EstimatorWarning, match="use --estimator mc_n") as caught:
        clrender.render("analytic:edge", spp=16, estimators=["mc", "vor_sn"], resolution=(8, 6))
    assert len(caught) == 1


@pytest.mark.device
def test_render_returns_the_image_as_float32_array():
    result = clrender.render("analytic:edge", spp=4, sampler="independent", resolution=(8, 6))
    assert result.image.shape == (6, 8, 3)
    assert result.image.dtype == np.float32
    assert result.settings.estimator.name == "mc"
    assert result.film.complete
    assert result.max_depth is None and result.russian_roulette is None  # no paths


def test_render_result_says_which_paths_it_traced():
    for depth, roulette in ((3, True), (5, False)):
        result = clrender.render(
            "cornell-box", spp=4, resolution=(8, 6), max_depth=depth, russian_roulette=roulette
        )
        assert (result.max_depth, result.russian_roulette) == (depth, roulette)


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


@pytest.mark.device
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
        ({"overlap": "no"}, "overlap must be True or False"),
        ({"progress": "yes"}, "progress must be a callable"),
        # an analytic image traces no paths, yet a wrong depth is refused as for a scene
        ({"max_depth": -1}, "max_depth must be an integer"),
        ({"max_depth": "x"}, "max_depth must be an integer"),
        ({"executor": "x"}, "executor must be None"),
        ({"executor": 3}, "executor must be None"),
    ],
)
def test_bad_arguments_are_one_line_errors(arguments, message):
    with pytest.raises(clrender.ClrenderError, match=message) as info:
        clrender.render("analytic:edge", **{"spp": 4, **arguments})
    assert "\n" not in str(info.value)


@pytest.mark.device
def test_numpy_integers_are_accepted_and_progress_takes_a_bool_or_a_callable(capsys):
    # A sweep such as `for n in 2 ** np.arange(2, 5)` passes NumPy integers
    calls = []
    result = clrender.render(
        "analytic:edge",
        spp=np.int64(4),
        resolution=(np.int32(8), np.int64(6)),
        progress=lambda done, total: calls.append((done, total)),
    )
    assert result.settings.sampler.n == 4 and type(result.settings.sampler.n) is int
    assert result.image.shape == (6, 8, 3)
    assert calls[-1] == (48, 48)
    same = clrender.render("analytic:edge", spp=4, resolution=(8, 6), progress=False)
    assert np.array_equal(same.image, result.image)
    clrender.render("analytic:edge", spp=4, resolution=(8, 6), progress=True)


def test_load_scene_names_shipped_scenes_and_analytic_images():
    scene = clrender.load_scene("cornell-box")
    assert scene.resolution
    assert clrender.load_scene("analytic:disc") == "analytic:disc"
    with pytest.raises(clrender.ClrenderError, match="no-such-scene"):
        clrender.load_scene("no-such-scene")


def half_self_normalised(sums: PixelSums) -> np.ndarray:
    return 0.5 * registry.self_normalised(sums)


@pytest.mark.device
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


@pytest.mark.device
def test_pvor_over_a_poisson_count_has_the_mean_its_advice_states():
    # Over the SPPP sampler's Poisson count pvor's mean is (1 - e^-n) times the pixel's value
    # (the empty pixels' 0): at n = 1 the image mean is 0.632 of the exact one, and the pair is
    # warned about; 16 384 pixels, the bound 4 standard errors of the pixels' mean
    with pytest.warns(EstimatorWarning, match=r"e\^-n = 0.37"):
        result = clrender.render("analytic:smooth", spp=1, estimator="pvor", resolution=128)
    from clrender.analytic import AnalyticSource
    from clrender.api import runtime_for

    exact = AnalyticSource.for_scene("analytic:smooth", runtime_for(None).queue, 128, 128)
    truth = exact.pixel_integrals().mean()
    values = result.image.mean(axis=-1).ravel()
    error = values.std() / np.sqrt(values.size)
    assert abs(values.mean() - (1 - np.exp(-1)) * truth) < 4 * error
    assert abs(values.mean() - truth) > 40 * error  # the bias is real, not noise


@pytest.mark.parametrize("n, warned", [(6, True), (7, False)])
@pytest.mark.parametrize("estimator", ["mc_n", "vor_sn", "fvor", "cvor", "pvor", "ivor_sn"])
def test_empty_pixel_advice_stops_where_the_empty_pixels_stop_mattering(estimator, n, warned):
    from clrender.estimators import pairing_advice

    advice = pairing_advice(estimator, "sppp", n)
    assert (advice is not None) == warned
    if warned:
        assert advice.startswith(f"{estimator} over the sppp sampler at n = {n}")
        assert "unbiased at this n: mc over sppp, ivor, or mc over --sampler sobol" in advice
    assert pairing_advice(estimator, "sobol", 1) is None  # fixed counts: no empty pixel


@pytest.mark.parametrize(
    "arguments", [{"scene": "analytic:foo"}, {"max_depth": -1}, {"executor": "x"}]
)
def test_bad_arguments_are_refused_before_any_advice(arguments):
    # vor_sn at n = 2 gets the small-n advice, but only for a render that will run
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(clrender.ParameterError):
            clrender.render(**{"scene": "analytic:edge", "spp": 2, "resolution": 4, **arguments})
    assert caught == []


@pytest.mark.parametrize("estimator", ["mc", "vor", "ivor"])
def test_estimators_unbiased_over_a_poisson_count_get_no_empty_pixel_advice(estimator):
    from clrender.estimators import pairing_advice

    advice = pairing_advice(estimator, "sppp", 1)
    assert advice is None or "e^-n" not in advice


@pytest.mark.parametrize("n, recommends_mc_n", [(2, False), (64, True)])
def test_the_mc_over_sppp_advice_recommends_mc_n_only_where_it_is_unbiased(n, recommends_mc_n):
    from clrender.estimators import pairing_advice

    advice = pairing_advice("mc", "sppp", n)
    assert advice.endswith("mc with --sampler sobol")
    assert ("mc_n or vor_sn" in advice) == recommends_mc_n


def test_the_version_and_the_compare_module_are_reachable(capsys):
    from clrender import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out == f"clrender {clrender.__version__}\n"
    # The README's `clrender.compare.read_reference` works after a plain `import clrender` (in
    # a new process: here another test may have imported the module already)
    code = "import clrender; print(callable(clrender.compare.read_reference))"
    root = str(Path(clrender.__file__).parents[1])
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root)
    assert shown.stdout == "True\n", shown.stderr


TIMES = ("time_s", "render_time_s")


def test_save_writes_what_the_command_line_writes(tmp_path, capsys):
    from clrender import cli
    from clrender.imageio import read_exr, read_exr_channels

    argv = ["cornell-box", "--res", "12x8", "--spp", "8", "--estimator", "mc_n,vor_sn"]
    assert cli.main(["render", *argv, "-o", str(tmp_path / "cli.exr"), "--quiet"]) == 0
    result = clrender.render(
        "cornell-box", spp=8, resolution=(12, 8), estimators=["mc_n", "vor_sn"]
    )
    written = result.save(tmp_path / "api")
    assert list(written) == ["mc_n", "vor_sn"]
    for name, pair in written.items():
        assert pair.exr == tmp_path / f"api.{name}.exr" and pair.png.is_file()
        pixels, metadata = read_exr(pair.exr)
        cli_pixels, cli_metadata = read_exr(tmp_path / f"cli.{name}.exr")
        assert pixels.tobytes() == cli_pixels.tobytes()
        assert metadata.keys() == cli_metadata.keys()
        for key, value in cli_metadata.items():
            if not key.endswith(TIMES):
                assert metadata[key] == value, key
        assert (
            read_exr_channels(pair.exr).keys()
            == read_exr_channels(tmp_path / f"cli.{name}.exr").keys()
        )
        assert (tmp_path / f"cli.{name}.png").read_bytes() == pair.png.read_bytes()


def test_save_needs_a_result_of_render(tmp_path):
    result = clrender.render("analytic:disc", spp=8, resolution=8)
    result.labels = None
    with pytest.raises(clrender.ParameterError, match="save the result of clrender.render"):
        result.save(tmp_path / "out.exr")
    assert not list(tmp_path.iterdir())


def test_save_keeps_the_previous_files_of_a_render_with_no_pixel(tmp_path):
    result = clrender.render("analytic:disc", spp=8, resolution=8)
    result.save(tmp_path / "out.exr")
    before = (tmp_path / "out.exr").read_bytes(), (tmp_path / "out.png").read_bytes()
    result.film.rendered[:] = False  # as a render interrupted before its first tile leaves it
    with pytest.raises(clrender.ParameterError, match="nothing to save"):
        result.save(tmp_path / "out.exr")
    assert ((tmp_path / "out.exr").read_bytes(), (tmp_path / "out.png").read_bytes()) == before


def test_a_signal_while_saving_waits_for_both_files(tmp_path, monkeypatch):
    """Ctrl-C as the EXR is renamed into place: the PNG is replaced too, then the
    KeyboardInterrupt comes (before: the new EXR stood beside the old PNG)."""
    import os
    import signal
    import time

    from clrender import imageio

    old = clrender.render("analytic:disc", spp=8, resolution=8, seed=1)
    old.save(tmp_path / "out.exr")
    old_png = (tmp_path / "out.png").read_bytes()
    new = clrender.render("analytic:disc", spp=8, resolution=8, seed=2)
    real_replace = os.replace

    def replace(source, target):
        real_replace(source, target)
        if str(target).endswith(".exr"):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)  # in a call: Python runs the signal's handler before it returns

    monkeypatch.setattr(imageio.os, "replace", replace)
    # Ctrl-C as at a terminal (a test run in the background ignores SIGINT)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            new.save(tmp_path / "out.exr")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert imageio.read_exr(tmp_path / "out.exr")[1]["seed"] == 2
    assert (tmp_path / "out.png").read_bytes() != old_png


@pytest.mark.device
def test_a_result_shows_itself_in_one_line():
    result = clrender.render("analytic:edge", spp=16, estimators=["mc_n", "vor_sn"], resolution=8)
    text = repr(result)
    assert "\n" not in text and len(text) < 400  # no film arrays
    assert text.startswith("<RenderResult 8x8 sppp 16 spp seed 0 [mc_n, vor_sn] ")
    assert " complete on " in text
    result.films["vor_sn"].rendered[:3] = False  # as an interrupted render leaves it
    assert "partial 61/64 pixels" in repr(result)


@pytest.mark.device
def test_errors_against_a_reference_result_take_its_own_noise():
    from clrender.compare import ReferenceWarning
    from clrender.report import own_noise

    reference = clrender.render(
        "analytic:smooth", spp=64, sampler="independent", estimator="mc", resolution=8, seed=1
    )
    image = clrender.render("analytic:smooth", spp=16, estimator="vor_sn", resolution=8)
    noise = own_noise(reference, "mc")
    assert noise is not None and noise > 0
    by_hand = clrender.image_errors(image.image, reference.image, noise)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # other seeds, the same scene: nothing to warn of
        errors = clrender.image_errors(image, reference)
    assert errors == by_hand and errors.reference_noise == noise
    # The same seed: warned, as `compare` warns of two EXRs
    same_seed = clrender.render("analytic:smooth", spp=16, estimator="mc_n", resolution=8, seed=1)
    with pytest.warns(ReferenceWarning, match="same seed"):
        clrender.image_errors(same_seed, reference)
    # Another scene: warned; a partial result: refused
    other = clrender.render("analytic:edge", spp=16, estimator="vor_sn", resolution=8)
    with pytest.warns(ReferenceWarning, match="is of scene"):
        clrender.image_errors(other, reference)
    reference.film.rendered[0] = False
    with pytest.raises(clrender.ParameterError, match="partial render \\(63 of 64 pixels\\)"):
        clrender.image_errors(image, reference)


@pytest.mark.device
def test_an_interrupted_render_stops_the_script_with_its_pixels(tmp_path, monkeypatch):
    """Ctrl-C in clrender.render raises RenderInterrupted (a KeyboardInterrupt) holding the
    finished pixels (before: render returned a partial image as if nothing had happened, and a
    loop of renders went on with black images)."""
    from clrender.film import Film
    from clrender.imageio import read_exr

    real_record, writes = Film.record, []

    def interrupted_record(film, *args):
        writes.append(1)
        if len(writes) == 2:
            raise KeyboardInterrupt
        return real_record(film, *args)

    monkeypatch.setattr(Film, "record", interrupted_record)
    with pytest.raises(KeyboardInterrupt) as info:
        clrender.render("analytic:disc", spp=16, resolution=64, tile_samples=16 * 1024)
    assert isinstance(info.value, clrender.RenderInterrupted)
    result = info.value.result
    done = result.film.rendered_count
    assert result.stats.interrupted and 0 < done < 64 * 64
    assert str(info.value).startswith(f"render interrupted: {done} of 4096 pixels finished")
    monkeypatch.setattr(Film, "record", real_record)
    copied = pickle.loads(pickle.dumps(info.value))  # as another process would get it
    assert str(copied) == str(info.value) and copied.result.film.rendered_count == done
    result.save(tmp_path / "partial.exr")
    assert read_exr(tmp_path / "partial.exr")[1]["partial"] == 1
