"""The constraint-free single-effector DLS kernel (kernels/dls_free.py) against the general kernel, the NumPy twin
and closed forms; batch == one at a time; Crowd.solve picks it exactly when it applies."""

import numpy as np
import pytest
import taichi as ti

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.kernels.dls_free import qexp_series
from crowd_ik.reference.dls import dls_solve, qexp
from solve_checks import assert_each_alone_gives_the_same_bits

CHAIN16 = dict(n_bones=16, bone_length=0.1, dim=3)


def ball_targets(n, radius, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d * radius * rng.uniform(0, 1, (n, 1)) ** (1 / 3)).astype(np.float32)


def one_arm_tree():
    """A constraint-free tree with one effector: a side branch off the path, which DLS never moves."""
    joints = [("root", -1, (0, 0, 0)), ("a", 0, (0, 0.3, 0)), ("b", 1, (0, 0.3, 0)), ("side", 1, (0.2, 0.1, 0)),
              ("side_tip", 3, (0.2, 0.0, 0)), ("c", 2, (0.0, 0.3, 0.1)), ("tip", 5, (0.0, 0.2, 0.0))]
    return cik.Rig(tuple(cik.Joint(n, p, o) for n, p, o in joints), (cik.Effector("tip", 6),))


def solve(rig, targets, start, roots, yaw, general, monkeypatch=None, **kwargs):
    from crowd_ik.solvers import dls as adapter

    crowd = cik.Crowd(rig, n=len(targets), spacing=0.0)
    crowd.set_roots(roots, yaw)
    crowd.set_angles(start)
    free = adapter._free
    if general:  # the general kernel solves what the closed form would
        adapter._free = adapter._general
    try:
        rep = crowd.solve(targets, method="dls", **kwargs)
    finally:
        adapter._free = free
    return rep, crowd.joint_positions(), crowd.rotations()


@pytest.mark.parametrize("rig_name", ["chain16", "tree"])
def test_free_kernel_takes_the_general_kernels_steps(rig_name):
    rig = cik.Rig.chain(**CHAIN16) if rig_name == "chain16" else one_arm_tree()
    assert rig.constraint_free and rig.n_effectors == 1
    n = 300
    rng = np.random.default_rng(3)
    roots = rng.uniform(-20, 20, (n, 3)).astype(np.float32)
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    reach = float(rig.reach[0])
    targets = roots[:, None] + ball_targets(n, 0.95 * reach, seed=4)[:, None]
    targets[:20] = roots[:20, None] + ball_targets(20, 2.0 * reach, seed=5)[:, None] * 1.5  # many out of reach
    start = (rng.normal(size=(n, rig.n_dof)) * 0.3).astype(np.float32)
    a, pa, qa = solve(rig, targets, start, roots, yaw, general=True, max_iterations=60, tolerance=1e-3)
    b, pb, qb = solve(rig, targets, start, roots, yaw, general=False, max_iterations=60, tolerance=1e-3)
    assert np.mean(b.status == Status.CONVERGED) > 0.8
    # the same steps up to float32 rounding: the same decisions for nearly every character
    assert np.mean(a.status == b.status) >= 0.99
    same = a.iterations == b.iterations
    reachable = a.status != Status.UNREACHABLE  # a plateau far from the target: its stall point is round-off
    assert np.mean(same[reachable]) >= 0.97
    np.testing.assert_allclose(b.error[same], a.error[same], atol=2e-4)
    np.testing.assert_allclose(pb[same], pa[same], atol=2e-3)
    np.testing.assert_allclose(np.linalg.norm(qb, axis=-1), 1.0, atol=1e-6)
    if rig_name == "tree":  # the side branch keeps its start rotation (renormalised only)
        side = 3  # "side"
        start_rot = solve(rig, targets, start, roots, yaw, general=False, max_iterations=1, tolerance=1e9)[2]
        np.testing.assert_allclose(qb[:, side], start_rot[:, side], atol=1e-6)


def test_free_kernel_matches_the_numpy_twin():
    rig = cik.Rig.chain(6, 0.25, dim=3)
    n = 24
    rng = np.random.default_rng(8)
    crowd = cik.Crowd(rig, n=n, spacing=1.5)
    roots, _ = crowd.roots()
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    crowd.set_roots(roots, yaw)
    targets = (roots[:, None] + ball_targets(n, 1.6, seed=9)[:, None]).astype(np.float32)
    crowd.set_angles((rng.normal(size=(n, rig.n_dof)) * 0.3).astype(np.float32))
    rot0 = crowd.rotations()
    rep = crowd.solve(targets, method="dls", max_iterations=60, tolerance=1e-3)
    rot, pos, err, iters, stalled = dls_solve(rig, roots, yaw, rot0, targets, max_iterations=60, tolerance=1e-3)
    agree = iters == rep.iterations
    assert np.mean(agree) >= 0.85
    np.testing.assert_allclose(rep.error[agree], err[agree], atol=1e-5)
    np.testing.assert_allclose(crowd.joint_positions()[agree], pos[agree], atol=1e-4)


def test_batch_equals_one_at_a_time():
    rig = cik.Rig.chain(**CHAIN16)
    n = 5
    rng = np.random.default_rng(6)
    roots = np.c_[rng.integers(-30, 30, n), np.zeros(n), rng.integers(-30, 30, n)].astype(np.float32)
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    targets = np.round((roots[:, None] + ball_targets(n, 1.5, seed=7)[:, None]) * 1024) / 1024
    _, rep = assert_each_alone_gives_the_same_bits(rig, roots, yaw, targets, "dls", max_iterations=100, tolerance=1e-4)
    assert np.all(rep.iterations > 0)  # each one solved something


