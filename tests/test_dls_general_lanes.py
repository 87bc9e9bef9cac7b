"""The general DLS as SIMD lanes (kernels/dls_general_lanes.py, solvers/dls.py): what the one-character kernel
(kernels/dls.py) and the float64 NumPy twin give, for every lane, a character alone or among other lane-mates, the
request's row layout, and the dispatch only where the lanes reproduce the request."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.reference.dls import dls_solve
from crowd_ik.solvers import dls as adapter
from crowd_ik.solvers import settings
from rig_cases import free_tree


@pytest.fixture(autouse=True)
def lanes_only():
    if settings.general_lanes() <= 1:  # CUDA, or switched off: the one-character kernel everywhere
        pytest.skip("general DLS lanes off")


def cone_arm():
    """Limits of every kind the kernel handles: a ball joint with a cone solved on its quaternion, one with a box and
    a cone solved in its Euler angles, a hinge, a universal joint; two effectors, the hand with an axis."""
    J = cik.Joint
    return cik.Rig(
        (J("root", -1, (0, 0, 0)), J("shoulder", 0, (0, 0.3, 0), cone=0.7),
         J("upper", 1, (0, 0.3, 0), lo=(-0.8, -0.6, -0.5), hi=(0.8, 0.6, 0.5), cone=0.6),
         J("elbow", 2, (0, 0.3, 0), kind="hinge", lo=(0.0,), hi=(2.4,)),
         J("wrist", 3, (0, 0.2, 0), kind="universal", lo=(-0.9, -0.4), hi=(0.9, 0.4)),
         J("hand", 4, (0, 0.1, 0)), J("side", 1, (0.25, 0.1, 0))),
        (cik.Effector("hand", 5, axis=(0.0, 1.0, 0.0)), cik.Effector("side", 6)))


RIGS = {"humanoid": cik.Rig.humanoid, "tree": free_tree, "arm": cone_arm}


def _case(rig, n, seed):
    """n characters, turned roots, a start pose off rest, targets near and out of reach, unequal weights per
    character (some weight an effector zero: zero rows in their lanes), orientation targets for some (zero axis
    rows for the others)."""
    rng = np.random.default_rng(seed)
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    roots, _ = crowd.roots()
    crowd.set_roots(roots, yaw=rng.uniform(-3, 3, n).astype(np.float32))
    crowd.set_angles(rng.normal(size=(n, rig.n_dof)).astype(np.float32) * 0.2)
    targets = crowd.effector_positions() + rng.normal(size=(n, rig.n_effectors, 3)).astype(np.float32) * 0.15
    targets[0] = crowd.effector_positions()[0]  # already there, but for the start pose's projection onto the limits
    targets[1::5, 0] += np.float32(2.0)  # out of reach
    weights = rng.uniform(0.5, 2.0, (n, rig.n_effectors)).astype(np.float32)
    weights[2::4, -1] = 0.0
    orient = None
    if rig.arrays["eff_has_axis"].any():
        orient = np.zeros((n, rig.n_effectors, 3), np.float32)
        axis = rng.normal(size=(n, 3)).astype(np.float32)
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        has = np.flatnonzero(rig.arrays["eff_has_axis"])
        orient[::2, has] = axis[::2, None]
        orient[0] = 0.0
    return crowd, targets, weights, orient


def _solve(crowd, targets, weights, orient, iterations):
    return crowd.solve(targets, method="dls", weights=weights, orientations=orient, max_iterations=iterations,
                       tolerance=1e-3)


def _on_both(monkeypatch, run):
    """[run() with the lanes, run() with the one-character kernel]."""
    out = []
    for lanes in (True, False):
        monkeypatch.setattr(settings, "general_lanes", settings.general_lanes if lanes else (lambda: 0))
        out.append(run())
    monkeypatch.undo()
    return out


def _on_both_and_twin(monkeypatch, rig, n, seed, kw):
    """_case(rig, n, seed) solved with DLS and the request kw: [(report, joint positions)] with the lanes and with the
    one-character kernel, and the float64 twin's result from the same start."""
    crowd, targets, weights, orient = _case(rig, n, seed)
    start = (*crowd.roots(), crowd.rotations())

    def run():
        crowd = _case(rig, n, seed)[0]
        rep = crowd.solve(targets, method="dls", weights=weights, orientations=orient, **kw)
        return rep, crowd.joint_positions()

    lanes, kernel = _on_both(monkeypatch, run)
    return lanes, kernel, dls_solve(rig, *start, targets, weights=weights, orientations=orient, **kw)


