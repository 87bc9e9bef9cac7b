"""CCD with characters as SIMD lanes: kernels/ccd.py's ccd_solve with position targets and (on a limited rig)
orientation targets, per lane; no full rotation targets (goals 0 and 1).

As kernels/fabrik_limited_lanes.py: each scalar of a character's state is one lane of a ``ti.types.vector(L,
ti.f32)``; S streams, each a contiguous range of characters whose lanes refill (a lane whose character converged,
stalled or ran out of sweeps writes its result and takes the stream's next character); the streams' state lives in
fields of compile-time shape. Which joints and effectors are active is the same for every character (``active``,
``eff_on``: the host checks that the request's weights switch the same effectors on for every character that
weights any), so the rig's structure decides the branches as scalars (the reach step's hinge, a joint's only active
child, a serial run); what depends on a character's numbers (the straighten step where every target below a joint
is out of reach, the rounds of swing averaging, an orientation target) is a per-lane select. A character's start
(FK relative to its root, its errors) and its result are handled one lane at a time with the one-character kernel's
scalar code; each sweep is lane-packed (kernels/ccd_lane_steps.py), with the operations of ccd_sweep in the same
order, except that normalisations multiply by one reciprocal (kernels/lane_math.py) and angles are
kernels/lane_trig.py's polynomials. Two kernels per width: ``limited=False`` for constraint-free rigs without
orientation targets (an unlimited ball joint's clamp leaves a rotation as it is, so there is none), ``limited=True``
with the joint limits of kernels/lane_limits.py, hinges and universal joints, and orientation targets.
"""

import functools

import taichi as ti

from crowd_ik.kernels import lane_limits as lim
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_streams as ls
from crowd_ik.kernels import lane_trig as lt
from crowd_ik.kernels.ccd_lane_steps import lane_steps
from crowd_ik.kernels.lane_plan import MAX_STREAMS, lane_rows
from crowd_ik.kernels.quat import qmul, qrot, yaw_quat
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.solvers.settings import CCD_FLAT as FLAT
from crowd_ik.solvers.settings import CCD_STALL_AFTER as STALL_AFTER

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4


