"""NumPy twin of kernels/poles.py: pole hints after a solve, one character at a time, in float64, for clarity."""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.fk import forward_kinematics, yaw_quat
from crowd_ik.geometry.quat import axis_angle, best_angle_about, constrain_rotation, qconj, qmul, qnormalize
from crowd_ik.solvers.poles import pole_joints
from crowd_ik.solvers.settings import POLE_MIN_BEND, POLE_SLACK


def _errors(rig, pos, targets, weights):
    return np.where(weights > 0, np.linalg.norm(pos[rig.arrays["eff_joint"]] - targets, axis=-1), 0.0)


def pole_swivel(rig, root_pos, root_yaw, local_rot, targets, weights, poles, pole_on, tolerance=1e-3):
    """Twin of kernels/poles.pole_swivel. local_rot (N, J, 4) after a solve; targets, poles (N, E, 3) world;
    weights, pole_on (N, E). Returns (local_rot, world_pos, error (N,))."""
    rot_all = np.array(local_rot, np.float64)
    N, E = rot_all.shape[0], rig.n_effectors
    bend, pivot = pole_joints(rig)
    parent, kind, offset = rig.arrays["parent"], rig.arrays["kind"], rig.arrays["offset"].astype(np.float64)
    lo_all, hi_all = rig.angle_limits()
    eff = rig.arrays["eff_joint"]
    pos_out = np.zeros((N, rig.n_joints, 3))
    error = np.zeros(N)
    for i in range(N):
        q = rot_all[i : i + 1]

        def fk():
            p, w = forward_kinematics(rig, root_pos[i : i + 1], root_yaw[i : i + 1], q)
            return p[0], w[0]

        pos, wrot = fk()
        e_pos = _errors(rig, pos, targets[i], weights[i])
        for e in range(E):
            k, p = int(bend[e]), int(pivot[e])
            if not pole_on[i, e] or k < 0 or p < 0:
                continue
            a = pos[eff[e]] - pos[p]
            u, v = pos[k] - pos[p], poles[i, e] - pos[p]
            if np.linalg.norm(a) <= 1e-9:
                continue
            a = a / np.linalg.norm(a)
            if np.linalg.norm(u - u @ a * a) <= POLE_MIN_BEND * np.linalg.norm(u) \
                    or np.linalg.norm(v - v @ a * a) <= 1e-9:
                continue
            ang = float(best_angle_about(a, u, v))
            if abs(ang) <= 1e-6:
                continue
            base = yaw_quat(np.array([root_yaw[i]]))[0] if parent[p] < 0 else wrot[parent[p]]
            old = q[0, p].copy()
            turned = qnormalize(qmul(qconj(base), qmul(axis_angle(a, ang), qmul(base, old))))
            joint = rig.joints[p]
            s = int(rig.arrays["dof_start"][p])
            axes = np.array(joint.axes or [(0.0, 0.0, 1.0)] * 2, np.float64)
            bone = offset[k] / np.linalg.norm(offset[k])
            q[0, p] = constrain_rotation(int(kind[p]), axes, turned[None], lo_all[s : s + joint.dof],
                                         hi_all[s : s + joint.dof], joint.cone or 0.0, bone)[0]
            pos, wrot = fk()
            d = _errors(rig, pos, targets[i], weights[i])
            if np.any(d > np.maximum(e_pos, tolerance) + POLE_SLACK):
                q[0, p] = old
                pos, wrot = fk()
            else:
                e_pos = d
        pos_out[i] = pos
        error[i] = e_pos.max()
    return rot_all, pos_out, error