def test_zero_weight_characters_do_not_move_and_others_do():
    rig = cik.Rig.chain(5, 0.2, dim=3)
    crowd = cik.Crowd(rig, n=3, spacing=1.0)
    before = crowd.joint_positions().copy()
    targets = crowd.effector_positions() - np.float32([0.3, -0.2, 0.1])  # the chain lies along +x: in reach
    rep = crowd.solve(targets, method="dls", weights=np.float32([[1.0], [0.0], [2.0]]), tolerance=1e-4)
    np.testing.assert_allclose(crowd.joint_positions()[1], before[1], atol=1e-6)
    assert rep.iterations[1] == 0
    assert np.all(rep.error[[0, 2]] <= 1e-4)


def test_crowd_uses_the_free_kernel_exactly_where_it_applies(monkeypatch):
    from crowd_ik.solvers import dls as adapter

    calls = []
    free = adapter._free
    monkeypatch.setattr(adapter, "_free", lambda crowd, req: (calls.append(1), free(crowd, req)))
    chain = cik.Rig.chain(4, 0.3, dim=3)
    two_arms = cik.Rig(one_arm_tree().joints, (cik.Effector("tip", 6), cik.Effector("side_tip", 4)))
    cases = [(chain, {}, 1), (one_arm_tree(), {}, 1), (chain, dict(damping=0.02), 1),
             (chain, dict(rest_weight=1e-3), 0), (chain, dict(velocity_weight=1e-3), 0),
             (chain, dict(joint_weights=np.ones(chain.n_dof)), 0), (two_arms, {}, 0),
             (cik.Rig.chain(4, 0.3, dim=3, lo=-1.0, hi=1.0), {}, 0), (cik.Rig.humanoid(), {}, 0)]
    for rig, kwargs, expected in cases:
        calls.clear()
        crowd = cik.Crowd(rig, n=2, spacing=2.0)
        crowd.solve(crowd.effector_positions() + 0.05, method="dls", **kwargs)
        assert len(calls) == expected, (rig.n_joints, kwargs)


@pytest.mark.parametrize("rig_name", ["chain16", "tree"])
def test_lane_packed_kernel_solves_each_character_as_the_one_character_kernel(monkeypatch, rig_name):
    """kernels/dls_lanes.py (streams of lanes that refill) against kernels/dls_free.py (one character per thread,
    what lanes = 1 selects): the same statuses, the same iteration counts for nearly all, the same poses up to
    float32 rounding, which a redundant chain's null space can grow to a millimetre for a few characters."""
    from crowd_ik.kernels import lane_plan
    from crowd_ik.solvers import settings

    rig = cik.Rig.chain(**CHAIN16) if rig_name == "chain16" else one_arm_tree()
    n = 2 * lane_plan.pass_lanes(settings.lanes()) + 7  # a partial last packet
    rng = np.random.default_rng(13)
    roots = rng.uniform(-20, 20, (n, 3)).astype(np.float32)
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    reach = float(rig.reach[0])
    targets = roots[:, None] + ball_targets(n, 0.95 * reach, seed=14)[:, None]
    targets[:3] = roots[:3, None] + ball_targets(3, 2.0 * reach, seed=15)[:, None] * 1.5  # some out of reach
    start = (rng.normal(size=(n, rig.n_dof)) * 0.3).astype(np.float32)
    a, pa, qa = solve(rig, targets, start, roots, yaw, general=False, max_iterations=60, tolerance=1e-3)
    with monkeypatch.context() as m:
        m.setattr(settings, "lanes", lambda: 1)
        b, pb, qb = solve(rig, targets, start, roots, yaw, general=False, max_iterations=60, tolerance=1e-3)
    np.testing.assert_array_equal(a.status, b.status)
    same = a.iterations == b.iterations
    # the out-of-reach characters stop where float32 rounding decides the stall test (at 8 lanes their share of
    # this small crowd is 3 of 39)
    assert np.mean(same[a.status == Status.CONVERGED]) >= 0.95 and np.mean(same) >= 0.9
    close = np.abs(pa - pb).max(axis=(1, 2)) <= 1e-4
    assert np.mean(close[same]) >= 0.9
    np.testing.assert_allclose(pa[same], pb[same], atol=5e-3)
    np.testing.assert_allclose(a.error[same], b.error[same], atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(qa, axis=-1), 1.0, atol=1e-6)


@ti.kernel
def _qexp_series_kernel(r: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), out: ti.types.ndarray(dtype=ti.math.vec4,
                                                                                               ndim=1)):
    for i in r:
        out[i] = qexp_series(r[i])


def test_series_exponential_equals_the_closed_form_on_both_sides_of_its_switch():
    rng = np.random.default_rng(2)
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.r_[0.0, 1e-9, 1e-4, rng.uniform(0, 3.1, 391), 1.4999, 1.5, 1.5001, 2.0, 3.14, 3.1415]
    r = (axes * angles[:, None]).astype(np.float32)
    rn = ti.ndarray(ti.math.vec3, shape=len(r))
    rn.from_numpy(r)
    out = ti.ndarray(ti.math.vec4, shape=len(r))
    _qexp_series_kernel(rn, out)
    np.testing.assert_allclose(out.to_numpy(), qexp(r.astype(np.float64)), atol=3e-7)
