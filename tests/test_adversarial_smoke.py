"""The adversarial-input harness (bench/adversarial_inputs.py): its classifier on synthetic
runs, one per branch; its catalog (sizes, stable ids, valid mutations); and a tiny slice run
as a user would against this repository, known cases landing in their classes (a missing
scene file is a clean error, a valid render ok, a snippet raising RuntimeError a traceback, a
NaN image a wrong image)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

adv = pytest.importorskip("adversarial_inputs")
catalog = pytest.importorskip("adversarial_catalog")

from adversarial_catalog import (  # noqa: E402
    ANY,
    ERROR,
    ERROR_OR_WARNING,
    PARTIAL,
    SAME_IMAGE,
    WARNING,
    Case,
)
from adversarial_inputs import Facts, classify  # noqa: E402

ERROR_LINE = "clrender: error: scene file 'missing.toml' does not exist\n"
TRACE = (
    "Traceback (most recent call last):\n"
    '  File "<string>", line 1, in <module>\n'
    "RuntimeError: boom\n"
)


# --- the classifier, one branch at a time ------------------------------------------------------


@pytest.mark.parametrize(
    "exit_code, stderr, facts, expect, outcome",
    [
        # ok, warning
        (0, "", Facts(image="finite"), ANY, "ok"),
        (0, "clrender: warning: no emitter\n", Facts(image="finite"), ANY, "warning"),
        (0, "stray line\n", Facts(image="finite"), ANY, "warning"),
        (0, "clrender: warning: plane\n", Facts(image="finite"), WARNING, "warning"),
        # clean errors
        (2, ERROR_LINE, Facts(prior="intact"), ERROR, "clean error"),
        (143, "clrender: interrupted: 7 of 64 pixels (partial=1)\n",
         Facts(image="finite", partial=True, started=True), PARTIAL, "clean error"),
        (-15, "", Facts(started=False), PARTIAL, "clean error"),
        # tracebacks
        (1, TRACE, Facts(), ANY, "traceback"),
        (0, TRACE, Facts(image="finite"), ANY, "traceback"),
        (2, "1 error generated.\n" + ERROR_LINE, Facts(), ANY, "traceback"),
        (-11, "", Facts(), ANY, "traceback"),
        # wrong images
        (0, "", Facts(image="nonfinite"), ANY, "wrong image"),
        (0, "", Facts(image="unreadable"), ANY, "wrong image"),
        (0, "", Facts(), ANY, "wrong image"),
        (0, "", Facts(image="finite"), ERROR, "wrong image"),
        (0, "", Facts(image="finite", black=True, base_black=False), ANY, "wrong image"),
        (0, "", Facts(image="finite", differs=True), SAME_IMAGE, "wrong image"),
        (0, "", Facts(image="finite"), WARNING, "wrong image"),
        (0, "", Facts(image="finite"), ERROR_OR_WARNING, "wrong image"),
        # data lost
        (2, ERROR_LINE, Facts(prior="replaced"), ANY, "data lost"),
        (0, "", Facts(image="empty", prior="empty"), ANY, "data lost"),
        (2, ERROR_LINE, Facts(prior="missing"), ANY, "data lost"),
        (2, ERROR_LINE, Facts(prior="intact", stale=[".out.exr.123.tmp"]), ANY, "data lost"),
        (-15, "", Facts(started=True), PARTIAL, "data lost"),
        # hang
        (None, "", Facts(), ANY, "hang"),
    ],
)  # fmt: skip
def test_classify_each_branch(exit_code, stderr, facts, expect, outcome):
    assert classify(exit_code, stderr, facts, expect)[0] == outcome


def test_classify_exemptions():
    # a black image is right where the case says it may be, or where clrender warned
    black = Facts(image="finite", black=True, base_black=False)
    assert classify(0, "", black, ANY, black_ok=True)[0] == "ok"
    assert classify(0, "clrender: warning: no emitter\n", black, ANY)[0] == "warning"
    # a case without an image to write (an API call, --help)
    assert classify(0, "", Facts(), ANY, needs_image=False)[0] == "ok"
    # a successful render replaces the previous output: not data lost
    assert classify(0, "", Facts(image="finite", prior="replaced"), ANY)[0] == "ok"


def test_progress_bar_redraws_are_not_error_lines():
    stderr = "\rbox [##....] 10.0% 1.0 s elapsed, ETA 9.0 s  \r\nclrender: interrupted\r\n"
    assert adv.stderr_lines(stderr) == ["clrender: interrupted"]
    tqdm = (
        "\rbox 8x8: 0px [00:00, ?px/s]\rbox 8x8:  18%|##  | 11991/65536 [00:00<00:02, "
        "21705.25px/s]\r\nclrender: interrupted: the image holds 13704 of 65536 pixels\r\n"
    )
    assert adv.stderr_lines(tqdm) == [
        "clrender: interrupted: the image holds 13704 of 65536 pixels"
    ]
    assert adv.shows_progress(tqdm.encode()) and not adv.shows_progress(b"0/64 [00:00<?")
    assert adv.message(["Traceback (most recent call last):", "  x", "KeyError: 1"]) == (
        "KeyError: 1"
    )


def test_changed_pixels_and_difference():
    base = np.ones((4, 4, 3), np.float32)
    same = base.copy()
    assert adv.changed_share(same, base) == 0.0 and adv.relative_difference(same, base) == 0.0
    moved = base.copy()
    moved[0, :2] = 0.5
    assert adv.changed_share(moved, base) == 2 / 16


# --- the catalog ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def every_case():
    return catalog.catalog()


def test_catalog_sizes_and_stable_ids(every_case):
    first, second = every_case, catalog.catalog()
    assert [c.id for c in first] == [c.id for c in second]
    assert [c.files for c in first] == [c.files for c in second]
    counts = {kind: sum(c.kind == kind for c in first) for kind in catalog.KINDS}
    assert counts == catalog.CATALOG_COUNTS
    assert all(c.description and "\n" not in c.description for c in first)


def test_every_numeric_field_kind_gets_every_value(every_case):
    values = [c for c in every_case if c.id.startswith("scene-value-")]
    kinds = {c.id.split("-value-")[1] for c in values}
    assert len(values) == 22 * len(catalog.VALUES) == len(kinds)


def test_scene_mutations_parse_where_they_should(every_case):
    import tomllib

    scenes = catalog.shipped_scenes()
    text = scenes["cornell-box"]
    scaled = tomllib.loads(catalog.scaled_text(text, 1e3))
    assert scaled["camera"]["look_from"] == [278e3, 278e3, -800e3]
    assert scaled["camera"]["up"] == [0.0, 1.0, 0.0] and scaled["camera"]["fov"] == 40.0
    assert scaled["shapes"][6]["radius"] == 90e3
    for name, text in scenes.items():
        for label, _ in catalog.FAR_SHAPES:
            document = tomllib.loads(catalog.far_geometry(text, label))
            assert document["shapes"][-1]["material"] == "adversarial_black", name
    for case in every_case:
        if case.expect == SAME_IMAGE or case.id.startswith("scene-control-"):
            tomllib.loads(case.files["scene.toml"].decode())


def test_select_takes_a_nested_spread_slice():
    cases = catalog.catalog(["cli", "api"])
    small, large = catalog.select(cases, 3, None), catalog.select(cases, 6, None)
    assert len(small) == 6 and {c.id for c in small} <= {c.id for c in large}
    assert [c.id for c in catalog.select(cases, None, ["cli-scene-fifo"])] == ["cli-scene-fifo"]


# --- a slice run against this repository ------------------------------------------------------


def snippet_case(label: str, body: str, image: bool = False) -> Case:
    """A Python API case made here, not in the catalog (its body runs as main())."""
    return catalog.api_case(label, label, body, ANY, image=image)


@pytest.mark.device
def test_known_cases_land_in_their_classes(tmp_path, every_case):
    # Two at a time, as `--jobs 2` runs them (each case is a new process).
    runner = adv.Runner(adv.REPO, tmp_path, timeout=60, memory_gb=6)
    known = {c.id: c for c in every_case}
    nan = "import numpy as np\nnp.save('image.npy', np.full((2, 2, 3), np.nan))"
    expected = [
        (known["cli-scene-missing-file"], "clean error"),
        (known["cli-valid"], "ok"),
        (known["api-settings-width-minus1"], "clean error"),
        (known["scene-encoding-junk"], "clean error"),
        (snippet_case("broken", 'raise RuntimeError("boom")'), "traceback"),
        (snippet_case("nan", nan, image=True), "wrong image"),
    ]
    results = adv.run_cases(runner, [case for case, _ in expected], jobs=2, log=lambda _: None)
    for (case, outcome), result in zip(expected, results, strict=True):
        assert result["id"] == case.id and result["outcome"] == outcome, result
    assert results[4]["message"] == "RuntimeError: boom"
    assert list(tmp_path.iterdir()) == []  # every case directory removed


@pytest.mark.device
def test_main_writes_json_and_tables(tmp_path, capsys):
    # SIGTERM mid-render (after the first tile): the finished pixels written, exit 143. (An
    # early signal's outcome depends on what is loading at that moment: not a smoke test.)
    argv = ["--ids", "signal-sigterm-tile", "--out", str(tmp_path), "--label", "smoke"]
    data = adv.main(argv)
    (case,) = data["cases"]
    assert case["outcome"] == "clean error" and case["exit"] == 143, case
    assert case["facts"]["partial"] and case["facts"]["started"], case
    saved = json.loads((tmp_path / "smoke.json").read_text())
    assert saved["checkout"]["commit"] and saved["summary"]["total"]["tried"] == 1
    report = (tmp_path / "smoke.md").read_text()
    assert "| total | 1 | 0 | 1 | 0 | 0 | 0 | 0 | 0 |" in report, report
    capsys.readouterr()
    adv.main(["--compare", str(tmp_path / "smoke.json"), str(tmp_path / "smoke.json")])
    assert "| total | 1 -> 1 | 0 -> 0 | 1 -> 1 |" in capsys.readouterr().out
