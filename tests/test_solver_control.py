"""Issue 15, solver control: cone + box limits on one joint, and the checks of the new solve arguments.

Each feature is checked against a NumPy or closed-form reference and on a batch.
"""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.geometry import quat as rq
from crowd_ik.rig import Effector, Joint

METHODS = ("fabrik", "dls", "ccd")


def one_bone_hip(cone=0.8):
    """A ball joint with a box (a hip's) and a cone about its bone, the bone pointing down."""
    return cik.Rig(joints=[Joint("hip", -1, (0.0, 1.0, 0.0), "ball", lo=(-2.0, -0.5, -0.35), hi=(0.5, 0.7, 1.0),
                                 cone=cone),
                           Joint("foot", 0, (0.0, -0.5, 0.0), "fixed")], effectors=[Effector("foot", 1)])


@pytest.mark.parametrize("method", METHODS)
def test_a_cone_and_a_box_on_one_ball_joint_both_hold(method):
    # before issue 15 (same rig, seeds and targets): FABRIK 157, DLS 58, CCD 157 of 500 outside the cone,
    # up to 1.40 rad
    cone, n = 0.8, 500
    rig = one_bone_hip(cone)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    targets = (np.array([0.0, 1.0, 0.0]) + 0.5 * d)[:, None].astype(np.float32)
    crowd = cik.Crowd(rig, n=n, spacing=0.0)
    crowd.set_rotations(np.random.default_rng(1).normal(size=(n, 2, 4)).astype(np.float32))
    crowd.solve(targets, method=method, max_iterations=50, tolerance=1e-4)
    bone = np.array([0.0, -1.0, 0.0])
    q = crowd.rotations()[:, 0].astype(np.float64)
    ang = np.arccos(np.clip(rq.qrot(q, np.broadcast_to(bone, (n, 3))) @ bone, -1, 1))
    assert np.count_nonzero(ang > cone + 1e-3) == 0
    lo, hi = rig.angle_limits()
    a = crowd.angles()
    assert np.count_nonzero(np.maximum(a - hi, lo - a).max(axis=1) > 1e-4) == 0
    # the limits bite (many targets lie outside the cone), and the reachable ones are reached
    assert np.mean(ang > cone - 1e-2) > 0.3
    inside = np.arccos(np.clip(-d[:, 1], -1, 1)) < cone - 0.05
    inside &= np.all(np.abs(rq.quat_to_euler_xyz(rq.qmul(rq.swing(np.broadcast_to(bone, (n, 3)), d),
                                                         np.array([0.0, 0.0, 0.0, 1.0])))) < 0.3, axis=1)
    err = np.linalg.norm(crowd.effector_positions()[:, 0] - targets[:, 0], axis=-1)
    assert inside.sum() > 10 and np.median(err[inside]) < 1e-3


# --------------------------------------------------------------------------------------------- poles
def bent_humanoids(n, seed):
    """n humanoids in random in-limit poses with bent knees and elbows: (rig, crowd, effector positions)."""
    rig = cik.Rig.humanoid()
    rng = np.random.default_rng(seed)
    lo, hi = rig.angle_limits()
    a = np.clip(rng.normal(0.0, 0.25, (n, rig.n_dof)), lo, hi)
    for name in ("elbow_l", "elbow_r", "knee_l", "knee_r"):
        a[:, rig.arrays["dof_start"][rig.joint_names.index(name)]] = rng.uniform(0.4, 1.2, n)
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    crowd.set_angles(a.astype(np.float32))
    return rig, crowd, crowd.effector_positions().copy()


def swivel_angle(pos, pole, p, k, end):
    """Angle about the line p -> end between joint k and the pole (closed form): 0 when k bends toward the pole."""
    a = pos[:, end] - pos[:, p]
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    u, v = pos[:, k] - pos[:, p], pole - pos[:, p]
    u -= np.sum(u * a, -1, keepdims=True) * a
    v -= np.sum(v * a, -1, keepdims=True) * a
    return np.arctan2(np.sum(a * np.cross(u, v), -1), np.sum(u * v, -1))


