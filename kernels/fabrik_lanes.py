"""FABRIK on constraint-free rigs with many characters per CPU thread as SIMD lanes.

Each scalar of a character's state is one lane of a ``ti.types.vector(L, ti.f32)``: joint j of a packet
is three lane vectors (x, y, z), every operation is element-wise, so Taichi's CPU backend emits packed
vector code, and branches become per-lane selects (kernels/lane_math.py).

Two kernels, built per lane width and scratch size by cached factories (importing this module creates
no Taichi state; crowd_ik/solvers/settings.py chooses the machine's width L):

- :func:`free_solver` moves the joints. It runs S streams, each a contiguous range of characters worked
  through by ``lane_plan.pass_lanes`` (2L) lanes: when a lane's character converges, stalls or runs out of
  iterations, its result is written out and the lane takes the stream's next character. So a stream
  costs the sum of its characters' iterations over the lane count, not the lane count times the slowest
  one's (chain16: a 16-lane packet's slowest character takes 2.8 times the mean iterations). A stream
  stops when no lane has work.
- :func:`free_recover` then recovers the rotations of the final positions, once, L consecutive
  characters at a time (exact on a chain; at a sub-base the best fit, as kernels/fabrik.py's
  recover_and_constrain does for unlimited ball joints), runs FK and measures the fitted pose's error.
  It re-sums the weights that reach each joint (the passes' sums, in the same order) instead of reading
  them back, keeps its packet's pose in field rows, and writes it to the crowd's arrays once, joint by
  joint, from local vectors (a lane of a local vector is one load; a lane of a field row reloads the
  field's base after every store to an ndarray).

The streams' scratch lives in fields of compile-time shape (a row per stream, lane_plan.MAX_STREAMS of them on the
CPU, of a power-of-two joint capacity), not in ndarrays: LLVM reloads an ndarray's pointer and shape after every
store to any array, and that integer work was a third of the passes' instructions (chain16, 16,384 characters: 13.9
-> 8.8 ms). On CUDA (one lane) a stream is a GPU thread, lane_plan.GPU_STREAMS of them, and the rows are laid out
joint-major so that a warp's reads of one joint coalesce (lane_plan.stream_rows). Per lane the arithmetic is that
of the one-character solver (kernels/fabrik.py's passes and recovery; the NumPy twin's ``fabrik_solve`` without
constraints) in the same order, except that a normalisation multiplies by one reciprocal (kernels/lane_math.py), so
statuses and iteration counts match it and results do not depend on a character's lane-mates.

Positions relative to the root: both kernels work on a character's joint positions and targets minus its root_pos
(exact differences of float32 world values) and add it back once on the way out. In world coordinates float32's
spacing is 7.6 um at 64-128 m and 30 um at 256-512 m, so in a big crowd's far corners the recovered pose (rebuilt by
FK) missed the tolerance its positions had met: chain16 at 100,000 characters (a 316 m grid), 767 characters ended
1.60-1.77 mm from their targets against the 1.6 mm tolerance (none within 16 m of the origin, 1.5 % beyond 128 m);
relative, 3 (within 2 um of it), as the float64 numba peer and the twin (the one-character kernel, CUDA's, solves in
the root's frame too: kernels/root_frame.py). The root's base position is 0, not root_pos minus itself: a branch that zeroed the root
joint's position made LLVM compile lanes 6-15 of a packet apart from lanes 0-5 (16 copies of one character: two
results).

Flat rows: a character's rows of an (N, J) ndarray are addressed as ``a[0, i * J + j]``. Taichi's
ndarrays are C-contiguous, so that is the same element, and with a constant first index LLVM drops the
reload of the array's shape and the multiply that otherwise follow every store (only the pointer is
reloaded); the per-lane hand-outs and the write-back are chains of such stores.
"""

import functools

import taichi as ti

from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_streams as ls
from crowd_ik.kernels.lane_plan import stream_rows
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.solvers.settings import FABRIK_FLAT as FLAT, FABRIK_STALL_AFTER as STALL_AFTER, SWING_ROUNDS

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4

