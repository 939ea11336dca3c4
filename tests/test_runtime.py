"""OpenCL runtime: device selection without prompts, clear errors, program building."""

import importlib.util
import os
import re
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from clrender import runtime as rt
from clrender.errors import DeviceError, KernelBuildError
from clrender.estimators.device_cells import _defines

REPO = Path(__file__).resolve().parent.parent


def test_first_device_by_default(monkeypatch):
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    assert rt.select_device() == rt.list_devices()[0]


def test_device_by_index_and_by_name_substring():
    devices = rt.list_devices()
    first = devices[0]
    assert rt.select_device("0") == first
    descriptions = [rt.describe_device(device).lower() for device in devices]
    if descriptions.count(descriptions[0]) > 1:
        pytest.skip("two devices alike here: only an index tells them apart")
    names = [device.name.strip().lower() for device in devices]
    if names.count(names[0]) == 1:
        assert rt.select_device(first.name.strip().upper()) == first  # a whole name
    description = descriptions[0]
    unique = next(
        description[i : i + length]
        for length in range(6, len(description) + 1)
        for i in range(len(description) - length + 1)
        if not any(description[i : i + length] in other for other in descriptions[1:])
    )
    assert rt.select_device(unique) == first


def fake_device(name, platform, version="OpenCL 3.0"):
    return SimpleNamespace(name=name, platform=SimpleNamespace(name=platform), version=version)


def test_a_device_name_part_that_several_devices_share_is_refused_not_guessed():
    # PoCL and Intel's runtime on one Xeon: "Intel" is in all three names; the first used to
    # win silently, so "--device Intel" rendered on PoCL
    devices = [
        fake_device("pthread-skylake-avx512-Intel(R) Xeon(R) Processor", "Portable Computing"),
        fake_device("Intel(R) Xeon(R) Processor", "Intel(R) OpenCL"),
        fake_device("pthread-Intel(R) Xeon(R) Processor", "Portable Computing", "PoCL rocketlake"),
    ]
    with pytest.raises(DeviceError) as err:
        rt.match_device("Intel", devices)
    message = str(err.value)
    assert "\n" not in message
    assert "'Intel' matches 3 devices (0, 1, 2)" in message and "2: pthread-Intel" in message
    assert rt.match_device("intel(r) xeon(r) processor", devices) is devices[1]  # whole name
    assert rt.match_device("Intel(R) OpenCL", devices) is devices[1]  # its platform
    assert rt.match_device("rocketlake", devices) is devices[2]  # its version string
    assert rt.match_device("skylake", devices) is devices[0]
    assert rt.match_device("1", devices) is devices[1]
    with pytest.raises(DeviceError, match="'3' matches nothing; accepted: 0: pthread-skylake"):
        rt.match_device("3", devices)


def test_unknown_device_lists_the_accepted_ones():
    with pytest.raises(DeviceError) as err:
        rt.select_device("no-such-device-xyz")
    assert "--device" in str(err.value) and "accepted: 0:" in str(err.value)
    with pytest.raises(DeviceError):
        rt.select_device("999")


@pytest.mark.parametrize("spec", ["0", "0:0", ":0"])
def test_pyopencl_ctx_is_honoured(monkeypatch, spec):
    monkeypatch.setenv("PYOPENCL_CTX", spec)
    assert rt.select_device() == rt.list_devices()[0]


def test_explicit_device_wins_over_pyopencl_ctx(monkeypatch):
    monkeypatch.setenv("PYOPENCL_CTX", "no-such-platform")
    assert rt.select_device("0") == rt.list_devices()[0]
    with pytest.raises(DeviceError, match="PYOPENCL_CTX platform"):
        rt.select_device()


def test_no_platform_says_what_to_install(monkeypatch):
    def no_platforms():
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")

    monkeypatch.setattr(cl, "get_platforms", no_platforms)
    with pytest.raises(DeviceError, match=r'pip install "pyopencl\[pocl\]"'):
        rt.list_devices()
    monkeypatch.setattr(cl, "get_platforms", lambda: [])
    with pytest.raises(DeviceError, match="no OpenCL platform"):
        rt.list_devices()


