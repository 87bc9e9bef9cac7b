"""kernels/quat.py against its NumPy twin (crowd_ik/geometry/quat.py): the joint-limit projection, whose
no-limit-bites test runs on pseudo-angles instead of trigonometry, and the pseudo-angle itself."""

import numpy as np
import pytest
from limit_cases import LIMIT_CASES

import crowd_ik as cik
from crowd_ik.geometry import quat as rq

cik.init("cpu")

import taichi as ti  # noqa: E402

from crowd_ik.kernels import quat as kq  # noqa: E402


@ti.kernel
def _constrain(kind: ti.i32, ax0: ti.math.vec3, ax1: ti.math.vec3, q: ti.types.ndarray(dtype=ti.math.vec4, ndim=1),
               lo: ti.types.ndarray(ndim=1), hi: ti.types.ndarray(ndim=1), lim_p: ti.types.ndarray(ndim=2),
               cone: ti.f32, bone: ti.math.vec3, out: ti.types.ndarray(dtype=ti.math.vec4, ndim=1)):
    for i in range(q.shape[0]):
        out[i] = kq.constrain_rotation(kind, ax0, ax1, q[i], lo, hi, lim_p, 0, cone, bone)


@ti.kernel
def _pseudo(xy: ti.types.ndarray(dtype=ti.math.vec2, ndim=1), out: ti.types.ndarray(ndim=1)):
    for i in range(xy.shape[0]):
        out[i] = kq.pseudo_angle(xy[i].x, xy[i].y)


def _random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _distance(a, b):
    """Per row, the largest component of a - b: the kernel keeps its twin's signs (w >= 0 on each hinge factor)."""
    return np.abs(a - b).max(axis=1)


def _kernel_constrain(kind, axes, q, lo, hi, cone=0.0, bone=(0.0, 0.0, 0.0)):
    pad = lambda v: np.append(np.asarray(v, np.float32), np.float32(0.0))  # noqa: E731
    lo32, hi32 = pad(lo), pad(hi)
    q32 = np.ascontiguousarray(q, np.float32)
    out = np.zeros_like(q32)
    ax = [ti.math.vec3(*a) for a in axes] + [ti.math.vec3(0.0, 0.0, 1.0)] * (2 - len(axes))
    _constrain(kind, ax[0], ax[1], q32, lo32, hi32, rq.limit_pseudo_angles(lo32, hi32), cone, ti.math.vec3(*bone),
               out)
    return out


