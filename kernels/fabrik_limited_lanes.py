"""FABRIK with joint limits (hinge, universal, ball with cone and box) with many characters per CPU thread as
SIMD lanes: kernels/fabrik.py's fabrik_solve (recover_each_iteration 1, no rotation targets) per lane.

As kernels/fabrik_lanes.py: each scalar of a character's state is one lane of a ``ti.types.vector(L,
ti.f32)``; S streams, each a contiguous range of characters whose lanes refill (a lane whose character
converged, stalled or ran out of iterations writes its result and takes the stream's next character);
the streams' state lives in fields of compile-time shape. Each iteration is the backward and forward
passes of fabrik_lanes, then the topological sweep of fabrik.recover_and_constrain: FK, each active joint's
rotation recovered from the proposals (the hinge's best angle, the ball joint's swing rounds, the closed-form
two-bone limb and the twist for a hinge child: kernels/fabrik_lane_joints.py, an orientation target's turn:
kernels/lane_align.py) and clamped (kernels/lane_limits.py). As in kernels/fabrik_lanes.py the positions and targets
are the character's minus its root_pos (float32's precision does not depend on where it stands) and the root goes
back on once, when the pose is written out.

Which joints are active (some positively weighted effector below them) is the same for every character
(``active``, from the host): the rig's structure decides the branches as scalars, and only what depends on a
character's numbers is a per-lane select. A costly branch (the swivel test, an Euler rebuild, a clamp) runs
only when some live lane takes it. Per lane the arithmetic is fabrik_solve's in the same order, except
that normalisations multiply by one reciprocal (kernels/lane_math.py), zero products in the Euler rebuild
are dropped, and all trigonometry (the hinge's, the two-bone limb's, the twist's, the ball joints' limits) is the
element-wise polynomials of kernels/lane_trig.py (within 3 ulp of the true values; instead of libm's calls, one per
lane: the warm 10,000-humanoid game solve 12-20 % faster, and the ball joints' 12 % more, kernels/lane_limits.py),
so statuses and iteration counts match and results do not depend on a character's lane-mates (bit for bit:
tests/test_fabrik_lanes.py).
"""

import functools

import taichi as ti
from crowd_ik.kernels import lane_align as la
from crowd_ik.kernels import lane_limits as lim
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_streams as ls
from crowd_ik.kernels.compile_settings import with_opt_level0
from crowd_ik.kernels.fabrik_lane_joints import joint_steps
from crowd_ik.kernels.lane_plan import MAX_STREAMS, lane_rows
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.kernels.quat import qrot, yaw_quat

from crowd_ik.solvers.settings import FABRIK_FLAT as FLAT
from crowd_ik.solvers.settings import FABRIK_STALL_AFTER as STALL_AFTER
from crowd_ik.solvers.settings import SWING_ROUNDS

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4