def test_platforms_without_devices_name_pocls_cache(monkeypatch, tmp_path):
    """PoCL offers no device when it cannot create its kernel cache (a read-only home): the
    error names the platforms and the cache, not 'install OpenCL' (before)."""

    class Empty:
        name = "Portable Computing Language"

        def get_devices(self):
            raise cl.RuntimeError("clGetDeviceIDs failed: DEVICE_NOT_FOUND")

    monkeypatch.setattr(cl, "get_platforms", lambda: [Empty()])
    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path / "ro"))
    with pytest.raises(DeviceError) as info:
        rt.list_devices()
    message = str(info.value)
    assert message.startswith("the OpenCL platforms (Portable Computing Language) offer no")
    assert f"make {tmp_path / 'ro'} writable" in message and "\n" not in message
    monkeypatch.delenv("POCL_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    with pytest.raises(DeviceError, match=f"make {tmp_path / 'xdg' / 'pocl'} writable"):
        rt.list_devices()


def test_build_failure_carries_the_compiler_log_with_file_and_line(runtime, tmp_path, monkeypatch):
    (tmp_path / "broken.cl").write_text(
        "// a kernel with a type error on line 3\n"
        "__kernel void broken(__global float *out) {\n"
        "    out[0] = undefined_symbol;\n"
        "}\n"
    )
    monkeypatch.setattr(rt, "kernels_dir", lambda: tmp_path)
    with pytest.raises(KernelBuildError) as err:
        runtime.build("broken.cl")
    message = str(err.value)
    assert f"{tmp_path / 'broken.cl'}:3:" in message
    assert "undefined_symbol" in message


def test_defines_reach_the_kernel_as_compile_time_constants(runtime, tmp_path, monkeypatch):
    (tmp_path / "defs.cl").write_text(
        "__kernel void defs(__global float *out) { out[0] = SCALE * (float)COUNT; }\n"
    )
    monkeypatch.setattr(rt, "kernels_dir", lambda: tmp_path)
    import numpy as np

    out = np.zeros(1, np.float32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=4)
    runtime.kernel("defs.cl", "defs", {"SCALE": 0.5, "COUNT": 6})(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    assert out[0] == 3.0


def test_programs_are_built_once_per_process(runtime):
    assert runtime.build("sampling.cl") is runtime.build("sampling.cl")
    assert runtime.kernel("sampling.cl", "fill_traced") is runtime.kernel(
        "sampling.cl", "fill_traced"
    )


def test_defines_spelled_alike_share_one_program(runtime, tmp_path, monkeypatch):
    """Values that give the same build options (8 and "8", 0.5 and float32 0.5) are one program,
    built once (bench/device_voronoi_speed.py passes "8" where the tests pass 8); values that
    do not (a flag and 1) are two."""
    (tmp_path / "spelled.cl").write_text(
        "__kernel void spelled(__global float *out) { out[0] = SCALE * (float)COUNT; }\n"
    )
    monkeypatch.setattr(rt, "kernels_dir", lambda: tmp_path)
    program = runtime.build("spelled.cl", {"COUNT": 8, "SCALE": 0.5})
    assert runtime.build("spelled.cl", {"COUNT": "8", "SCALE": np.float32(0.5)}) is program
    assert runtime.build("spelled.cl", {"SCALE": 0.5, "COUNT": np.int64(8)}) is program
    assert runtime.build("spelled.cl", {"COUNT": 9, "SCALE": 0.5}) is not program
    flag = runtime.build("spelled.cl", {"COUNT": True, "SCALE": 0.5})
    assert flag is not runtime.build("spelled.cl", {"COUNT": 1, "SCALE": 0.5})
    kernel = runtime.kernel("spelled.cl", "spelled", {"COUNT": "8", "SCALE": 0.5})
    assert kernel is runtime.kernel("spelled.cl", "spelled", {"COUNT": 8, "SCALE": "0.5f"})


# Build options the kernels need (the single-precision ones: any device has them)
DEFINES_OF = {name: _defines("single") for name in ("voronoi_cells.cl", "voronoi_sums.cl")}
WARMED_KERNELS = [
    (source_file, name)
    for source_file in sorted(rt.WARM_UP_FILES)
    for name in re.findall(r"__kernel\s+void\s+(\w+)", (rt.kernels_dir() / source_file).read_text())
]


@pytest.mark.parametrize("source_file, name", WARMED_KERNELS)
def test_warm_up_launches_do_nothing(runtime, source_file, name):
    """Every kernel of the render is launched once with all scalars 0 (Runtime.warm_up): each
    work-item must return before touching memory, so a sentinel buffer stays as it was."""
    program = runtime.build(source_file, DEFINES_OF.get(source_file))
    kernel = cl.Kernel(program, name)
    sentinel = np.full(16, 0xA5A5A5A5, np.uint32)
    dummy = runtime.upload(sentinel)
    arguments = rt.warm_up_arguments(source_file, name, dummy)
    kernel(runtime.queue, (runtime.local_size,), (runtime.local_size,), *arguments).wait()
    after = np.empty_like(sentinel)
    cl.enqueue_copy(runtime.queue, after, dummy)
    assert np.array_equal(after, sentinel)


def test_warm_up_is_counted_as_build_time_once(runtime):
    defines = {"CLRENDER_WARM_UP_TEST": 1}  # a program of its own, built for this test only
    before = rt.thread_build_seconds()
    runtime.kernel("voronoi_sums.cl", "pixel_moments", defines)
    key = (runtime.context.int_ptr, "voronoi_sums.cl", (("CLRENDER_WARM_UP_TEST", "1"),))
    assert any(entry[:3] == key for entry in rt._WARMED)
    first = rt.thread_build_seconds() - before
    assert first > 0
    again = rt.thread_build_seconds()
    runtime.kernel("voronoi_sums.cl", "pixel_moments", defines)
    assert rt.thread_build_seconds() - again < first / 10


def test_kernel_parameters_are_read_from_the_source(tmp_path):
    source = tmp_path / "k.cl"
    source.write_text(
        "__kernel void k(uint count, const float x, __global float *out,\n"
        "                __local uint *scratch)\n{}\n"
        "__kernel void bad(float3 v) {}\n"
        "__kernel SOME_ATTRIBUTE void\nwith_attribute(uint n, __global uint *out) {}\n"
    )
    assert rt.kernel_parameters(source, "k") == ("uint", "float", "global", "local")
    assert rt.kernel_parameters(source, "with_attribute") == ("uint", "global")
    with pytest.raises(KernelBuildError, match="float3 v"):
        rt.kernel_parameters(source, "bad")
    with pytest.raises(KernelBuildError, match="no __kernel void missing"):
        rt.kernel_parameters(source, "missing")


@pytest.mark.parametrize("count, padded", [(1, 64), (64, 64), (65, 128), (0, 64), (1000, 1024)])
def test_global_sizes_are_padded_to_the_local_size(count, padded):
    assert rt.padded_global_size(count) == padded
    assert rt.launch_global_size(count) == max(padded, rt.MIN_LAUNCH_SIZE)
    if count:
        assert rt.launch_global_size(rt.MIN_LAUNCH_SIZE + count) == rt.MIN_LAUNCH_SIZE + padded


def test_kernels_are_found_from_the_source_checkout():
    assert (rt.kernels_dir() / "rng.h").is_file()


def test_an_installed_wheel_carries_the_kernels(tmp_path):
    """Build the wheel, unpack it elsewhere and import clrender from there: kernels/ must be
    found inside the package, whatever the current directory."""
    if importlib.util.find_spec("hatchling") is None:
        pytest.skip("hatchling is not installed (it comes with the test extras)")
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(REPO),
        ],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0, build.stderr
    wheel = next(tmp_path.glob("clrender-*.whl"))
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    assert (site / "clrender" / "kernels" / "sampling.cl").is_file()
    # the packaged kernels are under test, not a developer's override of them
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop(rt.KERNELS_DIR_VARIABLE, None)
    probe = subprocess.run(
        [sys.executable, "-c", "import clrender.runtime as r; print(r.kernels_dir())"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    assert probe.returncode == 0, probe.stderr
    assert Path(probe.stdout.strip()) == site / "clrender" / "kernels"


@pytest.mark.parametrize("asked", [False, True])
def test_a_successful_build_log_is_shown_only_when_asked(runtime, tmp_path, monkeypatch, asked):
    # Intel's CPU runtime logs every build ("Compilation started ... Done."), which pyopencl
    # reports as a CompilerWarning: two stray lines on stderr in every render
    (tmp_path / "chatty.cl").write_text("__kernel void chatty(__global int *out) { *out = 1; }\n")
    monkeypatch.setattr(rt, "kernels_dir", lambda: tmp_path)
    build = cl.Program.build

    def chatty_build(self, *args, **kwargs):
        warnings.warn("Non-empty compiler output encountered.", cl.CompilerWarning, stacklevel=2)
        return build(self, *args, **kwargs)

    monkeypatch.setattr(cl.Program, "build", chatty_build)
    if asked:
        monkeypatch.setenv("PYOPENCL_COMPILER_OUTPUT", "1")
    else:
        monkeypatch.delenv("PYOPENCL_COMPILER_OUTPUT", raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runtime.build("chatty.cl", {"ASKED": asked})  # its own defines: built, not cached
    # (asked, the device's own log may come too: Intel's does)
    assert (cl.CompilerWarning in [w.category for w in caught]) == asked


def test_platform_defines_choose_the_bvh_call_on_pocl_only(runtime):
    # PoCL calls the BVH traversal (faster there), every other platform inlines it (Intel's CPU
    # runtime returns wrong hits from the called form): kernels/geometry.h BVH_FUNCTION
    from clrender.runtime import build_options

    assert "-DCLRENDER_BVH_CALLED" in build_options((), "Portable Computing Language")
    assert "-DCLRENDER_BVH_CALLED" not in build_options((), "Intel(R) OpenCL")
    platform = runtime.device.platform.name.strip()
    expected = platform == "Portable Computing Language"
    assert ("-DCLRENDER_BVH_CALLED" in build_options((), platform)) == expected


def test_portable_math_gives_the_clang_builtins_bits(runtime, tmp_path, monkeypatch):
    """kernels/vecmath.h's Sqrt, Fabs, Copysign, Floor, Rint and Ctz: the clang builtins on PoCL
    (CLRENDER_CLANG_BUILTINS), the OpenCL C builtins elsewhere (Oclgrind has no code for the
    LLVM intrinsics the clang builtins become: bench/oclgrind_check.py). Both forms, built
    here, give the same bits."""
    import shutil

    shutil.copy(rt.kernels_dir() / "vecmath.h", tmp_path / "vecmath.h")
    (tmp_path / "portable_math.cl").write_text(
        "#ifdef PORTABLE\n#undef CLRENDER_CLANG_BUILTINS\n#endif\n"
        '#include "vecmath.h"\n'
        "__kernel void portable_math(__global const float *x, __global float *out)\n"
        "{\n"
        "    uint i = get_global_id(0);\n"
        "    float v = x[i];\n"
        "    out[6 * i] = Sqrt(Fabs(v));\n"
        "    out[6 * i + 1] = Fabs(v);\n"
        "    out[6 * i + 2] = Copysign(1.5f, v);\n"
        "    out[6 * i + 3] = Floor(v);\n"
        "    out[6 * i + 4] = Rint(v);\n"
        "    out[6 * i + 5] = (float)Ctz(as_uint(v) | 0x80000000u);\n"
        "}\n"
    )
    monkeypatch.setattr(rt, "kernels_dir", lambda: tmp_path)
    gen = np.random.default_rng(4)
    x = np.concatenate(
        [
            [0.0, -0.0, 0.5, 1.5, 2.5, -2.5, -0.5, 1e-40, -1e-40, 3.0e38, np.inf, -np.inf],
            gen.uniform(-100.0, 100.0, 52),
        ]
    ).astype(np.float32)
    x_buf = runtime.upload(x)
    results = []
    for defines in ({}, {"PORTABLE": True}):
        out = np.empty(6 * len(x), np.float32)
        out_buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=out.nbytes)
        kernel = runtime.kernel("portable_math.cl", "portable_math", defines)
        kernel(runtime.queue, (len(x),), None, x_buf, out_buf)
        cl.enqueue_copy(runtime.queue, out, out_buf)
        results.append(out.reshape(-1, 6))
    np.testing.assert_array_equal(results[0].view(np.uint32), results[1].view(np.uint32))
    # and the values are the functions' (Ctz: the lowest set bit of the float's bits)
    np.testing.assert_array_equal(results[1][:, 3], np.floor(x))
    np.testing.assert_array_equal(results[1][:, 4], np.rint(x))
    bits = x.view(np.uint32) | np.uint32(0x80000000)
    lowest = np.array([(int(b) & -int(b)).bit_length() - 1 for b in bits], np.float32)
    np.testing.assert_array_equal(results[1][:, 5], lowest)


def test_platform_defines_give_the_clang_builtins_to_pocl_only():
    from clrender.runtime import build_options

    assert "-DCLRENDER_CLANG_BUILTINS" in build_options((), "Portable Computing Language")
    assert "-DCLRENDER_CLANG_BUILTINS" not in build_options((), "Oclgrind")
    assert "-DCLRENDER_CLANG_BUILTINS" not in build_options((), "Intel(R) OpenCL")


def test_platform_defines_keep_intels_vectoriser_off_the_trace_kernels():
    from clrender.runtime import build_options

    # Intel's CPU runtime packs work-items of a kernel into vector lanes: the trace kernels
    # ran 2.7x (SIMD) and 4x (megakernel) slower so, the Voronoi cells 4x (README: Intel's CPU
    # runtime); its define gives them intel_vec_len_hint(1) (kernels/vecmath.h
    # KERNEL_SCALAR_WORK_ITEMS), PoCL's and other platforms' source stays as it was
    assert "-DCLRENDER_SCALAR_WORK_ITEMS" in build_options((), "Intel(R) OpenCL")
    assert "-DCLRENDER_SCALAR_WORK_ITEMS" not in build_options((), "Portable Computing Language")
    assert "-DCLRENDER_SCALAR_WORK_ITEMS" not in build_options((), "Oclgrind")


def test_programs_are_cached_per_kernels_folder(runtime, tmp_path, monkeypatch):
    # The same file name in another CLRENDER_KERNELS_DIR is another program: a process that
    # changes the folder (bench scripts comparing source trees) builds the new folder's source
    values = {}
    for value in (1, 2):
        folder = tmp_path / f"tree{value}"
        folder.mkdir()
        (folder / "which_tree.cl").write_text(
            f"__kernel void which_tree(__global int *out) {{ *out = {value}; }}\n"
        )
        monkeypatch.setenv(rt.KERNELS_DIR_VARIABLE, str(folder))
        out = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, 4)
        runtime.kernel("which_tree.cl", "which_tree")(runtime.queue, (1,), None, out)
        host = np.zeros(1, np.int32)
        cl.enqueue_copy(runtime.queue, host, out)
        values[value] = int(host[0])
    assert values == {1: 1, 2: 2}
