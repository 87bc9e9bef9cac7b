"""Analytic two-bone IK: lengths, reach, mirrored solutions, pole side, scalar reference, degenerate and bad input."""

import math

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.reference.two_bone import two_bone_scalar
from crowd_ik.analytic import two_bone, two_bone_angles


def random_cases(n, rng):
    upper = rng.uniform(0.1, 1.0, n)
    lower = rng.uniform(0.1, 1.0, n)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # distances from well inside the fold limit to beyond full reach
    dist = rng.uniform(0.0, 1.3, n) * (upper + lower)
    pole = rng.normal(size=(n, 3))
    return upper, lower, d * dist[:, None], pole


def test_public_name_calls_the_function():
    # the public name is the function, not a module
    args = (0.3, 0.25, [0.2, -0.3, 0.1], [0.0, 0.0, 1.0])
    r = cik.two_bone(*args, solution=-1)
    np.testing.assert_array_equal(r.mid, two_bone(*args, solution=-1).mid)


def test_bone_lengths_and_reach():
    rng = np.random.default_rng(0)
    upper, lower, target, pole = random_cases(2000, rng)
    r = two_bone(upper, lower, target, pole)
    np.testing.assert_allclose(np.linalg.norm(r.mid, axis=1), upper, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(r.end - r.mid, axis=1), lower, rtol=1e-9, atol=1e-12)
    dist = np.linalg.norm(target, axis=1)
    expect = (dist >= np.abs(upper - lower)) & (dist <= upper + lower)
    np.testing.assert_array_equal(r.reachable, expect)
    assert 0.3 < r.reachable.mean() < 0.9  # both kinds are exercised
    np.testing.assert_array_equal(r.end[r.reachable], target[r.reachable])
    # unreachable: the end is on the root-target ray, as near the target as the bones allow
    far = ~r.reachable
    d_hat = target[far] / dist[far, None]
    np.testing.assert_allclose(r.end[far], d_hat * np.clip(dist[far], np.abs(upper - lower)[far],
                                                           (upper + lower)[far])[:, None], atol=1e-12)
    stretched = dist > upper + lower
    np.testing.assert_allclose(r.mid[stretched], (target[stretched] / dist[stretched, None]) * upper[stretched, None])
    np.testing.assert_allclose(r.mid_angle[stretched], np.pi)
    np.testing.assert_allclose(r.bend, np.pi - r.mid_angle)


def test_interior_and_root_angles_match_the_positions():
    rng = np.random.default_rng(1)
    upper, lower, target, pole = random_cases(500, rng)
    r = two_bone(upper, lower, target, pole)
    a, b = -r.mid, r.end - r.mid
    cos_mid = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    np.testing.assert_allclose(np.cos(r.mid_angle), cos_mid, atol=1e-9)
    end_dir = r.end / np.linalg.norm(r.end, axis=1, keepdims=True)
    np.testing.assert_allclose(np.cos(r.root_angle), np.sum(r.mid * end_dir, 1) / upper, atol=1e-9)


def test_solutions_mirror_each_other_and_respect_the_pole():
    rng = np.random.default_rng(2)
    upper, lower, target, pole = random_cases(1000, rng)
    plus = two_bone(upper, lower, target, pole, solution=+1)
    minus = two_bone(upper, lower, target, pole, solution=-1)
    np.testing.assert_allclose(plus.end, minus.end)
    d_hat = target / np.linalg.norm(target, axis=1, keepdims=True)
    # mirror across the root-target line: same component along it, opposite perpendicular component
    along_p = np.sum(plus.mid * d_hat, 1)
    along_m = np.sum(minus.mid * d_hat, 1)
    np.testing.assert_allclose(along_p, along_m, atol=1e-12)
    np.testing.assert_allclose(plus.mid - along_p[:, None] * d_hat, -(minus.mid - along_m[:, None] * d_hat),
                               atol=1e-12)
    # the +1 elbow lies on the pole's side of the line, in the plane of the line and the pole
    side = np.sum(plus.mid * pole, 1) - along_p * np.sum(d_hat * pole, 1)
    bent = plus.reachable & (np.sin(plus.root_angle) > 1e-6)
    assert np.all(side[bent] > 0)
    normal = np.cross(d_hat, pole)
    np.testing.assert_allclose(np.sum(plus.mid * normal, 1), 0.0, atol=1e-12)


def test_knee_bends_forward_with_a_forward_pole():
    # hip at the origin, ankle target below and a little forward, pole +z (in front): the knee goes forward
    r = two_bone(0.42, 0.42, [0.0, -0.7, 0.1], [0.0, 0.0, 1.0])
    assert r.reachable and r.mid[2] > 0.1
    np.testing.assert_allclose(r.end, [0.0, -0.7, 0.1])
    # root keyword: world positions in, world positions out
    hip = np.array([1.0, 0.9, -2.0])
    w = two_bone(0.42, 0.42, hip + [0.0, -0.7, 0.1], [0.0, 0.0, 1.0], root=hip)
    np.testing.assert_allclose(w.mid, r.mid + hip)
    np.testing.assert_allclose(w.end, r.end + hip)


