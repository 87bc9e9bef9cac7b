"""crowd_ik.planar: the homework's reference values, the lab's checks, DLS, regularised IK, follow."""

import numpy as np
import pytest

from crowd_ik import planar


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _random_target(rng, n, lo, hi):
    """A target at lo..hi times the reach n of an n-bone unit chain, in a random direction."""
    d, a = rng.uniform(lo, hi) * n, rng.uniform(-np.pi, np.pi)
    return d * np.array([np.cos(a), np.sin(a)]), a


# --- homework 4 (CS328) reference values --------------------------------------------------------


def test_chain_simple_reference_values():
    np.testing.assert_allclose(planar.chain([]), [0.0, 0.0])
    np.testing.assert_allclose(planar.chain([0.0]), [1.0, 0.0])
    np.testing.assert_allclose(planar.chain([np.pi / 4]), [0.70710678, 0.70710678], atol=1e-8)


def test_chain_reference_values():
    np.testing.assert_allclose(planar.chain([0.1, 0.2, 0.3, 0.4]), [3.31597858, 1.80146708], atol=1e-8)
    np.testing.assert_allclose(planar.chain([np.pi] * 4), [0.0, 0.0], atol=1e-12)


def test_dchain_reference_values():
    np.testing.assert_allclose(planar.dchain([0.0]), [[0.0], [1.0]], atol=1e-12)
    np.testing.assert_allclose(planar.dchain([np.pi / 4]), [[-0.70710678], [0.70710678]], atol=1e-8)
    np.testing.assert_allclose(planar.dchain([0, 0, 0, 0]), [[0, 0, 0, 0], [4, 3, 2, 1]], atol=1e-12)
    np.testing.assert_allclose(
        planar.dchain([0.1, 0.2, 0.3]),
        [[-0.9599961, -0.86016268, -0.56464247], [2.77567627, 1.7806721, 0.82533561]],
        atol=1e-8,
    )


def test_newton_reference_values():
    one = planar.newton(np.array([0.0]), np.array([0.0, 1.0]))
    np.testing.assert_allclose(planar.chain(one), [0.0, 1.0], atol=1e-9)
    two = planar.newton(np.array([0.0, 0.0]), np.array([0.5, 0.5]))
    np.testing.assert_allclose(planar.chain(two), [0.5, 0.5], atol=1e-9)
    assert two.shape == (2,)


def test_newton_runs_exactly_the_given_iterations():
    # one pseudoinverse step from the rest pose is the linearised move, not the solution
    step = planar.newton([0.0, 0.0], [0.5, 0.5], iterations=1)
    np.testing.assert_allclose(step, np.linalg.pinv(planar.dchain([0, 0])) @ ([0.5, 0.5] - planar.chain([0, 0])))


# --- forward kinematics with bone lengths -------------------------------------------------------


def test_chain_all_joints_and_lengths():
    rng = np.random.default_rng(0)
    t, lengths = rng.uniform(-np.pi, np.pi, 5), rng.uniform(0.2, 2.0, 5)
    joints = planar.chain_all(t, lengths=lengths)
    assert joints.shape == (6, 2)
    np.testing.assert_allclose(joints[0], [0, 0])
    np.testing.assert_allclose(joints[-1], planar.chain(t, lengths=lengths))
    np.testing.assert_allclose(np.linalg.norm(np.diff(joints, axis=0), axis=1), lengths)
    # each bone's absolute direction is the running sum of the relative angles
    d = np.diff(joints, axis=0)
    np.testing.assert_allclose(_wrap(np.arctan2(d[:, 1], d[:, 0]) - np.cumsum(t)), 0, atol=1e-12)


def test_dchain_matches_central_differences():
    rng = np.random.default_rng(1)
    h = 1e-6
    for n in (1, 2, 3, 7):
        t, lengths = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.3, 1.5, n)
        fd = np.stack(
            [
                (planar.chain(t + h * e, lengths=lengths) - planar.chain(t - h * e, lengths=lengths)) / (2 * h)
                for e in np.eye(n)
            ],
            axis=1,
        )
        np.testing.assert_allclose(planar.dchain(t, lengths=lengths), fd, atol=1e-8)


