"""The general FABRIK kernel's solve in each character's root frame (crowd_ik/solvers/fabrik.py): world_pos and the
targets moved by minus root_pos before the launch and back after it.

In float32 world coordinates the positions of a big crowd's far corners are 8-30 um apart (7.6 um at 64-128 m), and
the rotations a FABRIK solve recovers rebuild those positions by FK: chain16 at 100,000 characters on a 1 m grid
(up to 158 m out), 786 characters whose positions had met the 1.6 mm tolerance ended up to 1.77 mm off. The
difference of two float32 world values less than 2 m apart is exact, so in the root's frame the solve keeps float32's
relative precision and only the way back rounds, once. kernels/fabrik_lanes.py does the same inside its kernels.
"""

import taichi as ti

from crowd_ik.kernels.quat import vec3

ndarray = ti.types.ndarray


@ti.kernel
def to_root_frame(root_pos: ndarray(dtype=vec3, ndim=1), world_pos: ndarray(dtype=vec3, ndim=2),
                  targets: ndarray(dtype=vec3, ndim=2), rel_targets: ndarray(dtype=vec3, ndim=2),
                  serial: ti.template()):
    """world_pos -= root_pos in place, rel_targets = targets - root_pos, per character (N = root_pos.shape[0]).
    serial: on the launching thread (kernels/serial_loops.py)."""
    ti.loop_config(serialize=serial)
    for i in range(root_pos.shape[0]):
        r = root_pos[i]
        for j in range(world_pos.shape[1]):
            world_pos[i, j] = world_pos[i, j] - r
        for e in range(targets.shape[1]):
            rel_targets[i, e] = targets[i, e] - r


@ti.kernel
def to_world_frame(root_pos: ndarray(dtype=vec3, ndim=1), world_pos: ndarray(dtype=vec3, ndim=2),
                   serial: ti.template()):
    """world_pos += root_pos in place: to_root_frame's way back."""
    ti.loop_config(serialize=serial)
    for i in range(root_pos.shape[0]):
        r = root_pos[i]
        for j in range(world_pos.shape[1]):
            world_pos[i, j] = world_pos[i, j] + r
