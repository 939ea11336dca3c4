"""Shared fixtures: one OpenCL runtime per test session (PYOPENCL_CTX or the first device)."""

import pytest

from clrender.runtime import create_runtime


@pytest.fixture(scope="session")
def runtime():
    return create_runtime()
