"""Session fixture: Taichi is initialised once for the whole test run, on the CPU unless `--arch cuda`."""

import os

import pytest

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")


def pytest_addoption(parser):
    parser.addoption("--arch", default="cpu", choices=("cpu", "cuda"),
                     help="Taichi backend for the kernels under test (cuda needs a GPU; default cpu)")


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime(request):
    import crowd_ik

    return crowd_ik.init(arch=request.config.getoption("--arch"))
