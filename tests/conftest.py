"""Test-wide set-up: Taichi runs on the CPU (CI has no GPU), once per session."""
import pytest

from gausstac_maniskill import backend


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu():
    backend.init("cpu")
    yield
