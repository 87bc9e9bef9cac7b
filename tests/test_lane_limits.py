"""kernels/lane_limits.py's trigonometry-free joint-limit projection on 8-lane packets against the NumPy twin
(crowd_ik/geometry/quat.py's constrain_rotation), and the half angles it runs on: lane_math.half_turn and
solvers/limits.py's limit_half_turns."""

import numpy as np
import pytest
from limit_cases import LIMIT_CASES

import crowd_ik as cik
from crowd_ik.geometry import quat as rq
from crowd_ik.solvers.limits import limit_half_turns, limit_pseudo_angles

cik.init("cpu")

import taichi as ti  # noqa: E402

from crowd_ik.kernels import lane_limits as lim  # noqa: E402
from crowd_ik.kernels import lane_math as lm  # noqa: E402

L = 8
V = ti.types.vector(L, ti.f32)


@ti.kernel
def _half_turns(xy: ti.types.ndarray(dtype=V, ndim=2), out: ti.types.ndarray(dtype=V, ndim=2)):
    for i in range(xy.shape[0]):
        out[i, 0], out[i, 1] = lm.half_turn(xy[i, 0], xy[i, 1])
        out[i, 2], out[i, 3] = lm.unit_half_turn(xy[i, 0], xy[i, 1])


@ti.kernel
def _constrain(kind: ti.template(), q: ti.types.ndarray(dtype=V, ndim=2), ax0: ti.math.vec3, ax1: ti.math.vec3,
               lo: ti.template(), hi: ti.template(), lim_p: ti.template(), lim_h: ti.template(), cone: ti.f32,
               bone: ti.math.vec3, out: ti.types.ndarray(dtype=V, ndim=2)):
    for i in range(q.shape[0]):
        qx, qy, qz, qw = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        rx, ry, rz, rw = qx, qy, qz, qw
        if ti.static(kind == 1):
            rx, ry, rz, rw = lim.constrain_hinge(qx, qy, qz, qw, ax0, lim_p, lim_h, 0)
        elif ti.static(kind == 2):
            rx, ry, rz, rw = lim.constrain_universal(qx, qy, qz, qw, ax0, ax1, lim_p, lim_h, 0)
        else:
            rx, ry, rz, rw = lim.constrain_ball(qx, qy, qz, qw, lo, hi, lim_p, lim_h, 0, cone, bone, qw == qw)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = rx, ry, rz, rw


def _field(a):
    a = np.ascontiguousarray(a, np.float32)
    f = ti.field(ti.f32, shape=a.shape)
    f.from_numpy(a)
    return f


def _lane_constrain(kind, axes, q, lo, hi, cone=0.0, bone=(0.0, 0.0, 0.0)):
    """The lane functions on (N, 4) rotations, N a multiple of L, one rotation per lane."""
    lo64, hi64 = np.append(lo, 0.0), np.append(hi, 0.0)
    ax = [ti.math.vec3(*a) for a in axes] + [ti.math.vec3(0.0, 0.0, 1.0)] * (2 - len(axes))
    packed = np.ascontiguousarray(q.reshape(-1, L, 4).transpose(0, 2, 1), np.float32)
    out = np.zeros_like(packed)
    _constrain(kind, packed, ax[0], ax[1], _field(lo64), _field(hi64), _field(limit_pseudo_angles(lo64, hi64)),
               _field(limit_half_turns(lo64, hi64)), cone, ti.math.vec3(*bone), out)
    return out.transpose(0, 2, 1).reshape(-1, 4).astype(np.float64)


def _rotation_distance(a, b):
    """Per row, the largest component of a - b or of a + b, whichever is smaller: q and -q are one rotation."""
    return np.minimum(np.abs(a - b).max(axis=1), np.abs(a + b).max(axis=1))


CASES = LIMIT_CASES + [(1, [(0.0, 1.0, 0.0)], [-3.1], [-2.0])]  # and a hinge's limits on one side of pi


