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
from rig_cases import free_tree


@pytest.fixture(autouse=True)
def lanes_only():
    if settings.lanes() == 1:  # CUDA: one character per thread, so there is no lane kernel to compare
        pytest.skip("lane width 1 (CUDA)")


RIGS = {"chain": lambda: cik.Rig.chain(7, 0.2, dim=3), "tree": free_tree}


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


def test_limited_lanes_stay_as_close_to_the_twin_as_the_kernel(monkeypatch):
    """The bench's humanoid (random poses, 100 sweeps, most targets out of reach): against the float64 twin the limited
    lanes agree as often as the one-character kernel does (long stalled solves amplify float32 rounding either way:
    1,000 characters, iterations 98.3 % against 98.4 %, poses within 1e-4 m 97.4 % for both), the statuses match the
    kernel's, and the characters that converge end within 1e-3 m of the twin."""
    if settings.limited_lanes() <= 1:
        pytest.skip("limited lanes off")
    from crowd_ik.bench import workloads as w

    wl = w.make_workload("humanoid", 100)
    runs = []
    for lanes in (True, False):
        monkeypatch.setattr(adapter, "lane_weights", adapter.lane_weights if lanes else (lambda crowd, req: None))
        crowd = cik.Crowd(wl.rig, wl.n, spacing=w.SPACING)
        crowd.set_angles(wl.angles)
        roots, yaw, rot0 = *crowd.roots(), crowd.rotations()
        rep = crowd.solve(wl.targets, method="ccd", max_iterations=wl.max_iterations, tolerance=wl.tolerance)
        runs.append((rep, crowd.joint_positions()))
    monkeypatch.undo()
    twin = ccd_solve(wl.rig, roots, yaw, rot0, wl.targets, max_iterations=wl.max_iterations, tolerance=wl.tolerance)
    (a, pa), (b, pb) = runs
    agree = [np.mean(r.iterations == twin["iterations"]) for r, _ in runs]
    assert agree[0] >= agree[1] - 0.05, agree
    assert np.mean(a.status == b.status) >= 0.95
    ok = (a.status == Status.CONVERGED) & (twin["iterations"] == a.iterations)
    assert ok.any()
    np.testing.assert_allclose(pa[ok], twin["pos"][ok], atol=1e-3)


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


def _game(n, orient):
    """n game humanoids in their cold-solved poses, the warm frames' moved targets, and flat-sole axis targets (or
    none)."""
    from crowd_ik.bench import workloads as w

    wl = w.game_workload(n)
    rig = wl.rig
    feet = np.array([name.startswith("foot") for name in rig.effector_names])
    offsets = w._smooth_offsets(n, rig.n_effectors, 5)
    frames = [(wl.targets + np.where(feet[None, :, None], 0.0, offsets(t))).astype(np.float32) for t in (0.2, 0.6)]
    axes = None
    if orient:
        axes = np.zeros((n, rig.n_effectors, 3), np.float32)
        axes[:, feet] = (0.0, -1.0, 0.0)
    return wl, frames, axes


@pytest.mark.parametrize("orient", [False, True], ids=["positions", "flat_soles"])
def test_limited_lanes_match_the_one_character_kernel_on_the_humanoid(monkeypatch, orient):
    """The game's warm 10-sweep solves of humanoids (joint limits, hinges, universal joints, the reach step), with
    and without orientation targets: the same statuses and iteration counts, poses within 1e-4 m for >= 99 %."""
    if settings.limited_lanes() <= 1:
        pytest.skip("limited lanes off")
    n = 4 * settings.limited_lanes() + 3
    wl, frames, axes = _game(n, orient)
    out = []
    for lanes in (True, False):
        monkeypatch.setattr(adapter, "lane_weights", adapter.lane_weights if lanes else (lambda crowd, req: None))
        crowd = cik.Crowd(wl.rig, n, spacing=2.0)
        crowd.set_angles(wl.angles)
        crowd.solve(wl.targets, method="fabrik", max_iterations=100, tolerance=wl.tolerance)
        start = crowd.rotations()
        got = []
        for targets in frames:
            crowd.set_rotations(start)
            rep = crowd.solve(targets, method="ccd", max_iterations=10, tolerance=wl.tolerance, orientations=axes)
            got.append((rep, crowd.joint_positions()))
        out.append(got)
    monkeypatch.undo()
    for (a, pa), (b, pb) in zip(*out):
        assert np.array_equal(a.status, b.status) and np.mean(a.iterations == b.iterations) >= 0.99
        assert a.iterations.max() > 1
        d = np.abs(pa - pb).max(axis=(1, 2))
        assert np.mean(d <= 1e-4) >= 0.99, np.sort(d)[-3:]


def test_limited_lanes_keep_the_characters_apart():
    """Humanoids with flat soles, the crowd solved in another order: every character's pose bit for bit."""
    if settings.limited_lanes() <= 1:
        pytest.skip("limited lanes off")
    n = 2 * settings.limited_lanes() + 3
    wl, frames, axes = _game(n, True)
    out = []
    for order in (np.arange(n), np.roll(np.arange(n), 3)):
        crowd = cik.Crowd(wl.rig, n, spacing=2.0)
        roots, yaw = crowd.roots()
        crowd.set_roots(roots[order], yaw[order])
        crowd.set_angles(wl.angles[order])
        rep = crowd.solve(frames[0][order], method="ccd", max_iterations=20, tolerance=wl.tolerance,
                          orientations=axes)
        back = np.argsort(order)
        out.append((rep.iterations[back], crowd.joint_positions()[back] - roots[:, None, :]))
    np.testing.assert_array_equal(out[1][0], out[0][0])
    np.testing.assert_array_equal(out[1][1], out[0][1])


def test_lanes_only_where_they_reproduce_the_request(monkeypatch):
    """Requests whose characters weight the same effectors (or none) take the lanes (a limited rig or orientation
    targets however many sweeps they ask for); per-character weight patterns and rotation targets take the
    one-character kernel."""
    calls = []
    real = adapter._solve_lanes
    monkeypatch.setattr(adapter, "_solve_lanes", lambda *a: calls.append(1) or real(*a))
    rig = free_tree()
    crowd, targets, weights = _case(rig, 8, seed=2)
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert len(calls) == 1
    weights[3] = 0.0  # a character weighting nothing: the same pattern among the others
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert len(calls) == 2
    weights[4, 0] = 0.0  # another pattern for one character
    crowd.solve(targets, method="ccd", weights=weights, max_iterations=5)
    assert len(calls) == 2
    human = cik.Crowd(cik.Rig.humanoid(), n=4)
    rots = np.zeros((4, human.rig.n_effectors, 4), np.float32)
    rots[..., 3] = 1.0
    human.solve(human.effector_positions(), method="ccd", max_iterations=2, rotations=rots)
    assert len(calls) == 2
    limited = 1 if settings.limited_lanes() > 1 else 0
    human.solve(human.effector_positions() + np.float32(0.05), method="ccd", max_iterations=2)
    assert len(calls) == 2 + limited
    human.solve(human.effector_positions() + np.float32(0.05), method="ccd", max_iterations=100)
    assert len(calls) == 2 + 2 * limited