def test_lab_pseudoinverse_of_square_jacobian_is_inverse():
    # CS157 lab 2: for the 2-bone arm J is square, and J^+ J must print the 2x2 identity
    jac = planar.dchain([0.4, 0.9])
    np.testing.assert_allclose(np.linalg.pinv(jac) @ jac, np.eye(2), atol=1e-12)


# --- damped least squares ---------------------------------------------------------------------


def test_dls_converges_on_reachable_targets_and_error_never_increases():
    rng = np.random.default_rng(2)
    for _ in range(25):
        n = int(rng.integers(2, 7))
        target, _ = _random_target(rng, n, 0.05, 0.95)
        history = []
        t = planar.dls(rng.uniform(-np.pi, np.pi, n), target, history=history)
        assert np.linalg.norm(planar.chain(t) - target) <= 1e-6
        assert history[-1] == pytest.approx(np.linalg.norm(planar.chain(t) - target))
        assert np.all(np.diff(history) <= 0), history


def test_dls_unreachable_ends_stretched_toward_target():
    rng = np.random.default_rng(3)
    for lo, hi in [(1.02, 1.5)] * 15 + [(2.0, 5.0)] * 15:  # just beyond the reach, and far beyond
        n = int(rng.integers(2, 7))
        target, heading = _random_target(rng, n, lo, hi)
        history = []
        t = planar.dls(rng.uniform(-np.pi, np.pi, n), target, history=history)
        # every bone's absolute direction points at the target: collinear, no winding
        assert np.abs(_wrap(np.cumsum(t) - heading)).max() < 1e-3
        assert np.linalg.norm(planar.chain(t) - target) == pytest.approx(np.linalg.norm(target) - n, abs=1e-4)
        assert np.all(np.diff(history) <= 0)


def test_dls_leaves_the_straight_pose_pointing_away():
    # rest pose along +x, target behind the root: J^T e = 0 there (a saddle), pinv would stay put
    assert np.allclose(planar.newton(np.zeros(4), [-1.0, 0.0]), 0.0)
    t = planar.dls(np.zeros(4), [-1.0, 0.0])
    assert np.linalg.norm(planar.chain(t) - [-1.0, 0.0]) <= 1e-6
    t = planar.dls(np.zeros(3), [-10.0, 0.0])
    np.testing.assert_allclose(planar.chain(t), [-3.0, 0.0], atol=1e-6)


def test_dls_clamps_each_step():
    # a step aims at most ERROR_CLAMP * mean bone length away: its linearised tip motion J dtheta
    # is no longer than that however far the target (here 1.78 away, for bones of length 0.5)
    start, lengths = np.array([0.3, 0.3, 0.3]), np.full(3, 0.5)
    t = planar.dls(start, [-0.5, 0.3], iterations=1, lengths=lengths)
    assert not np.allclose(t, start)
    linear = np.linalg.norm(planar.dchain(start, lengths=lengths) @ (t - start))
    assert 0.5 * planar.ERROR_CLAMP * 0.5 < linear <= planar.ERROR_CLAMP * 0.5


def test_dls_limits_hold_and_reachable_targets_inside_limits_converge():
    # the coursework's arm: theta1 in [-45, 45], theta2 in [-90, 90], theta3 in [-170, 170] degrees
    lo = np.radians([-45, -90, -170])
    hi = -lo
    rng = np.random.default_rng(4)
    converged = 0
    for _ in range(30):
        target = planar.chain(rng.uniform(lo, hi))
        history = []
        t = planar.dls(rng.uniform(lo, hi), target, iterations=200, limits=(lo, hi), history=history)
        assert np.all(t >= lo) and np.all(t <= hi)
        assert np.all(np.diff(history) <= 0)
        converged += history[-1] <= 1e-6
    assert converged >= 24  # the rest are the coursework's "stuck at a limit" poses: stopped, not looping
    # from the rest pose a target inside the limits is reached
    goal = planar.chain(np.radians([30, 60, -40]))
    t = planar.dls(np.zeros(3), goal, limits=(lo, hi))
    assert np.linalg.norm(planar.chain(t) - goal) <= 1e-6