def test_vectorised_equals_scalar_reference():
    rng = np.random.default_rng(3)
    upper, lower, target, pole = random_cases(1000, rng)
    root = rng.normal(size=(1000, 3))
    # a few degenerate ones among them
    target[:5] = 0.0
    pole[5:10] = target[5:10] * rng.uniform(0.5, 2.0, (5, 1))
    pole[10:12] = 0.0
    lower[12:15] = upper[12:15]
    target[12] = 0.0
    for solution in (1, -1):
        r = two_bone(upper, lower, target + root, pole, solution=solution, root=root)
        for i in range(1000):
            mid, end, mid_angle, root_angle, ok = two_bone_scalar(upper[i], lower[i], target[i] + root[i], pole[i],
                                                                  solution, root=root[i])
            # near the reach limits the middle joint is ill-conditioned (sqrt of a tiny difference)
            np.testing.assert_allclose(r.mid[i], mid, atol=1e-7)
            np.testing.assert_allclose(r.end[i], end, atol=1e-12)
            assert math.isclose(r.mid_angle[i], mid_angle, abs_tol=1e-6)
            assert math.isclose(r.root_angle[i], root_angle, abs_tol=1e-6)
            assert r.reachable[i] == ok


def test_unbatched_inputs_give_unbatched_outputs_and_broadcast():
    r = two_bone(0.3, 0.25, [0.2, -0.3, 0.1], [0.0, 0.0, 1.0])
    assert r.mid.shape == (3,) and r.end.shape == (3,) and np.ndim(r.mid_angle) == 0 and r.reachable is True
    many = two_bone(np.full(4, 0.3), 0.25, [0.2, -0.3, 0.1], np.tile([0.0, 0.0, 1.0], (4, 1)))
    assert many.mid.shape == (4, 3)
    np.testing.assert_allclose(many.mid, np.tile(r.mid, (4, 1)))


def test_degenerate_inputs_never_nan():
    cases = [
        (0.3, 0.3, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),   # target at the root, equal bones: folded shut
        (0.3, 0.2, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),   # target at the root, unequal bones
        (0.3, 0.2, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),   # and no pole at all
        (0.3, 0.2, [0.4, 0.0, 0.0], [2.0, 0.0, 0.0]),   # pole along the root-target line
        (0.3, 0.2, [0.4, 0.0, 0.0], [0.0, 0.0, 0.0]),   # zero pole
        (0.3, 0.2, [0.05, 0.0, 0.0], [0.0, 1.0, 0.0]),  # closer than |upper - lower|
        (0.2, 0.3, [0.05, 0.0, 0.0], [0.0, 1.0, 0.0]),  # same, long lower bone
        (0.3, 0.2, [9.0, 0.0, 0.0], [0.0, 1.0, 0.0]),   # far beyond reach
        (0.3, 0.2, [0.5, 0.0, 0.0], [0.0, 1.0, 0.0]),   # exactly at full reach
        (0.3, 0.2, [1e-300, 0.0, 0.0], [0.0, 1.0, 0.0]),
    ]
    for upper, lower, target, pole in cases:
        for solution in (1, -1):
            r = two_bone(upper, lower, target, pole, solution=solution)
            for value in (r.mid, r.end, r.mid_angle, r.root_angle, r.bend):
                assert np.all(np.isfinite(value)), (upper, lower, target, pole)
            assert math.isclose(np.linalg.norm(r.mid), upper, rel_tol=1e-9)
            assert math.isclose(np.linalg.norm(r.end - r.mid), lower, rel_tol=1e-9)
    # equal bones, target at the root: the middle joint sits on the pole side
    r = two_bone(0.3, 0.3, [0.0, 0.0, 0.0], [0.0, 0.0, 2.0])
    np.testing.assert_allclose(r.mid, [0.0, 0.0, 0.3], atol=1e-12)
    assert r.reachable
    # folded: long upper bone points at the target, the lower bone folds back
    r = two_bone(0.3, 0.2, [0.05, 0.0, 0.0], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(r.mid, [0.3, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(r.end, [0.1, 0.0, 0.0], atol=1e-12)
    assert not r.reachable and r.mid_angle == 0.0
    # pole along the line: the bend plane holds the axis least aligned with the line (here y, first of y/z)
    r = two_bone(0.3, 0.2, [0.4, 0.0, 0.0], [1.0, 0.0, 0.0])
    assert abs(r.mid[2]) < 1e-12 and r.mid[1] > 0


def test_two_bone_angles():
    root, mid, bend = two_bone_angles(0.42, 0.42, np.array([0.84, 0.42, 0.0, 2.0]))
    np.testing.assert_allclose(mid, [np.pi, np.pi / 3, 0.0, np.pi])
    np.testing.assert_allclose(root, [0.0, np.pi / 3, np.pi / 2, 0.0])
    np.testing.assert_allclose(bend, np.pi - mid)
    with pytest.raises(ValueError, match="distance"):
        two_bone_angles(0.4, 0.4, -1.0)


@pytest.mark.parametrize("kwargs, name", [
    (dict(upper=0.0), "upper"),
    (dict(upper=-1.0), "upper"),
    (dict(lower=np.nan), "lower"),
    (dict(lower=np.ones((2, 2))), "lower"),
    (dict(target=[1.0, 2.0]), "target"),
    (dict(target=[[np.inf, 0.0, 0.0]]), "target"),
    (dict(target="abc"), "target"),
    (dict(pole=np.zeros((2, 2, 3))), "pole"),
    (dict(pole=[0.0, np.nan, 1.0]), "pole"),
    (dict(solution=0), "solution"),
    (dict(solution=True), "solution"),
    (dict(root=[0.0, 0.0]), "root"),
    (dict(target=np.zeros((3, 3)), pole=np.ones((4, 3))), "pole"),
])
def test_bad_inputs_raise_value_error_naming_the_argument(kwargs, name):
    args = dict(upper=0.3, lower=0.25, target=[0.2, -0.3, 0.1], pole=[0.0, 0.0, 1.0])
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"^{name}"):
        two_bone(**args)