@pytest.mark.parametrize("kind, axes, lo, hi", CASES)
def test_the_lane_projection_matches_the_numpy_twin(kind, axes, lo, hi):
    rng = np.random.default_rng(kind * 31 + int(100 * hi[0]) % 89)
    n = 4096
    bound = np.array([3.0, 1.5, 3.0]) if kind == 3 else np.full(kind, 3.0)
    low, high = np.clip(np.array(lo), -bound, bound), np.clip(np.array(hi), -bound, bound)
    ax = np.array(axes, np.float64) if axes else np.zeros((0, 3))
    q_in = rq.joint_quat(kind, ax, low + (high - low) * rng.uniform(0.02, 0.98, (n // 2, kind)))
    q = rng.normal(size=(n - n // 2, 4))
    q = np.concatenate([q_in, q / np.linalg.norm(q, axis=1, keepdims=True)])
    want = rq.constrain_rotation(kind, ax, q, np.array(lo), np.array(hi), 0.0, np.zeros(3))
    got = _lane_constrain(kind, axes, q, lo, hi)
    assert np.all(np.isfinite(got))
    assert np.abs(np.linalg.norm(got, axis=1) - 1.0).max() < 1e-5
    assert _rotation_distance(got, want).max() < 5e-6
    assert _rotation_distance(got[: n // 2], q_in).max() < 5e-6  # inside the limits nothing moves
    # the twin clamps many of the others: the test sees limits that bite
    assert np.mean(_rotation_distance(want[n // 2:], q[n // 2:]) > 1e-3) > 0.2 or max(hi) > 3.2


@pytest.mark.parametrize("lo, hi, cone, bone", [
    ([-2.0, -0.5, -0.35], [0.5, 0.7, 1.0], 0.8, (0.0, -1.0, 0.0)),  # a hip's box with a cone about its thigh
    ([-0.5, -1.0, -1.5], [0.5, 1.0, 1.5], 1.0, (0.6, -0.8, 0.0)),
    ([-1e30, -1e30, -1e30], [1e30, 1e30, 1e30], 0.6, (0.0, 1.0, 0.0)),  # a cone alone
])
def test_the_lane_ball_joint_with_a_cone_matches_the_numpy_twin(lo, hi, cone, bone):
    rng = np.random.default_rng(5)
    q = rng.normal(size=(4096, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    want = rq.constrain_rotation(3, np.zeros((0, 3)), q, np.array(lo), np.array(hi), cone, np.array(bone))
    got = _lane_constrain(3, [], q, lo, hi, cone=cone, bone=bone)
    assert _rotation_distance(got, want).max() < 1e-4  # float32 acos and bisection tests near the cone's edge
    assert np.mean(_rotation_distance(got, want) < 1e-5) > 0.99


def test_half_turn_is_half_of_atan2_in_every_quadrant_and_on_the_axes():
    # its domain: |(x, y)| within 1e-18..1e18, where x * x + y * y neither underflows nor overflows in float32
    rng = np.random.default_rng(3)
    xy = rng.normal(size=(4096, 2)) * np.exp(rng.uniform(-20.0, 20.0, (4096, 1)))
    xy[:16] = [[1, 0], [0, 1], [-1, 0], [0, -1], [0, 0], [-1, 1e-30], [-1, -1e-30], [3, 4], [-3, 4], [-3, -4],
               [3, -4], [1e-30, -1], [-1e-30, -1], [1e18, 1e18], [-1e-18, 1e-18], [2, 0]]
    packed = np.ascontiguousarray(xy.reshape(-1, L, 2).transpose(0, 2, 1), np.float32)
    out = np.zeros((packed.shape[0], 4, L), np.float32)
    _half_turns(packed, out)
    got = out.transpose(0, 2, 1).reshape(-1, 4).astype(np.float64)
    x32, y32 = xy.astype(np.float32).astype(np.float64).T
    h = 0.5 * np.arctan2(y32, x32)
    h[(x32 == 0) & (y32 == 0)] = 0.0
    assert np.all(got[:, 0] >= 0.0)  # cos h >= 0: h in [-pi/2, pi/2]
    assert np.allclose(np.arctan2(got[:, 1], got[:, 0]), h, atol=2e-6, rtol=0)
    assert np.allclose(got[:, 2], np.cos(h), atol=1e-6) and np.allclose(got[:, 3], np.sin(h), atol=1e-6)
    assert (got[4, 2], got[4, 3]) == (1.0, 0.0)  # no angle at the origin: the identity


def test_limit_half_turns_are_the_half_angles_of_the_clipped_limits():
    lo = np.array([-1e30, -4.0, -np.pi, -0.5, 0.0, 1.0])
    hi = np.array([1e30, 4.0, np.pi, 0.25, 2.62, 3.0])
    h = limit_half_turns(lo, hi)
    assert h.shape == (6, 4) and h.dtype == np.float32
    lo_c, hi_c = np.clip(lo, -np.pi, np.pi), np.clip(hi, -np.pi, np.pi)
    want = np.stack([np.cos(lo_c / 2), np.sin(lo_c / 2), np.cos(hi_c / 2), np.sin(hi_c / 2)], -1)
    assert np.abs(h - want).max() < 1e-7
    # the rotation by a limit about an axis is (axis sin, cos): the hinge quaternion of joint_quat
    axis = np.array([[0.0, 0.0, 1.0]])
    for d in (3, 4, 5):
        q = rq.joint_quat(1, axis, np.array([[hi[d]]]))[0]
        assert np.abs(q - [0.0, 0.0, h[d, 3], h[d, 2]]).max() < 1e-6
