"""bench/portability.py, the suite on every OpenCL device: pytest's output read back (counts,
failing ids, the device named in the header), the ICD folder written for Intel's runtime, and
the device listing, which a child process, clrender's PYOPENCL_CTX parsing and pytest's header
must all agree on (seconds: one real pytest child runs a single test)."""

import os
import re
import sys
from pathlib import Path

import pytest

from clrender.runtime import describe_device, select_device

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import portability  # noqa: E402

LOG_TAIL = """\
tests/test_zz.py ..F.s                                                    [100%]

=========================== short test summary info ============================
SKIPPED [1] tests/test_zz.py:40: no matplotlib
FAILED tests/test_api.py::test_bad_arguments_are_one_line_errors[arguments7-at most 256 samples]
FAILED tests/test_trace.py::test_furnace[8] - AssertionError: assert 1.75 == 1.5 - 0.25
ERROR tests/test_broken.py - ImportError: cannot import name 'x'
ERROR tests/test_rng.py::test_philox_known_answers - pyopencl.LogicError: no device
FAILED tests/test_trace.py::test_furnace[8] - AssertionError: again
= 2 failed, 390 passed, 3 skipped, 2 errors, 1 xfailed, 4 warnings in 301.25s (0:05:01) =
"""


@pytest.mark.parametrize(
    "line, expected",
    [
        (
            "= 2 failed, 390 passed, 3 skipped, 2 errors, 1 xfailed, 4 warnings in 301.25s"
            " (0:05:01) =",
            {
                "passed": 390,
                "failed": 2,
                "skipped": 3,
                "errors": 2,
                "xfailed": 1,
                "warnings": 4,
            },
        ),
        ("5 passed in 0.12s", {"passed": 5, "failed": 0, "skipped": 0, "errors": 0}),
        (
            "==== 1 passed, 1 error, 1 warning in 2.00s ====",
            {"passed": 1, "failed": 0, "skipped": 0, "errors": 1, "warnings": 1},
        ),
        (
            "======= 12 passed, 797 deselected in 30.1s =======",
            {"passed": 12, "failed": 0, "skipped": 0, "errors": 0, "deselected": 797},
        ),
        ("no tests ran in 0.01s", {"passed": 0, "failed": 0, "skipped": 0, "errors": 0}),
    ],
)
def test_summary_line_counts(line, expected):
    assert portability.parse_summary(f"tests/x.py .....\n{line}\n") == expected


def test_a_run_cut_short_has_no_summary():
    # killed mid-run: the progress line is all there is (its 'passed' is not a count)
    assert portability.parse_summary("tests/test_zz.py ....   [ 40%]\n") is None
    assert portability.parse_summary("") is None


def test_failing_ids_from_the_short_summary():
    assert portability.failed_tests(LOG_TAIL) == [
        "tests/test_api.py::test_bad_arguments_are_one_line_errors[arguments7-at most 256 samples]",
        "tests/test_trace.py::test_furnace[8]",
        "tests/test_broken.py",
        "tests/test_rng.py::test_philox_known_answers",
    ]
    assert portability.parse_summary(LOG_TAIL)["failed"] == 2


def test_device_from_the_header():
    text = "rootdir: /x\nclrender device: pthread-AMD EPYC [PoCL, OpenCL 3.0] (PYOPENCL_CTX=2:0)\n"
    assert portability.header_device(text) == "pthread-AMD EPYC [PoCL, OpenCL 3.0]"
    assert portability.header_device("rootdir: /x\n") is None


def test_icd_folder_registers_intel_beside_the_system_platforms(tmp_path):
    vendors = tmp_path / "vendors"
    vendors.mkdir()
    (vendors / "pocl.icd").write_text("libpocl.so.2\n")
    (vendors / "notes.txt").write_text("not an icd file")
    library = tmp_path / "prefix" / "lib" / "libintelocl.so"
    library.parent.mkdir(parents=True)
    library.write_bytes(b"")
    icd = tmp_path / "icd"
    icd.mkdir()
    (icd / "stale.icd").write_text("/gone/libold.so\n")
    base = {"OCL_ICD_VENDORS": str(vendors), "LD_LIBRARY_PATH": "/opt/x", "PATH": "/bin"}
    env, setup = portability.opencl_environment(base, library, icd)
    assert env["OCL_ICD_VENDORS"] == str(icd)
    assert env["LD_LIBRARY_PATH"] == f"{library.parent}{os.pathsep}/opt/x"
    assert env["PATH"] == "/bin" and base["OCL_ICD_VENDORS"] == str(vendors)
    assert sorted(p.name for p in icd.iterdir()) == ["intel-cpu.icd", "pocl.icd"]
    assert (icd / "intel-cpu.icd").read_text() == f"{library}\n"
    assert (icd / "pocl.icd").read_text() == "libpocl.so.2\n"
    assert setup["icd_files"]["intel-cpu.icd"] == str(library)
    # written again from itself (OCL_ICD_VENDORS already the folder): the same files
    again, _ = portability.opencl_environment(env, library, icd)
    assert sorted(p.name for p in icd.iterdir()) == ["intel-cpu.icd", "pocl.icd"]
    assert (icd / "pocl.icd").read_text() == "libpocl.so.2\n"
    # without Intel's runtime the environment is left alone
    plain, setup = portability.opencl_environment(base, None, tmp_path / "unused")
    assert plain == base and setup["intel_library"] is None
    assert not (tmp_path / "unused").exists()


