"""crowd_ik.ease: the corrected sine ease curve and keyframe interpolation of joint angles."""

import numpy as np
import pytest

from crowd_ik.ease import ease, ease_velocity, interpolate_keyframes, load_keyframes

KS = [(0.2, 0.75), (0.3, 0.7), (0.0, 0.6), (0.4, 1.0), (0.5, 0.5), (0.0, 1.0)]


@pytest.mark.parametrize("k1, k2", KS)
def test_ends_and_monotone(k1, k2):
    t = np.linspace(0, 1, 2001)
    s = ease(t, k1, k2)
    assert s[0] == 0.0 and s[-1] == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.diff(s) > 0)
    assert np.all((s >= 0) & (s <= 1 + 1e-15))
    assert isinstance(ease(0.5, k1, k2), float)


def test_linear_when_there_is_no_ease():
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(ease(t, 0.0, 1.0), t, atol=1e-15)
    np.testing.assert_allclose(ease_velocity(t, 0.0, 1.0), 1.0)


def test_zero_slope_at_both_ends():
    h = 1e-6
    assert ease_velocity(0.0) == pytest.approx(0.0, abs=1e-12)
    assert ease_velocity(1.0) == pytest.approx(0.0, abs=1e-12)
    assert ease(h) / h < 1e-5
    assert (1 - ease(1 - h)) / h < 1e-5


@pytest.mark.parametrize("k1, k2", KS[:4])
def test_velocity_continuous_at_k1_and_k2(k1, k2):
    h = 1e-6
    for k in (k1, k2):
        if 0 < k < 1:
            left = (ease(k, k1, k2) - ease(k - h, k1, k2)) / h
            right = (ease(k + h, k1, k2) - ease(k, k1, k2)) / h
            assert left == pytest.approx(right, abs=1e-3)
            assert ease_velocity(k, k1, k2) == pytest.approx(left, abs=1e-3)


@pytest.mark.parametrize("k1, k2", KS)
def test_velocity_is_the_derivative(k1, k2):
    t = np.linspace(0.013, 0.987, 37)
    h = 1e-6
    fd = (ease(t + h, k1, k2) - ease(t - h, k1, k2)) / (2 * h)
    np.testing.assert_allclose(ease_velocity(t, k1, k2), fd, atol=1e-6)


def test_middle_segment_is_linear_with_constant_velocity():
    k1, k2 = 0.2, 0.75
    f = 2 * k1 / np.pi + (k2 - k1) + 2 * (1 - k2) / np.pi  # the README's normaliser
    t = np.linspace(k1, k2, 23)
    s = ease(t, k1, k2)
    np.testing.assert_allclose(np.diff(s, 2), 0.0, atol=1e-14)
    np.testing.assert_allclose(np.diff(s) / np.diff(t), 1 / f, rtol=1e-9)
    np.testing.assert_allclose(ease_velocity(t, k1, k2), 1 / f)
    # the ease-in piece by the README formula at one point
    assert ease(0.1, k1, k2) == pytest.approx(k1 * 2 / np.pi * (np.sin(0.1 / k1 * np.pi / 2 - np.pi / 2) + 1) / f)


@pytest.mark.parametrize(
    "t, k1, k2",
    [(0.5, 0.8, 0.2), (0.5, -0.1, 0.5), (0.5, 0.2, 1.5), (1.2, 0.2, 0.8), (-0.1, 0.2, 0.8), (np.nan, 0.2, 0.8), (0.5, np.nan, 0.8)],
)
def test_ease_validates(t, k1, k2):
    with pytest.raises(ValueError, match="k1|k2|t:"):
        ease(t, k1, k2)


# --- keyframes -------------------------------------------------------------------------------