def test_dls_active_set_pins_a_joint_pushed_past_its_limit():
    # target up and to the left: the first joint wants to turn far past its 0.2 rad limit
    lo, hi = np.array([-0.2, -2.0, -2.0]), np.array([0.2, 2.0, 2.0])
    t = planar.dls(np.zeros(3), [0.0, 2.5], limits=(lo, hi))
    assert t[0] == hi[0]
    assert np.all(t >= lo) and np.all(t <= hi)


def test_dls_rates_weight_the_joints():
    start, goal = np.array([0.3, 0.3, 0.3]), np.array([1.0, 1.5])
    # a zero rate freezes that joint; the others still reach the target
    t = planar.dls(start, goal, rates=[1.0, 0.0, 1.0])
    assert t[1] == start[1]
    assert np.linalg.norm(planar.chain(t) - goal) <= 1e-6
    # a slow first joint moves less on the first step than with equal rates
    even = planar.dls(start, goal, iterations=1)
    slow = planar.dls(start, goal, iterations=1, rates=[0.1, 1.0, 1.0])
    assert abs(slow[0] - start[0]) < abs(even[0] - start[0])


def test_dls_stops_at_tolerance_and_respects_iterations():
    history = []
    planar.dls([0.1, 0.2], [1.0, 1.0], tolerance=1e-3, history=history)
    assert history[-1] <= 1e-3 and (len(history) == 2 or history[-2] > 1e-3)
    history = []
    planar.dls([0.1, 0.2, 0.3], [-1.0, 1.5], iterations=3, history=history)
    assert len(history) == 4


# --- regularised IK against scipy ------------------------------------------------------------


def _objective(t, target, alpha, l1):
    r = planar.chain(t) - target
    return alpha * r @ r + (np.abs(t).sum() if l1 else t @ t)


@pytest.mark.parametrize("penalty", ["l2", "l1"])
def test_regularized_at_least_as_good_as_scipy(penalty):
    minimize = pytest.importorskip("scipy.optimize").minimize
    rng = np.random.default_rng(5 if penalty == "l2" else 6)
    l1 = penalty == "l1"
    for _ in range(20):
        n = int(rng.integers(2, 7))
        start = rng.uniform(-np.pi, np.pi, n)
        target = rng.uniform(-1, 1, 2) * n * 0.9
        ours = planar.regularized(start, target, alpha=10.0, penalty=penalty)
        ref = minimize(_objective, start, args=(target, 10.0, l1), method="Nelder-Mead" if l1 else "BFGS")
        assert _objective(ours, target, 10.0, l1) <= ref.fun + 1e-6


def test_regularized_returns_a_stationary_point():
    rng = np.random.default_rng(7)
    for _ in range(5):
        t0, target = rng.uniform(-2, 2, 4), rng.uniform(-3, 3, 2)
        t = planar.regularized(t0, target)
        grad = 20.0 * planar.dchain(t).T @ (planar.chain(t) - target) + 2 * t
        assert np.abs(grad).max() < 1e-6
        t = planar.regularized(t0, target, penalty="l1")
        g = 20.0 * planar.dchain(t).T @ (planar.chain(t) - target)
        nz = t != 0
        assert np.abs(g[nz] + np.sign(t[nz])).max() < 1e-5  # smooth where nonzero
        assert np.all(np.abs(g[~nz]) <= 1 + 1e-6)  # subgradient condition at zero


def test_regularized_l1_is_sparser_than_l2():
    # a target a little short of the straight chain: L1 bends one joint, L2 spreads the bend
    target = np.array([3.6, 0.8])
    l2 = planar.regularized(np.zeros(4), target)
    l1 = planar.regularized(np.zeros(4), target, penalty="l1")
    assert np.count_nonzero(np.abs(l1) > 1e-9) < np.count_nonzero(np.abs(l2) > 1e-9)


# --- the lab's move(dP, depth) ---------------------------------------------------------------


