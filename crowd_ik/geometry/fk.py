"""NumPy twins of kernels/fk.py and kernels/jacobian.py, vectorised over characters (loops over joints only)."""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.quat import axis_angle, joint_angles, joint_quat, qmul, qrot
from crowd_ik.rig import Rig


def angles_to_rotations(rig: Rig, angles: np.ndarray) -> np.ndarray:
    """(N, D) radians -> (N, J, 4) local rotations."""
    angles = np.asarray(angles, np.float64)
    out = np.zeros((angles.shape[0], rig.n_joints, 4))
    for j, joint in enumerate(rig.joints):
        s = rig.dof_start[j]
        out[:, j] = joint_quat(joint.dof, np.array(joint.axes or [(0, 0, 1)] * 2), angles[:, s : s + joint.dof])
    return out


def rotations_to_angles(rig: Rig, rot: np.ndarray) -> np.ndarray:
    """(N, J, 4) -> (N, D) radians."""
    out = np.zeros((rot.shape[0], rig.n_dof))
    for j, joint in enumerate(rig.joints):
        s = rig.dof_start[j]
        out[:, s : s + joint.dof] = joint_angles(joint.dof, np.array(joint.axes or [(0, 0, 1)] * 2), rot[:, j])
    return out


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    return axis_angle(np.array([0.0, 1.0, 0.0]), np.asarray(yaw, np.float64))


def forward_kinematics(rig: Rig, root_pos: np.ndarray, root_yaw: np.ndarray, rot: np.ndarray):
    """(world_pos (N, J, 3), world_rot (N, J, 4)) from roots (N, 3), yaw (N,) and local rotations (N, J, 4)."""
    N = rot.shape[0]
    pos = np.zeros((N, rig.n_joints, 3))
    wrot = np.zeros((N, rig.n_joints, 4))
    q_root = yaw_quat(root_yaw)
    for j, joint in enumerate(rig.joints):
        base_pos, base_rot = (root_pos, q_root) if joint.parent < 0 else (pos[:, joint.parent], wrot[:, joint.parent])
        pos[:, j] = base_pos + qrot(base_rot, np.broadcast_to(np.array(joint.offset), (N, 3)))
        wrot[:, j] = qmul(base_rot, rot[:, j])
    return pos, wrot


def jacobian(rig: Rig, root_yaw: np.ndarray, rot: np.ndarray, pos: np.ndarray, wrot: np.ndarray,
             ball_mode: str = "euler") -> np.ndarray:
    """(N, 6E, D): per effector 3 position rows (w x (p_eff - p_joint)) then 3 orientation rows (w)."""
    N = rot.shape[0]
    jac = np.zeros((N, 6 * rig.n_effectors, rig.n_dof))
    q_root = yaw_quat(root_yaw)
    ex, ey, ez = (np.broadcast_to(v, (N, 3)) for v in np.eye(3))
    for e, eff in enumerate(rig.effectors):
        p_eff = pos[:, eff.joint]
        for n in rig.path_to_root(eff.joint):
            joint = rig.joints[n]
            if joint.dof == 0:
                continue
            base = q_root if joint.parent < 0 else wrot[:, joint.parent]
            axes = np.array(joint.axes or [(0, 0, 1)] * 2)
            a = joint_angles(joint.dof, axes, rot[:, n])
            if joint.kind == "hinge":
                ws = [qrot(base, np.broadcast_to(axes[0], (N, 3)))]
            elif joint.kind == "universal":
                ws = [qrot(base, np.broadcast_to(axes[0], (N, 3))),
                      qrot(qmul(base, axis_angle(axes[0], a[:, 0])), np.broadcast_to(axes[1], (N, 3)))]
            elif ball_mode == "euler":
                rx = qmul(base, axis_angle(np.eye(3)[0], a[:, 0]))
                ws = [qrot(base, ex), qrot(rx, ey), qrot(qmul(rx, axis_angle(np.eye(3)[1], a[:, 1])), ez)]
            else:
                ws = [ex, ey, ez]
            s = rig.dof_start[n]
            for c, w in enumerate(ws):
                jac[:, 6 * e : 6 * e + 3, s + c] = np.cross(w, p_eff - pos[:, n])
                jac[:, 6 * e + 3 : 6 * e + 6, s + c] = w
    return jac
