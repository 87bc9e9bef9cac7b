"""crowd_ik.init: idempotent, refuses to switch arch, refuses CUDA without a GPU, validates arguments."""

import subprocess
import sys

import pytest

import crowd_ik
from crowd_ik import runtime


def test_init_is_idempotent_and_reports_cpu():
    assert crowd_ik.init(arch="cpu") == "cpu"
    assert crowd_ik.init() == "cpu"
    assert runtime.current()["arch"] == "cpu"


def test_the_offline_cache_holds_every_kernel():
    """Taichi cleans its offline cache down at exit once it passes offline_cache_max_size_of_files (100 MB by
    default, less than crowd_ik's kernels take): the limit is raised so that a bench or test run does not evict the
    kernels the next command needs."""
    import taichi as ti

    crowd_ik.init(arch="cpu")
    cfg = ti.lang.impl.current_cfg()
    assert cfg.offline_cache and cfg.offline_cache_max_size_of_files == runtime.CACHE_BYTES >= 1 << 30


def test_switching_arch_raises():
    with pytest.raises(RuntimeError, match="already running on cpu"):
        crowd_ik.init(arch="cuda")


@pytest.mark.parametrize("kwargs, match", [
    (dict(arch="gpu"), "arch"), (dict(fp=16), "fp"), (dict(threads=0), "threads"), (dict(threads=True), "threads"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        crowd_ik.init(**kwargs)


def test_cuda_without_gpu_raises_in_a_fresh_process():
    code = (
        "import crowd_ik, crowd_ik.runtime as r\n"
        "if r._cuda_available(__import__('taichi')):\n    print('HAS_GPU')\n    raise SystemExit(0)\n"
        "try:\n    crowd_ik.init(arch='cuda')\nexcept RuntimeError as e:\n    print('REFUSED', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout
    if "HAS_GPU" in out:
        pytest.skip("this machine has a CUDA GPU")
    assert "REFUSED" in out and "no CUDA GPU" in out


def test_import_creates_no_taichi_state():
    code = "import crowd_ik, crowd_ik.rig, crowd_ik.crowd, crowd_ik.kernels.fk, crowd_ik.runtime as r; print(r.current())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("{}")
    assert "[Taichi] Starting" not in out.stdout


def test_kernel_errors_keep_file_line_and_source_after_the_short_debug_info():
    # runtime._short_debug_info swaps Taichi's per-node position message (source lines with caret rows, half
    # of the frontend's time) for file, line, function and the source line
    crowd_ik.init(arch="cpu")
    import taichi as ti

    @ti.kernel
    def broken() -> ti.f32:
        x = 1.0
        return x + not_defined_anywhere  # noqa: F821

    with pytest.raises(Exception) as info:
        broken()
    text = str(info.value)
    assert f'File "{__file__}"' in text and "in broken:" in text
    assert "return x + not_defined_anywhere" in text and "not_defined_anywhere" in text.splitlines()[-1]
    assert "^" not in text  # Taichi's own message draws carets under the node


def test_taichi_reads_a_function_source_once_and_hands_out_copies():
    # runtime._remembered_sources: Taichi's frontend re-read a ti.func's source at every call site it inlined
    import inspect

    from taichi.lang import kernel_impl

    crowd_ik.init(arch="cpu")
    read = kernel_impl.getsourcelines
    assert getattr(read, "_crowd_ik_remembered", False)
    first, start = read(_a_function)
    second, again = read(_a_function)
    assert (first, start) == tuple(inspect.getsourcelines(_a_function)) and (second, again) == (first, start)
    assert first is not second  # a copy each time: a caller that edits its list leaves the next one whole


def _a_function(x):
    return x + 1


def test_a_bad_opt_level_variable_is_refused_by_name(monkeypatch):
    monkeypatch.setenv("CROWD_IK_TAICHI_OPT_LEVEL", "fast")
    with pytest.raises(ValueError, match="CROWD_IK_TAICHI_OPT_LEVEL: expected 0 or 1"):
        runtime._opt_level()
    monkeypatch.setenv("CROWD_IK_TAICHI_OPT_LEVEL", "0")
    assert runtime._opt_level() == 0