def test_interpolation_hits_the_key_poses():
    poses = np.radians([[0, 0, 0], [90, -45, 10], [30, 10, -20], [30, 10, -20]])
    durations = [0.5, 1.0, 0.4, 0.3]  # a half-second hold on pose 0, then three moves
    fps = 10
    frames = interpolate_keyframes(durations, poses, fps, 0.2, 0.75)
    assert frames.shape == (int(np.ceil(2.2 * fps)) + 1, 3)
    np.testing.assert_array_equal(frames[:6], np.repeat(poses[:1], 6, axis=0))  # t = 0 .. 0.5 s: the hold
    np.testing.assert_array_equal(frames[15], poses[1])  # t = 1.5 s
    np.testing.assert_array_equal(frames[19], poses[2])  # t = 1.9 s
    np.testing.assert_array_equal(frames[-1], poses[-1])
    # within a move every joint goes monotonically from one key to the next
    seg = frames[5:16]
    assert np.all(np.diff(seg[:, 0]) >= 0) and np.all(np.diff(seg[:, 1]) <= 0)
    # eased: the first step of a move is shorter than a middle step
    assert abs(seg[1, 0] - seg[0, 0]) < abs(seg[5, 0] - seg[4, 0])


def test_interpolation_frame_values_follow_the_curve():
    frames = interpolate_keyframes([0.0, 1.0], [[0.0], [2.0]], fps=4, k1=0.3, k2=0.7)
    np.testing.assert_allclose(frames[:, 0], 2.0 * ease(np.arange(5) / 4, 0.3, 0.7))


def test_interpolation_last_row_is_last_pose_when_fps_does_not_divide():
    poses = np.array([[0.1, 0.2], [0.7, -1.3]])
    frames = interpolate_keyframes([0.0, 0.33], poses, fps=7)
    np.testing.assert_array_equal(frames[0], poses[0])
    np.testing.assert_array_equal(frames[-1], poses[1])
    assert len(frames) == int(np.ceil(0.33 * 7)) + 1


def test_single_pose_holds():
    frames = interpolate_keyframes([1.0], [[0.5, -0.5]], fps=5)
    np.testing.assert_array_equal(frames, np.tile([0.5, -0.5], (6, 1)))


@pytest.mark.parametrize(
    "durations, poses, fps, name",
    [
        ([0.0, 0.0], [[0.0], [1.0]], 10, "durations"),
        ([-1.0, 1.0], [[0.0], [1.0]], 10, "durations"),
        ([0.0, 1.0, 1.0], [[0.0], [1.0]], 10, "durations"),
        ([0.0, 1.0], [0.0, 1.0], 10, "poses"),
        ([0.0, 1.0], [[0.0], [np.nan]], 10, "poses"),
        ([0.0, 1.0], [[0.0], [1.0]], 0, "fps"),
    ],
)
def test_interpolation_validates(durations, poses, fps, name):
    with pytest.raises(ValueError, match=name):
        interpolate_keyframes(durations, poses, fps)


def test_load_keyframes(tmp_path):
    path = tmp_path / "keys.csv"
    path.write_text("duration_s,theta1,theta2\n# rest\n0,0,0\n\n1.5,90,-45\n0.5, 180 ,30\n")
    durations, poses = load_keyframes(path)
    np.testing.assert_allclose(durations, [0.0, 1.5, 0.5])
    np.testing.assert_allclose(poses, np.radians([[0, 0], [90, -45], [180, 30]]))


@pytest.mark.parametrize(
    "text, line, fragment",
    [
        ("theta1,duration_s\n0,0\n", 1, "header"),
        ("", 1, "empty"),
        ("duration_s,theta1\n", 2, "at least one"),
        ("duration_s,theta1\n0,0\n1,abc\n", 3, "'abc'"),
        ("duration_s,theta1\n0,0\n# note\n1,nan\n", 4, "'nan'"),
        ("duration_s,theta1,theta2\n0,0,0\n1,20\n", 3, "3 fields"),
        ("duration_s,theta1\n0,0\n0,20\n", 3, "duration_s"),
        ("duration_s,theta1\n-1,0\n", 2, "duration_s"),
    ],
)
def test_load_keyframes_errors_name_file_and_line(tmp_path, text, line, fragment):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        load_keyframes(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert fragment in message


def test_load_keyframes_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_keyframes(tmp_path / "nope.csv")
