"""Portability check: the test suite on every OpenCL device of this machine, one after another.

    python bench/portability.py                          # the whole suite on every device
    python bench/portability.py --kernel-tests-only      # only the tests marked `device`
    python bench/portability.py --list                   # the devices, as the children see them
    python bench/portability.py --devices 0:0 Intel      # some devices: platform:device or name
    python bench/portability.py --no-fp64 --devices 0:0  # as a device without double precision
    python bench/portability.py -- -k philox             # extra pytest arguments after --

Every device visible through the ICD loader is tested: pip PoCL (bundled with pyopencl), the
platforms registered in /etc/OpenCL/vendors (Debian's pocl-opencl-icd), any GPU driver, and
Intel's CPU runtime when its PyPI package is installed in this Python (`pip install
intel-opencl-rt intel-cmplr-lib-rt`) or named with --intel-lib: its package ships no usable
.icd file, so the script writes an ICD folder (default ~/.cache/clrender/icd, --icd-dir) holding
a copy of every system .icd file plus one whose line is the path of libintelocl.so, and runs
each child with OCL_ICD_VENDORS set to that folder and libintelocl.so's folder first on
LD_LIBRARY_PATH (its libraries: TBB, the compiler runtime).

The devices are listed by a child process with exactly the environment the test runs get, and
each test run selects its device by index (PYOPENCL_CTX=platform:device) from that listing; the
pytest header names the device the run uses (tests/conftest.py) and a run on any other device
is an error. Per device: platform, device, driver version, double precision (cl_khr_fp64),
largest work-group, preferred vector widths, local, global and largest-allocation memory, and
pytest's counts (passed, failed, skipped, errors), the failing tests' ids and the run's wall
and CPU seconds (the child's user + system time: PoCL's and Intel's worker threads included).
--kernel-tests-only runs `pytest -m device`: the tests that use the `runtime` fixture (marked
by tests/conftest.py) and the ones marked by hand that reach a device through the command
line or clrender.render. --no-fp64 sets CLRENDER_NO_FP64=1 in the children: clrender then
treats every device as lacking cl_khr_fp64 and takes its single-precision paths.

Output: JSON on stdout, bench/results/portability/results.json (rewritten after each device),
results.md (a table) and one pytest log per device (--out to change the folder). Exit status:
0 when every device passed, 1 when a run failed or ran on the wrong device, 2 for bad arguments
or no device at all.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "bench" / "results" / "portability"
SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
INTEL_PACKAGE = "intel-opencl-rt"
INTEL_LIBRARY = "libintelocl.so"
INTEL_ICD = "intel-cpu.icd"
# What tests/conftest.py prints in pytest's header (pytest_report_header)
DEVICE_HEADER = "clrender device: "
COUNT_WORDS = {
    "passed": "passed",
    "failed": "failed",
    "skipped": "skipped",
    "error": "errors",
    "errors": "errors",
    "xfailed": "xfailed",
    "xpassed": "xpassed",
    "deselected": "deselected",
    "warning": "warnings",
    "warnings": "warnings",
}
VECTOR_TYPES = ("char", "short", "int", "long", "half", "float", "double")


def fail(message: str) -> None:
    """One line on stderr and exit status 2."""
    print(f"portability: {message}", file=sys.stderr)
    raise SystemExit(2)


def default_icd_dir() -> Path:
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "clrender" / "icd"


# ---------------------------------------------------------------------------------------------
# The OpenCL environment of the children


def find_intel_library() -> Path | None:
    """libintelocl.so of the intel-opencl-rt package installed in this Python, if any (the
    wheel puts it in <prefix>/lib, listed in the package's files)."""
    try:
        dist = importlib.metadata.distribution(INTEL_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return None
    for file in dist.files or ():
        if file.name == INTEL_LIBRARY:
            path = Path(dist.locate_file(file)).resolve()
            if path.is_file():
                return path
    return None


def icd_sources(env: dict[str, str]) -> list[Path]:
    """The .icd files the loader would read: $OCL_ICD_VENDORS (a folder or one file) if set,
    else the system folder."""
    vendors = env.get("OCL_ICD_VENDORS", "")
    place = Path(vendors) if vendors else SYSTEM_VENDORS
    if place.is_file():
        return [place]
    if place.is_dir():
        return sorted(p for p in place.iterdir() if p.suffix == ".icd" and p.is_file())
    return []


def opencl_environment(
    base: dict[str, str], intel_library: Path | None, icd_dir: Path
) -> tuple[dict[str, str], dict]:
    """(the children's environment, a description of it). With Intel's runtime: an ICD folder
    with a copy of every .icd the loader would read plus one for libintelocl.so, and its folder
    on LD_LIBRARY_PATH. Without it the environment is left as it is."""
    env = dict(base)
    if intel_library is None:
        return env, {"OCL_ICD_VENDORS": env.get("OCL_ICD_VENDORS"), "intel_library": None}
    # read before clearing: $OCL_ICD_VENDORS may be this very folder
    texts = {p.name: p.read_text() for p in icd_sources(env) if p.name != INTEL_ICD}
    icd_dir.mkdir(parents=True, exist_ok=True)
    for old in icd_dir.glob("*.icd"):
        old.unlink()
    for name, text in texts.items():
        (icd_dir / name).write_text(text)
    (icd_dir / INTEL_ICD).write_text(f"{intel_library}\n")
    env["OCL_ICD_VENDORS"] = str(icd_dir)
    library_path = env.get("LD_LIBRARY_PATH", "")
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        p for p in (str(intel_library.parent), library_path) if p
    )
    return env, {
        "OCL_ICD_VENDORS": str(icd_dir),
        "icd_files": {p.name: p.read_text().strip() for p in sorted(icd_dir.glob("*.icd"))},
        "LD_LIBRARY_PATH_added": str(intel_library.parent),
        "intel_library": str(intel_library),
    }


# ---------------------------------------------------------------------------------------------
# Devices (listed in a child with the test runs' environment)


def _info(getter, default=None):
    try:
        return getter()
    except Exception:  # an attribute a platform does not report
        return default


def describe_devices() -> list[dict]:
    """Every device of every platform, in the ICD loader's order, with what the report keeps."""
    import pyopencl as cl

    from clrender.runtime import describe_device

    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    devices = []
    for p, platform in enumerate(platforms):
        for d, device in enumerate(_info(platform.get_devices, [])):
            widths = {
                kind: _info(lambda k=kind, dev=device: getattr(dev, f"preferred_vector_width_{k}"))
                for kind in VECTOR_TYPES
            }
            kinds = [
                name
                for name in ("CPU", "GPU", "ACCELERATOR", "CUSTOM")
                if device.type & getattr(cl.device_type, name, 0)
            ]
            devices.append(
                {
                    "selector": f"{p}:{d}",
                    "platform": platform.name.strip(),
                    "platform_version": platform.version.strip(),
                    "device": device.name.strip(),
                    "identity": describe_device(device),
                    "type": "|".join(kinds) or str(device.type),
                    "driver_version": device.driver_version.strip(),
                    "device_version": device.version.strip(),
                    "fp64": "cl_khr_fp64" in device.extensions.split(),
                    "compute_units": device.max_compute_units,
                    "max_work_group_size": device.max_work_group_size,
                    "preferred_vector_width": widths,
                    "local_mem_bytes": device.local_mem_size,
                    "global_mem_bytes": device.global_mem_size,
                    "max_alloc_bytes": device.max_mem_alloc_size,
                }
            )
    return devices


def list_devices(env: dict[str, str]) -> list[dict]:
    """describe_devices() as a child process with env sees them."""
    child = subprocess.run(
        [sys.executable, __file__, "--describe-json"],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    if child.returncode != 0:
        fail(f"listing the devices failed:\n{child.stderr.strip()}")
    return json.loads(child.stdout)


def choose(devices: list[dict], wanted: list[str] | None) -> list[dict]:
    """The devices named by selectors: 'platform:device' indices, or a substring of the
    platform or device name (case-insensitive); all of them when wanted is empty."""
    if not wanted:
        return list(devices)
    chosen = []
    for spec in wanted:
        if re.fullmatch(r"\d+(:\d+)?", spec):
            key = spec if ":" in spec else f"{spec}:0"
            hits = [d for d in devices if d["selector"] == key]
        else:
            low = spec.lower()
            hits = [d for d in devices if low in f"{d['platform']} {d['device']}".lower()]
        if not hits:
            accepted = ", ".join(f"{d['selector']} {d['device']}" for d in devices)
            fail(f"--devices {spec!r} matches nothing; have: {accepted}")
        chosen += [d for d in hits if d not in chosen]
    return chosen


# ---------------------------------------------------------------------------------------------
# pytest's output


def parse_summary(text: str) -> dict[str, int] | None:
    """The counts of pytest's closing line ('=== 3 failed, 390 passed, 2 skipped in 301.2s
    (0:05:01) ==='), None when there is none (a crash). 'no tests ran' gives all zeros."""
    for line in reversed(text.splitlines()):
        stripped = line.strip().strip("=").strip()
        if not re.search(r"\bin [\d.]+s\b", stripped):
            continue
        found = re.findall(r"(\d+) ([a-z]+)", stripped.split(" in ")[0])
        if not found and not stripped.startswith("no tests ran"):
            continue
        counts = dict.fromkeys(("passed", "failed", "skipped", "errors"), 0)
        for number, word in found:
            if word in COUNT_WORDS:
                key = COUNT_WORDS[word]
                counts[key] = counts.get(key, 0) + int(number)
        return counts
    return None


def failed_tests(text: str) -> list[str]:
    """Ids of the tests in the short summary's FAILED and ERROR lines (pytest -ra): 'FAILED
    tests/t.py::test[param id, spaces and all] - message', 'ERROR tests/t.py - message' for a
    module that failed to import."""
    ids = []
    for line in text.splitlines():
        match = re.match(r"(?:FAILED|ERROR) (\S+?(?:::[^\s\[]+(?:\[.*?\])?)?)(?: - |$)", line)
        if match and match.group(1) not in ids:
            ids.append(match.group(1))
    return ids


def header_device(text: str) -> str | None:
    """The device named in the header by tests/conftest.py, without the PYOPENCL_CTX note."""
    for line in text.splitlines():
        if line.startswith(DEVICE_HEADER):
            return re.sub(r" \(PYOPENCL_CTX=[^()]*\)$", "", line[len(DEVICE_HEADER) :])
    return None


# ---------------------------------------------------------------------------------------------
# Runs


def run_suite(device: dict, env: dict[str, str], pytest_args: list[str], log: Path) -> dict:
    """pytest on one device in a child process; its counts, failures and times."""
    child_env = dict(env, PYOPENCL_CTX=device["selector"])
    command = [sys.executable, "-m", "pytest", "-ra", "-p", "no:cacheprovider", *pytest_args]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    with log.open("w") as out:
        returncode = subprocess.run(
            command, stdout=out, stderr=subprocess.STDOUT, env=child_env, cwd=ROOT
        ).returncode
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    text = log.read_text(errors="replace")
    counts = parse_summary(text)
    tested = header_device(text)
    right_device = tested == device["identity"]
    ok = (
        returncode == 0
        and counts is not None
        and counts["failed"] == 0
        and counts["errors"] == 0
        and counts["passed"] > 0
        and right_device
    )
    return {
        "pytest": {
            "command": " ".join(["PYOPENCL_CTX=" + device["selector"], "python", *command[1:]]),
            "returncode": returncode,
            "counts": counts,
            "failures": failed_tests(text),
            "tested_device": tested,
            "right_device": right_device,
            "log": str(log),
        },
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "ok": ok,
    }


def gib(nbytes) -> str:
    return "?" if nbytes is None else f"{nbytes / 2**30:.1f} GiB"


def markdown(report: dict) -> str:
    header = [
        "device (PYOPENCL_CTX)",
        "platform, driver",
        "fp64",
        "max WG",
        "vec float/double",
        "local / global mem",
        "passed",
        "failed",
        "skipped",
        "errors",
        "wall s",
        "CPU s",
    ]
    rows = []
    for d in report["devices"]:
        counts = (d.get("pytest") or {}).get("counts") or {}
        widths = d["preferred_vector_width"]
        rows.append(
            [
                f"{d['device']} ({d['selector']})",
                f"{d['platform']} {d['driver_version']}",
                "yes" if d["fp64"] else "no",
                d["max_work_group_size"],
                f"{widths.get('float')}/{widths.get('double')}",
                f"{d['local_mem_bytes'] // 1024} KiB / {gib(d['global_mem_bytes'])}",
                *(counts.get(k, "?") for k in ("passed", "failed", "skipped", "errors")),
                d.get("wall_s", ""),
                d.get("cpu_s", ""),
            ]
        )
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in rows]
    failures = [
        f"- {d['selector']} {d['device']}: {', '.join(d['pytest']['failures']) or 'see the log'}"
        for d in report["devices"]
        if d.get("pytest") and not d["ok"]
    ]
    text = [
        f"# Portability: {report['selection']}",
        "",
        f"`{report['command']}`",
        "",
        *lines,
        "",
    ]
    loads = [report.get("load_before"), report.get("load_after")]
    text += [
        "Load average (1, 5, 15 min) before and after: "
        + " / ".join(", ".join(f"{x:.1f}" for x in load) for load in loads if load),
        "",
    ]
    if report["no_fp64"]:
        text += ["CLRENDER_NO_FP64=1: every device run as if it had no cl_khr_fp64.", ""]
    if failures:
        text += ["Failures:", *failures, ""]
    return "\n".join(text)


def write_report(report: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (
        ("results.json", json.dumps(report, indent=1)),
        ("results.md", markdown(report)),
    ):
        temp = out / f".{name}.tmp"
        temp.write_text(text)
        temp.replace(out / name)


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--kernel-tests-only",
        action="store_true",
        help="run only the tests marked `device` (pytest -m device) on each device",
    )
    parser.add_argument(
        "--devices", nargs="+", help="platform:device indices or name substrings (default: all)"
    )
    parser.add_argument("--list", action="store_true", help="list the devices and stop")
    parser.add_argument(
        "--no-fp64",
        action="store_true",
        help="CLRENDER_NO_FP64=1 in the children: every device treated as lacking cl_khr_fp64",
    )
    parser.add_argument(
        "--intel-lib", type=Path, help="libintelocl.so to register (default: the installed one)"
    )
    parser.add_argument("--no-intel", action="store_true", help="do not register Intel's runtime")
    parser.add_argument("--icd-dir", type=Path, default=None, help="ICD folder to write")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="results folder")
    parser.add_argument("--describe-json", action="store_true", help=argparse.SUPPRESS)
    if "--" in argv:
        cut = argv.index("--")
        args = parser.parse_args(argv[:cut])
        args.pytest_args = argv[cut + 1 :]
    else:
        args = parser.parse_args(argv)
        args.pytest_args = []
    return args


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_args(argv)
    if args.describe_json:
        print(json.dumps(describe_devices()))
        return 0
    intel = None
    if not args.no_intel:
        intel = args.intel_lib or find_intel_library()
        if intel is not None and not Path(intel).is_file():
            fail(f"--intel-lib {intel} is not a file")
    base = dict(os.environ)
    if args.no_fp64:
        base["CLRENDER_NO_FP64"] = "1"
    env, setup = opencl_environment(
        base, Path(intel).resolve() if intel else None, args.icd_dir or default_icd_dir()
    )
    devices = choose(list_devices(env), args.devices)
    if not devices:
        fail("no OpenCL device found")
    if args.list:
        print(json.dumps({"environment": setup, "devices": devices}, indent=1))
        return 0
    pytest_args = (["-m", "device"] if args.kernel_tests_only else []) + args.pytest_args
    selection = "kernel tests (-m device)" if args.kernel_tests_only else "whole suite"
    report = {
        "command": " ".join(["python bench/portability.py", *argv]),
        "selection": selection,
        "pytest_args": pytest_args,
        "no_fp64": args.no_fp64,
        "environment": setup,
        "load_before": list(os.getloadavg()),
        "devices": devices,
        "ok": False,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    for device in devices:
        slug = device["selector"].replace(":", "-")
        print(f"portability: {device['selector']} {device['identity']} ...", file=sys.stderr)
        device.update(run_suite(device, env, pytest_args, args.out / f"pytest-{slug}.log"))
        counts = device["pytest"]["counts"] or {}
        print(
            f"portability: {device['selector']} {'ok' if device['ok'] else 'FAILED'}: "
            + ", ".join(f"{v} {k}" for k, v in counts.items())
            + f" in {device['wall_s']} s",
            file=sys.stderr,
        )
        write_report(report, args.out)
    report["ok"] = all(d["ok"] for d in devices)
    report["load_after"] = list(os.getloadavg())
    write_report(report, args.out)
    print(json.dumps(report, indent=1))
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
