"""Shared fixtures: one OpenCL runtime per test session (PYOPENCL_CTX or the first device).

Every test that touches an OpenCL device carries the `device` marker (bench/portability.py
--kernel-tests-only runs `-m device` on each device): added here to each test that uses the
`runtime` fixture, and by hand (@pytest.mark.device) where a test reaches a device another way (a
render through the command line or clrender.render). The header names the device under test.
"""

import os

import pytest

from clrender.errors import ClrenderError
from clrender.estimators.device_cells import resolve_precision
from clrender.runtime import NO_FP64_VARIABLE, create_runtime, describe_device, select_device

DEVICE_HEADER = "clrender device: "


def pytest_report_header(config):
    """The device the runtime fixture will use, as bench/portability.py checks it."""
    selection = os.environ.get("PYOPENCL_CTX", "") or "unset"
    try:
        device = describe_device(select_device())
    except ClrenderError as err:
        device = f"none ({err})"
    return f"{DEVICE_HEADER}{device} (PYOPENCL_CTX={selection})"


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "runtime" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.device)


@pytest.fixture(scope="session")
def runtime():
    return create_runtime()


@pytest.fixture
def shared_cli_runtime(runtime, monkeypatch):
    """The in-process command line (clrender.cli.main) renders on the session's runtime instead
    of the process's own (clrender.api.runtime_for), so its programs are built once per
    session: for tests of what a render writes and says, not of a process's first builds
    (those run the command line in child processes, or without this fixture). A --device
    request still gets its own runtime."""
    from clrender import api

    real = api.runtime_for
    monkeypatch.setattr(
        api, "runtime_for", lambda request=None: runtime if request is None else real(request)
    )


@pytest.fixture
def single_precision(runtime) -> bool:
    """Whether the device cells and sums run in float32 here (a device without cl_khr_fp64, or
    CLRENDER_NO_FP64 set): tests of them then hold to their stated single-precision bounds."""
    return resolve_precision(runtime, "auto") == "single"


@pytest.fixture
def no_fp64(monkeypatch):
    """Run the test as on a device without double precision (the single-precision paths)."""
    monkeypatch.setenv(NO_FP64_VARIABLE, "1")


@pytest.fixture(scope="session")
def cluster():
    """One Dask LocalCluster of 2 worker processes for every cluster test (tests/test_cluster*):
    starting one and compiling the kernels on its workers costs seconds, so it is shared. A test
    that kills a worker leaves it to its nanny, which starts a new one."""
    pytest.importorskip("distributed")
    from clrender.cluster import DaskExecutor

    with DaskExecutor(workers=2) as executor:
        yield executor
