"""CCD on constraint-free rigs (unlimited ball joints) with many characters per CPU thread as SIMD lanes:
kernels/ccd.py's ccd_solve with position targets only (goals 0), per lane.

As kernels/fabrik_limited_lanes.py: each scalar of a character's state is one lane of a ``ti.types.vector(L,
ti.f32)``; S streams, each a contiguous range of characters whose lanes refill (a lane whose character converged,
stalled or ran out of sweeps writes its result and takes the stream's next character); the streams' state lives in
fields of compile-time shape. Which joints and effectors are active is the same for every character (``active``,
``eff_on``: the host checks that the request's weights switch the same effectors on for every character that
weights any), so the rig's structure decides the branches as scalars; what depends on a character's numbers (the
straighten step where every target below a joint is out of reach, the rounds of swing averaging a joint with
several effectors takes) is a per-lane select. A character's start (FK relative to its root, its error) and its
result are handled one lane at a time; each sweep is lane-packed, with the operations of ccd_sweep in the same
order, except that normalisations multiply by one reciprocal (kernels/lane_math.py). An unlimited ball joint's
clamp (quat.constrain_rotation) leaves a rotation as it is, so there is none here.
"""

import functools

import taichi as ti

from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels.ccd_steps import MULTI_ROUNDS
from crowd_ik.kernels.lane_plan import MAX_STREAMS, lane_rows
from crowd_ik.kernels.quat import qmul, qrot, yaw_quat
from crowd_ik.kernels.work_split import spread_stride

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4

FLAT = 1e-4  # kernels/ccd.py: a sweep that improves the error by less than this share is flat
STALL_AFTER = 4  # flat sweeps in a row that make a stall


