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