def test_device_selectors():
    devices = [
        {"selector": "0:0", "platform": "Portable Computing Language", "device": "pthread-a"},
        {"selector": "1:0", "platform": "Intel(R) OpenCL", "device": "AMD EPYC"},
        {"selector": "1:1", "platform": "Intel(R) OpenCL", "device": "FPGA emulator"},
    ]
    assert portability.choose(devices, None) == devices
    assert portability.choose(devices, ["1"]) == [devices[1]]
    assert portability.choose(devices, ["intel", "0:0", "1:0"]) == devices[1:] + devices[:1]
    with pytest.raises(SystemExit) as exit_status:
        portability.choose(devices, ["2:0"])
    assert exit_status.value.code == 2


@pytest.mark.device
def test_listing_selectors_and_header_agree(tmp_path, monkeypatch):
    """The child's listing equals this process's (same environment), each selector picks that
    device through clrender's PYOPENCL_CTX parsing, and a real pytest child on a selector
    passes and names the same device in its header."""
    listed = portability.list_devices(dict(os.environ))
    # Memory sizes may follow the memory free at the moment (PoCL's CPU device): they differ
    # between two listings on a busy machine, everything else must not
    varying = ("global_mem_bytes", "max_alloc_bytes")

    def fixed(devices):
        return [{k: v for k, v in device.items() if k not in varying} for device in devices]

    assert fixed(listed) == fixed(portability.describe_devices()) and listed
    for device in listed:
        monkeypatch.setenv("PYOPENCL_CTX", device["selector"])
        assert describe_device(select_device()) == device["identity"]
        assert device["max_work_group_size"] >= 1 and device["global_mem_bytes"] > 0
    last = listed[-1]
    run = portability.run_suite(
        last,
        dict(os.environ),
        ["tests/test_portability.py::test_device_from_the_header"],
        tmp_path / "run.log",
    )
    assert run["pytest"]["counts"]["passed"] == 1 and run["ok"], run
    assert run["pytest"]["tested_device"] == last["identity"]


# --- the kernels need no double precision outside their precision switches ------------------

KERNELS = Path(__file__).resolve().parents[1] / "kernels"
# -D options clrender.estimators.device_cells sets only where the device has cl_khr_fp64
DOUBLE_SWITCHES = ("VORONOI_DOUBLE", "VORONOI_AREA_DOUBLE")
DOUBLE_TOKEN = re.compile(r"\b(?:double\d*|convert_double\w*|as_double\d*|cl_khr_fp64)\b")
# A floating literal without the f suffix is a double where the device has fp64
UNSUFFIXED = re.compile(
    r"(?<![\w.])(?:(?:\d+\.\d*|\.\d+)(?:[eE][-+]?\d+)?|\d+[eE][-+]?\d+)(?![\w.])"
)


def fp64_uses(source: str) -> list[tuple[int, str]]:
    """(line, text) of every double type, double builtin or unsuffixed floating literal outside
    an #if/#ifdef block on a DOUBLE_SWITCHES macro (its #else branch is the single path)."""
    code = re.sub(
        r"//[^\n]*|/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group()), source, flags=re.S
    )
    found, guarded = [], []
    for number, line in enumerate(code.splitlines(), 1):
        directive = re.match(r"\s*#\s*(ifdef|ifndef|if|elif|else|endif)\b(.*)", line)
        if directive:
            kind, condition = directive.groups()
            if kind in ("if", "ifdef"):
                guarded.append(any(name in condition for name in DOUBLE_SWITCHES))
            elif kind == "ifndef":
                guarded.append(False)
            elif kind in ("elif", "else"):
                guarded[-1] = False
            else:
                guarded.pop()
            continue
        if any(guarded) or line.lstrip().startswith("#include"):
            continue
        found += [(number, hit) for hit in DOUBLE_TOKEN.findall(line) + UNSUFFIXED.findall(line)]
    return found


def test_the_fp64_scan_finds_what_it_looks_for():
    source = """float a = 0.5f * 2.0f + 1e-3f;  // 0.5 in a comment
#ifdef VORONOI_DOUBLE
typedef double real;
#else
typedef float real;
float b = 0.25;
#endif
/* 1.5 */ float c = 1.5 + 1e-7 + x2.5f;
double d = as_double(0x7ff0000000000000L);
"""
    assert fp64_uses(source) == [
        (6, "0.25"),
        (8, "1.5"),
        (8, "1e-7"),
        (9, "double"),
        (9, "as_double"),
    ]


def test_kernels_need_no_fp64_outside_the_precision_switches():
    # The tracing, sampling and Voronoi kernels run on devices without cl_khr_fp64: double
    # appears only where device_cells asks for it (mixed or double precision, fp64 devices)
    sources = [p for p in sorted(KERNELS.iterdir()) if p.suffix in (".cl", ".h")]
    sources = [p for p in sources if not p.name.endswith("_test.cl")]  # test-only kernels
    assert {"integrator.cl", "sampling.cl", "voronoi_cells.cl", "voronoi_sums.cl"} <= {
        p.name for p in sources
    }
    uses = {p.name: fp64_uses(p.read_text()) for p in sources}
    assert {name: hits for name, hits in uses.items() if hits} == {}
