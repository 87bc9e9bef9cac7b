"""Crowd.solve's host-side shortcuts give what the plain way gives: prepared launches (crowd_ik/prepared.py) equal
ordinary ones solve after solve, the DLS settings kept between solves follow every change of damping, joint
weights and solver variant, and the report's rotation errors (the measured effectors' world rotations read back
by one kernel, the cross products written out) equal the np.cross formula on Crowd.world_rotations()."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik import crowd as crowd_module
from crowd_ik.solvers import dls as dls_solver, fabrik as fabrik_solver, fabrik_free
from crowd_ik.solvers.errors import rotation_error
from crowd_ik.solvers.request import check_request


def _state(crowd, report) -> tuple:
    return (report.status.tobytes(), report.iterations.tobytes(), report.error.tobytes(),
            report.rotation_error.tobytes(), crowd.rotations().tobytes(), crowd.joint_positions().tobytes(),
            crowd.world_rotations().tobytes())


def _requests(rig, crowd, seed):
    """Solve arguments that change targets, orientations (on and off), scalars and settings from solve to solve."""
    rng = np.random.default_rng(seed)
    eff = crowd.effector_positions()
    out = []
    for k in range(5):
        kw = dict(targets=eff + rng.normal(0.0, 0.08, eff.shape).astype(np.float32),
                  max_iterations=4 + k, tolerance=0.004 + 0.001 * k)
        if rig.name == "humanoid" and k % 2:
            ori = np.zeros((crowd.n, rig.n_effectors, 3), np.float32)
            ori[:, 3:, 1] = 1.0
            ori[:, 3:, 2] = rng.uniform(-0.3, 0.3, (crowd.n, 2))
            kw["orientations"] = ori
        out.append(kw)
    return out


@pytest.mark.parametrize("rig_name, method, module", [
    ("humanoid", "fabrik", fabrik_solver),  # the general kernel, with and without orientation targets
    ("chain4", "fabrik", fabrik_free),  # the lane kernels (their plan made once per crowd)
    ("chain4", "dls", dls_solver),  # the lane kernel
])
def test_prepared_solves_equal_ordinary_ones(monkeypatch, rig_name, method, module):
    rig = cik.Rig.humanoid() if rig_name == "humanoid" else cik.Rig.chain(4, 0.2)
    prepared_crowd, plain_crowd = cik.Crowd(rig, 3, spacing=2.0), cik.Crowd(rig, 3, spacing=2.0)
    requests = _requests(rig, prepared_crowd, seed=1)
    got = [_state(prepared_crowd, prepared_crowd.solve(method=method, **kw)) for kw in requests]
    for launcher in (module, crowd_module):  # every launch the ordinary way
        monkeypatch.setattr(launcher, "prepared", lambda kernel: kernel)
    want = [_state(plain_crowd, plain_crowd.solve(method=method, **kw)) for kw in requests]
    assert got == want


def test_dls_settings_follow_damping_joint_weights_and_variant():
    """One crowd solving under changing settings equals a fresh crowd per solve: what the crowd keeps uploaded
    (damping, joint weights, the lane kernel's path) is redone whenever the settings change."""
    rig = cik.Rig.chain(4, 0.2)
    rng = np.random.default_rng(2)
    start = np.zeros((2, rig.n_dof), np.float32)
    targets = [cik.Crowd(rig, 2, spacing=2.0).effector_positions() + rng.normal(0, 0.1, (2, 1, 3)).astype(np.float32)
               for _ in range(2)]
    jw = np.linspace(0.5, 1.5, rig.n_dof).astype(np.float32)
    settings = [dict(), dict(damping=0.05), dict(joint_weights=jw), dict(joint_weights=jw, damping=0.05),
                dict(joint_weights=jw[::-1].copy()), dict(), dict(damping=0.05)]
    kept = cik.Crowd(rig, 2, spacing=2.0)
    for k, extra in enumerate(settings):
        kept.set_angles(start)
        got = kept.solve(targets[k % 2], method="dls", max_iterations=6, **extra)
        fresh = cik.Crowd(rig, 2, spacing=2.0)
        want = fresh.solve(targets[k % 2], method="dls", max_iterations=6, **extra)
        assert _state(kept, got) == _state(fresh, want), extra


def _rotation_error_np_cross(rig, world_rot, req):
    """The report's rotation errors as first written: np.cross, the axes normalised on every call."""
    out = np.zeros(world_rot.shape[0], np.float64)
    q = world_rot[:, rig.arrays["eff_joint"]].astype(np.float64)
    if req.orientations is not None:
        axis = rig.arrays["eff_axis"].astype(np.float64)
        axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-30)
        u, w = q[..., :3], q[..., 3:]
        t = 2.0 * np.cross(u, np.broadcast_to(axis, u.shape))
        world_axis = axis + w * t + np.cross(u, t)
        has = (np.sum(req.orientations * req.orientations, axis=-1) > 0) & (req.weights > 0)
        cos = np.clip(np.sum(world_axis * req.orientations, axis=-1), -1.0, 1.0)
        out = np.maximum(out, np.max(np.where(has, np.arccos(cos), 0.0), axis=1))
    if req.rotations is not None:
        dot = np.abs(np.sum(q * req.rotations.astype(np.float64), axis=-1))
        has = req.rotation_weights > 0
        out = np.maximum(out, np.max(np.where(has, 2.0 * np.arccos(np.clip(dot, 0.0, 1.0)), 0.0), axis=1))
    return out.astype(np.float32)


def test_rotation_errors_equal_the_np_cross_formula_bit_for_bit():
    rig = cik.Rig.humanoid()
    rng = np.random.default_rng(3)
    E, J = rig.n_effectors, rig.n_joints
    for trial in range(30):
        n = int(rng.integers(1, 60))
        world_rot = rng.normal(size=(n, J, 4)).astype(np.float32)
        world_rot /= np.linalg.norm(world_rot, axis=-1, keepdims=True)
        ori = rng.normal(size=(n, E, 3))
        ori[:, :3] = 0.0  # only the feet have an axis
        ori[rng.random((n, E)) < 0.2] = 0.0
        if trial % 3 == 0:  # near the answer: arccos close to 0
            ori[:, 3:] = world_rot[:, rig.arrays["eff_joint"][3:], :3]
        rot = rng.normal(size=(n, E, 4))
        rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
        weights = (rng.random((n, E)) < 0.8).astype(np.float32)
        req = check_request(rig, n, np.zeros((n, E, 3), np.float32), "fabrik", 1, 1e-3, weights, ori, 0, 0, None,
                            None, 0, rotations=rot if trial % 2 else None)
        got = rotation_error(rig, world_rot, req)
        assert got.tobytes() == _rotation_error_np_cross(rig, world_rot, req).tobytes()


def test_report_rotation_errors_are_those_of_the_final_pose():
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, 4, spacing=2.0)
    for kw in _requests(rig, crowd, seed=4):
        if "orientations" not in kw:
            continue
        report = crowd.solve(**kw)  # read back through the kept buffer
        req = check_request(rig, 4, kw["targets"], "fabrik", kw["max_iterations"], kw["tolerance"], None,
                            kw["orientations"], 0, 0, None, None, 0)
        assert report.rotation_error.tobytes() == rotation_error(rig, crowd.world_rotations(), req).tobytes()
        assert np.any(report.rotation_error > 0)
