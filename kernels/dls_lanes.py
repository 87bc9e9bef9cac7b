"""Closed-form DLS (one position effector, constraint-free rig) with many characters per thread as SIMD lanes.

The solve of kernels/dls_free.py (read its docstring for the maths: J J^T = sum_n (|r_n|^2 I - r_n r_n^T),
the step r_n x y, world rotations turned root to leaf, LM damping, acceptance and stall rules), with each
scalar of a character's state one lane of a ``ti.types.vector(L, ti.f32)`` and its branches per-lane
selects. As kernels/fabrik_lanes.py does, the kernel runs streams, each a contiguous range of characters
worked through by L lanes: a lane whose character is done hands its result out and takes the stream's
next character, so a stream costs the sum of its characters' attempts over L (chain16: a 16-lane
packet's slowest character takes twice the mean iterations). The streams' pose, backup and turn rows
live in fields of compile-time shape. A character's start (normalised rotations, FK, objective) and its
result are computed one lane at a time with the one-character helpers of kernels/dls_free.py; every
attempt in between is lane-packed, with the same operations in the same order as dls_solve_free.
"""

import functools

import taichi as ti

from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_streams as ls
from crowd_ik.kernels.lane_plan import MAX_STREAMS
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.kernels.dls_free import objective
from crowd_ik.kernels.quat import qconj, qmul, qnormalize, qrot, yaw_quat
from crowd_ik.solvers.settings import (
    DLS_FLAT as FLAT, DLS_LAM_CAP as LAM_CAP, DLS_PROGRESS as PROGRESS, DLS_STALL_AFTER as STALL_AFTER,
    DLS_WINDOW as WINDOW,
)

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4