def _both(monkeypatch, rig, n, seed, iterations):
    def run():
        crowd, targets, weights, orient = _case(rig, n, seed)
        rep = _solve(crowd, targets, weights, orient, iterations)
        return rep, crowd.joint_positions(), crowd.rotations(), crowd

    return _on_both(monkeypatch, run)


@pytest.mark.parametrize("name", sorted(RIGS))
def test_lanes_match_the_one_character_kernel(monkeypatch, name):
    """Short solves (LM rejections, the active set, limits): the same statuses, iteration counts and poses within
    1e-4 m for nearly all (float32 rounding in another order and the polynomial trigonometry), a character whose
    targets its start pose meets the same, and the written positions FK of the written rotations."""
    rig = RIGS[name]()
    n = 12 * settings.general_lanes() + 3  # a partial last packet
    (a, pa, qa, crowd), (b, pb, qb, _) = _both(monkeypatch, rig, n, seed=3, iterations=8)
    assert a.iterations.max() > 2
    assert np.mean(a.status == b.status) >= 0.97 and np.mean(a.iterations == b.iterations) >= 0.95
    assert a.iterations[0] == b.iterations[0] <= 1 and np.allclose(qa[0], qb[0], atol=1e-5)
    d = np.abs(pa - pb).max(axis=(1, 2))
    assert np.mean(d <= 1e-4) >= 0.95, np.sort(d)[-4:]
    crowd.set_rotations(qa)
    np.testing.assert_allclose(crowd.joint_positions(), pa, atol=2e-6)


def test_lanes_stay_as_close_to_the_twin_as_the_kernel(monkeypatch):
    """The bench's humanoid (random poses, 100 iterations, most targets out of reach): against the float64 twin the
    lanes agree as often as the one-character kernel does (long stalled solves amplify rounding either way), the
    same characters converge, and those that converge in both end within 1e-3 m."""
    from crowd_ik.bench import workloads as w

    wl = w.make_workload("humanoid", 48)

    def run():
        crowd = cik.Crowd(wl.rig, wl.n, spacing=w.SPACING)
        crowd.set_angles(wl.angles)
        start = (*crowd.roots(), crowd.rotations())
        rep = crowd.solve(wl.targets, method="dls", max_iterations=wl.max_iterations, tolerance=wl.tolerance)
        return rep, crowd.joint_positions(), start

    (a, pa, start), (b, pb, _) = _on_both(monkeypatch, run)
    twin = dls_solve(wl.rig, *start, wl.targets, max_iterations=wl.max_iterations, tolerance=wl.tolerance)
    agree = [np.mean(r.iterations == twin[3]) for r in (a, b)]
    assert agree[0] >= agree[1] - 0.1, agree
    assert np.mean(a.status == b.status) >= 0.95
    ok = (a.status == 0) & (b.status == 0) & (twin[2] <= wl.tolerance)
    assert ok.sum() >= 3
    np.testing.assert_allclose(pa[ok], twin[1][ok], atol=1e-3)