@functools.cache
def limited_solver(L: int, max_joints: int, max_effectors: int):
    """The kernel for L lanes per stream and scratch of max_joints and max_effectors rows per stream: f* (world
    positions), r* (world rotations), l* (local rotations), w*, aw (proposals and their weights), t* (targets),
    d* (orientation targets), o*, y* (root position and yaw rotation, one row per stream)."""
    V = ti.types.vector(L, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    J_, E_ = (MAX_STREAMS, max_joints), (MAX_STREAMS, max_effectors)
    fx, fy, fz, rx, ry, rz, rw, lx, ly, lz, lw, wx, wy, wz, aw = lane_rows(L, J_, 15)
    tx, ty, tz, tw, dx, dy, dz = lane_rows(L, E_, 7)
    ox, oy, oz, yx, yy, yz, yw = lane_rows(L, (MAX_STREAMS,), 7)

    to_base, swing_round, twist_for_hinge_child, two_bone_swing = joint_steps(L, lx, ly, lz, lw, wx, wy, wz, aw)

    @ti.func
    def sweep(s, on, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
              lo: ti.template(), hi: ti.template(), lim_p: ti.template(), lim_h: ti.template(), cone: ti.template(),
              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
              active: ti.template(), eff_joint: ti.template(), eff_axis: ti.template(), use_orient):
        """fabrik.recover_and_constrain per lane: rotations from the proposals, clamped, then FK."""
        for j in range(parent.shape[0]):
            p = parent[j]
            zero = yx[s] * 0.0  # the root, at the origin of the lanes' positions
            bx, by, bz, bqx, bqy, bqz, bqw = zero, zero, zero, yx[s], yy[s], yz[s], yw[s]
            if p >= 0:
                bx, by, bz, bqx, bqy, bqz, bqw = fx[s, p], fy[s, p], fz[s, p], rx[s, p], ry[s, p], rz[s, p], rw[s, p]
            o = offset[j]
            px, py, pz = lm.qrot(bqx, bqy, bqz, bqw, o.x, o.y, o.z)
            jx, jy, jz = bx + px, by + py, bz + pz
            fx[s, j], fy[s, j], fz[s, j] = jx, jy, jz
            qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
            k = kind[j]
            if k > 0 and active[j]:
                ix, iy, iz, iw = -bqx, -bqy, -bqz, bqw
                c0, c1 = child_start[j], child_start[j + 1]
                first_bone = vec3(0.0)
                n_active = 0
                if k == 1:
                    ax = axes[j, 0]
                    s_cross, s_dot = V(0.0), V(0.0)
                    for cc in range(c0, c1):
                        c = child_list[cc]
                        if active[c]:
                            wc = aw[s, c]
                            oc = offset[c]
                            ux, uy, uz = lm.qrot(qx, qy, qz, qw, oc.x, oc.y, oc.z)
                            du = lm.dot3(ux, uy, uz, ax.x, ax.y, ax.z)
                            ux, uy, uz = ux - du * ax.x, uy - du * ax.y, uz - du * ax.z
                            vx, vy, vz = to_base(s, c, ix, iy, iz, iw, jx, jy, jz)
                            dv = lm.dot3(vx, vy, vz, ax.x, ax.y, ax.z)
                            vx, vy, vz = vx - dv * ax.x, vy - dv * ax.y, vz - dv * ax.z
                            s_cross += wc * lm.dot3(ax.x, ax.y, ax.z, *lm.cross(ux, uy, uz, vx, vy, vz))
                            s_dot += wc * lm.dot3(ux, uy, uz, vx, vy, vz)
                    turn = (s_cross != 0.0) | (s_dot != 0.0)
                    ch, sh = lm.half_turn(s_dot, s_cross)  # half of atan2(s_cross, s_dot), scaled: normalised below
                    hx, hy, hz, hw = lm.qnormalize(*lm.qmul(ax.x * sh, ax.y * sh, ax.z * sh, ch, qx, qy, qz, qw))
                    qx, qy, qz, qw = ti.select(turn, hx, qx), ti.select(turn, hy, qy), ti.select(turn, hz, qz), \
                        ti.select(turn, hw, qw)
                else:
                    first, n_active = -1, 0
                    for cc in range(c0, c1):
                        if active[child_list[cc]]:
                            n_active += 1
                            if n_active == 1:
                                first = child_list[cc]
                    if first >= 0:
                        first_bone = offset[first].normalized()
                    free = on
                    if n_active == 1 and k == 3:
                        hx, hy, hz, hw, limb = two_bone_swing(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, on,
                                                              kind, axes, offset, lo, hi, lim_p, lim_h, cone, dof_start,
                                                              child_start, child_list, active)
                        qx, qy, qz, qw = hx, hy, hz, hw
                        free = on & (limb == 0)
                    if n_active > 0 and lm.any_lane(free):
                        rounds = 1 if n_active <= 1 else SWING_ROUNDS
                        hx, hy, hz, hw = qx, qy, qz, qw
                        for _ in range(rounds):
                            hx, hy, hz, hw = swing_round(s, hx, hy, hz, hw, c0, c1, ix, iy, iz, iw, jx, jy, jz,
                                                         offset, child_list, active)
                        if n_active == 1 and k == 3:
                            hx, hy, hz, hw = twist_for_hinge_child(s, j, hx, hy, hz, hw, ix, iy, iz, iw, jx, jy, jz,
                                                                   free, kind, axes, offset, lo, hi, dof_start,
                                                                   child_start, child_list, active)
                        qx, qy, qz, qw = ti.select(free, hx, qx), ti.select(free, hy, qy), ti.select(free, hz, qz), \
                            ti.select(free, hw, qw)
                # an orientation target on this joint's effector overrides the swing of its local axis
                for e in range(eff_joint.shape[0] if use_orient else 0):
                    if eff_joint[e] == j:
                        has = on & (tw[s, e] > 0.0) & (dx[s, e] * dx[s, e] + dy[s, e] * dy[s, e] + dz[s, e] * dz[s, e]
                                                       > 0.0)
                        if lm.any_lane(has):
                            gx, gy, gz = lm.qrot(ix, iy, iz, iw, dx[s, e], dy[s, e], dz[s, e])
                            hx, hy, hz, hw = la.align_axis(k, axes[j, 0], axes[j, 1], qx, qy, qz, qw, eff_axis[e],
                                                           gx, gy, gz)
                            qx, qy, qz, qw = ti.select(has, hx, qx), ti.select(has, hy, qy), ti.select(has, hz, qz), \
                                ti.select(has, hw, qw)
                d = dof_start[j]
                if k == 1:
                    qx, qy, qz, qw = lim.constrain_hinge(qx, qy, qz, qw, axes[j, 0], lim_p, lim_h, d)
                elif k == 2:
                    qx, qy, qz, qw = lim.constrain_universal(qx, qy, qz, qw, axes[j, 0], axes[j, 1], lim_p, lim_h, d)
                else:
                    ux, uy, uz, uw = qx, qy, qz, qw
                    qx, qy, qz, qw = lim.constrain_ball(qx, qy, qz, qw, lo, hi, lim_p, lim_h, d, cone[j], first_bone,
                                                        on)
                    if n_active >= 2 and p > 0 and kind[p] == 3 and child_start[p + 1] - child_start[p] == 1:
                        # kernels/fabrik_pass_up.py: the parent takes what the clamp removed
                        ex, ey, ez, ew = lm.qmul(ux, uy, uz, uw, -qx, -qy, -qz, qw)
                        moved = on & (ex * ex + ey * ey + ez * ez > 1e-12)
                        if lm.any_lane(moved):
                            ax_, ay_, az_, aw_ = lx[s, p], ly[s, p], lz[s, p], lw[s, p]
                            bn = offset[j].normalized()
                            nx, ny, nz, nw = lim.constrain_ball(*lm.qmul(ax_, ay_, az_, aw_, ex, ey, ez, ew), lo, hi,
                                                                lim_p, lim_h, dof_start[p], cone[p], bn, moved)
                            nx, ny, nz, nw = ti.select(moved, nx, ax_), ti.select(moved, ny, ay_), \
                                ti.select(moved, nz, az_), ti.select(moved, nw, aw_)
                            lx[s, p], ly[s, p], lz[s, p], lw[s, p] = nx, ny, nz, nw
                            g = parent[p]
                            cx, cy, cz, cw = lm.qmul(rx[s, g], ry[s, g], rz[s, g], rw[s, g], nx, ny, nz, nw)
                            bqx, bqy, bqz, bqw = ti.select(moved, cx, bqx), ti.select(moved, cy, bqy), \
                                ti.select(moved, cz, bqz), ti.select(moved, cw, bqw)
                            rx[s, p], ry[s, p], rz[s, p], rw[s, p] = bqx, bqy, bqz, bqw
                            # the joint's new place in the lanes that moved only: recomputed in the others, fast
                            # math may round it differently, and a lane would depend on its mates
                            px, py, pz = lm.qrot(bqx, bqy, bqz, bqw, o.x, o.y, o.z)
                            fx[s, j] = ti.select(moved, bx + px, jx)
                            fy[s, j] = ti.select(moved, by + py, jy)
                            fz[s, j] = ti.select(moved, bz + pz, jz)
                            wx, wy, wz, ww = lm.qmul(-nx, -ny, -nz, nw, *lm.qmul(ax_, ay_, az_, aw_, ux, uy, uz, uw))
                            wx, wy, wz, ww = lim.constrain_ball(wx, wy, wz, ww, lo, hi, lim_p, lim_h, d, cone[j],
                                                                first_bone, moved)
                            qx, qy, qz, qw = ti.select(moved, wx, qx), ti.select(moved, wy, qy), \
                                ti.select(moved, wz, qz), ti.select(moved, ww, qw)
                lx[s, j], ly[s, j], lz[s, j], lw[s, j] = qx, qy, qz, qw
            rx[s, j], ry[s, j], rz[s, j], rw[s, j] = lm.qmul(bqx, bqy, bqz, bqw, qx, qy, qz, qw)

    @ti.func
    def lane_turn(s, eff_joint: ti.template(), eff_axis: ti.template()):
        """fabrik.orientation_error per lane: max over effectors with an orientation target of 1 - cos(angle
        between its axis and the target)."""
        turn = V(0.0)
        for e in range(eff_joint.shape[0]):
            k = eff_joint[e]
            a = eff_axis[e]
            has = (tw[s, e] > 0.0) & (dx[s, e] * dx[s, e] + dy[s, e] * dy[s, e] + dz[s, e] * dz[s, e] > 0.0)
            cx, cy, cz = lm.qrot(rx[s, k], ry[s, k], rz[s, k], rw[s, k], a.x, a.y, a.z)
            turn = ti.select(has, ti.max(turn, 1.0 - lm.dot3(cx, cy, cz, dx[s, e], dy[s, e], dz[s, e])), turn)
        return turn

    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1), offset: ndarray(dtype=vec3, ndim=1), kind: ndarray(dtype=ti.i32, ndim=1),
        axes: ndarray(dtype=vec3, ndim=2), lo: ndarray(ndim=1), hi: ndarray(ndim=1), lim_p: ndarray(ndim=2),
        cone: ndarray(ndim=1), dof_start: ndarray(dtype=ti.i32, ndim=1), child_start: ndarray(dtype=ti.i32, ndim=1),
        child_list: ndarray(dtype=ti.i32, ndim=1), eff_joint: ndarray(dtype=ti.i32, ndim=1),
        eff_axis: ndarray(dtype=vec3, ndim=1), lim_h: ndarray(ndim=2), bone: ndarray(dtype=vec4, ndim=1), active: ndarray(dtype=ti.i32, ndim=1),
        root_pos: ndarray(dtype=vec3, ndim=1), root_yaw: ndarray(ndim=1), local_rot: ndarray(dtype=vec4, ndim=2),
        world_pos: ndarray(dtype=vec3, ndim=2), world_rot: ndarray(dtype=vec4, ndim=2),
        targets: ndarray(dtype=vec3, ndim=2), weights: ndarray(ndim=2), orient: ndarray(dtype=vec3, ndim=2),
        use_orient: ti.i32, n_streams: ti.i32, max_iterations: ti.i32,
        tolerance: ti.f32, error: ndarray(ndim=1), iterations: ndarray(dtype=ti.i32, ndim=1),
        stalled: ndarray(dtype=ti.i32, ndim=1),
    ):
        """Solve the N = root_pos.shape[0] characters in place, as fabrik_solve(recover_each_iteration=1) without
        rotation targets; active (J,) 1 where a positively weighted effector lies at or below the joint, the same
        for every character; orient (N, E, 3) unit directions or zero, read only when use_orient is 1."""
        N = root_pos.shape[0]
        J = parent.shape[0]
        E = eff_joint.shape[0]
        stride = spread_stride(n_streams)
        for slot in range(n_streams * stride):  # (kernels/work_split.py: the streams on every thread)
            if skipped(slot, stride):
                continue
            s, nxt, end = ls.stream_range(slot, stride, N, n_streams)
            cur = Vi(-1)  # each lane's character, -1 for none
            live = V(0.0)
            err = V(0.0)
            turn = V(0.0)
            it = V(0.0)
            flat = V(0.0)
            pending = V(1.0)  # lanes to hand their character's result out and take the next one
            while pending.max() + live.max() > 0.0:
                for l in range(L):
                    if pending[l] > 0.0:
                        i = cur[l]
                        if i >= 0:
                            error[i] = err[l]
                            iterations[i] = ti.cast(it[l], ti.i32)
                            stalled[i] = 1 if flat[l] >= STALL_AFTER else 0
                            for j in range(J):
                                local_rot[i, j] = vec4(lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l])
                                world_pos[i, j] = vec3(fx[s, j][l] + ox[s][l], fy[s, j][l] + oy[s][l],
                                                       fz[s, j][l] + oz[s][l])
                                world_rot[i, j] = vec4(rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l])
                        cur[l] = -1
                        live[l] = 0.0
                        while nxt < end and cur[l] < 0:  # take the next character that needs iterations
                            i = nxt
                            nxt += 1
                            e0 = 0.0
                            t0 = 0.0
                            r = root_pos[i]  # the origin of the lane's positions
                            for e in range(E):
                                v = targets[i, e] - r
                                w = weights[i, e]
                                tx[s, e][l], ty[s, e][l], tz[s, e][l], tw[s, e][l] = v.x, v.y, v.z, w
                                if w > 0.0:
                                    e0 = ti.max(e0, ((world_pos[i, eff_joint[e]] - r) - v).norm())
                                o = vec3(0.0)
                                if use_orient:
                                    o = orient[i, e]
                                    if w > 0.0 and o.norm_sqr() > 0.0:  # fabrik.orientation_error
                                        t0 = ti.max(t0, 1.0 - qrot(world_rot[i, eff_joint[e]], eff_axis[e]).dot(o))
                                dx[s, e][l], dy[s, e][l], dz[s, e][l] = o.x, o.y, o.z
                            if max_iterations > 0 and (e0 > tolerance or t0 > 1e-6):
                                for j in range(J):
                                    v = world_pos[i, j] - r
                                    fx[s, j][l], fy[s, j][l], fz[s, j][l] = v.x, v.y, v.z
                                    q = local_rot[i, j]
                                    lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l] = q.x, q.y, q.z, q.w
                                y = yaw_quat(root_yaw[i])
                                ox[s][l], oy[s][l], oz[s][l] = r.x, r.y, r.z
                                yx[s][l], yy[s][l], yz[s][l], yw[s][l] = y.x, y.y, y.z, y.w
                                cur[l] = i
                                live[l] = 1.0
                                err[l] = e0
                                turn[l] = t0
                                it[l] = 0.0
                                flat[l] = 0.0
                            else:
                                error[i] = e0
                                iterations[i] = 0
                                stalled[i] = 0
                pending = V(0.0)
                if live.max() > 0.0:
                    going = live > 0.0
                    # backward pass (fabrik_lanes.free_solver's): the effectors' weighted targets, then toward the root
                    for j in range(J):
                        wx[s, j], wy[s, j], wz[s, j], aw[s, j] = V(0.0), V(0.0), V(0.0), V(0.0)
                    for e in range(E):
                        k = eff_joint[e]
                        w = tw[s, e]
                        on = w > 0.0
                        wx[s, k] = ti.select(on, wx[s, k] + w * tx[s, e], wx[s, k])
                        wy[s, k] = ti.select(on, wy[s, k] + w * ty[s, e], wy[s, k])
                        wz[s, k] = ti.select(on, wz[s, k] + w * tz[s, e], wz[s, k])
                        aw[s, k] = ti.select(on, aw[s, k] + w, aw[s, k])
                    for jj in range(J - 1):
                        j = J - 1 - jj
                        q = parent[j]
                        b = bone[j]
                        w = aw[s, j]
                        on = w > 0.0
                        inv = 1.0 / ti.select(on, w, 1.0)
                        cx, cy, cz = wx[s, j] * inv, wy[s, j] * inv, wz[s, j] * inv
                        wx[s, j], wy[s, j], wz[s, j] = cx, cy, cz
                        ux, uy, uz = lm.safe_normalize(fx[s, q] - cx, fy[s, q] - cy, fz[s, q] - cz, -b.x, -b.y, -b.z)
                        wx[s, q] = ti.select(on, wx[s, q] + w * (cx + b.w * ux), wx[s, q])
                        wy[s, q] = ti.select(on, wy[s, q] + w * (cy + b.w * uy), wy[s, q])
                        wz[s, q] = ti.select(on, wz[s, q] + w * (cz + b.w * uz), wz[s, q])
                        aw[s, q] = ti.select(on, aw[s, q] + w, aw[s, q])
                    # forward pass from the fixed root
                    wx[s, 0], wy[s, 0], wz[s, 0] = fx[s, 0], fy[s, 0], fz[s, 0]
                    for j in range(1, J):
                        q = parent[j]
                        b = bone[j]
                        on = aw[s, j] > 0.0
                        bx, by, bz = wx[s, q], wy[s, q], wz[s, q]
                        ux, uy, uz = lm.safe_normalize(wx[s, j] - bx, wy[s, j] - by, wz[s, j] - bz, b.x, b.y, b.z)
                        wx[s, j] = ti.select(on, bx + b.w * ux, wx[s, j])
                        wy[s, j] = ti.select(on, by + b.w * uy, wy[s, j])
                        wz[s, j] = ti.select(on, bz + b.w * uz, wz[s, j])
                    sweep(s, going, parent, offset, kind, axes, lo, hi, lim_p, lim_h, cone, dof_start, child_start,
                          child_list, active, eff_joint, eff_axis, use_orient)
                    new_err = ls.lane_error(s, eff_joint, fx, fy, fz, tx, ty, tz, tw)
                    new_turn = V(0.0)
                    if use_orient:
                        new_turn = lane_turn(s, eff_joint, eff_axis)
                    # stalled: four updates in a row that improved neither error by one part in a million
                    err, turn, it, flat, pending, live = ls.stop_rule(live, new_err, new_turn, err, turn, it, flat, FLAT,
                                                                      STALL_AFTER, max_iterations, tolerance, 1e-6)

    # Taichi's whole-kernel CSE off for this kernel: 2.3x sooner compiled, the same poses bit for bit
    # (kernels/compile_settings.py)
    return with_opt_level0(solve)