@functools.cache
def free_ccd_solver(L: int, max_joints: int, max_effectors: int):
    """The kernel for L lanes per stream and scratch of max_joints and max_effectors rows per stream: l* (local
    rotations), p* (positions relative to the root), r* (world rotations), e* (effectors carried through a sweep),
    t* (targets relative to the root and their weights), y* (the root's yaw rotation, one row per stream)."""
    V = ti.types.vector(L, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    lx, ly, lz, lw, px, py, pz, rx, ry, rz, rw = lane_rows(L, (MAX_STREAMS, max_joints), 11)
    ex, ey, ez, tx, ty, tz, tw = lane_rows(L, (MAX_STREAMS, max_effectors), 7)
    yx, yy, yz, yw = lane_rows(L, (MAX_STREAMS,), 4)

    @ti.func
    def swing_step(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, below: ti.template(), eff_on: ti.template()):
        """ccd_steps.swing_step per lane: q preceded by the (averaged) swing turning the effectors below j toward
        their targets, in the parent's frame (i: the inverse of the parent's world rotation)."""
        E = eff_on.shape[0]
        n_eff = V(0.0)
        for e in range(E):
            if below[j, e] != 0 and eff_on[e] != 0:
                dx, dy, dz = ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz
                n_eff += ti.select(dx * dx + dy * dy + dz * dz > 1e-18, 1.0, 0.0)
        rounds = ti.select(n_eff > 1.0, float(MULTI_ROUNDS), 1.0)
        dx_, dy_, dz_, dw_ = V(0.0), V(0.0), V(0.0), V(1.0)
        for r in range(MULTI_ROUNDS if lm.any_lane(n_eff > 1.0) else 1):
            ax, ay, az, a_w = V(0.0), V(0.0), V(0.0), V(0.0)
            for e in range(E):
                if below[j, e] != 0 and eff_on[e] != 0:
                    ux, uy, uz = lm.qrot(ix, iy, iz, iw, ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz)
                    ux, uy, uz = lm.qrot(dx_, dy_, dz_, dw_, ux, uy, uz)
                    vx, vy, vz = lm.qrot(ix, iy, iz, iw, tx[s, e] - jx, ty[s, e] - jy, tz[s, e] - jz)
                    nu = lm.norm3(ux, uy, uz)
                    nv = lm.norm3(vx, vy, vz)
                    ok = (nu > 1e-9) & (nv > 1e-9)
                    du = ti.select(ok, nu, 1.0)
                    dv = ti.select(ok, nv, 1.0)
                    sx, sy, sz, sw = lm.swing(ux / du, uy / du, uz / du, vx / dv, vy / dv, vz / dv)
                    flip = ti.select(sw < 0.0, -1.0, 1.0)
                    k = tw[s, e] * nu * nv
                    ax = ti.select(ok, ax + k * (flip * sx), ax)
                    ay = ti.select(ok, ay + k * (flip * sy), ay)
                    az = ti.select(ok, az + k * (flip * sz), az)
                    a_w = ti.select(ok, a_w + k * (flip * sw), a_w)
            nx, ny, nz, nw = lm.qnormalize(*lm.qmul(*lm.qnormalize(ax, ay, az, a_w), dx_, dy_, dz_, dw_))
            take = (n_eff > 0.0) & (float(r) < rounds) & (ax * ax + ay * ay + az * az + a_w * a_w > 0.0)
            dx_, dy_, dz_, dw_ = ti.select(take, nx, dx_), ti.select(take, ny, dy_), ti.select(take, nz, dz_), \
                ti.select(take, nw, dw_)
        return lm.qnormalize(*lm.qmul(dx_, dy_, dz_, dw_, qx, qy, qz, qw))

    @ti.func
    def straighten(qx, qy, qz, qw, ux, uy, uz, vx, vy, vz):
        """ccd_steps.straighten_step for a ball joint per lane: q turned so that the child bone u lines up with the
        parent bone v (both in the parent's frame)."""
        ok = (ux * ux + uy * uy + uz * uz > 0.0) & (vx * vx + vy * vy + vz * vz > 0.0)
        ax, ay, az = lm.normalized(ux, uy, uz)
        bx, by, bz = lm.normalized(vx, vy, vz)
        hx, hy, hz, hw = lm.qnormalize(*lm.qmul(*lm.swing(ax, ay, az, bx, by, bz), qx, qy, qz, qw))
        return ti.select(ok, hx, qx), ti.select(ok, hy, qy), ti.select(ok, hz, qz), ti.select(ok, hw, qw)

    @ti.func
    def sweep(s, going, parent: ti.template(), offset: ti.template(), kind: ti.template(),
              child_start: ti.template(), child_list: ti.template(), eff_joint: ti.template(), below: ti.template(),
              reach: ti.template(), active: ti.template(), eff_on: ti.template()):
        """ccd.ccd_sweep per lane (goals 0), deepest joint first, then FK."""
        J = parent.shape[0]
        E = eff_joint.shape[0]
        for e in range(E):
            k = eff_joint[e]
            ex[s, e], ey[s, e], ez[s, e] = px[s, k], py[s, k], pz[s, k]
        for jj in range(J):
            j = J - 1 - jj
            if kind[j] > 0 and active[j] != 0:
                p = parent[j]
                bx, by, bz, bw = yx[s], yy[s], yz[s], yw[s]
                if p >= 0:
                    bx, by, bz, bw = rx[s, p], ry[s, p], rz[s, p], rw[s, p]
                ix, iy, iz, iw = -bx, -by, -bz, bw
                jx, jy, jz = px[s, j], py[s, j], pz[s, j]
                qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
                # every effector served by j out of the whole chain's reach (ccd_sweep's out_of_reach)
                far = going
                for e in range(E):
                    if eff_on[e] != 0 and below[j, e] != 0:
                        d = lm.norm3(tx[s, e] - px[s, 0], ty[s, e] - py[s, 0], tz[s, e] - pz[s, 0])
                        far = far & (d > reach[e])
                only_child, n_children = -1, 0
                for cc in range(child_start[j], child_start[j + 1]):
                    if active[child_list[cc]] != 0:
                        only_child = child_list[cc]
                        n_children += 1
                serial = 0
                if p >= 0 and n_children == 1 and child_start[p + 1] - child_start[p] == 1:
                    serial = 1
                hx, hy, hz, hw = qx, qy, qz, qw
                if serial != 0 and lm.any_lane(far):
                    c = only_child
                    ux, uy, uz = lm.qrot(ix, iy, iz, iw, px[s, c] - jx, py[s, c] - jy, pz[s, c] - jz)
                    vx, vy, vz = lm.qrot(ix, iy, iz, iw, jx - px[s, p], jy - py[s, p], jz - pz[s, p])
                    hx, hy, hz, hw = straighten(qx, qy, qz, qw, ux, uy, uz, vx, vy, vz)
                if serial == 0 or lm.any_lane(going & (far == 0)):
                    sx, sy, sz, sw = swing_step(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, below, eff_on)
                    aim = far == 0  # the straighten step only inside a serial run
                    if serial == 0:
                        aim = going | (going == 0)
                    hx, hy, hz, hw = ti.select(aim, sx, hx), ti.select(aim, sy, hy), ti.select(aim, sz, hz), \
                        ti.select(aim, sw, hw)
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
        for j in range(1, J):
            p = parent[j]
            o = offset[j]
            vx, vy, vz = lm.qrot(rx[s, p], ry[s, p], rz[s, p], rw[s, p], o.x, o.y, o.z)
            px[s, j], py[s, j], pz[s, j] = px[s, p] + vx, py[s, p] + vy, pz[s, p] + vz
            rx[s, j], ry[s, j], rz[s, j], rw[s, j] = lm.qmul(rx[s, p], ry[s, p], rz[s, p], rw[s, p], lx[s, j],
                                                              ly[s, j], lz[s, j], lw[s, j])

    @ti.func
    def lane_error(s, eff_joint: ti.template()):
        """ccd_steps.relative_error per lane: max over weighted effectors of |effector - target|."""
        err = V(0.0)
        for e in range(eff_joint.shape[0]):
            k = eff_joint[e]
            n = lm.norm3(px[s, k] - tx[s, e], py[s, k] - ty[s, e], pz[s, k] - tz[s, e])
            err = ti.select(tw[s, e] > 0.0, ti.max(err, n), err)
        return err

    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1), offset: ndarray(dtype=vec3, ndim=1), kind: ndarray(dtype=ti.i32, ndim=1),
        child_start: ndarray(dtype=ti.i32, ndim=1), child_list: ndarray(dtype=ti.i32, ndim=1),
        eff_joint: ndarray(dtype=ti.i32, ndim=1), below: ndarray(dtype=ti.i32, ndim=2), reach: ndarray(ndim=1),
        active: ndarray(dtype=ti.i32, ndim=1), eff_on: ndarray(dtype=ti.i32, ndim=1),
        root_pos: ndarray(dtype=vec3, ndim=1), root_yaw: ndarray(ndim=1), local_rot: ndarray(dtype=vec4, ndim=2),
        world_pos: ndarray(dtype=vec3, ndim=2), world_rot: ndarray(dtype=vec4, ndim=2),
        targets: ndarray(dtype=vec3, ndim=2), weights: ndarray(ndim=2), n_streams: ti.i32, max_iterations: ti.i32,
        tolerance: ti.f32, error: ndarray(ndim=1), iterations: ndarray(dtype=ti.i32, ndim=1),
        stalled: ndarray(dtype=ti.i32, ndim=1),
    ):
        """Solve the N = root_pos.shape[0] characters in place as ccd.ccd_solve (goals 0) does; active (J,) 1 where a
        positively weighted effector lies at or below the joint, eff_on (E,) 1 for the positively weighted
        effectors, the same for every character that weights any (one that weights none does no sweep)."""
        N = root_pos.shape[0]
        J = parent.shape[0]
        E = eff_joint.shape[0]
        S = n_streams
        chunk = (N + S - 1) // S
        stride = spread_stride(S)
        for slot in range(S * stride):  # (kernels/work_split.py: the streams on every thread)
            if slot % stride != 0:
                continue
            s = slot // stride
            nxt = s * chunk
            end = ti.min(nxt + chunk, N)
            cur = Vi(-1)  # each lane's character, -1 for none
            live = V(0.0)
            err = V(0.0)
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
                            for e in range(E):
                                t = targets[i, e] - r
                                w = weights[i, e]
                                tx[s, e][l], ty[s, e][l], tz[s, e][l], tw[s, e][l] = t.x, t.y, t.z, w
                                if w > 0.0:
                                    k = eff_joint[e]
                                    e0 = ti.max(e0, (vec3(px[s, k][l], py[s, k][l], pz[s, k][l]) - t).norm())
                            if max_iterations > 0 and e0 > tolerance:
                                cur[l] = i
                                live[l] = 1.0
                                err[l] = e0
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
                    sweep(s, going, parent, offset, kind, child_start, child_list, eff_joint, below, reach, active,
                          eff_on)
                    new_err = lane_error(s, eff_joint)
                    it = it + live
                    # stalled: four sweeps in a row that improved the error by less than 0.01 %
                    flat = ti.select(going, ti.select(new_err > err * (1.0 - FLAT), flat + 1.0, 0.0), flat)
                    err = ti.select(going, new_err, err)
                    done = going & ((flat >= STALL_AFTER) | (it >= ti.cast(max_iterations, ti.f32)) | (err <= tolerance))
                    pending = ti.select(done, 1.0, 0.0)
                    live = ti.select(done, 0.0, live)

    return solve
