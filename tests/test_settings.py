"""crowd_ik/solvers/settings.py: the lane width and the constants shared by kernels and twins."""

import pytest

from crowd_ik.solvers import settings


def test_cpu_lanes_from_the_flags(tmp_path):
    for flags, lanes in (("fpu sse2 avx avx2 avx512f avx512bw", 16), ("fpu sse2 avx avx2 fma", 8), ("fpu sse2", 4)):
        f = tmp_path / "cpuinfo"
        f.write_text(f"processor\t: 0\nflags\t\t: {flags}\n")
        assert settings.cpu_vector_lanes(str(f)) == lanes
    assert settings.cpu_vector_lanes(str(tmp_path / "missing")) == 4


def test_choose_lanes_order(monkeypatch):
    monkeypatch.delenv("CROWD_IK_LANES", raising=False)
    assert settings.choose_lanes("cuda") == 1
    assert settings.choose_lanes("cpu") == settings.cpu_vector_lanes()
    monkeypatch.setenv("CROWD_IK_LANES", "4")
    assert settings.choose_lanes("cpu") == 4 and settings.choose_lanes("cuda") == 4
    assert settings.choose_lanes("cpu", 8) == 8  # an explicit request wins


@pytest.mark.parametrize("value", ["3", "0", "sixteen", "", True, 64])
def test_bad_lane_widths_are_refused_naming_the_source(monkeypatch, value):
    with pytest.raises(ValueError, match="lanes: expected one of"):
        settings.parse_lanes(value, "lanes")
    if isinstance(value, str) and value:
        monkeypatch.setenv("CROWD_IK_LANES", value)
        with pytest.raises(ValueError, match="CROWD_IK_LANES"):
            settings.choose_lanes("cpu")


def test_init_records_the_lane_width():
    import crowd_ik

    crowd_ik.init()  # already running (the session fixture): returns its arch
    assert settings.lanes() == crowd_ik.runtime.current()["lanes"] in settings.LANE_CHOICES
    assert settings.on_gpu() == (crowd_ik.runtime.current()["arch"] == "cuda")
    with pytest.raises(RuntimeError, match="lanes"):
        crowd_ik.init(lanes=32 if settings.lanes() != 32 else 16)


def test_twins_and_kernels_share_the_constants():
    from crowd_ik.geometry import quat
    from crowd_ik.reference import dls, fabrik

    assert fabrik.STALL_AFTER == settings.FABRIK_STALL_AFTER and fabrik.FLAT == settings.FABRIK_FLAT
    assert dls.STALL_AFTER == settings.DLS_STALL_AFTER and dls.LAM_CAP == settings.DLS_LAM_CAP
    assert quat.GIMBAL == settings.GIMBAL
