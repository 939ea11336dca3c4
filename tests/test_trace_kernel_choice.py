"""Which kernel traces a render (clrender.trace.choose_trace_kernel): the simd kernel on CPU
devices by default, the megakernel elsewhere, either on request; the same image whichever, and
the render says which ran (result, EXR metadata, summary, JSON; a cluster render's tasks')."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest
from scene_texts import mesh_text

import clrender
from clrender import cli
from clrender.cluster import LocalExecutor, RenderJob, render_on
from clrender.errors import ParameterError
from clrender.imageio import read_exr
from clrender.pipeline import RenderSettings
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import TRACE_KERNEL_CHOICES, PathTracer, choose_trace_kernel

SCENES = Path(__file__).resolve().parents[1] / "scenes"

pytestmark = pytest.mark.device


CPU = SimpleNamespace(type=cl.device_type.CPU)
GPU = SimpleNamespace(type=cl.device_type.GPU)


def test_auto_chooses_simd_on_a_cpu_and_the_megakernel_on_other_devices():
    assert choose_trace_kernel(CPU) == "simd"
    assert choose_trace_kernel(GPU) == "megakernel"
    accelerator = SimpleNamespace(type=cl.device_type.ACCELERATOR)
    assert choose_trace_kernel(accelerator) == "megakernel"
    for asked in ("megakernel", "simd"):  # a request is kept on any device and scene
        assert choose_trace_kernel(GPU, asked) == asked
        assert choose_trace_kernel(CPU, asked, load_scene("veach-mis")) == asked
    assert TRACE_KERNEL_CHOICES == ("auto", "megakernel", "simd")


@pytest.mark.parametrize(
    "scene, kernel",
    [
        ("mitsuba-cbox", "simd"),  # quads, diffuse, a quad emitter
        ("cornell-box", "simd"),  # and a sphere
        ("cornell-box-glossy", "simd"),  # and rough conductors, a dielectric
        ("furnace", "simd"),
        ("veach-mis", "megakernel"),  # sphere emitters: light samples lane by lane
    ],
)
def test_auto_on_a_cpu_takes_simd_where_the_paths_run_in_its_lanes(scene, kernel):
    assert choose_trace_kernel(CPU, "auto", load_scene(scene)) == kernel
    assert choose_trace_kernel(GPU, "auto", load_scene(scene)) == "megakernel"


def test_auto_on_a_cpu_leaves_triangle_scenes_to_the_megakernel(tmp_path):
    text = (SCENES / "mitsuba-cbox.toml").read_text()
    triangle = mesh_text([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]], [[0, 1, 2]])
    scene_file = tmp_path / "box.toml"
    scene_file.write_text(text + triangle)
    scene = load_scene(scene_file)
    assert len(scene.triangles) == 1
    assert choose_trace_kernel(CPU, "auto", scene) == "megakernel"


@pytest.mark.parametrize("bad", ["fast", "", None, 1, "SIMD"])
def test_a_bad_trace_kernel_is_one_line(runtime, bad):
    for call in (
        lambda: clrender.render("cornell-box", spp=16, resolution=4, trace_kernel=bad),
        lambda: PathTracer(runtime, load_scene("cornell-box"), trace_kernel=bad),
    ):
        with pytest.raises(ParameterError) as err:
            call()
        message = str(err.value)
        assert "\n" not in message
        assert "trace_kernel must be one of auto, megakernel, simd" in message


def test_the_same_image_from_either_kernel_and_the_result_says_which(runtime):
    is_cpu = bool(runtime.device.type & cl.device_type.CPU)
    results = {
        asked: clrender.render(
            "cornell-box",
            spp=8,
            sampler="sobol",
            estimators=["mc"],
            resolution=(20, 12),
            seed=3,
            trace_kernel=asked,
        )
        for asked in TRACE_KERNEL_CHOICES
    }
    assert results["megakernel"].trace_kernel == "megakernel"
    assert results["simd"].trace_kernel == "simd"
    assert results["auto"].trace_kernel == ("simd" if is_cpu else "megakernel")
    reference = results["megakernel"].image
    assert reference.any()
    for asked, result in results.items():
        np.testing.assert_array_equal(result.image, reference, err_msg=asked)
        assert result.stats.rays == results["megakernel"].stats.rays
    # an analytic image has no paths, so no trace kernel
    assert clrender.render("analytic:edge", spp=8, resolution=8).trace_kernel is None


def test_the_command_line_records_the_kernel(tmp_path, capsys):
    out = tmp_path / "box.exr"
    command = ["render", "cornell-box", "--res", "12x8", "--spp", "4", "-o", str(out)]
    assert cli.main([*command, "--trace-kernel", "megakernel", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["trace_kernel"] == "megakernel"
    assert read_exr(out)[1]["trace_kernel"] == "megakernel"
    assert cli.main([*command, "--trace-kernel", "simd"]) == 0
    assert "simd kernel" in capsys.readouterr().out
    assert read_exr(out)[1]["trace_kernel"] == "simd"
    with pytest.raises(SystemExit):
        cli.main([*command, "--trace-kernel", "fastest"])
    assert "invalid choice: 'fastest'" in capsys.readouterr().err


def test_a_cluster_job_carries_the_request_and_reports_the_tasks_kernel(runtime):
    pytest.importorskip("distributed")
    scene = load_scene("cornell-box")
    settings = RenderSettings(12, 8, make_sampler("independent", 4), ["mc"], 1)
    images = {}
    for asked in ("megakernel", "simd"):
        job = RenderJob.of(scene, settings, 8, False, None, asked)
        result = render_on(LocalExecutor(), job, tasks=3)
        assert result.trace_kernel == asked
        images[asked] = result.image
    np.testing.assert_array_equal(images["simd"], images["megakernel"])


def test_a_path_tracer_is_the_megakernel_unless_asked(runtime):
    # benchmarks and tests compare against PathTracer(runtime, scene): the megakernel
    scene = load_scene("mitsuba-cbox")
    assert PathTracer(runtime, scene).trace_kernel == "megakernel"
    is_cpu = bool(runtime.device.type & cl.device_type.CPU)
    expected = "simd" if is_cpu else "megakernel"
    assert PathTracer(runtime, scene, trace_kernel="auto").trace_kernel == expected


def test_auto_leaves_a_scene_in_a_bvh_to_the_megakernel(runtime):
    # cornell-box's sphere put in a BVH (as 97 quads or more would be, or many spheres): the
    # simd kernel would intersect it lane by lane
    scene = load_scene("cornell-box")
    tracer = PathTracer(runtime, scene, trace_kernel="auto", brute_force_limit=-1)
    assert len(tracer.bvh_nodes) > 0
    assert tracer.trace_kernel == "megakernel"
    assert choose_trace_kernel(CPU, "auto", scene, has_bvh=True) == "megakernel"
    assert choose_trace_kernel(CPU, "simd", scene, has_bvh=True) == "simd"
