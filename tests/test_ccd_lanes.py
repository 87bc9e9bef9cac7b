"""CCD on constraint-free rigs as SIMD lanes (kernels/ccd_lanes.py, solvers/ccd.py): what the one-character kernel
and the NumPy twin give, for every lane, a character alone or among other lane-mates, and the dispatch only where
the lanes reproduce the request."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.reference.ccd import ccd_solve
from crowd_ik.solvers import ccd as adapter
from crowd_ik.solvers import settings


@pytest.fixture(autouse=True)
def lanes_only():
    if settings.lanes() == 1:  # CUDA: one character per thread, so there is no lane kernel to compare
        pytest.skip("lane width 1 (CUDA)")


def _tree():
    """A constraint-free tree of 7 joints (a sub-base with two branches), two effectors."""
    return cik.Rig(
        tuple(cik.Joint(n, p, o) for n, p, o in [("root", -1, (0, 0, 0)), ("a", 0, (0, 0.3, 0)), ("b", 1, (0, 0.3, 0)),
                                              ("l", 2, (0.2, 0.1, 0)), ("r", 2, (-0.2, 0.1, 0)), ("lt", 3, (0.2, 0, 0)),
                                              ("rt", 4, (-0.2, 0, 0))]),
        (cik.Effector("left", 5), cik.Effector("right", 6)))


RIGS = {"chain": lambda: cik.Rig.chain(7, 0.2, dim=3), "tree": _tree}


def _case(rig, n, seed):
    """n characters, turned roots, a start pose off rest, targets near, on, or out of reach (the straighten step),
    unequal weights (the sub-base's swing mean is weighted), every character weighting every effector."""
    rng = np.random.default_rng(seed)
    crowd = cik.Crowd(rig, n=n, spacing=1.5)
    roots, _ = crowd.roots()
    crowd.set_roots(roots, yaw=rng.uniform(-3, 3, n).astype(np.float32))
    crowd.set_angles(rng.normal(size=(n, rig.n_dof)).astype(np.float32) * 0.3)
    targets = crowd.effector_positions() + rng.normal(size=(n, rig.n_effectors, 3)).astype(np.float32) * 0.3
    targets[0] = crowd.effector_positions()[0]  # already there: no sweep, the pose is left as it is
    targets[1::4, 0] += np.float32(3.0)  # out of reach: the serial joints straighten
    weights = rng.uniform(0.5, 2.5, (n, rig.n_effectors)).astype(np.float32)
    return crowd, targets, weights


def _solve_both(monkeypatch, rig, n, seed, iterations=60, tolerance=1e-4):
    out = []
    for lanes in (True, False):
        monkeypatch.setattr(adapter, "lane_weights", adapter.lane_weights if lanes else (lambda crowd, req: None))
        crowd, targets, weights = _case(rig, n, seed)
        rep = crowd.solve(targets, method="ccd", weights=weights, max_iterations=iterations, tolerance=tolerance)
        out.append((rep, crowd.joint_positions(), crowd.rotations(), crowd))
    monkeypatch.undo()
    return out


@pytest.mark.parametrize("name", sorted(RIGS))
def test_lanes_match_the_one_character_kernel(monkeypatch, name):
    """The same statuses and iteration counts for nearly all, poses within 1e-4 m (float32 rounding in another
    order: reciprocal normalisations), and the written pose is FK of the written rotations."""
    rig = RIGS[name]()
    n = 6 * settings.lanes() + 5  # a partial last packet
    (a, pa, qa, crowd), (b, pb, qb, _) = _solve_both(monkeypatch, rig, n, seed=4)
    assert np.mean(a.status == b.status) >= 0.97 and np.mean(a.iterations == b.iterations) >= 0.95
    assert a.iterations[0] == 0 and np.array_equal(qa[0], qb[0])
    d = np.abs(pa - pb).max(axis=(1, 2))
    assert np.mean(d <= 1e-4) >= 0.95, np.sort(d)[-5:]
    same = a.iterations == b.iterations
    np.testing.assert_allclose(a.error[same], b.error[same], atol=1e-4)
    crowd.set_rotations(qa)  # FK of the written rotations gives the written positions
    np.testing.assert_allclose(crowd.joint_positions(), pa, atol=2e-6)


def test_lanes_match_the_twin_on_chain16():
    """Against the float64 NumPy twin on the bench's chain16 targets: statuses for nearly all, poses within 1e-3 m
    where the iteration counts agree."""
    from crowd_ik.bench import workloads as w

    wl = w.make_workload("chain16", 40)
    crowd = cik.Crowd(wl.rig, wl.n, spacing=w.SPACING)
    crowd.set_angles(wl.angles)
    roots, yaw = crowd.roots()
    rot0 = crowd.rotations()
    rep = crowd.solve(wl.targets, method="ccd", max_iterations=wl.max_iterations, tolerance=wl.tolerance)
    twin = ccd_solve(wl.rig, roots, yaw, rot0, wl.targets, max_iterations=wl.max_iterations, tolerance=wl.tolerance)
    pos, iters = twin["pos"], twin["iterations"]
    same = rep.iterations == iters
    assert np.mean(same) >= 0.8
    np.testing.assert_allclose(crowd.joint_positions()[same], pos[same], atol=1e-3)
    assert np.all(rep.status[rep.error <= wl.tolerance] == Status.CONVERGED)


@pytest.mark.parametrize("name", sorted(RIGS))
def test_a_character_does_not_depend_on_its_lane_mates(name):
    """Alone in a padded packet, or in a crowd solved in another order: every character's pose bit for bit."""
    rig = RIGS[name]()
    n = 3 * settings.lanes() + 3
    crowd, targets, weights = _case(rig, n, seed=9)
    start, (roots, yaw) = crowd.rotations(), crowd.roots()
    crowd.set_rotations(start)  # every crowd below starts from set_rotations of the same rotations
    rep = crowd.solve(targets, method="ccd", weights=weights, max_iterations=40, tolerance=1e-4)
    pos = crowd.joint_positions()
    order = np.roll(np.arange(n), 5)
    other = cik.Crowd(rig, n=n, spacing=1.5)
    other.set_roots(roots[order], yaw[order])
    other.set_rotations(start[order])
    got = other.solve(targets[order], method="ccd", weights=weights[order], max_iterations=40, tolerance=1e-4)
    np.testing.assert_array_equal(got.iterations, rep.iterations[order])
    np.testing.assert_array_equal(other.joint_positions(), pos[order])
    for i in (2, n - 1):
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i:i + 1], yaw[i:i + 1])
        one.set_rotations(start[i:i + 1])
        r1 = one.solve(targets[i:i + 1], method="ccd", weights=weights[i:i + 1], max_iterations=40, tolerance=1e-4)
        assert r1.iterations[0] == rep.iterations[i] and r1.status[0] == rep.status[i]
        np.testing.assert_array_equal(one.joint_positions()[0], pos[i])


