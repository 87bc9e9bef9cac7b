"""Taichi kernels of the walking crowd (crowd_ik/game/gait.py, crowd_ik/game/crowd_motion.py).

gait_step: every body's footsteps (a swing advances and lands, a step starts, the footprint follows the body),
then its ankles' targets and the walk's pelvis bob, hand swing and head lean (twin: crowd_ik/reference/gait.py).
plant_legs: after the batched solve, both legs of every humanoid are set analytically (two-bone IK:
hip ball joint, knee hinge, universal ankle) so that each ankle lands exactly on its footprint and
the sole stays flat; the legs' world transforms are rewritten in the same pass (no second FK).
separate: the neighbours of every walker on a uniform ground grid -> a steering push away from them
and the displacement that resolves overlaps.

Metres, world frame, y up; quaternions (x, y, z, w) as in kernels/quat.py. NumPy twin:
crowd_ik/reference/gait_kernels.py.
"""

import taichi as ti

from crowd_ik.kernels.quat import axis_angle, qconj, qmul, qrot

ndarray = ti.types.ndarray
vec2 = ti.math.vec2
vec3 = ti.math.vec3
vec4 = ti.math.vec4


@ti.func
def frame_quat(x, y, z):
    """Unit quaternion of the rotation whose matrix has columns x, y, z (orthonormal, right-handed)."""
    m00, m01, m02 = x[0], y[0], z[0]
    m10, m11, m12 = x[1], y[1], z[1]
    m20, m21, m22 = x[2], y[2], z[2]
    q = vec4(0.0, 0.0, 0.0, 1.0)
    tr = m00 + m11 + m22
    if tr > 0.0:
        s = ti.sqrt(tr + 1.0) * 2.0
        q = vec4((m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s)
    elif m00 > m11 and m00 > m22:
        s = ti.sqrt(1.0 + m00 - m11 - m22) * 2.0
        q = vec4(0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s)
    elif m11 > m22:
        s = ti.sqrt(1.0 + m11 - m00 - m22) * 2.0
        q = vec4((m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s)
    else:
        s = ti.sqrt(1.0 + m22 - m00 - m11) * 2.0
        q = vec4((m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s)
    return q / q.norm()


@ti.kernel
def plant_legs(
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    local_rot: ndarray(dtype=vec4, ndim=2),
    offset: ndarray(dtype=vec3, ndim=1),
    legs: ndarray(dtype=ti.i32, ndim=2),
    feet: ndarray(dtype=vec3, ndim=2),
    yaw: ndarray(ndim=1),
    active: ndarray(dtype=ti.i32, ndim=1),
    serial: ti.template(),
):
    """Both legs of each active character n put its ankles on feet[n] (N, 2, 3) exactly (when in reach).

    legs (2, 4): the joints hip, knee, ankle, toe of each leg (a humanoid: thigh and shin along their
    joint's local -y, the knee a hinge about local +x that bends the shin backward, the ankle a
    universal joint about x then z). Per leg: the knee from the law of cosines in the plane of the
    hip-ankle line and the character's forward (sin yaw, 0, cos yaw), so knees bend forward; the
    hip's world frame has -y along the thigh and +z toward the knee's side; the ankle turns the
    sole's normal (its local +y) to world up. Out of reach, the leg stretches toward the footprint.
    Writes local_rot (N, J, 4) of hip, knee and ankle and world_rot / world_pos of hip..toe.
    """
    ti.loop_config(serialize=serial)
    for n in range(world_pos.shape[0]):
        if active[n] != 0:
            q_pelvis = world_rot[n, 0]
            fwd = vec3(ti.sin(yaw[n]), 0.0, ti.cos(yaw[n]))
            left = vec3(ti.cos(yaw[n]), 0.0, -ti.sin(yaw[n]))
            for side in range(2):
                hip, knee, ankle, toe = legs[side, 0], legs[side, 1], legs[side, 2], legs[side, 3]
                l1 = offset[knee].norm()
                l2 = offset[ankle].norm()
                h = world_pos[n, hip]
                d = feet[n, side] - h
                dist = d.norm()
                u = -vec3(0.0, 1.0, 0.0)
                if dist > 1e-9:
                    u = d / dist
                dc = ti.min(ti.max(dist, ti.abs(l1 - l2) + 1e-6), l1 + l2)
                cos_root = ti.min(ti.max((l1 * l1 + dc * dc - l2 * l2) / (2.0 * l1 * dc), -1.0), 1.0)
                cos_mid = ti.min(ti.max((l1 * l1 + l2 * l2 - dc * dc) / (2.0 * l1 * l2), -1.0), 1.0)
                w = fwd - fwd.dot(u) * u
                if w.norm() < 1e-6:
                    w = left - left.dot(u) * u
                w = w / w.norm()
                sin_root = ti.sqrt(ti.max(0.0, 1.0 - cos_root * cos_root))
                k = h + l1 * (cos_root * u + sin_root * w)
                y_h = (h - k) / l1
                z_h = w - w.dot(y_h) * y_h
                z_h = z_h / z_h.norm()
                x_h = ti.math.cross(y_h, z_h)
                q_hip = frame_quat(x_h, y_h, z_h)
                bend = 3.141592653589793 - ti.acos(cos_mid)
                q_knee_local = axis_angle(vec3(1.0, 0.0, 0.0), bend)
                q_knee = qmul(q_hip, q_knee_local)
                up = qrot(qconj(q_knee), vec3(0.0, 1.0, 0.0))
                a = ti.atan2(up[2], up[1])
                b = -ti.asin(ti.min(ti.max(up[0], -1.0), 1.0))
                q_ankle_local = qmul(axis_angle(vec3(1.0, 0.0, 0.0), a), axis_angle(vec3(0.0, 0.0, 1.0), b))
                q_ankle = qmul(q_knee, q_ankle_local)
                p_knee = h + qrot(q_hip, offset[knee])
                p_ankle = p_knee + qrot(q_knee, offset[ankle])
                local_rot[n, hip] = qmul(qconj(q_pelvis), q_hip)
                local_rot[n, knee] = q_knee_local
                local_rot[n, ankle] = q_ankle_local
                world_rot[n, hip] = q_hip
                world_rot[n, knee] = q_knee
                world_rot[n, ankle] = q_ankle
                world_rot[n, toe] = qmul(q_ankle, local_rot[n, toe])
                world_pos[n, knee] = p_knee
                world_pos[n, ankle] = p_ankle
                world_pos[n, toe] = p_ankle + qrot(q_ankle, offset[toe])


@ti.kernel
def separate(
    points: ndarray(dtype=vec2, ndim=1),
    radius: ndarray(ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    order: ndarray(dtype=ti.i32, ndim=1),
    cell_start: ndarray(dtype=ti.i32, ndim=1),
    origin_x: ti.f32,
    origin_z: ti.f32,
    cell: ti.f32,
    cells_x: ti.i32,
    cells_z: ti.i32,
    reach: ti.f32,
    steer: ndarray(dtype=vec2, ndim=1),
    push: ndarray(dtype=vec2, ndim=1),
    serial: ti.template(),
):
    """Separation of M bodies on the ground: points (M, 2) (x, z) metres, radius (M,) metres, kind (M,):
    0 ignored, 1 a walker (moved), 2 an obstacle (pushes, never moved).

    The grid: cells of `cell` metres (>= reach and >= any radius sum) from (origin_x, origin_z),
    cells_x by cells_z; a point's cell is clamped into it; cell c = cx * cells_z + cz holds the
    points order[cell_start[c]:cell_start[c + 1]] (ascending index). For each walker i, over the
    other non-ignored bodies j in its 3 x 3 cells (in that order), with d = p_i - p_j:
      steer[i] = sum of d / |d| * (1 - |d| / reach) over |d| < reach (a push away, 0..1 each);
      push[i] = sum of d / |d| * overlap * share over |d| < r_i + r_j, overlap = r_i + r_j - |d|,
    share 0.5 against a walker (each moves half) and 1 against an obstacle. Coincident points push
    apart along (cos a, sin a), a = 2.4 min(i, j), signed so that the two go opposite ways.
    Non-walkers get zeros.
    """
    ti.loop_config(serialize=serial)
    for i in range(points.shape[0]):
        s = vec2(0.0, 0.0)
        q = vec2(0.0, 0.0)
        if kind[i] == 1:
            p = points[i]
            cx = ti.min(ti.max(ti.cast(ti.floor((p[0] - origin_x) / cell), ti.i32), 0), cells_x - 1)
            cz = ti.min(ti.max(ti.cast(ti.floor((p[1] - origin_z) / cell), ti.i32), 0), cells_z - 1)
            for gx in range(ti.max(cx - 1, 0), ti.min(cx + 2, cells_x)):
                for gz in range(ti.max(cz - 1, 0), ti.min(cz + 2, cells_z)):
                    c = gx * cells_z + gz
                    for t in range(cell_start[c], cell_start[c + 1]):
                        j = order[t]
                        if j != i and kind[j] != 0:
                            d = p - points[j]
                            dist = d.norm()
                            limit = radius[i] + radius[j]
                            if dist < reach or dist < limit:
                                unit = vec2(0.0, 0.0)
                                if dist > 1e-6:
                                    unit = d / dist
                                else:
                                    a = 2.4 * ti.cast(ti.min(i, j), ti.f32)
                                    sign = 1.0
                                    if i > j:
                                        sign = -1.0
                                    unit = sign * vec2(ti.cos(a), ti.sin(a))
                                if dist < reach:
                                    s += unit * (1.0 - dist / reach)
                                if dist < limit:
                                    share = 0.5
                                    if kind[j] == 2:
                                        share = 1.0
                                    q += unit * (limit - dist) * share
        steer[i] = s
        push[i] = q


# gait_step's parameters (crowd_ik/game/gait.py: its constants, lengths and speeds times the bodies' scale), in the
# order of its `params` array; the kernel reads them by these indices
GAIT_PARAMS = ("step_length", "step_per_speed", "step_max", "step_time_min", "step_time_max", "walking",
               "stand_tolerance", "lift_share", "step_lift", "bob", "bob_speed", "arm_swing", "arm_max", "head_lean",
               "small_step")
(P_STEP_LENGTH, P_STEP_PER_SPEED, P_STEP_MAX, P_STEP_TIME_MIN, P_STEP_TIME_MAX, P_WALKING, P_STAND_TOLERANCE,
 P_LIFT_SHARE, P_STEP_LIFT, P_BOB, P_BOB_SPEED, P_ARM_SWING, P_ARM_MAX, P_HEAD_LEAN,
 P_SMALL_STEP) = range(len(GAIT_PARAMS))


@ti.func
def step_period(p: ti.template(), speed):
    """A step's duration at speed m/s: step length / speed, clamped (game.gait: STEP_LENGTH ... STEP_TIME)."""
    length = ti.min(p[P_STEP_LENGTH] + p[P_STEP_PER_SPEED] * speed, p[P_STEP_MAX])
    return ti.min(ti.max(length / ti.max(speed, 1e-6), p[P_STEP_TIME_MIN]), p[P_STEP_TIME_MAX])


@ti.func
def yaw_turn(v, c, s):
    """geometry.vectors.yaw_rotate of v by the yaw whose cosine and sine are c, s."""
    return vec3(c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2])


@ti.kernel
def gait_step(
    ground: ndarray(dtype=vec3, ndim=1),
    yaw: ndarray(ndim=1),
    velocity: ndarray(dtype=vec3, ndim=1),
    active: ndarray(dtype=ti.i32, ndim=1),
    foot_local: ndarray(dtype=vec3, ndim=1),
    params: ndarray(ndim=1),
    dt: ti.f32,
    feet: ndarray(dtype=vec3, ndim=2),
    swing: ndarray(dtype=ti.i32, ndim=1),
    progress: ndarray(ndim=1),
    period: ndarray(ndim=1),
    start: ndarray(dtype=vec3, ndim=1),
    goal: ndarray(dtype=vec3, ndim=1),
    last: ndarray(dtype=ti.i32, ndim=1),
    started: ndarray(dtype=ti.i32, ndim=1),
    targets: ndarray(dtype=vec3, ndim=2),
    bob: ndarray(ndim=1),
    hands: ndarray(dtype=vec3, ndim=2),
    head: ndarray(dtype=vec3, ndim=1),
    serial: ti.template(),
):
    """One gait step of dt s for N bodies (crowd_ik/game/gait.py's module docstring; twin:
    crowd_ik/reference/gait.py), then their foot targets and walk pose.

    In: ground (N, 3) pelvises on the ground (y ignored), yaw (N,), velocity (N, 3) m/s (y ignored), active (N,)
    1 for bodies that may start a step; foot_local (2, 3) the ankles under the root at yaw 0; params (GAIT_PARAMS).
    State, updated: feet (N, 2) planted footprints, swing (N,) the foot in the air or -1, its progress (N,) in
    [0, 1) and period (N,) s, start / goal (N, 3) of the swing, last (N,) the foot that stepped last; started[0]
    counts the steps begun. Out: targets (N, 2) the ankles' targets (the swinging one on its arc), bob (N,) the
    pelvis rise, hands (N, 2) the hands' offsets, head (N,) the head's."""
    ti.loop_config(serialize=serial)
    for n in range(ground.shape[0]):
        g = vec3(ground[n][0], 0.0, ground[n][2])
        c, s = ti.cos(yaw[n]), ti.sin(yaw[n])
        v = vec3(velocity[n][0], 0.0, velocity[n][2])
        speed = v.norm()
        # 1. the swing advances; a foot that lands is planted on its goal
        if swing[n] >= 0:
            progress[n] += dt / period[n]
            if progress[n] >= 1.0:
                feet[n, swing[n]] = goal[n]
                last[n] = swing[n]
                swing[n] = -1
                progress[n] = 0.0
        # 2. a new step: the other foot while walking, else the one farthest from its place under the body
        d0 = feet[n, 0] - (g + yaw_turn(foot_local[0], c, s))
        d1 = feet[n, 1] - (g + yaw_turn(foot_local[1], c, s))
        lag0 = vec2(d0[0], d0[2]).norm()
        lag1 = vec2(d1[0], d1[2]).norm()
        walking = speed > params[P_WALKING]
        if swing[n] < 0 and active[n] != 0 and (walking or ti.max(lag0, lag1) > params[P_STAND_TOLERANCE]):
            foot = 0
            if walking:
                foot = 1 - last[n]
            elif lag1 > lag0:
                foot = 1
            start[n] = feet[n, foot]
            swing[n] = foot
            progress[n] = 0.0
            period[n] = step_period(params, speed)
            ti.atomic_add(started[0], 1)
        # 3. the swing's footprint from the body now: it shortens when the body speeds up and, until its set-down,
        # follows the body predicted at the landing plus half a step's lead
        if swing[n] >= 0:
            period[n] = ti.min(period[n], step_period(params, speed))
            if progress[n] < 1.0 - params[P_LIFT_SHARE]:
                landing = g + v * ((1.0 - progress[n]) * period[n])
                goal[n] = landing + yaw_turn(foot_local[swing[n]], c, s) + v * (0.5 * period[n])
        # 4. the ankles' targets: the planted feet, the swinging one on an arc (lifts, moves along a smoothstep,
        # sets down), lower for a small step
        mid = 0.0
        for f in ti.static(range(2)):
            targets[n, f] = feet[n, f]
        if swing[n] >= 0:
            t = progress[n]
            h = ti.min(ti.max((t - params[P_LIFT_SHARE]) / (1.0 - 2.0 * params[P_LIFT_SHARE]), 0.0), 1.0)
            h = h * h * (3.0 - 2.0 * h)
            a, b = start[n], goal[n]
            q = a + (b - a) * h
            reach = vec2(b[0] - a[0], b[2] - a[2]).norm()
            q[1] += params[P_STEP_LIFT] * ti.min(1.0, reach / params[P_SMALL_STEP]) * ti.sin(3.141592653589793 * t)
            targets[n, swing[n]] = q
            mid = ti.sin(3.141592653589793 * t)
        # 5. the walk's pose: the pelvis rises mid-swing, the hands swing against the feet, the head leans in
        gain = ti.min(1.0, speed / params[P_BOB_SPEED])
        bob[n] = params[P_BOB] * gain * (mid - 0.5)
        fwd = vec3(s, 0.0, c)
        split = (targets[n, 1] - targets[n, 0]).dot(fwd)
        arm = ti.min(ti.max(params[P_ARM_SWING] * split, -params[P_ARM_MAX]), params[P_ARM_MAX]) * gain
        hands[n, 0] = fwd * arm
        hands[n, 1] = -fwd * arm
        head[n] = fwd * (params[P_HEAD_LEAN] * gain)