@functools.cache
def free_solver(L: int, max_joints: int):
    """The lane-packed closed-form DLS kernel for L lanes per stream and rigs of at most max_joints joints."""
    V = ti.types.vector(L, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    shape = (MAX_STREAMS, max_joints)
    # per stream and joint: world rotation R, position relative to the root point P, R before the step B,
    # the step's turn D
    Rx, Ry, Rz, Rw, Px, Py, Pz, Bx, By, Bz, Bw, Dx, Dy, Dz, Dw = (ti.Vector.field(L, ti.f32, shape=shape)
                                                                  for _ in range(15))

    @ti.func
    def objective_lanes(tx, ty, tz, bx, by, bz, px, py, pz, w, reach):
        """dls_free.objective per lane: (F, position error)."""
        dx, dy, dz = tx - px, ty - py, tz - pz
        perr = lm.norm3(dx, dy, dz)
        rx, ry, rz = tx - bx, ty - by, tz - bz
        dist = lm.norm3(rx, ry, rz)
        qx, qy, qz = px - bx, py - by, pz - bz
        qn = lm.norm3(qx, qy, qz)
        far = w * (2.0 * (dist * reach - lm.dot3(rx, ry, rz, qx, qy, qz)) - (reach - qn) * (reach + qn))
        near = w * (dx * dx + dy * dy + dz * dz)
        on = w > 0.0
        return ti.select(on, ti.select(dist > reach, far, near), 0.0), ti.select(on, perr, 0.0)

    @ti.func
    def aimed_error_lanes(tx, ty, tz, bx, by, bz, px, py, pz, reach, dmax):
        """dls_free.aimed_error per lane."""
        vx, vy, vz = tx - bx, ty - by, tz - bz
        dist = lm.norm3(vx, vy, vz)
        pull = dist > reach + dmax
        f = (reach + dmax) / ti.select(pull, dist, 1.0)
        gx = ti.select(pull, bx + vx * f, tx)
        gy = ti.select(pull, by + vy * f, ty)
        gz = ti.select(pull, bz + vz * f, tz)
        dx, dy, dz = gx - px, gy - py, gz - pz
        dn = lm.norm3(dx, dy, dz)
        clamp = dn > dmax
        c = dmax / ti.select(clamp, dn, 1.0)
        return ti.select(clamp, dx * c, dx), ti.select(clamp, dy * c, dy), ti.select(clamp, dz * c, dz)

    @ti.func
    def solve3_lanes(a00, a10, a11, a20, a21, a22, bx, by, bz):
        """dls_free.solve3 per lane: (x, y, z, ok), ok 0 where A is not positive definite."""
        ok = V(1.0)
        bad0 = a00 <= 0.0
        ok = ti.select(bad0, 0.0, ok)
        a00 = ti.select(bad0, 1.0, a00)
        l00 = ti.sqrt(a00)
        l10 = a10 / l00
        l20 = a20 / l00
        v1 = a11 - l10 * l10
        bad1 = v1 <= 0.0
        ok = ti.select(bad1, 0.0, ok)
        v1 = ti.select(bad1, 1.0, v1)
        l11 = ti.sqrt(v1)
        l21 = (a21 - l20 * l10) / l11
        v2 = a22 - l20 * l20 - l21 * l21
        bad2 = v2 <= 0.0
        ok = ti.select(bad2, 0.0, ok)
        v2 = ti.select(bad2, 1.0, v2)
        l22 = ti.sqrt(v2)
        z0 = bx / l00
        z1 = (by - l10 * z0) / l11
        z2 = (bz - l20 * z0 - l21 * z1) / l22
        x2 = z2 / l22
        x1 = (z1 - l21 * x2) / l11
        x0 = (z0 - l10 * x1 - l20 * x2) / l00
        return x0, x1, x2, ok

    @ti.func
    def qexp_lanes(rx, ry, rz):
        """dls_free.qexp_series per lane (libm only when some lane's rotation exceeds the series' range)."""
        h2 = 0.25 * (rx * rx + ry * ry + rz * rz)
        sinc = 1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0)))
        cosh = 1.0 - h2 / 2.0 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0 * (1.0 - h2 / 56.0 * (1.0 - h2 / 90.0))))
        hs = 0.5 * sinc
        ox, oy, oz, ow = hs * rx, hs * ry, hs * rz, cosh
        big = h2 > 0.5625
        if ti.select(big, 1.0, 0.0).max() > 0.0:
            a = ti.sqrt(4.0 * h2)
            s = ti.sin(0.5 * a) / a
            c = ti.cos(0.5 * a)
            ox, oy, oz, ow = (ti.select(big, rx * s, ox), ti.select(big, ry * s, oy), ti.select(big, rz * s, oz),
                              ti.select(big, c, ow))
        return ox, oy, oz, ow

    @ti.func
    def fk_lanes(s, j, par, ys, yc, offset: ti.template()):
        """P[s, j] from the parent's position and world rotation (the root's: the yaw (0, ys, 0, yc))."""
        o = offset[j]
        bqx, bqy, bqz, bqw = V(0.0), ys, V(0.0), yc
        bx, by, bz = V(0.0), V(0.0), V(0.0)
        if par >= 0:
            bqx, bqy, bqz, bqw = Rx[s, par], Ry[s, par], Rz[s, par], Rw[s, par]
            bx, by, bz = Px[s, par], Py[s, par], Pz[s, par]
        ox, oy, oz = lm.qrot(bqx, bqy, bqz, bqw, V(o.x), V(o.y), V(o.z))
        Px[s, j], Py[s, j], Pz[s, j] = bx + ox, by + oy, bz + oz

    @ti.func
    def lane_rot(s, j, l):
        return vec4(Rx[s, j][l], Ry[s, j][l], Rz[s, j][l], Rw[s, j][l])

    @ti.func
    def lane_pos(s, j, l):
        return vec3(Px[s, j][l], Py[s, j][l], Pz[s, j][l])

    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1),
        offset: ndarray(dtype=vec3, ndim=1),
        kind: ndarray(dtype=ti.i32, ndim=1),
        on_path: ndarray(dtype=ti.i32, ndim=1),
        eff_joint: ndarray(dtype=ti.i32, ndim=1),
        eff_lim: ndarray(ndim=2),
        root_pos: ndarray(dtype=vec3, ndim=1),
        root_yaw: ndarray(ndim=1),
        local_rot: ndarray(dtype=vec4, ndim=2),
        world_pos: ndarray(dtype=vec3, ndim=2),
        world_rot: ndarray(dtype=vec4, ndim=2),
        targets: ndarray(dtype=vec3, ndim=2),
        weights: ndarray(ndim=2),
        n_streams: ti.i32,
        max_iterations: ti.i32,
        tolerance: ti.f32,
        damping: ti.f32,
        length: ti.f32,
        error: ndarray(ndim=1),
        iterations: ndarray(dtype=ti.i32, ndim=1),
        stalled: ndarray(dtype=ti.i32, ndim=1),
        serial: ti.template(),
    ):
        """dls_free.dls_solve_free, lane-packed: the same arguments (n_streams streams instead of n_joints); serial:
        the streams on the launching thread (kernels/serial_loops.py; the same results)."""
        N = root_pos.shape[0]
        J = parent.shape[0]
        k = eff_joint[0]
        reach = eff_lim[0, 0]
        dmax = eff_lim[0, 1]
        max_attempts = 2 * max_iterations + 8
        stride = spread_stride(n_streams)
        ti.loop_config(serialize=serial)
        for slot in range(n_streams * stride):  # (kernels/work_split.py: the streams on every thread)
            if skipped(slot, stride):
                continue
            s, nxt, end = ls.stream_range(slot, stride, N, n_streams)
            cur = Vi(-1)
            tx, ty, tz, w, sw, ys, yc = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(1.0)
            f_cur, perr, ref_f, lam = V(0.0), V(0.0), V(0.0), V(0.0)
            accepted, ref_accepted, attempts, bad, stop = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
            live = V(0.0)
            pending = V(1.0)
            while pending.max() + live.max() > 0.0:
                for l in range(L):  # a lane whose character is done hands its result out and takes the next
                    if pending[l] > 0.0:
                        i = cur[l]
                        if i >= 0:
                            for j in range(J):
                                q = lane_rot(s, j, l)
                                world_rot[i, j] = q
                                world_pos[i, j] = root_pos[i] + lane_pos(s, j, l)
                                if accepted[l] > 0.0 and kind[j] > 0:
                                    base_rot = yaw_quat(root_yaw[i])
                                    if parent[j] >= 0:
                                        base_rot = lane_rot(s, parent[j], l)
                                    local_rot[i, j] = qnormalize(qmul(qconj(base_rot), q))
                            error[i] = perr[l]
                            iterations[i] = ti.cast(accepted[l], ti.i32)
                            stalled[i] = ti.cast(stop[l], ti.i32)
                        cur[l] = -1
                        live[l] = 0.0
                        while nxt < end and cur[l] < 0:
                            i = nxt
                            nxt += 1
                            # the start pose: the crowd's world rotations (every setter and solver keeps them
                            # equal to FK of unit local rotations) and the positions FK gives relative to the
                            # root point, built in a local array (a lane row just written is slow to read back)
                            base_root = yaw_quat(root_yaw[i])
                            rel = ti.Matrix.zero(ti.f32, max_joints, 3)
                            for j in range(J):
                                par = parent[j]
                                base_rot = base_root
                                base_pos = vec3(0.0)
                                if par >= 0:
                                    base_rot = world_rot[i, par]
                                    base_pos = vec3(rel[par, 0], rel[par, 1], rel[par, 2])
                                pj = base_pos + qrot(base_rot, offset[j])
                                rel[j, 0], rel[j, 1], rel[j, 2] = pj.x, pj.y, pj.z
                                rj = world_rot[i, j]
                                Px[s, j][l], Py[s, j][l], Pz[s, j][l] = pj.x, pj.y, pj.z
                                Rx[s, j][l], Ry[s, j][l], Rz[s, j][l], Rw[s, j][l] = rj.x, rj.y, rj.z, rj.w
                            t = targets[i, 0] - root_pos[i]
                            wi = weights[i, 0]
                            obj = objective(t, lane_pos(s, 0, l), lane_pos(s, k, l), wi, reach)
                            if obj[1] <= tolerance or max_iterations <= 0:  # nothing to do
                                error[i] = obj[1]
                                iterations[i] = 0
                                stalled[i] = 0
                            else:
                                cur[l] = i
                                live[l] = 1.0
                                tx[l], ty[l], tz[l], w[l] = t.x, t.y, t.z, wi
                                sw[l] = ti.sqrt(ti.max(wi, 0.0))
                                ys[l], yc[l] = base_root.y, base_root.w
                                f_cur[l], perr[l], ref_f[l], lam[l] = obj[0], obj[1], obj[0], damping
                                accepted[l], ref_accepted[l], attempts[l], bad[l], stop[l] = 0.0, 0.0, 0.0, 0.0, 0.0
                pending = V(0.0)
                if live.max() > 0.0:
                    going = live > 0.0
                    attempts += live
                    # the step at this pose: A = w sum_n (|r_n|^2 I - r_n r_n^T) + lam^2 I, b = sqrt(w) e
                    ex, ey, ez = Px[s, k], Py[s, k], Pz[s, k]
                    a00, a10, a11, a20, a21, a22 = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
                    for j in range(J):
                        if on_path[j] != 0:
                            rx, ry, rz = ex - Px[s, j], ey - Py[s, j], ez - Pz[s, j]
                            rr = rx * rx + ry * ry + rz * rz
                            a00 += rr - rx * rx
                            a10 -= ry * rx
                            a11 += rr - ry * ry
                            a20 -= rz * rx
                            a21 -= rz * ry
                            a22 += rr - rz * rz
                    lam2 = lam * lam
                    bx, by, bz = aimed_error_lanes(tx, ty, tz, Px[s, 0], Py[s, 0], Pz[s, 0], ex, ey, ez, reach, dmax)
                    x0, x1, x2, ok = solve3_lanes(w * a00 + lam2, w * a10, w * a11 + lam2, w * a20, w * a21,
                                                  w * a22 + lam2, sw * bx, sw * by, sw * bz)
                    g = sw * ok  # a void step is zero
                    yx, yy, yz = g * x0, g * x1, g * x2
                    # take it: R_j <- D_j R_j, D_j = D_p exp(r_j x y), and FK, root to leaf
                    for j in range(J):
                        par = parent[j]
                        ox, oy, oz, ow = Rx[s, j], Ry[s, j], Rz[s, j], Rw[s, j]
                        Bx[s, j], By[s, j], Bz[s, j], Bw[s, j] = ox, oy, oz, ow
                        dx, dy, dz, dw = V(0.0), V(0.0), V(0.0), V(1.0)
                        if par >= 0:
                            dx, dy, dz, dw = Dx[s, par], Dy[s, par], Dz[s, par], Dw[s, par]
                        if on_path[j] != 0:
                            cx, cy, cz = lm.cross(ex - Px[s, j], ey - Py[s, j], ez - Pz[s, j], yx, yy, yz)
                            qx, qy, qz, qw = qexp_lanes(cx, cy, cz)
                            dx, dy, dz, dw = lm.qmul(dx, dy, dz, dw, qx, qy, qz, qw)
                        Dx[s, j], Dy[s, j], Dz[s, j], Dw[s, j] = dx, dy, dz, dw
                        fk_lanes(s, j, par, ys, yc, offset)
                        nx, ny, nz, nw = lm.qmul(dx, dy, dz, dw, ox, oy, oz, ow)
                        m = 1.5 - 0.5 * (nx * nx + ny * ny + nz * nz + nw * nw)  # dls_free.renormalize
                        Rx[s, j], Ry[s, j], Rz[s, j], Rw[s, j] = nx * m, ny * m, nz * m, nw * m
                    nf, nperr = objective_lanes(tx, ty, tz, Px[s, 0], Py[s, 0], Pz[s, 0], Px[s, k], Py[s, k],
                                                Pz[s, k], w, reach)
                    take = going & (nf < f_cur) & (ok > 0.0)
                    back = going & (take == 0)
                    bad = ti.select(take, ti.select(f_cur - nf < FLAT * f_cur, bad + 1.0, 0.0), bad)
                    f_cur = ti.select(take, nf, f_cur)
                    perr = ti.select(take, nperr, perr)
                    accepted = ti.select(take, accepted + 1.0, accepted)
                    lam = ti.select(take, ti.max(0.5 * lam, damping), lam)
                    window = take & (accepted - ref_accepted >= WINDOW)  # too slow: F fell by less than PROGRESS
                    bad = ti.select(window & (f_cur > (1.0 - PROGRESS) * ref_f), ti.cast(STALL_AFTER, ti.f32), bad)
                    ref_f = ti.select(window, f_cur, ref_f)
                    ref_accepted = ti.select(window, accepted, ref_accepted)
                    bad = ti.select(back, bad + 1.0, bad)
                    lam = ti.select(back, lam * 4.0, lam)
                    if ti.select(back, 1.0, 0.0).max() > 0.0:  # rejected lanes go back to the pose before the step
                        for j in range(J):
                            Rx[s, j] = ti.select(back, Bx[s, j], Rx[s, j])
                            Ry[s, j] = ti.select(back, By[s, j], Ry[s, j])
                            Rz[s, j] = ti.select(back, Bz[s, j], Rz[s, j])
                            Rw[s, j] = ti.select(back, Bw[s, j], Rw[s, j])
                            fk_lanes(s, j, parent[j], ys, yc, offset)
                    stop = ti.select(going & ((bad >= STALL_AFTER) | (lam > LAM_CAP * length)), 1.0, stop)
                    done = going & ((accepted >= ti.cast(max_iterations, ti.f32))
                                    | (attempts >= ti.cast(max_attempts, ti.f32)) | (stop > 0.0) | (perr <= tolerance))
                    # attempts ran out: too many rejected steps
                    stop = ti.select(done & (stop == 0.0) & (accepted < ti.cast(max_iterations, ti.f32))
                                     & (perr > tolerance), 1.0, stop)
                    pending = ti.select(done, 1.0, 0.0)
                    live = ti.select(done, 0.0, live)

    return solve
