"""Constraint-free FABRIK as SIMD lanes (kernels/fabrik_lanes.py, solvers/fabrik_free.py): the recovery's write-back,
its re-summed weights and the flat-row addressing give what the one-character kernel and the NumPy twin give, for
every lane, any stream count and a character alone."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.geometry.fk import forward_kinematics
from crowd_ik.reference.fabrik import fabrik_solve
from rig_cases import free_tree


def _case(rig, n, seed):
    """n characters, turned roots, a start pose off rest, targets near, on, or out of reach, per-character weights."""
    rng = np.random.default_rng(seed)
    crowd = cik.Crowd(rig, n=n, spacing=1.5)
    roots, _ = crowd.roots()
    crowd.set_roots(roots, yaw=rng.uniform(-3, 3, n).astype(np.float32))
    angles = rng.normal(size=(n, rig.n_dof)).astype(np.float32) * 0.3
    crowd.set_angles(angles)
    targets = crowd.effector_positions() + rng.normal(size=(n, rig.n_effectors, 3)).astype(np.float32) * 0.3
    targets[0] = crowd.effector_positions()[0]  # already there: no iteration, the pose is left as it is
    targets[1, 0] += (5.0, 0.0, 0.0)  # out of reach
    weights = np.ones((n, rig.n_effectors), np.float32)
    if rig.n_effectors > 1:
        weights[2::3, 0] = 0.0  # one branch only: the sub-base has one active child
        weights[3::3, 1] = 2.5  # unequal weights: the sub-base's centroid and swing mean are weighted
    return crowd, angles, targets, weights


RIGS = {"chain": lambda: cik.Rig.chain(7, 0.2, dim=3), "tree": free_tree}


@pytest.mark.parametrize("name", sorted(RIGS))
def test_lanes_match_the_twin_and_the_recovered_pose_is_its_own_fk(name):
    """Against the NumPy twin (deferred recovery, float64): the same iterations for nearly all, poses within 2e-4 m;
    and the written pose is FK of the written local rotations (world positions and rotations, every joint)."""
    rig = RIGS[name]()
    n = 3 * cik.solvers.settings.lanes() + 5  # a partial last packet
    crowd, angles, targets, weights = _case(rig, n, seed=4)
    rot0 = crowd.rotations()
    roots, yaw = crowd.roots()
    pos0 = crowd.joint_positions()
    rep = crowd.solve(targets, weights=weights, max_iterations=30, tolerance=1e-4)
    rot, pos, err, iters, _ = fabrik_solve(rig, roots, yaw, rot0, targets, weights=weights, max_iterations=30,
                                           tolerance=1e-4)
    same = rep.iterations == iters
    reachable = rep.status != Status.UNREACHABLE
    assert np.mean(same[reachable]) >= 0.95 and same[0] and rep.iterations[0] == 0
    np.testing.assert_allclose(crowd.joint_positions()[same], pos[same], atol=2e-4)
    np.testing.assert_allclose(rep.error[same], err[same], atol=2e-4)
    np.testing.assert_array_equal(crowd.joint_positions()[0], pos0[0])  # not iterated: not rewritten
    fk_pos, fk_rot = forward_kinematics(rig, roots.astype(np.float64), yaw.astype(np.float64),
                                        crowd.rotations().astype(np.float64))
    np.testing.assert_allclose(crowd.joint_positions(), fk_pos, atol=2e-5)
    np.testing.assert_allclose(np.abs(np.sum(crowd.world_rotations() * fk_rot, axis=-1)), 1.0, atol=2e-5)
    # the error reported is the written pose's
    eff = rig.arrays["eff_joint"]
    d = np.linalg.norm(crowd.joint_positions()[:, eff] - targets, axis=-1)
    np.testing.assert_allclose(rep.error, np.max(np.where(weights > 0, d, 0.0), axis=1), atol=1e-6)


@pytest.mark.parametrize("name", sorted(RIGS))
def test_lanes_match_the_one_character_kernel(monkeypatch, name):
    """The lane kernels, at the machine's width and at one lane (CUDA's streams, joint-major scratch), against
    fabrik_solve one character per thread with the rotations recovered once (CROWD_IK_FREE_LANES=0): the same
    status (but at the tolerance), iterations and pose up to the lanes' reciprocal multiplies."""
    from crowd_ik.solvers import settings

    rig = RIGS[name]()
    L = settings.lanes()
    n = max(6 * L, 96) + 3  # partial last packets; enough characters for the shares below at 8 lanes too

    def run(lanes, free_lanes):
        monkeypatch.setattr(settings, "lanes", lambda: lanes)
        monkeypatch.setenv("CROWD_IK_FREE_LANES", free_lanes)
        crowd, _, targets, weights = _case(rig, n, seed=11)
        rep = crowd.solve(targets, weights=weights, max_iterations=40, tolerance=1e-4)
        return rep, crowd.joint_positions(), crowd.rotations(), crowd.world_rotations()

    b, pb, qb, wb = run(L, "0")
    for lanes in sorted({L, 1}):
        a, pa, qa, wa = run(lanes, "1")
        reachable = a.status != Status.UNREACHABLE
        same = a.iterations == b.iterations
        # characters that converge: the same count; those that stall far off (a tree's effectors pulled apart) stop
        # where float32 rounding decides the "no progress" test, a few iterations apart (on 1,000: 97 % the same, at
        # 8 and 16 lanes alike)
        assert np.mean(same[a.status == Status.CONVERGED]) >= 0.95 and np.mean(same[reachable]) >= 0.85
        # the same status, but for a character that ends at the tolerance (float32 rounding decides it)
        edge = (np.abs(a.error - 1e-4) <= 1e-6) & (np.abs(b.error - 1e-4) <= 1e-6)
        assert np.mean(edge) <= 0.05
        # and STALLED against MAX_ITERATIONS for a character that stopped at another count (both not converged)
        stop = (Status.STALLED, Status.MAX_ITERATIONS)
        swap = ~same & np.isin(a.status, stop) & np.isin(b.status, stop)
        assert np.mean(swap) <= 0.05
        keep = reachable & ~edge & ~swap
        np.testing.assert_array_equal(a.status[keep], b.status[keep])
        for x, y in ((pa, pb), (qa, qb), (wa, wb)):
            np.testing.assert_allclose(x[same], y[same], atol=1e-4)


