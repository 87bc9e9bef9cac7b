"""FABRIK on the joint-limited humanoid (issue 15): the quality figures of tests/fabrik_quality.py as tests. The
head dragged forward keeps the neck from taking the bend alone; the cross-body reach is within 5 mm; at least 97 % of
the in-limit poses converge (seeds 0-2, 1,000 characters), the issue's goal."""

import numpy as np
import pytest

import crowd_ik as cik

from fabrik_quality import bend, cross_body, head_forward, in_limit_poses


def test_the_head_dragged_forward_bends_the_spine_not_the_neck_alone():
    # 0.3 m forward is out of reach with the feet and hands held: the torso leans from the pelvis, straight
    ratio, err, _ = head_forward()
    assert ratio <= 0.5 and 0.05 < err < 0.08  # measured 0.0014, 64 mm (DLS: 64 mm)
    # 0.3 m forward and 0.1 m down is reachable: the bend spreads over spine, chest and neck
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=1)
    t = crowd.effector_positions().copy()
    t[0, 0] += np.array([0.0, -0.1, 0.3], np.float32)
    rep = crowd.solve(t, method="fabrik", max_iterations=100, tolerance=5e-3)
    rot = crowd.rotations()
    b = [bend(rig, rot, j, c)[0] for j, c in (("spine", "chest"), ("chest", "neck"), ("neck", "head"))]
    assert rep.converged[0] and b[2] <= 0.5 * sum(b)  # measured 0.296 of 0.852 rad


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_in_limit_poses_converge_for_97_percent(seed):
    rep = in_limit_poses(1000, seed=seed)
    # measured 97.5, 97.3, 97.6 % with the windowed solve's restarts and jumps (solvers/fabrik_restart.py); one
    # launch of 100 iterations: 91.9, 91.4, 91.8 %; without the chest passing its clamped excess to the spine
    # (kernels/fabrik_pass_up.py) as well 85.2, 83.4, 81.3 %; DLS 100 %
    assert np.mean(rep.converged) >= 0.97
    assert rep.iterations.max() <= 100


def test_cross_body_reach_within_5_mm():
    err, rep = cross_body()
    assert err <= 5e-3 and rep.error[0] <= 5e-3  # measured 2.7 mm (one launch 3.4 mm; 6.8 mm without the pass-up)