@pytest.mark.parametrize("name", ["humanoid", "arm"])
def test_a_character_does_not_depend_on_its_lane_mates(name):
    """Reordered, and alone in a padded packet (with its own row layout: fewer rows where it weights fewer effectors
    or has fewer orientation targets), every character's statuses, iterations and pose bit for bit."""
    rig = RIGS[name]()
    n = 2 * settings.general_lanes() + 3
    crowd, targets, weights, orient = _case(rig, n, seed=7)
    start, (roots, yaw) = crowd.rotations(), crowd.roots()
    crowd.set_rotations(start)
    rep = _solve(crowd, targets, weights, orient, 12)
    pos = crowd.joint_positions()
    order = np.roll(np.arange(n), 5)
    other = cik.Crowd(rig, n=n, spacing=2.0)
    other.set_roots(roots[order], yaw[order])
    other.set_rotations(start[order])
    got = _solve(other, targets[order], weights[order], None if orient is None else orient[order], 12)
    np.testing.assert_array_equal(got.iterations, rep.iterations[order])
    np.testing.assert_array_equal(other.joint_positions(), pos[order])
    for i in (4, 2, 3):
        # 4 weights every effector and has an orientation target: alone it has the crowd's row layout; 2 (a zero
        # weight) and 3 (no orientation target) alone have fewer rows, whose absence changes no bits (the kernel sums
        # in the order written, without fast math's regrouping)
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i:i + 1], yaw[i:i + 1])
        one.set_rotations(start[i:i + 1])
        r1 = _solve(one, targets[i:i + 1], weights[i:i + 1], None if orient is None else orient[i:i + 1], 12)
        assert r1.iterations[0] == rep.iterations[i] and r1.status[0] == rep.status[i]
        np.testing.assert_array_equal(one.joint_positions()[0], pos[i])


def test_a_big_rig_gets_fewer_streams_and_the_same_bits(monkeypatch):
    """The stream scratch of a big rig is capped (kernels/dls_general_lanes.SCRATCH_BYTES): fewer streams, at least 8,
    256 for the humanoid; a crowd run on the fewest streams gets every character's bits of the usual run."""
    from crowd_ik.kernels import dls_general_lanes as g
    from crowd_ik.kernels import lane_plan
    from crowd_ik.kernels.lane_plan import capacity as cap

    assert g.max_streams(8, cap(22), cap(37), cap(30), cap(5)) == 256
    big = (8, 128, 256, 256, 32)
    assert 8 <= g.max_streams(*big) < 64
    assert lane_plan.streams(4000, settings.general_lanes()) > 8
    out = []
    for limit in (g.SCRATCH_BYTES, 1):
        monkeypatch.setattr(g, "SCRATCH_BYTES", limit)
        crowd, targets, weights, orient = _case(cone_arm(), 4000, seed=21)  # 16 streams, or 8 under the cap
        rep = _solve(crowd, targets, weights, orient, 10)
        out.append((rep.iterations, crowd.joint_positions()))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])


def test_row_layout():
    """Bits: 1 the 3 position rows of an effector some character weights (or gives a rotation target), 2 its axis rows
    where one of those also gives it an orientation target and the rig has its axis, 4 its rotation rows; none for an
    effector nobody weights."""
    rig = cone_arm()
    weights = np.array([[1.0, 0.0], [0.5, 0.0]], np.float32)
    np.testing.assert_array_equal(adapter.row_layout(rig, weights, None), [1, 0])
    orient = np.zeros((2, 2, 3), np.float32)
    orient[1, 0] = (0, 1, 0)
    np.testing.assert_array_equal(adapter.row_layout(rig, weights, orient), [3, 0])
    rot_w = np.array([[0.0, 0.0], [0.0, 2.0]], np.float32)
    np.testing.assert_array_equal(adapter.row_layout(rig, weights, orient, rot_w), [3, 5])
    weights[1, 0] = 0.0  # the one with the orientation target weights nothing: no axis rows
    np.testing.assert_array_equal(adapter.row_layout(rig, weights, orient), [1, 0])