@pytest.mark.parametrize("method", METHODS)
def test_poles_turn_knees_and_elbows_toward_them_and_keep_the_effectors(method):
    from crowd_ik.reference import poles as ref_poles

    n = 64
    rig, crowd, eff = bent_humanoids(n, 2)
    roots, yaw = crowd.roots()
    start = crowd.rotations().copy()
    # knees 1 m in front (+z) at knee height, elbows out (+-x) and down; the head's pole left out (NaN)
    ix = {name: rig.joint_names.index(name) for name in ("shoulder_l", "elbow_l", "hand_l", "shoulder_r", "elbow_r",
                                                     "hand_r", "hip_l", "knee_l", "ankle_l", "hip_r", "knee_r", "ankle_r")}
    pole = np.full((n, 5, 3), np.nan, np.float32)
    pole[:, 1] = roots + [0.8, 0.6, -0.3]
    pole[:, 2] = roots + [-0.8, 0.6, -0.3]
    pole[:, 3] = roots + [0.1, 0.5, 1.0]
    pole[:, 4] = roots + [-0.1, 0.5, 1.0]
    before = crowd.joint_positions()
    rep = crowd.solve(eff, method=method, max_iterations=20, tolerance=2e-3, poles=pole)
    pos = crowd.joint_positions()
    assert np.all(rep.error <= 2e-3 + 1e-5) and np.all(rep.converged)
    limbs = [(1, "shoulder_l", "elbow_l", "hand_l"), (2, "shoulder_r", "elbow_r", "hand_r"),
             (3, "hip_l", "knee_l", "ankle_l"), (4, "hip_r", "knee_r", "ankle_r")]
    for e, p, k, end in limbs:
        was = np.abs(swivel_angle(before, pole[:, e], ix[p], ix[k], ix[end]))
        now = np.abs(swivel_angle(pos, pole[:, e], ix[p], ix[k], ix[end]))
        assert np.median(now) < 1e-3 < np.median(was)  # turned onto the pole where the limits allow
        assert np.all(now <= was + 1e-4)
    # against the NumPy twin, from the pose the solver left (the solve itself does nothing here: converged)
    if method == "fabrik":
        c2 = cik.Crowd(rig, n=n, spacing=2.0)
        c2.set_rotations(start)
        r0 = c2.solve(eff, method=method, max_iterations=20, tolerance=2e-3)
        assert np.all(r0.iterations == 0)
        w = np.ones((n, 5))
        q, p_ref, err = ref_poles.pole_swivel(rig, roots.astype(np.float64), yaw, start, eff, w, pole,
                                              ~np.isnan(pole[..., 0]), tolerance=2e-3)
        np.testing.assert_allclose(pos, p_ref, atol=2e-4)
        np.testing.assert_allclose(rep.error, err, atol=2e-5)


def assert_batch_equals_one_at_a_time(rig, roots, yaw, angles, targets, method, per_character, atol=0.0, **kwargs):
    """A batch solve against each character solved alone (per_character: the (N, ...) arguments): the same
    iterations and status, rotations and errors bit for bit (atol 0), or within atol where a kernel packs
    characters as SIMD lanes (a character alone in a padded packet: tests/test_fabrik_lanes.py)."""
    n = len(roots)
    batch = cik.Crowd(rig, n=n)
    batch.set_roots(roots, yaw)
    batch.set_angles(angles)
    rep = batch.solve(targets, method=method, **per_character, **kwargs)
    for i in range(n):
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i : i + 1], yaw[i : i + 1])
        one.set_angles(angles[i : i + 1])
        r1 = one.solve(targets[i : i + 1], method=method, **{k: v[i : i + 1] for k, v in per_character.items()},
                       **kwargs)
        assert r1.iterations[0] == rep.iterations[i] and r1.status[0] == rep.status[i]
        if atol == 0.0:
            np.testing.assert_array_equal(one.rotations()[0], batch.rotations()[i])
            assert r1.error[0] == rep.error[i] and r1.rotation_error[0] == rep.rotation_error[i]
        else:
            np.testing.assert_allclose(one.rotations()[0], batch.rotations()[i], atol=atol)
            np.testing.assert_allclose(one.joint_positions()[0], batch.joint_positions()[i], atol=atol)
            assert abs(r1.error[0] - rep.error[i]) <= atol and abs(r1.rotation_error[0] - rep.rotation_error[i]) <= atol
    return batch, rep


