"""Session fixture: Taichi is initialised once, on the CPU, for the whole test run."""

import os

import pytest

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    import crowd_ik

    return crowd_ik.init(arch="cpu")