def test_lanes_only_where_they_reproduce_the_request(monkeypatch):
    """Constraint-free rigs with position targets whose characters weight the same effectors (or none) take the lanes;
    per-character weight patterns, orientation targets and limited rigs take the one-character kernel."""
    calls = []
    real = adapter._solve_lanes
    monkeypatch.setattr(adapter, "_solve_lanes", lambda *a: calls.append(1) or real(*a))
    rig = _tree()
    crowd, targets, weights = _case(rig, 8, seed=2)
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert calls == [1]
    weights[3] = 0.0  # a character weighting nothing: the same pattern among the others
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert calls == [1, 1]
    weights[4, 0] = 0.0  # another pattern for one character
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert calls == [1, 1]
    pointed = cik.Rig(rig.joints, (cik.Effector("left", 5, axis=(1.0, 0.0, 0.0)), cik.Effector("right", 6)))
    crowd = cik.Crowd(pointed, n=8, spacing=1.5)
    axes = np.zeros((8, 2, 3), np.float32)
    axes[:, 0] = (0.0, 1.0, 0.0)
    crowd.solve(targets, method="ccd", max_iterations=5)
    assert calls == [1, 1, 1]
    crowd.solve(targets, method="ccd", orientations=axes, max_iterations=5)
    assert calls == [1, 1, 1]
    human = cik.Crowd(cik.Rig.humanoid(), n=4)
    human.solve(human.effector_positions(), method="ccd", max_iterations=2)
    assert calls == [1, 1, 1]