def test_blocks_and_shared_column_runs():
    """The system's blocks of three rows (one per layout bit of an effector) and, per pair of effectors, the runs of
    DOF columns both move: the arm's hand moves columns 0-14 (root, shoulder, upper arm, elbow, wrist, hand), its side
    effector 0-5 and 15-17."""
    np.testing.assert_array_equal(adapter.row_groups(np.array([3, 0, 1, 5, 7])), [0, 0, 2, 3, 3, 4, 4, 4])
    count, runs = adapter.shared_runs(cone_arm())
    got = {(a, b): [tuple(r) for r in runs[a, b, : count[a, b]]] for a in range(2) for b in range(2)}
    assert got == {(0, 0): [(0, 15)], (0, 1): [(0, 6)], (1, 0): [(0, 6)], (1, 1): [(0, 6), (15, 18)]}


@pytest.mark.parametrize("name", ["humanoid", "arm"])
def test_rotation_targets_match_the_one_character_kernel(monkeypatch, name):
    """Full rotation targets (their own kernel, three more rows per effector) on some characters' effectors, weighted
    apart from the positions: the same statuses and iterations as the one-character kernel for nearly all, and as
    close to the float64 twin's poses as that kernel (the humanoid's hands turned toward random rotations amplify
    float32 rounding: after 8 iterations 86 % of the lanes' poses and 88 % of the kernel's are within 1e-4 m of the
    twin, 100 % of both after 1)."""
    rig = RIGS[name]()
    n = 6 * settings.general_lanes() + 3
    rng = np.random.default_rng(11)
    rots = rng.normal(size=(n, rig.n_effectors, 4)).astype(np.float32)
    rots /= np.linalg.norm(rots, axis=-1, keepdims=True)
    rot_w = np.where(rng.uniform(size=(n, rig.n_effectors)) < 0.5, 0.0, 0.7).astype(np.float32)
    kw = dict(rotations=rots, rotation_weights=rot_w, max_iterations=8, tolerance=1e-3)
    (a, pa), (b, pb), twin = _on_both_and_twin(monkeypatch, rig, n, 13, kw)
    assert a.iterations.max() > 2
    assert np.mean(a.status == b.status) >= 0.97 and np.mean(a.iterations == b.iterations) >= 0.95
    near = [np.mean(np.abs(p - twin[1]).max(axis=(1, 2)) <= 1e-4) for p in (pa, pb)]
    assert near[0] >= near[1] - 0.05, near
    assert np.mean(np.abs(pa - pb).max(axis=(1, 2)) <= 1e-3) >= 0.95


@pytest.mark.parametrize("name", ["humanoid", "arm"])
def test_a_free_root_matches_the_one_character_kernel(monkeypatch, name):
    """A free root (three more columns, its own kernel) with targets near and far: the same statuses, iterations and
    poses within 1e-4 m for nearly all, roots moved the same, and every target reached where the kernel reaches it."""
    rig = RIGS[name]()
    n = 6 * settings.general_lanes() + 3

    def run():
        crowd, targets, weights, orient = _case(rig, n, seed=17)
        rep = crowd.solve(targets, method="dls", weights=weights, orientations=orient, root_weight=0.5,
                          max_iterations=8, tolerance=1e-3)
        return rep, crowd.joint_positions(), crowd.roots()[0]

    (a, pa, ra), (b, pb, rb) = _on_both(monkeypatch, run)
    assert a.iterations.max() > 2 and np.abs(ra - _case(rig, n, seed=17)[0].roots()[0]).max() > 0.01
    assert np.mean(a.status == b.status) >= 0.97 and np.mean(a.iterations == b.iterations) >= 0.95
    d = np.abs(pa - pb).max(axis=(1, 2))
    assert np.mean(d <= 1e-4) >= 0.95, np.sort(d)[-4:]
    assert np.mean(np.abs(ra - rb).max(axis=1) <= 1e-4) >= 0.95