def test_follow_small_reachable_delta():
    start = np.array([0.3, 0.4, 0.5, 0.2])
    for delta in ([0.02, -0.03], [0.3, -0.4]):  # [0.3, -0.4]: two sub-steps
        t, reached = planar.follow(start, delta)
        assert reached
        moved = planar.chain(t) - planar.chain(start)
        assert np.linalg.norm(moved - delta) <= 0.05  # reached: the tip ends within the threshold
    # two accepted sub-steps that drift 6.6 cm in all: each passed the lab's test, the whole is not reached
    t, reached = planar.follow(start, [0.5, -0.7])
    assert np.linalg.norm(planar.chain(t) - planar.chain(start) - [0.5, -0.7]) > 0.05
    assert not reached


def test_follow_far_jump_is_lost_with_last_accepted_angles():
    start = np.array([0.3, 0.4, 0.5, 0.2])
    accepted = []
    t, reached = planar.follow(start, [100.0, 0.0], history=accepted)
    assert not reached
    assert accepted, "some sub-steps toward the target are accepted before it is lost"
    np.testing.assert_array_equal(t, accepted[-1])
    assert planar.chain(t)[0] > planar.chain(start)[0]
    assert np.linalg.norm(planar.chain(t)) > 3.9  # driven out to the edge of the reach


def test_follow_gives_up_at_max_depth_and_keeps_the_start():
    start = np.array([0.3, 0.4])
    t, reached = planar.follow(start, [1.0, 1.0], max_depth=0)
    assert not reached
    np.testing.assert_array_equal(t, start)


@pytest.mark.parametrize("delta", [[-0.3, 0.0], [-1.0, 0.0], [0.5, 0.0]])
def test_follow_fails_when_the_tip_ends_off_the_goal(delta):
    # a straight chain pulled along its axis: J^+ delta = 0, so each sub-step passes the lab's residual test
    # while the tip stays at (3, 0); the goal (closed form) is (3 + dx, 0), |dx| >= 0.3 > threshold
    start = np.zeros(3)
    t, reached = planar.follow(start, delta)
    goal = planar.chain(start) + np.asarray(delta)
    assert np.linalg.norm(planar.chain(t) - goal) > 0.05
    assert not reached


def test_follow_reached_means_within_threshold_of_the_goal():
    rng = np.random.default_rng(3)
    n_reached = 0
    for _ in range(60):
        start = rng.uniform(-1.0, 1.0, 4)
        delta = rng.uniform(-0.6, 0.6, 2)
        t, reached = planar.follow(start, delta)
        off = np.linalg.norm(planar.chain(t) - (planar.chain(start) + delta))
        if not reached:
            continue
        n_reached += 1
        assert off <= 0.05
    assert n_reached > 30


# --- validation --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: planar.chain([0.1, np.nan]), "thetas"),
        (lambda: planar.chain([[0.1, 0.2]]), "thetas"),
        (lambda: planar.chain([0.1, 0.2], lengths=[1.0, -1.0]), "lengths"),
        (lambda: planar.dchain([0.1], lengths=[1.0, 1.0]), "lengths"),
        (lambda: planar.newton([0.1], [1.0, 2.0, 3.0]), "target"),
        (lambda: planar.newton([0.1], [1.0, np.inf]), "target"),
        (lambda: planar.newton([0.1], [1.0, 0.0], iterations=0), "iterations"),
        (lambda: planar.dls([0.1], [1.0, 0.0], damping=-0.1), "damping"),
        (lambda: planar.dls([0.1], [1.0, 0.0], iterations=2.5), "iterations"),
        (lambda: planar.dls([0.1], [1.0, 0.0], tolerance=np.nan), "tolerance"),
        (lambda: planar.dls([0.1], [1.0, 0.0], limits=([1.0], [0.0])), "limits"),
        (lambda: planar.dls([0.1], [1.0, 0.0], rates=[-1.0]), "rates"),
        (lambda: planar.regularized([0.1], [1.0, 0.0], penalty="l3"), "penalty"),
        (lambda: planar.regularized([0.1], [1.0, 0.0], alpha=0), "alpha"),
        (lambda: planar.follow([0.1], [0.1, 0.0], threshold=0.0), "threshold"),
        (lambda: planar.follow([0.1], [0.1, 0.0], max_depth=-1), "max_depth"),
    ],
)
def test_bad_input_names_the_argument(call, name):
    with pytest.raises(ValueError, match=name):
        call()