@functools.cache
def ccd_solver(L: int, max_joints: int, max_effectors: int, limited: bool):
    """The kernel for L lanes per stream and scratch of max_joints and max_effectors rows per stream: l* (local
    rotations), p* (positions relative to the root), r* (world rotations), e* (effectors carried through a sweep),
    t* (targets relative to the root and their weights), d* (orientation targets), y* (the root's yaw rotation, one
    row per stream)."""
    V = ti.types.vector(L, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    lx, ly, lz, lw, px, py, pz, rx, ry, rz, rw = lane_rows(L, (MAX_STREAMS, max_joints), 11)
    ex, ey, ez, tx, ty, tz, tw, dx, dy, dz = lane_rows(L, (MAX_STREAMS, max_effectors), 10)
    yx, yy, yz, yw = lane_rows(L, (MAX_STREAMS,), 4)
    swing_step, straighten, hinge_step, hinge_reach_step = lane_steps(L, ex, ey, ez, tx, ty, tz, tw)

    @ti.func
    def clamp(j, qx, qy, qz, qw, on, kind: ti.template(), axes: ti.template(), lo: ti.template(),
              hi: ti.template(), lim_p: ti.template(), lim_h: ti.template(), cone: ti.template(),
              dof_start: ti.template(), offset: ti.template(), child_start: ti.template(),
              child_list: ti.template(), active: ti.template()):
        """ccd_steps.constrain_joint per lane: q clamped to joint j's limits, the cone on its first active child's
        bone (on: the lanes whose result is used)."""
        first = -1
        for cc in range(child_start[j], child_start[j + 1]):
            if first < 0 and active[child_list[cc]] != 0:
                first = child_list[cc]
        bone = vec3(0.0)
        if first >= 0:
            bone = offset[first].normalized()
        k = kind[j]
        d = dof_start[j]
        ox, oy, oz, ow = qx, qy, qz, qw
        if k == 1:
            ox, oy, oz, ow = lim.constrain_hinge(qx, qy, qz, qw, axes[j, 0], lim_p, lim_h, d)
        elif k == 2:
            ox, oy, oz, ow = lim.constrain_universal(qx, qy, qz, qw, axes[j, 0], axes[j, 1], lim_p, lim_h, d)
        else:
            ox, oy, oz, ow = lim.constrain_ball(qx, qy, qz, qw, lo, hi, lim_p, lim_h, d, cone[j], bone, on)
        return ox, oy, oz, ow

    @ti.func
    def base(s, p):
        """The world rotation a joint's local rotation is relative to: its parent's, or the root's yaw."""
        bx, by, bz, bw = yx[s], yy[s], yz[s], yw[s]
        if p >= 0:
            bx, by, bz, bw = rx[s, p], ry[s, p], rz[s, p], rw[s, p]
        return bx, by, bz, bw

    @ti.func
    def sweep(s, going, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
              lo: ti.template(), hi: ti.template(), lim_p: ti.template(), lim_h: ti.template(), cone: ti.template(),
              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
              eff_joint: ti.template(), below: ti.template(), reach: ti.template(), active: ti.template(),
              eff_on: ti.template()):
        """ccd.ccd_sweep's joints per lane, deepest first, then FK."""
        J = parent.shape[0]
        E = eff_joint.shape[0]
        for e in range(E):
            k = eff_joint[e]
            ex[s, e], ey[s, e], ez[s, e] = px[s, k], py[s, k], pz[s, k]
        for jj in range(J):
            j = J - 1 - jj
            k = kind[j]
            if k > 0 and active[j] != 0:
                p = parent[j]
                bx, by, bz, bw = base(s, p)
                ix, iy, iz, iw = -bx, -by, -bz, bw
                jx, jy, jz = px[s, j], py[s, j], pz[s, j]
                qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
                # the effectors j serves (and its parent), and whether all of them lie out of the chain's reach
                far = going
                n_j, n_p, single = 0, 0, -1
                for e in range(E):
                    if eff_on[e] != 0 and below[j, e] != 0:
                        n_j += 1
                        single = e
                        d = lm.norm3(tx[s, e] - px[s, 0], ty[s, e] - py[s, 0], tz[s, e] - pz[s, 0])
                        far = far & (d > reach[e])
                    if p >= 0 and eff_on[e] != 0 and below[p, e] != 0:
                        n_p += 1
                only_child, n_children = -1, 0
                for cc in range(child_start[j], child_start[j + 1]):
                    if active[child_list[cc]] != 0:
                        only_child = child_list[cc]
                        n_children += 1
                serial = 0
                if p >= 0 and n_children == 1 and child_start[p + 1] - child_start[p] == 1:
                    serial = 1
                ax = axes[j, 0]
                hx, hy, hz, hw = qx, qy, qz, qw
                if serial != 0 and lm.any_lane(far):
                    c = only_child
                    ux, uy, uz = lm.qrot(ix, iy, iz, iw, px[s, c] - jx, py[s, c] - jy, pz[s, c] - jz)
                    vx, vy, vz = lm.qrot(ix, iy, iz, iw, jx - px[s, p], jy - py[s, p], jz - pz[s, p])
                    hx, hy, hz, hw = straighten(k, ax, qx, qy, qz, qw, ux, uy, uz, vx, vy, vz)
                aim = far == 0  # the straighten step only inside a serial run
                if serial == 0:
                    aim = going | (going == 0)
                if lm.any_lane(going & aim):
                    sx, sy, sz, sw = qx, qy, qz, qw
                    if ti.static(limited):
                        pp = ti.max(p, 0)
                        if k == 1 and p >= 0 and n_j == 1 and n_p == 1 and kind[pp] == 3:  # the reach step
                            dj = dof_start[j]
                            sx, sy, sz, sw = hinge_reach_step(s, single, qx, qy, qz, qw, ax, lo[dj], hi[dj], ix, iy,
                                                              iz, iw, jx, jy, jz, px[s, pp], py[s, pp], pz[s, pp])
                        elif k == 1:
                            sx, sy, sz, sw = hinge_step(s, j, qx, qy, qz, qw, ax, ix, iy, iz, iw, jx, jy, jz, below,
                                                        eff_on)
                        else:
                            sx, sy, sz, sw = swing_step(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, below,
                                                        eff_on)
                    else:
                        sx, sy, sz, sw = swing_step(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, below, eff_on)
                    hx, hy, hz, hw = ti.select(aim, sx, hx), ti.select(aim, sy, hy), ti.select(aim, sz, hz), \
                        ti.select(aim, sw, hw)
                if ti.static(limited):
                    hx, hy, hz, hw = clamp(j, hx, hy, hz, hw, going, kind, axes, lo, hi, lim_p, lim_h, cone,
                                           dof_start, offset, child_start, child_list, active)
                # carry the effectors below j along with its turn (world turn = base q_new q_old^-1 base^-1)
                cx, cy, cz, cw = lm.qmul(*lm.qmul(bx, by, bz, bw, *lm.qmul(hx, hy, hz, hw, -qx, -qy, -qz, qw)),
                                         ix, iy, iz, iw)
                for e in range(E):
                    if below[j, e] != 0:
                        vx, vy, vz = lm.qrot(cx, cy, cz, cw, ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz)
                        ex[s, e] = ti.select(going, jx + vx, ex[s, e])
                        ey[s, e] = ti.select(going, jy + vy, ey[s, e])
                        ez[s, e] = ti.select(going, jz + vz, ez[s, e])
                lx[s, j], ly[s, j] = ti.select(going, hx, qx), ti.select(going, hy, qy)
                lz[s, j], lw[s, j] = ti.select(going, hz, qz), ti.select(going, hw, qw)
        # FK once per sweep, relative to the root (ccd_sweep, fk_after)
        o = offset[0]
        px[s, 0], py[s, 0], pz[s, 0] = lm.qrot(yx[s], yy[s], yz[s], yw[s], o.x, o.y, o.z)
        rx[s, 0], ry[s, 0], rz[s, 0], rw[s, 0] = lm.qmul(yx[s], yy[s], yz[s], yw[s], lx[s, 0], ly[s, 0], lz[s, 0],
                                                          lw[s, 0])
        fk_after(s, 0, going, parent, offset)

    @ti.func
    def fk_after(s, j0, on, parent: ti.template(), offset: ti.template()):
        """ccd_steps.fk_after per lane: the joints after j0 from their parents, in the lanes `on`."""
        for j in range(j0 + 1, parent.shape[0]):
            p = parent[j]
            o = offset[j]
            vx, vy, vz = lm.qrot(rx[s, p], ry[s, p], rz[s, p], rw[s, p], o.x, o.y, o.z)
            qx, qy, qz, qw = lm.qmul(rx[s, p], ry[s, p], rz[s, p], rw[s, p], lx[s, j], ly[s, j], lz[s, j], lw[s, j])
            px[s, j] = ti.select(on, px[s, p] + vx, px[s, j])
            py[s, j] = ti.select(on, py[s, p] + vy, py[s, j])
            pz[s, j] = ti.select(on, pz[s, p] + vz, pz[s, j])
            rx[s, j], ry[s, j] = ti.select(on, qx, rx[s, j]), ti.select(on, qy, ry[s, j])
            rz[s, j], rw[s, j] = ti.select(on, qz, rz[s, j]), ti.select(on, qw, rw[s, j])

    @ti.func
    def orient_pass(s, going, parent: ti.template(), offset: ti.template(), kind: ti.template(),
                    axes: ti.template(), lo: ti.template(), hi: ti.template(), lim_p: ti.template(),
                    lim_h: ti.template(), cone: ti.template(), dof_start: ti.template(), child_start: ti.template(),
                    child_list: ti.template(), eff_joint: ti.template(), eff_axis: ti.template(),
                    active: ti.template(), eff_on: ti.template()):
        """ccd_sweep's orientation pass per lane: each effector joint's local axis swung onto its target direction,
        clamped, in topological order, FK after each."""
        for j in range(parent.shape[0]):
            if kind[j] > 0:
                for e in range(eff_joint.shape[0]):
                    if eff_joint[e] == j and eff_on[e] != 0:
                        has = going & (tw[s, e] > 0.0) & (dx[s, e] * dx[s, e] + dy[s, e] * dy[s, e]
                                                          + dz[s, e] * dz[s, e] > 0.0)
                        if lm.any_lane(has):
                            bx, by, bz, bw = base(s, parent[j])
                            qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
                            a = eff_axis[e]
                            cx, cy, cz = lm.qrot(qx, qy, qz, qw, a.x, a.y, a.z)
                            wx, wy, wz = lm.qrot(-bx, -by, -bz, bw, dx[s, e], dy[s, e], dz[s, e])
                            hx, hy, hz, hw = lm.qnormalize(*lm.qmul(*lm.swing(cx, cy, cz, wx, wy, wz), qx, qy, qz, qw))
                            hx, hy, hz, hw = clamp(j, hx, hy, hz, hw, has, kind, axes, lo, hi, lim_p, lim_h, cone,
                                                   dof_start, offset, child_start, child_list, active)
                            lx[s, j], ly[s, j] = ti.select(has, hx, qx), ti.select(has, hy, qy)
                            lz[s, j], lw[s, j] = ti.select(has, hz, qz), ti.select(has, hw, qw)
                            gx, gy, gz, gw = lm.qmul(bx, by, bz, bw, hx, hy, hz, hw)
                            rx[s, j], ry[s, j] = ti.select(has, gx, rx[s, j]), ti.select(has, gy, ry[s, j])
                            rz[s, j], rw[s, j] = ti.select(has, gz, rz[s, j]), ti.select(has, gw, rw[s, j])
                            fk_after(s, j, has, parent, offset)

    @ti.func
    def lane_turn(s, eff_joint: ti.template(), eff_axis: ti.template()):
        """rotation_goals.turn_error per lane: max over effectors with an axis target of its angle, radians."""
        turn = V(0.0)
        for e in range(eff_joint.shape[0]):
            k = eff_joint[e]
            a = eff_axis[e]
            has = (tw[s, e] > 0.0) & (dx[s, e] * dx[s, e] + dy[s, e] * dy[s, e] + dz[s, e] * dz[s, e] > 0.0)
            cx, cy, cz = lm.qrot(rx[s, k], ry[s, k], rz[s, k], rw[s, k], a.x, a.y, a.z)
            ang = lt.acos(ti.math.clamp(lm.dot3(cx, cy, cz, dx[s, e], dy[s, e], dz[s, e]), -1.0, 1.0))
            turn = ti.select(has, ti.max(turn, ang), turn)
        return turn

    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1), offset: ndarray(dtype=vec3, ndim=1), kind: ndarray(dtype=ti.i32, ndim=1),
        axes: ndarray(dtype=vec3, ndim=2), lo: ndarray(ndim=1), hi: ndarray(ndim=1), lim_p: ndarray(ndim=2),
        lim_h: ndarray(ndim=2), cone: ndarray(ndim=1), dof_start: ndarray(dtype=ti.i32, ndim=1),
        child_start: ndarray(dtype=ti.i32, ndim=1), child_list: ndarray(dtype=ti.i32, ndim=1),
        eff_joint: ndarray(dtype=ti.i32, ndim=1), eff_axis: ndarray(dtype=vec3, ndim=1),
        below: ndarray(dtype=ti.i32, ndim=2), reach: ndarray(ndim=1), active: ndarray(dtype=ti.i32, ndim=1),
        eff_on: ndarray(dtype=ti.i32, ndim=1), root_pos: ndarray(dtype=vec3, ndim=1), root_yaw: ndarray(ndim=1),
        local_rot: ndarray(dtype=vec4, ndim=2), world_pos: ndarray(dtype=vec3, ndim=2),
        world_rot: ndarray(dtype=vec4, ndim=2), targets: ndarray(dtype=vec3, ndim=2), weights: ndarray(ndim=2),
        orient: ndarray(dtype=vec3, ndim=2), use_orient: ti.i32, n_streams: ti.i32, max_iterations: ti.i32,
        tolerance: ti.f32, rotation_tolerance: ti.f32, error: ndarray(ndim=1),
        iterations: ndarray(dtype=ti.i32, ndim=1), stalled: ndarray(dtype=ti.i32, ndim=1),
    ):
        """Solve the N = root_pos.shape[0] characters in place as ccd.ccd_solve (goals 0, or 1 with use_orient)
        does; active (J,) 1 where a positively weighted effector lies at or below the joint, eff_on (E,) 1 for the
        positively weighted effectors, the same for every character that weights any (one that weights none does no
        sweep); orient (N, E, 3) unit directions or zero, read only when use_orient is 1."""
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
                            r = root_pos[i]
                            for j in range(J):
                                local_rot[i, j] = vec4(lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l])
                                world_pos[i, j] = vec3(px[s, j][l], py[s, j][l], pz[s, j][l]) + r
                                world_rot[i, j] = vec4(rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l])
                        cur[l] = -1
                        live[l] = 0.0
                        while nxt < end and cur[l] < 0:  # take the next character that needs sweeps
                            i = nxt
                            nxt += 1
                            # FK relative to the root, as ccd_solve starts (ccd_steps.fk_after)
                            y = yaw_quat(root_yaw[i])
                            yx[s][l], yy[s][l], yz[s][l], yw[s][l] = y.x, y.y, y.z, y.w
                            for j in range(J):
                                q = local_rot[i, j]
                                p = parent[j]
                                wp = vec3(0.0)
                                wr = vec4(0.0)
                                if p >= 0:
                                    bq = vec4(rx[s, p][l], ry[s, p][l], rz[s, p][l], rw[s, p][l])
                                    wp = vec3(px[s, p][l], py[s, p][l], pz[s, p][l]) + qrot(bq, offset[j])
                                    wr = qmul(bq, q)
                                else:
                                    wp = qrot(y, offset[0])
                                    wr = qmul(y, q)
                                lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l] = q.x, q.y, q.z, q.w
                                px[s, j][l], py[s, j][l], pz[s, j][l] = wp.x, wp.y, wp.z
                                rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l] = wr.x, wr.y, wr.z, wr.w
                            r = root_pos[i]
                            e0 = 0.0
                            t0 = 0.0
                            for e in range(E):
                                t = targets[i, e] - r
                                w = weights[i, e]
                                tx[s, e][l], ty[s, e][l], tz[s, e][l], tw[s, e][l] = t.x, t.y, t.z, w
                                k = eff_joint[e]
                                if w > 0.0:
                                    e0 = ti.max(e0, (vec3(px[s, k][l], py[s, k][l], pz[s, k][l]) - t).norm())
                                o = vec3(0.0)
                                if use_orient:
                                    o = orient[i, e]
                                    if w > 0.0 and o.norm_sqr() > 0.0:  # rotation_goals.turn_error
                                        g = vec4(rx[s, k][l], ry[s, k][l], rz[s, k][l], rw[s, k][l])
                                        t0 = ti.max(t0, ti.acos(ti.math.clamp(qrot(g, eff_axis[e]).dot(o), -1.0, 1.0)))
                                dx[s, e][l], dy[s, e][l], dz[s, e][l] = o.x, o.y, o.z
                            if max_iterations > 0 and (e0 > tolerance or t0 > rotation_tolerance):
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
                                for j in range(J):
                                    world_pos[i, j] = vec3(px[s, j][l], py[s, j][l], pz[s, j][l]) + r
                                    world_rot[i, j] = vec4(rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l])
                pending = V(0.0)
                if live.max() > 0.0:
                    going = live > 0.0
                    sweep(s, going, parent, offset, kind, axes, lo, hi, lim_p, lim_h, cone, dof_start, child_start,
                          child_list, eff_joint, below, reach, active, eff_on)
                    new_turn = V(0.0)
                    if ti.static(limited):
                        if use_orient:
                            orient_pass(s, going, parent, offset, kind, axes, lo, hi, lim_p, lim_h, cone, dof_start,
                                        child_start, child_list, eff_joint, eff_axis, active, eff_on)
                            new_turn = lane_turn(s, eff_joint, eff_axis)
                    new_err = ls.lane_error(s, eff_joint, px, py, pz, tx, ty, tz, tw)  # ccd_steps.relative_error
                    # stalled: four sweeps in a row that improved neither error by 0.01 %
                    err, turn, it, flat, pending, live = ls.stop_rule(live, new_err, new_turn, err, turn, it, flat, FLAT,
                                                                      STALL_AFTER, max_iterations, tolerance,
                                                                      rotation_tolerance)

    return solve