def test_a_character_gets_the_same_result_alone_in_any_lane_and_stream_count():
    """Batch == one at a time, bit for bit: a character alone in a padded packet, and the whole crowd run with one
    stream, two, or the default count (which threads run which streams is all the thread count changes)."""
    from crowd_ik.kernels import fabrik_lanes, lane_plan
    from crowd_ik.solvers import bundles, settings

    rig = free_tree()
    n = 2 * settings.lanes() + 7
    crowd, angles, targets, weights = _case(rig, n, seed=8)
    batch = crowd.solve(targets, weights=weights, max_iterations=40, tolerance=1e-4)
    pos, rot, wrot = crowd.joint_positions(), crowd.rotations(), crowd.world_rotations()
    roots, yaw = crowd.roots()
    for i in (0, 1, 2, 3, min(9, n - 2), n - 1):  # n is 9 at one lane (CUDA)
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i:i + 1], yaw=yaw[i:i + 1])
        one.set_angles(angles[i:i + 1])
        rep = one.solve(targets[i:i + 1], weights=weights[i:i + 1], max_iterations=40, tolerance=1e-4)
        assert rep.iterations[0] == batch.iterations[i] and rep.status[0] == batch.status[i]
        np.testing.assert_array_equal(one.joint_positions()[0], pos[i])
        np.testing.assert_array_equal(one.rotations()[0], rot[i])
        np.testing.assert_array_equal(one.world_rotations()[0], wrot[i])
    # the kernels themselves with other stream counts, and at one lane with either scratch layout
    from crowd_ik.solvers.fabrik_free import lane_layout

    L, ra, ti = settings.lanes(), crowd.rig_arrays, crowd.ti
    LP, default_streams, cap, joint_major = lane_layout(n)
    P, J, E = lane_plan.packets(n, L), rig.n_joints, rig.n_effectors
    V = ti.types.vector(L, ti.f32)
    layout = (cap, joint_major)
    runs = [(default_streams, False, layout), (1, False, layout), (2, True, layout)]
    if L == 1:  # CUDA's joint-major scratch and the CPU's stream-major one: the same arithmetic
        runs.append((3, False, (lane_plan.MAX_STREAMS, False)))
    for streams, serial, lay in runs:
        crowd.set_angles(angles)
        crowd.buffers.targets[...] = targets
        crowd.buffers.weights[...] = weights
        proposals = [ti.ndarray(V, shape=(P, J)) for _ in range(3)]
        fabrik_lanes.free_solver(LP, L, lane_plan.capacity(J), lane_plan.capacity(E), *lay)(
            ra["parent"], ra["bone"], ra["eff_joint"], crowd.world_pos, crowd.root_pos,
            *bundles.goal(crowd, orientations=False),
            streams, *proposals, 40, 1e-4, *bundles.result(crowd), serial)
        fabrik_lanes.free_recover(L, lane_plan.capacity(J), *lay)(
            ra["parent"], ra["offset"], ra["bone"], ra["kind"], ra["child_start"], ra["child_list"], ra["eff_joint"],
            *bundles.pose(crowd), *bundles.goal(crowd, orientations=False), *proposals, streams,
            crowd.buffers.error, crowd.buffers.iterations, serial)
        got = (crowd.buffers.iterations.copy(), crowd.buffers.error.copy(), crowd.joint_positions(),
               crowd.rotations(), crowd.world_rotations())
        for a, b in zip(got, (batch.iterations, batch.error, pos, rot, wrot)):
            np.testing.assert_array_equal(a, b)


def test_the_stream_plan_per_backend(monkeypatch):
    """solvers/fabrik_free.lane_layout: the CPU's lanes keep the factories' defaults (two vectors per value, a stream
    per ~32 characters a lane, one stream on one thread); one lane on CUDA runs a stream per GPU thread over
    GPU_STREAMS joint-major rows; one lane on the CPU (CUDA's configuration, for the tests) the same layout in
    MAX_STREAMS rows."""
    from crowd_ik.kernels import lane_plan
    from crowd_ik.solvers import settings
    from crowd_ik.solvers.fabrik_free import lane_layout

    cpu, gpu = lane_plan.MAX_STREAMS, lane_plan.GPU_STREAMS
    monkeypatch.setattr(settings, "lanes", lambda: 16)
    assert lane_layout(100_000) == (32, lane_plan.streams(100_000, 32), cpu, False)
    assert lane_plan.streams(100_000, 32) > 8 and lane_layout(100, serial=True) == (32, 1, cpu, False)
    monkeypatch.setattr(settings, "lanes", lambda: 1)
    assert lane_layout(100_000) == (1, cpu, cpu, True) and lane_layout(9) == (1, 9, cpu, True)
    monkeypatch.setitem(settings._LANES, "arch", "cuda")
    assert lane_layout(1_000_000) == (1, gpu, gpu, True) and lane_layout(10_000) == (1, 10_000, gpu, True)