def test_poles_batch_equals_one_at_a_time():
    n = 6
    rig, crowd, eff = bent_humanoids(n, 4)
    roots = np.random.default_rng(0).uniform(-5, 5, (n, 3)).astype(np.float32)
    roots[:, 1] = 0.0
    yaw = np.linspace(-2, 2, n).astype(np.float32)
    c = cik.Crowd(rig, n=n)
    c.set_roots(roots, yaw)
    angles = crowd.angles()
    c.set_angles(angles)
    targets = c.effector_positions() + 0.02
    pole = np.full((n, 5, 3), np.nan, np.float32)
    pole[:, 3] = roots + [0.1, 0.5, 1.0]
    pole[:, 1] = roots + [0.8, 0.6, -0.3]
    for method in METHODS:
        # FABRIK's 10 iterations run in windows, its characters with a target out of reach on the limited lanes
        assert_batch_equals_one_at_a_time(rig, roots, yaw, angles, targets, method, dict(poles=pole),
                                          atol=1e-5 if method == "fabrik" else 0.0, max_iterations=10)


def test_pole_and_orientation_rows_follow_the_nan_convention():
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=2)
    t = crowd.effector_positions()
    bad = np.full((2, 5, 3), np.nan)
    bad[0, 1, 0] = 1.0  # partly NaN
    with pytest.raises(ValueError, match=r"poles: row \[0, 1\] is partly NaN"):
        crowd.solve(t, poles=bad)
    inf = np.full((2, 5, 3), np.nan)
    inf[1, 2] = np.inf
    with pytest.raises(ValueError, match="poles"):
        crowd.solve(t, poles=inf)
    with pytest.raises(ValueError, match="rotation_tolerance"):
        crowd.solve(t, rotation_tolerance=0.0)
    # all-NaN rows: no pole / no orientation, the same as leaving the argument out
    rep = crowd.solve(t, poles=np.full((2, 5, 3), np.nan), orientations=np.full((2, 5, 3), np.nan))
    assert np.all(rep.converged) and np.all(rep.rotation_error == 0)
    planar = cik.Crowd(cik.Rig.chain(3, dim=2), n=1)
    with pytest.raises(ValueError, match="poles"):
        planar.solve(planar.effector_positions(), poles=np.zeros((1, 1, 2)))


# --------------------------------------------------------------------------------------------- orientations
def test_ccd_no_longer_reports_converged_while_an_axis_target_is_off():
    # issue 15: CCD stopped on positions alone, CONVERGED after 0 sweeps with the soles 33 degrees off
    from crowd_ik.reference import ccd as ref_ccd

    n = 8
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    targets = crowd.effector_positions().copy()
    tilt = np.deg2rad(20.0)
    orient = np.zeros((n, 5, 3), np.float32)
    orient[:, 3] = orient[:, 4] = [0.0, np.cos(tilt), np.sin(tilt)]  # both soles tilted 20 degrees
    rep = crowd.solve(targets, method="ccd", max_iterations=40, tolerance=1e-3, orientations=orient,
                      rotation_tolerance=1e-2)
    # the report's angle is the closed form from the final pose
    wr = crowd.world_rotations()[:, rig.arrays["eff_joint"][3]].astype(np.float64)
    up = rq.qrot(wr, np.broadcast_to([0.0, 1.0, 0.0], (n, 3)))
    np.testing.assert_allclose(rep.rotation_error, np.arccos(np.clip(up @ orient[0, 3], -1, 1)), atol=1e-3)
    assert np.all(rep.iterations > 0)
    assert np.all(rep.converged == ((rep.error <= 1e-3) & (rep.rotation_error <= 1e-2)))
    assert np.all(rep.rotation_error < 1e-2) and np.all(rep.converged)
    # against the NumPy twin, which follows the same rule
    roots, yaw = crowd.roots()
    ref = ref_ccd.ccd_solve(rig, roots, yaw, np.tile([0.0, 0.0, 0.0, 1.0], (n, rig.n_joints, 1)), targets,
                            orient=orient, max_iterations=40, tolerance=1e-3, rotation_tolerance=1e-2)
    np.testing.assert_array_equal(ref["iterations"], rep.iterations)
    np.testing.assert_allclose(crowd.rotations(), ref["rot"], atol=2e-4)
    # 33 degrees: 3 beyond the ankles' 30 degree limit; the sweeps try, and the report says it is not met
    far = np.zeros((n, 5, 3), np.float32)
    far[:, 3] = far[:, 4] = [0.0, np.cos(np.deg2rad(33.0)), np.sin(np.deg2rad(33.0))]
    bad = cik.Crowd(rig, n=n, spacing=2.0).solve(targets, method="ccd", max_iterations=10, orientations=far)
    assert not np.any(bad.converged) and np.all(bad.iterations > 0)
    np.testing.assert_allclose(bad.rotation_error, np.deg2rad(3.0), atol=2e-3)