@functools.cache
def free_solver(L: int, LO: int, max_joints: int, max_effectors: int, streams: int, joint_major: bool):
    """The joint-moving kernel for L lanes per stream. Scratch per stream s (fields of max_joints and
    max_effectors rows for `streams` streams, laid out as lane_plan.stream_rows says): px, py, pz (pose), wx, wy,
    wz, aw (proposals and their weights), tx, ty, tz, tw (targets, weights). Output per character i in (P, J) rows
    of LO lanes, [i // LO][i % LO]: gx, gy, gz, the last proposals, laid out for free_recover(LO)."""
    V = ti.types.vector(L, ti.f32)
    VO = ti.types.vector(LO, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    # the streams' scratch in fields: their shapes are compile-time constants, so an access is one multiply-add
    # from a fixed base (an ndarray's pointer and shape are reloaded after every store to any array)
    px, py, pz, wx, wy, wz, aw = stream_rows(L, streams, max_joints, 7, joint_major)
    tx, ty, tz, tw = stream_rows(L, streams, max_effectors, 4, joint_major)

    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1),
        bone: ndarray(dtype=vec4, ndim=1),
        eff_joint: ndarray(dtype=ti.i32, ndim=1),
        world_pos: ndarray(dtype=vec3, ndim=2),
        root_pos: ndarray(dtype=vec3, ndim=1),
        targets: ndarray(dtype=vec3, ndim=2),
        weights: ndarray(ndim=2),
        n_streams: ti.i32,
        gx: ndarray(dtype=VO, ndim=2), gy: ndarray(dtype=VO, ndim=2), gz: ndarray(dtype=VO, ndim=2),
        max_iterations: ti.i32,
        tolerance: ti.f32,
        error: ndarray(ndim=1),
        iterations: ndarray(dtype=ti.i32, ndim=1),
        stalled: ndarray(dtype=ti.i32, ndim=1),
        serial: ti.template(),
    ):
        """Move the N = world_pos.shape[0] characters' joints; error, iterations, stalled (N,) as fabrik_solve
        (the error before the rotations are recovered). serial: the streams on the launching thread
        (kernels/serial_loops.py; the same results)."""
        N = world_pos.shape[0]
        J = parent.shape[0]
        E = eff_joint.shape[0]
        stride = spread_stride(n_streams)
        ti.loop_config(serialize=serial)
        for slot in range(n_streams * stride):  # (kernels/work_split.py: the streams on every thread)
            if skipped(slot, stride):
                continue
            s, nxt, end = ls.stream_range(slot, stride, N, n_streams)
            cur = Vi(-1)  # each lane's character, -1 for none
            live = V(0.0)
            err = V(0.0)
            it = V(0.0)
            flat = V(0.0)
            pending = V(1.0)  # lanes to hand their character's result out and take the next one
            while pending.max() + live.max() > 0.0:
                for l in range(L):  # a lane whose character stopped hands its result out and takes the next
                    if pending[l] > 0.0:
                        i = cur[l]
                        if i >= 0:
                            error[i] = err[l]
                            iterations[i] = ti.cast(it[l], ti.i32)
                            stalled[i] = 1 if flat[l] >= STALL_AFTER else 0
                            row, lane = (i // LO) * J, i % LO
                            for j in range(J):  # (flat rows: see the module docstring)
                                gx[0, row + j][lane] = wx[s, j][l]
                                gy[0, row + j][lane] = wy[s, j][l]
                                gz[0, row + j][lane] = wz[s, j][l]
                        cur[l] = -1
                        live[l] = 0.0
                        while nxt < end and cur[l] < 0:  # take the next character that needs iterations
                            i = nxt
                            nxt += 1
                            o = root_pos[i]  # the origin of the lane's positions
                            e0 = 0.0
                            for e in range(E):
                                v = targets[i, e] - o
                                w = weights[i, e]
                                tx[s, e][l] = v.x
                                ty[s, e][l] = v.y
                                tz[s, e][l] = v.z
                                tw[s, e][l] = w
                                if w > 0.0:
                                    e0 = ti.max(e0, ((world_pos[i, eff_joint[e]] - o) - v).norm())
                            if max_iterations > 0 and e0 > tolerance:
                                for j in range(J):
                                    v = world_pos[0, i * J + j] - o
                                    px[s, j][l], py[s, j][l], pz[s, j][l] = v.x, v.y, v.z
                                cur[l] = i
                                live[l] = 1.0
                                err[l] = e0
                                it[l] = 0.0
                                flat[l] = 0.0
                            else:
                                error[i] = e0
                                iterations[i] = 0
                                stalled[i] = 0
                pending = V(0.0)
                if live.max() > 0.0:
                    # backward pass: seed the effectors' weighted targets, then joints J-1..1 toward the root
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
                        b = bone[j]  # the offset's direction and length
                        length = b.w
                        fb = -b.xyz
                        w = aw[s, j]
                        on = w > 0.0
                        ws = ti.select(on, w, 1.0)
                        inv = 1.0 / ws  # (exact where the weights are 1, as on chain16)
                        cx, cy, cz = wx[s, j] * inv, wy[s, j] * inv, wz[s, j] * inv  # the centroid of what reached j
                        wx[s, j], wy[s, j], wz[s, j] = cx, cy, cz
                        ux, uy, uz = lm.safe_normalize(px[s, q] - cx, py[s, q] - cy, pz[s, q] - cz, fb.x, fb.y, fb.z)
                        wx[s, q] = ti.select(on, wx[s, q] + w * (cx + length * ux), wx[s, q])
                        wy[s, q] = ti.select(on, wy[s, q] + w * (cy + length * uy), wy[s, q])
                        wz[s, q] = ti.select(on, wz[s, q] + w * (cz + length * uz), wz[s, q])
                        aw[s, q] = ti.select(on, aw[s, q] + w, aw[s, q])
                    # forward pass from the fixed root; the live lanes' proposals become their pose
                    wx[s, 0], wy[s, 0], wz[s, 0] = px[s, 0], py[s, 0], pz[s, 0]
                    for j in range(1, J):
                        q = parent[j]
                        b = bone[j]
                        length = b.w
                        fb = b.xyz
                        on = aw[s, j] > 0.0
                        bx, by, bz = wx[s, q], wy[s, q], wz[s, q]
                        ux, uy, uz = lm.safe_normalize(wx[s, j] - bx, wy[s, j] - by, wz[s, j] - bz, fb.x, fb.y, fb.z)
                        nx = ti.select(on, bx + length * ux, wx[s, j])
                        ny = ti.select(on, by + length * uy, wy[s, j])
                        nz = ti.select(on, bz + length * uz, wz[s, j])
                        wx[s, j], wy[s, j], wz[s, j] = nx, ny, nz
                        move = on & (live > 0.0)
                        px[s, j] = ti.select(move, nx, px[s, j])
                        py[s, j] = ti.select(move, ny, py[s, j])
                        pz[s, j] = ti.select(move, nz, pz[s, j])
                    new_err = ls.lane_error(s, eff_joint, px, py, pz, tx, ty, tz, tw)
                    # stalled: STALL_AFTER updates in a row that improved the error by less than one part in FLAT
                    # (no orientation error here: both turns stay 0)
                    err, _turn, it, flat, pending, live = ls.stop_rule(live, new_err, V(0.0), err, V(0.0), it, flat,
                                                                       FLAT, STALL_AFTER, max_iterations, tolerance,
                                                                       0.0)

    return solve


@functools.cache
def free_recover(L: int, max_joints: int, streams: int, joint_major: bool):
    """The rotation-recovery kernel for lane width L: reads the proposals gx, gy, gz that free_solver left in
    (P, J) lane rows; each of at most `streams` streams keeps its packet's weights in field rows aw, its local
    rotations in lqx..lqw and its world pose in fx, fy, fz, fqx, fqy, fqz, fqw (laid out as free_solver's)."""
    V = ti.types.vector(L, ti.f32)
    fx, fy, fz, fqx, fqy, fqz, fqw, lqx, lqy, lqz, lqw = stream_rows(L, streams, max_joints, 11, joint_major)
    (acc,) = stream_rows(L, streams, 4, 1, joint_major)  # swing_round's running sums
    (aw,) = stream_rows(L, streams, max_joints, 1, joint_major)  # the proposals' weights

    @ti.func
    def swing_round(s, p, qx, qy, qz, qw, c0, c1, ix, iy, iz, iw, jx, jy, jz, bone: ti.template(),
                    child_list: ti.template(), gx: ti.template(), gy: ti.template(), gz: ti.template()):
        """fabrik.swing_round per lane: q turned by the weighted mean of the minimal swings aiming each active
        child at its proposal (inverse base rotation i, joint position j). The sums run in the stream's field
        row acc, not in registers: that keeps LLVM's loop vectorizer off the loop over children, which it
        widened into a copy many times the loop's size that only a joint with many children would run (the
        kernel's optimised IR: 22,000 -> 5,000 lines; cold compile of chain16 FABRIK 16.0 -> 13.4-15.1 s of
        CPU, bit for bit the same poses)."""
        for k in ti.static(range(4)):
            acc[s, k] = V(0.0)
        for cc in range(c0, c1):
            c = child_list[cc]
            wc = aw[s, c]
            on = wc > 0.0
            o = bone[c]  # the child's unit direction: qrot of it needs no normalisation
            ux, uy, uz = lm.qrot(qx, qy, qz, qw, V(o.x), V(o.y), V(o.z))
            vx, vy, vz = lm.qrot(ix, iy, iz, iw, gx[p, c] - jx, gy[p, c] - jy, gz[p, c] - jz)
            vx, vy, vz = lm.safe_normalize(vx, vy, vz, ux, uy, uz)
            sx, sy, sz, sw = lm.swing(ux, uy, uz, vx, vy, vz)
            flip = ti.select(sw < 0.0, -1.0, 1.0)
            sx, sy, sz, sw = flip * sx, flip * sy, flip * sz, flip * sw
            acc[s, 0] = ti.select(on, acc[s, 0] + wc * sx, acc[s, 0])
            acc[s, 1] = ti.select(on, acc[s, 1] + wc * sy, acc[s, 1])
            acc[s, 2] = ti.select(on, acc[s, 2] + wc * sz, acc[s, 2])
            acc[s, 3] = ti.select(on, acc[s, 3] + wc * sw, acc[s, 3])
        nx, ny, nz, nw = lm.qnormalize(acc[s, 0], acc[s, 1], acc[s, 2], acc[s, 3])
        mx, my, mz, mw = lm.qmul(nx, ny, nz, nw, qx, qy, qz, qw)
        return lm.qnormalize(mx, my, mz, mw)

    @ti.kernel
    def recover(
        parent: ndarray(dtype=ti.i32, ndim=1),
        offset: ndarray(dtype=vec3, ndim=1),
        bone: ndarray(dtype=vec4, ndim=1),
        kind: ndarray(dtype=ti.i32, ndim=1),
        child_start: ndarray(dtype=ti.i32, ndim=1),
        child_list: ndarray(dtype=ti.i32, ndim=1),
        eff_joint: ndarray(dtype=ti.i32, ndim=1),
        root_pos: ndarray(dtype=vec3, ndim=1),
        root_yaw: ndarray(ndim=1),
        local_rot: ndarray(dtype=vec4, ndim=2),
        world_pos: ndarray(dtype=vec3, ndim=2),
        world_rot: ndarray(dtype=vec4, ndim=2),
        targets: ndarray(dtype=vec3, ndim=2),
        weights: ndarray(ndim=2),
        gx: ndarray(dtype=V, ndim=2), gy: ndarray(dtype=V, ndim=2), gz: ndarray(dtype=V, ndim=2),
        n_streams: ti.i32,
        error: ndarray(ndim=1),
        iterations: ndarray(dtype=ti.i32, ndim=1),
        serial: ti.template(),
    ):
        """The characters that iterated get the rotations of their proposals, FK and that pose's error (serial as in
        the solve kernel)."""
        N = root_pos.shape[0]
        J = parent.shape[0]
        E = eff_joint.shape[0]
        P = gx.shape[0]
        stride = spread_stride(n_streams)
        ti.loop_config(serialize=serial)
        for slot in range(n_streams * stride):  # (kernels/work_split.py: the streams on every thread)
            if skipped(slot, stride):
                continue
            s, first, end = ls.stream_range(slot, stride, P, n_streams)
            for p in range(first, end):
                m = V(0.0)  # lanes whose character iterated
                rx, ry, rz, h = V(0.0), V(0.0), V(0.0), V(0.0)
                for l in range(L):
                    i = ti.min(p * L + l, N - 1)
                    if p * L + l < N and iterations[i] > 0:
                        m[l] = 1.0
                    r = root_pos[i]  # the origin of the solve's positions
                    rx[l], ry[l], rz[l], h[l] = r.x, r.y, r.z, 0.5 * root_yaw[i]
                if m.max() > 0.0:
                    # the proposals' weights: free_solver's backward sums (the same additions in the same order)
                    for j in range(J):
                        aw[s, j] = V(0.0)
                    for e in range(E):
                        w = V(0.0)
                        for l in range(L):
                            w[l] = weights[ti.min(p * L + l, N - 1), e]
                        k = eff_joint[e]
                        aw[s, k] = ti.select(w > 0.0, aw[s, k] + w, aw[s, k])
                    for jj in range(J - 1):
                        j = J - 1 - jj
                        q = parent[j]
                        w = aw[s, j]
                        aw[s, q] = ti.select(w > 0.0, aw[s, q] + w, aw[s, q])
                    for j in range(J):  # the local rotations (lq rows; the sweep turns them in place)
                        qx, qy, qz, qw = V(0.0), V(0.0), V(0.0), V(0.0)
                        for l in range(L):
                            qv = local_rot[0, ti.min(p * L + l, N - 1) * J + j]
                            qx[l], qy[l], qz[l], qw[l] = qv.x, qv.y, qv.z, qv.w
                        lqx[s, j], lqy[s, j], lqz[s, j], lqw[s, j] = qx, qy, qz, qw
                    yx, yy, yz, yw = V(0.0), ti.sin(h), V(0.0), ti.cos(h)  # quat.yaw_quat
                    for j in range(J):
                        par = parent[j]
                        bx, by, bz, bqx, bqy, bqz, bqw = V(0.0), V(0.0), V(0.0), yx, yy, yz, yw  # the root, at 0
                        if par >= 0:
                            bx, by, bz = fx[s, par], fy[s, par], fz[s, par]
                            bqx, bqy, bqz, bqw = fqx[s, par], fqy[s, par], fqz[s, par], fqw[s, par]
                        o = offset[j]
                        ox, oy, oz = lm.qrot(bqx, bqy, bqz, bqw, V(o.x), V(o.y), V(o.z))
                        jx, jy, jz = bx + ox, by + oy, bz + oz

                        qx, qy, qz, qw = lqx[s, j], lqy[s, j], lqz[s, j], lqw[s, j]
                        c0 = child_start[j]
                        c1 = child_start[j + 1]
                        if kind[j] > 0 and c1 > c0:
                            n_active = V(0.0)
                            for cc in range(c0, c1):
                                n_active += ti.select(aw[s, child_list[cc]] > 0.0, 1.0, 0.0)
                            turn = (aw[s, j] > 0.0) & (n_active > 0.0) & (m > 0.0)
                            if ti.select(turn, 1.0, 0.0).max() > 0.0:  # (.max() of an integer vector fails to compile)
                                ix, iy, iz, iw = -bqx, -bqy, -bqz, bqw
                                # one round, or SWING_ROUNDS where some lane's joint is a sub-base (a loop around
                                # one call site: each inlined copy of swing_round costs ~5 s of compile time)
                                rounds = 1 if n_active.max() <= 1.0 else SWING_ROUNDS
                                tx, ty, tz, tw = qx, qy, qz, qw
                                sx, sy, sz, sw = qx, qy, qz, qw
                                for r in range(rounds):
                                    tx, ty, tz, tw = swing_round(s, p, tx, ty, tz, tw, c0, c1, ix, iy, iz, iw, jx, jy,
                                                                 jz, bone, child_list, gx, gy, gz)
                                    if r == 0:
                                        sx, sy, sz, sw = tx, ty, tz, tw
                                several = n_active > 1.0  # the sub-base lanes take the refined rotation
                                sx, sy = ti.select(several, tx, sx), ti.select(several, ty, sy)
                                sz, sw = ti.select(several, tz, sz), ti.select(several, tw, sw)
                                qx, qy = ti.select(turn, sx, qx), ti.select(turn, sy, qy)
                                qz, qw = ti.select(turn, sz, qz), ti.select(turn, sw, qw)
                                lqx[s, j], lqy[s, j], lqz[s, j], lqw[s, j] = qx, qy, qz, qw
                        wqx, wqy, wqz, wqw = lm.qmul(bqx, bqy, bqz, bqw, qx, qy, qz, qw)
                        fx[s, j], fy[s, j], fz[s, j] = jx, jy, jz
                        fqx[s, j], fqy[s, j], fqz[s, j], fqw[s, j] = wqx, wqy, wqz, wqw
                    # the pose out, one character's rows at a time (a lane that did not turn a joint writes back the
                    # rotation it read), and the fitted pose's error
                    for j in range(J):
                        # one joint's rows in locals first: a lane of a local vector is one load, a lane of a field
                        # row reloads the field's base after every store to an ndarray
                        ax, ay, az, a4 = lqx[s, j], lqy[s, j], lqz[s, j], lqw[s, j]
                        cx, cy, cz = fx[s, j], fy[s, j], fz[s, j]
                        dx, dy, dz, dw = fqx[s, j], fqy[s, j], fqz[s, j], fqw[s, j]
                        for l in range(L):
                            if m[l] > 0.0:
                                f = (p * L + l) * J + j
                                local_rot[0, f] = vec4(ax[l], ay[l], az[l], a4[l])
                                world_pos[0, f] = vec3(cx[l] + rx[l], cy[l] + ry[l], cz[l] + rz[l])
                                world_rot[0, f] = vec4(dx[l], dy[l], dz[l], dw[l])
                    for l in range(L):
                        i = p * L + l
                        if m[l] > 0.0:
                            err = 0.0
                            for e in range(E):
                                if weights[i, e] > 0.0:
                                    k = eff_joint[e]
                                    t = targets[i, e] - vec3(rx[l], ry[l], rz[l])
                                    d = vec3(fx[s, k][l], fy[s, k][l], fz[s, k][l]) - t
                                    err = ti.max(err, d.norm())
                            error[i] = err

    return recover
