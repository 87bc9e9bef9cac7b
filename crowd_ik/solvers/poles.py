"""Pole hints for a Crowd: after any method's solve, kernels/poles.py swivels each limb with a pole toward it."""

from __future__ import annotations

import numpy as np

from crowd_ik.kernels.serial_loops import POSE, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles


def pole_joints(rig) -> tuple[np.ndarray, np.ndarray]:
    """(pole_joint (E,), pivot (E,)) int32: per effector the joint whose bend plane turns toward the pole (the
    nearest hinge strictly above the effector joint; without one, the effector joint's parent) and the nearest
    moving joint above that one, the pivot the limb swivels at; -1 where there is none."""
    kind, parent = rig.arrays["kind"], rig.arrays["parent"]
    E = rig.n_effectors
    bend, pivot = np.full(E, -1, np.int32), np.full(E, -1, np.int32)
    for e, eff in enumerate(rig.effectors):
        above = [int(j) for j in rig.path_to_root(eff.joint)[1:]]  # the effector joint's ancestors, nearest first
        hinges = [j for j in above if kind[j] == 1]
        k = hinges[0] if hinges else (above[0] if above else -1)
        if k < 0:
            continue
        p = int(parent[k])
        while p >= 0 and kind[p] == 0:
            p = int(parent[p])
        bend[e], pivot[e] = k, p
    return bend, pivot


def joints_below(rig, pivot: np.ndarray) -> np.ndarray:
    """(E, J) int32: 1 for pivot[e] and every joint under it (what a turn of the pivot moves); zeros without one."""
    parent = rig.arrays["parent"]
    below = np.zeros((len(pivot), len(parent)), np.int32)
    for e, p in enumerate(pivot):
        if p < 0:
            continue
        below[e, p] = 1
        for j in range(int(p) + 1, len(parent)):  # topological order: a parent comes before its children
            below[e, j] = below[e, parent[j]] if parent[j] >= 0 else 0
    return below


def apply(crowd, req) -> None:
    from crowd_ik.kernels import poles

    ra, ti, E, N = crowd.rig_arrays, crowd.ti, crowd.rig.n_effectors, crowd.n
    def limbs():  # the rig's limbs (int32), uploaded once per crowd
        bend, pivot = pole_joints(crowd.rig)
        return bend, pivot, joints_below(crowd.rig, pivot)

    arrays = dict(zip(("bend", "pivot", "below"), crowd.constants(("pole_bend", "pole_pivot", "pole_below"), limbs)))
    b = crowd.buffers
    prepared(poles.pole_swivel)(
        ra["parent"], ra["offset"], ra["kind"], ra["axes"], ra["lo"], ra["hi"], ra["lim_p"], ra["cone"],
        ra["dof_start"], ra["eff_joint"], arrays["bend"], arrays["pivot"], arrays["below"],
        *bundles.pose(crowd), b.targets,
        b.weights, b.poles, b.pole_on, crowd.scratch("pole_e_pos", ti.f32, (N, E)), req.tolerance, b.error,
        serial_for(N, POSE),
    )