def test_every_request_takes_the_lanes(monkeypatch):
    """Plain requests (limits, orientation targets, per-character weights), full rotation targets, a free root, and
    rest, velocity or balance terms (with a free root too) all take the lanes."""
    calls = []
    real = adapter._general_lanes
    monkeypatch.setattr(adapter, "_general_lanes", lambda *a, **k: calls.append(k["sec"]) or real(*a, **k))
    crowd, targets, weights, orient = _case(cik.Rig.humanoid(), 5, seed=1)
    _solve(crowd, targets, weights, orient, 2)
    rots = np.zeros((5, crowd.rig.n_effectors, 4), np.float32)
    rots[..., 3] = 1.0
    crowd.solve(targets, method="dls", max_iterations=2, rotations=rots)
    crowd.solve(targets, method="dls", max_iterations=2, root_weight=1.0)
    crowd.solve(targets, method="dls", max_iterations=2, rest_weight=0.01)
    crowd.solve(targets, method="dls", max_iterations=2, balance_weight=0.5, root_weight=1.0)
    assert calls == [False, False, False, True, True]


SECONDARY = {"humanoid": dict(rest_weight=0.01, velocity_weight=0.02, balance_weight=0.5),
             "arm": dict(rest_weight=0.05, velocity_weight=0.02)}


@pytest.mark.parametrize("name", sorted(SECONDARY))
def test_secondary_terms_match_the_one_character_kernel(monkeypatch, name):
    """Rest, velocity and (on the humanoid, which has feet) balance terms in the null space: the same statuses and
    iterations as the one-character kernel for nearly all, and as close to the float64 twin's poses and iterations as
    that kernel (after 8 iterations 94 % of the humanoid's poses are within 1e-4 m of the twin's for both, 98 % of the
    arm's; the two float32 kernels differ from each other a little more than each from the twin)."""
    rig = RIGS[name]()
    n = 6 * settings.general_lanes() + 3
    kw = dict(SECONDARY[name], max_iterations=8, tolerance=1e-3)
    (a, pa), (b, pb), twin = _on_both_and_twin(monkeypatch, rig, n, 19, kw)
    assert a.iterations.max() > 2
    assert np.mean(a.status == b.status) >= 0.97 and np.mean(a.iterations == b.iterations) >= 0.95
    assert np.mean(np.abs(pa - pb).max(axis=(1, 2)) <= 1e-3) >= 0.9
    near = [np.mean(np.abs(p - twin[1]).max(axis=(1, 2)) <= 1e-4) for p in (pa, pb)]
    assert near[0] >= near[1] - 0.03, near
    agree = [np.mean(r.iterations == twin[3]) for r in (a, b)]
    assert agree[0] >= agree[1] - 0.03, agree


def test_secondary_terms_alone_or_in_a_crowd():
    """With rest, velocity and balance terms a character alone in a padded packet (its own, smaller row layout) gets
    its statuses, iterations and pose of the crowd bit for bit."""
    rig = cik.Rig.humanoid()
    n = settings.general_lanes() + 3
    crowd, targets, weights, orient = _case(rig, n, seed=23)
    start, (roots, yaw) = crowd.rotations(), crowd.roots()
    crowd.set_rotations(start)  # the start pose as the lone characters get it (read back, bit for bit)
    kw = dict(SECONDARY["humanoid"], method="dls", max_iterations=12, tolerance=1e-3)
    rep = crowd.solve(targets, weights=weights, orientations=orient, **kw)
    pos = crowd.joint_positions()
    for i in (2, 4):  # 2 weights one effector zero (fewer rows alone)
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i:i + 1], yaw[i:i + 1])
        one.set_rotations(start[i:i + 1])
        r1 = one.solve(targets[i:i + 1], weights=weights[i:i + 1], orientations=orient[i:i + 1], **kw)
        assert r1.iterations[0] == rep.iterations[i] and r1.status[0] == rep.status[i]
        np.testing.assert_array_equal(one.joint_positions()[0], pos[i])
