"""Taichi kernels of the game's per-step bookkeeping (crowd_ik/game.py), so that the solved poses
go from the Crowd's ndarrays to the bullet pool without a round trip through NumPy.

Arrays: N characters, J joints, B = J - 1 bones (bone k joins joint parent[k] to joint k + 1),
C = N * B limb capsules (capsule n * B + k is character n's bone k). Metres, world frame, y up.
The NumPy twin is crowd_ik/reference/game_kernels.py.
"""

import taichi as ti

ndarray = ti.types.ndarray
vec3 = ti.math.vec3


@ti.kernel
def limb_capsules(
    world_pos: ndarray(dtype=vec3, ndim=2),
    bone_parent: ndarray(dtype=ti.i32, ndim=1),
    bone_radius: ndarray(ndim=1),
    prev_a: ndarray(dtype=vec3, ndim=1),
    prev_b: ndarray(dtype=vec3, ndim=1),
    a: ndarray(dtype=vec3, ndim=1),
    b: ndarray(dtype=vec3, ndim=1),
    joints: ndarray(dtype=vec3, ndim=2),
    box: ndarray(ndim=2),
):
    """From the joint positions world_pos (N, J, 3), one pass per character:

    a, b (C, 3) <- the limb capsules' ends (world_pos[n, bone_parent[k]], world_pos[n, k + 1]);
    joints (N, J, 3) <- world_pos (a copy, usually into host memory);
    box (N, 4) <- x_min, z_min, x_max, z_max over the character's capsules now (a, b) and at the
    previous step (prev_a, prev_b: (C, 3)), each grown by its bone_radius (B,): what the bullet
    pool needs to skip characters no bullet can reach (BulletPool.advance owner_boxes).
    """
    n_bones = bone_parent.shape[0]
    for n in range(world_pos.shape[0]):
        for j in range(world_pos.shape[1]):
            joints[n, j] = world_pos[n, j]
        lo = ti.Vector([ti.math.inf, ti.math.inf])
        hi = ti.Vector([-ti.math.inf, -ti.math.inf])
        for k in range(n_bones):
            c = n * n_bones + k
            pa = world_pos[n, bone_parent[k]]
            pb = world_pos[n, k + 1]
            a[c] = pa
            b[c] = pb
            r = bone_radius[k]
            for p in ti.static(range(4)):
                q = pa
                if ti.static(p == 1):
                    q = pb
                elif ti.static(p == 2):
                    q = prev_a[c]
                elif ti.static(p == 3):
                    q = prev_b[c]
                lo = ti.min(lo, ti.Vector([q[0], q[2]]) - r)
                hi = ti.max(hi, ti.Vector([q[0], q[2]]) + r)
        box[n, 0] = lo[0]
        box[n, 1] = lo[1]
        box[n, 2] = hi[0]
        box[n, 3] = hi[1]