@pytest.mark.parametrize("kind, axes, lo, hi", LIMIT_CASES)
def test_constrain_rotation_matches_the_numpy_twin_inside_and_outside_the_limits(kind, axes, lo, hi):
    rng = np.random.default_rng(kind * 100 + int(10 * hi[0]) % 97)
    n = 4000
    # half the rotations drawn inside the limits (the cheap test must pass them through), half anywhere
    # (an Euler middle angle past +-pi/2 stands for another decomposition: keep it inside +-1.5)
    bound = np.array([3.0, 1.5, 3.0]) if kind == 3 else np.full(kind, 3.0)
    low, high = np.clip(np.array(lo), -bound, bound), np.clip(np.array(hi), -bound, bound)
    inside_angles = low + (high - low) * rng.uniform(0.02, 0.98, (n // 2, kind))
    ax = np.array(axes, np.float64) if axes else np.zeros((0, 3))
    q_in = rq.joint_quat(kind, ax, inside_angles)
    q = np.concatenate([q_in, _random_quats(rng, n - n // 2)])
    want = rq.constrain_rotation(kind, ax, q, np.array(lo), np.array(hi), 0.0, np.zeros(3))
    got = _kernel_constrain(kind, axes, q, lo, hi)
    assert np.all(np.isfinite(got))
    assert np.abs(np.linalg.norm(got, axis=1) - 1.0).max() < 1e-5
    assert _distance(got, want).max() < 2e-6
    # inside the limits the projection leaves a rotation already on the joint's DOFs where it is
    assert _distance(got[: n // 2], q_in).max() < 2e-6
    # and the angles the kernel's rotations stand for are inside the limits
    angles = rq.joint_angles(kind, ax, got.astype(np.float64)) if kind < 3 else rq.quat_to_euler_xyz(got)
    assert np.all(angles >= np.array(lo) - 1e-3) and np.all(angles <= np.array(hi) + 1e-3)


def test_constrain_rotation_with_a_cone_matches_the_numpy_twin():
    rng = np.random.default_rng(7)
    q = _random_quats(rng, 3000)
    lo, hi, bone = [-1.0, -0.5, -1.0], [1.0, 0.5, 1.0], np.array([0.0, 1.0, 0.0])
    want = rq.constrain_rotation(3, np.zeros((0, 3)), q, np.array(lo), np.array(hi), 0.6, bone)
    got = _kernel_constrain(3, [], q, lo, hi, cone=0.6, bone=tuple(bone))
    assert _distance(got, want).max() < 1e-5  # float32 acos near the cone's edge


@pytest.mark.parametrize("lo, hi, cone, bone", [
    ([-2.0, -0.5, -0.35], [0.5, 0.7, 1.0], 0.8, (0.0, -1.0, 0.0)),  # a hip's box with a cone about its thigh
    ([-1.2, -0.4, -0.9], [1.2, 0.4, 0.9], 0.6, (0.0, -1.0, 0.0)),
    ([-0.5, -1.0, -1.5], [0.5, 1.0, 1.5], 1.0, (0.6, -0.8, 0.0)),
])
def test_a_cone_and_a_box_both_hold_after_the_projection(lo, hi, cone, bone):
    # issue 15: the box clamp after the cone put the bone up to 1.4 rad back outside the cone
    rng = np.random.default_rng(11)
    q = _random_quats(rng, 4000)
    bone = np.array(bone)
    want = rq.constrain_rotation(3, np.zeros((0, 3)), q, np.array(lo), np.array(hi), cone, bone)
    got = _kernel_constrain(3, [], q, lo, hi, cone=cone, bone=tuple(bone))
    assert _distance(got, want).max() < 1e-4  # float32 trigonometry in the bisection's tests
    for out, tol in ((want, 1e-6), (got.astype(np.float64), 1e-3)):
        ang = np.arccos(np.clip(np.sum(rq.qrot(out, np.broadcast_to(bone, out.shape[:-1] + (3,))) * bone, -1), -1, 1))
        assert ang.max() <= cone + tol
        a = rq.quat_to_euler_xyz(out)
        assert np.all(a >= np.array(lo) - 1e-4) and np.all(a <= np.array(hi) + 1e-4)
    # the projection still leaves rotations inside both alone, and the cone bites for many of the others
    inside = rq.constrain_rotation(3, np.zeros((0, 3)), want, np.array(lo), np.array(hi), cone, bone)
    assert _distance(inside, want).max() < 1e-6
    assert np.mean(ang > cone - 1e-2) > 0.2


def test_pseudo_angle_orders_directions_as_atan2_does():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(-np.pi, np.pi, 5000))
    xy = np.stack([np.cos(t), np.sin(t)], axis=1) * rng.uniform(0.1, 10.0, (5000, 1))
    got = np.zeros(5000, np.float32)
    _pseudo(np.ascontiguousarray(xy, np.float32), got)
    assert np.all(np.diff(got) >= 0) and got[0] > -2.0 and got[-1] <= 2.0
    np.testing.assert_allclose(got, rq.pseudo_angle(xy[:, 0], xy[:, 1]), atol=1e-6)
    # the half-turn sits at the top of the range, as atan2(0, -1) = pi
    assert rq.pseudo_angle(-1.0, 0.0) == 2.0 and rq.pseudo_angle(1.0, 0.0) == 0.0


def test_limit_pseudo_angles_keep_limits_past_a_half_turn_from_biting():
    got = rq.limit_pseudo_angles(np.array([-1e30, -np.pi, -0.5, 3.5]), np.array([1e30, np.pi, 0.5, 4.0]))
    assert got.dtype == np.float32 and got.shape == (4, 2)
    np.testing.assert_array_equal(got[:2], [[-3.0, 3.0], [-3.0, 3.0]])
    np.testing.assert_allclose(got[2], rq.pseudo_angle(np.cos([-0.5, 0.5]), np.sin([-0.5, 0.5])), atol=1e-7)
    assert got[3, 0] == 3.0  # a lower limit past pi always bites
