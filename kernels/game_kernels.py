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
    prev_box: ndarray(ndim=2),
    a: ndarray(dtype=vec3, ndim=1),
    b: ndarray(dtype=vec3, ndim=1),
    joints: ndarray(dtype=vec3, ndim=2),
    pose_box: ndarray(ndim=2),
    box: ndarray(ndim=2),
    serial: ti.template(),
):
    """From the joint positions world_pos (N, J, 3), one pass per character:

    a, b (C, 3) <- the limb capsules' ends (world_pos[n, bone_parent[k]], world_pos[n, k + 1]);
    joints (N, J, 3) <- world_pos (a copy, usually into host memory);
    pose_box (N, 4) <- x_min, z_min, x_max, z_max of the character's capsules, each grown by its
    bone_radius (B,);
    box (N, 4) <- the union of pose_box and prev_box (the previous step's pose_box): the box of
    the character's limbs in both poses, what the bullet pool needs to skip characters no bullet
    can reach (BulletPool.advance owner_boxes).
    """
    n_bones = bone_parent.shape[0]
    ti.loop_config(serialize=serial)
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
            lo = ti.min(lo, ti.min(ti.Vector([pa[0], pa[2]]), ti.Vector([pb[0], pb[2]])) - r)
            hi = ti.max(hi, ti.max(ti.Vector([pa[0], pa[2]]), ti.Vector([pb[0], pb[2]])) + r)
        pose_box[n, 0] = lo[0]
        pose_box[n, 1] = lo[1]
        pose_box[n, 2] = hi[0]
        pose_box[n, 3] = hi[1]
        box[n, 0] = ti.min(lo[0], prev_box[n, 0])
        box[n, 1] = ti.min(lo[1], prev_box[n, 1])
        box[n, 2] = ti.max(hi[0], prev_box[n, 2])
        box[n, 3] = ti.max(hi[1], prev_box[n, 3])


@ti.kernel
def dodge_targets(
    rest_targets: ndarray(dtype=vec3, ndim=2),
    lean: ndarray(dtype=vec3, ndim=1),
    duck: ndarray(ndim=1),
    guard: ndarray(ndim=1),
    roots: ndarray(dtype=vec3, ndim=1),
    yaw: ndarray(ndim=1),
    planted: ndarray(dtype=vec3, ndim=2),
    chest: ndarray(dtype=vec3, ndim=1),
    lean_gain: ndarray(ndim=1),
    duck_gain: ndarray(ndim=1),
    planted_slot: ndarray(dtype=ti.i32, ndim=1),
    hands: ndarray(dtype=ti.i32, ndim=1),
    hip_offset: ndarray(dtype=vec3, ndim=1),
    humanoid: ti.i32,
    pelvis_share: ti.f32,
    max_shift: ti.f32,
    leg_reach: ti.f32,
    scale: ti.f32,
    targets: ndarray(dtype=vec3, ndim=2),
    roots_out: ndarray(dtype=vec3, ndim=1),
    serial: ti.template(),
):
    """The IK targets (N, E, 3) and roots (N, 3) of characters holding a dodge (World._solve_characters).

    Per character n: its stance targets rest_targets[n] (E, 3) follow the low-passed lean (N, 3)
    by lean_gain (E,) and the duck (N,) downward by duck_gain (E,). A humanoid (humanoid != 0)
    also moves its root (roots (N, 3) standing, yaw (N,)) by pelvis_share of the lean, at most
    max_shift metres, and down by 0.85 duck, but never higher than both hips (hip_offset (2, 3)
    from the root at yaw 0) can stand over the planted feet (N, 2, 3) with legs of leg_reach
    metres; when the root is held down the non-planted targets drop with it. Its hands (the two
    effectors in hands, right side first) blend by guard (N,) toward a guard in front of the
    chest (N, 3) moved by 0.8 lean and the duck, and effectors with planted_slot[e] = k >= 0 are
    held at planted[n, k]. Otherwise roots_out = roots.
    """
    ti.loop_config(serialize=serial)
    for n in range(rest_targets.shape[0]):
        ln = lean[n]
        d = duck[n]
        root = roots[n]
        drop = 0.0
        if humanoid != 0:
            shift = ln * pelvis_share
            norm = shift.norm()
            shift = shift * ti.min(1.0, max_shift * scale / ti.max(norm, 1e-9))
            root = root + shift
            root[1] -= 0.85 * d
            wanted = root[1]
            c = ti.cos(yaw[n])
            s = ti.sin(yaw[n])
            highest = ti.math.inf
            for h in range(hip_offset.shape[0]):
                off = hip_offset[h]
                foot = planted[n, h]
                dx = root[0] + c * off[0] + s * off[2] - foot[0]
                dz = root[2] - s * off[0] + c * off[2] - foot[2]
                up = ti.sqrt(ti.max(leg_reach * leg_reach - (dx * dx + dz * dz), (0.2 * leg_reach) ** 2))
                highest = ti.min(highest, foot[1] + up - off[1])
            root[1] = ti.min(wanted, highest)
            drop = root[1] - wanted
        for e in range(rest_targets.shape[1]):
            t = rest_targets[n, e] + ln * lean_gain[e]
            t[1] -= d * duck_gain[e]
            if humanoid != 0 and planted_slot[e] < 0:
                t[1] += drop
            targets[n, e] = t
        if humanoid != 0:
            c = ti.cos(yaw[n])
            s = ti.sin(yaw[n])
            fwd = vec3(s, 0.0, c)
            left = vec3(c, 0.0, -s)
            front = chest[n] + ln * 0.8 - vec3(0.0, d, 0.0)
            g = guard[n]
            for k in range(hands.shape[0]):
                side = 1.0 - 2.0 * ti.cast(k, ti.f32)
                at = front + fwd * (0.28 * scale) + left * (0.1 * side * scale) + vec3(0.0, 0.14 * scale, 0.0)
                e = hands[k]
                targets[n, e] = targets[n, e] * (1.0 - g) + at * g
            for e in range(rest_targets.shape[1]):
                if planted_slot[e] >= 0:
                    targets[n, e] = planted[n, planted_slot[e]]
        roots_out[n] = root


@ti.kernel
def export_joints(world_pos: ndarray(dtype=vec3, ndim=2), joints: ndarray(dtype=vec3, ndim=2), serial: ti.template()):
    """joints (N, J, 3) <- world_pos (a copy into host memory: what to_numpy gives, without its launch's set-up)."""
    ti.loop_config(serialize=serial)
    for n in range(world_pos.shape[0]):
        for j in range(world_pos.shape[1]):
            joints[n, j] = world_pos[n, j]
