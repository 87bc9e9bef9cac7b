"""The general DLS (kernels/dls.py: LM damping, the joint-limit active set, escapes, orientation rows, full rotation
targets, a free root, rest / velocity / balance terms in the targets' null space) with characters as SIMD lanes.

As kernels/ccd_lanes.py: each scalar of a character's state is one lane of a ``ti.types.vector(L, ti.f32)``; S
streams, each a contiguous range of characters whose lanes refill (a lane whose character is done writes its
result and takes the stream's next character); the streams' state lives in fields of compile-time shape. Each
pass of dls_solve's attempt loop runs for a whole packet, every lane at its own place in it: a lane's first pass
projects its start pose, a kick lane takes its escape step, the others a DLS step; which of the loop's branches a
lane takes (accept, reject, stall, escape, return to the saved pose) is a per-lane select, and the costly ones
(restoring a pose, the kick, building and solving the system) run only when some lane needs them. The active
set's rounds repeat while some lane froze a DOF.

The rows are laid out by the request, the same for every lane, in blocks of three rows (``eff_rows`` bits per
effector: its 3 position rows where some character weights it, its 2 axis rows and a zero row where one also gives
it an orientation target, its 3 rotation rows where one gives it a rotation target): a lane that does not weight an
effector, or has no such target, has zero rows there. A zero row of J adds a row and column of J W J^T + lam^2 I
that are zero off the diagonal, so its Cholesky factor, back substitution and step are the compacted system's plus
zero terms; the kernel is compiled without fast math, so every sum runs in the order written and the zero terms
change no bits (a character alone, with its own layout, gets what it gets in any crowd). J W J^T and J^T y skip
the columns a block's effector does not move (kernels/dls_lane_system.py). A character's start (its angles from
its rotations) and its result are handled one lane at a time with the one-character kernel's scalar code. The rows
are built in kernels/dls_lane_rows.py, the secondary terms' parts in kernels/dls_lane_null.py.
"""

import functools

import taichi as ti

from crowd_ik.kernels import dls_lane_null
from crowd_ik.kernels import dls_lane_steps as dl
from crowd_ik.kernels import dls_lane_system as dsys
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_streams as ls
from crowd_ik.kernels.compile_settings import compiled_with
from crowd_ik.kernels.dls_pose import first_bone
from crowd_ik.kernels.dls_lane_rows import row_builder
from crowd_ik.kernels.lane_plan import MAX_STREAMS, lane_rows
from crowd_ik.kernels.quat import joint_angles, yaw_quat
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.solvers.settings import (
    DLS_DAMPING_MIN as DAMPING_MIN, DLS_ESCAPE_ATTEMPTS as ESCAPE_ATTEMPTS, DLS_FLAT as FLAT, DLS_LAM_CAP as LAM_CAP,
    DLS_MAX_ESCAPES as MAX_ESCAPES, DLS_NULL_BAND as NULL_BAND, DLS_NULL_STEP as NULL_STEP, DLS_PROGRESS as PROGRESS,
    DLS_STALL_AFTER as STALL_AFTER, DLS_WINDOW as WINDOW,
)

SCRATCH_BYTES = 64 << 20  # a kernel's stream scratch at most this (fewer streams for a big rig), see max_streams

ndarray = ti.types.ndarray
vec3 = ti.math.vec3
vec4 = ti.math.vec4
ESCAPES_F, STALL_F = float(ESCAPE_ATTEMPTS), float(STALL_AFTER)


def max_streams(L: int, max_joints: int, max_cols: int, max_rows: int, max_effectors: int, sec: bool = False) -> int:
    """The streams general_solver's scratch holds: lane_plan.MAX_STREAMS, fewer where that would pass SCRATCH_BYTES
    (a big imported rig: a humanoid's 256 streams take about 38 MB, 45 MB with `sec`), at least 8."""
    values = (20 * max_joints + 11 * max_cols + 2 * max_rows + max_rows * (max_cols + max_rows) + 12 * max_effectors
              + 3 + sec * dls_lane_null.per_stream_values(max_joints, max_cols))
    per_stream = 4 * L * values
    return max(8, min(MAX_STREAMS, SCRATCH_BYTES // per_stream))


@functools.cache
def general_solver(L: int, max_joints: int, max_cols: int, max_rows: int, max_effectors: int, rot: bool = False,
                   free_root: bool = False, sec: bool = False):
    """The kernel for L lanes per stream and scratch of max_joints, max_cols (DOFs + 1), max_rows and max_effectors
    per stream: l* (local rotations), b* (their backup before a step), v* (saved before an escape kick), p*
    (positions relative to the root), r* (world rotations); per DOF column th (angles), thb, ths (their backup and
    save), st (the step), fr (1 free, 0 frozen by the active set), mp (joint weight times fr), da* (world axes); the
    system's jac (rows x columns), sys (its Cholesky factor), e0 (the aimed error), yv (the solution), ga (J^T yv); per
    effector t* (target relative to the root, or in the world with a free root; weight), o* (orientation target), tq*
    (with `rot`: the rotation target and its weight tqk); root* (with `free_root`: root_pos, per stream). Joint row J
    (max_joints > J) holds the root's yaw rotation at the origin, the parent row of the root joint. With `sec` the
    rest, velocity and balance terms in the null space of the targets (kernels/dls_lane_null.py, with fields of its
    own)."""
    V = ti.types.vector(L, ti.f32)
    Vi = ti.types.vector(L, ti.i32)
    S = max_streams(L, max_joints, max_cols, max_rows, max_effectors, sec)
    (lx, ly, lz, lw, bx, by, bz, bw, vx, vy, vz, vw, px, py, pz,
     rx, ry, rz, rw) = lane_rows(L, (S, max_joints), 19)
    th, thb, ths, st, fr, mp, dax, day, daz = lane_rows(L, (S, max_cols), 9)
    e0, yv = lane_rows(L, (S, max_rows), 2)
    (ga,) = lane_rows(L, (S, max_cols), 1)
    (jac,) = lane_rows(L, (S, max_rows, max_cols), 1)
    (sys,) = lane_rows(L, (S, max_rows, max_rows), 1)
    tx, ty, tz, tw, ox, oy, oz = lane_rows(L, (S, max_effectors), 7)
    tqx, tqy, tqz, tqw, tqk = lane_rows(L, (S, max_effectors), 5) if rot else (None,) * 5
    rootx, rooty, rootz = lane_rows(L, (S,), 3) if free_root else (None,) * 3

    @ti.func
    def target(s, e, C):
        """Effector e's target relative to the root point (dls_pose.root_point): with a free root the stored world
        target minus (root_pos + the root's translation so far, the last three columns' angles), else the stored
        target (already relative to root_pos)."""
        ax, ay, az = tx[s, e], ty[s, e], tz[s, e]
        if ti.static(free_root):
            ax = ax - (rootx[s] + th[s, C - 3])
            ay = ay - (rooty[s] + th[s, C - 2])
            az = az - (rootz[s] + th[s, C - 1])
        return ax, ay, az

    @ti.func
    def parent_row(j, parent: ti.template()):
        """The row of joint j's parent, or J (one past the joints: the root's yaw rotation at the origin), so that a
        parent's rotation is one vector load per component wherever it comes from."""
        p = parent[j]
        if p < 0:
            p = parent.shape[0]
        return p

    @ti.func
    def parent_rot(s, j, parent: ti.template()):
        """dls_pose.parent_rot: the parent's world rotation, or the root's yaw."""
        p = parent_row(j, parent)
        return rx[s, p], ry[s, p], rz[s, p], rw[s, p]

    @ti.func
    def fk(s, on, parent: ti.template(), offset: ti.template()):
        """dls_pose.fk_relative in the lanes `on`."""
        for j in range(parent.shape[0]):
            o = offset[j]
            p = parent_row(j, parent)
            ax, ay, az, aw = rx[s, p], ry[s, p], rz[s, p], rw[s, p]
            cx, cy, cz = lm.qrot(ax, ay, az, aw, o.x, o.y, o.z)
            cx, cy, cz = px[s, p] + cx, py[s, p] + cy, pz[s, p] + cz  # the root row's position is 0
            gx, gy, gz, gw = lm.qmul(ax, ay, az, aw, lx[s, j], ly[s, j], lz[s, j], lw[s, j])
            px[s, j], py[s, j], pz[s, j] = ti.select(on, cx, px[s, j]), ti.select(on, cy, py[s, j]), \
                ti.select(on, cz, pz[s, j])
            rx[s, j], ry[s, j] = ti.select(on, gx, rx[s, j]), ti.select(on, gy, ry[s, j])
            rz[s, j], rw[s, j] = ti.select(on, gz, rz[s, j]), ti.select(on, gw, rw[s, j])

    @ti.func
    def apply_step(s, on, parent: ti.template(), offset: ti.template(), kind: ti.template(), jmode: ti.template(),
                   axes: ti.template(), lo: ti.template(), hi: ti.template(), lim_p: ti.template(),
                   lim_h: ti.template(), cone: ti.template(), dof_start: ti.template(), child_start: ti.template(),
                   child_list: ti.template(), C):
        """dls.apply_step in the lanes `on`: back up the pose, add st (angles clamped, cones projected), FK."""
        for d in range(C):
            thb[s, d] = ti.select(on, th[s, d], thb[s, d])
        if ti.static(free_root):  # the root's translation, the last three columns
            for c in ti.static(range(3)):
                th[s, C - 3 + c] = ti.select(on, th[s, C - 3 + c] + st[s, C - 3 + c], th[s, C - 3 + c])
        for j in range(parent.shape[0]):
            qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
            bx[s, j], by[s, j] = ti.select(on, qx, bx[s, j]), ti.select(on, qy, by[s, j])
            bz[s, j], bw[s, j] = ti.select(on, qz, bz[s, j]), ti.select(on, qw, bw[s, j])
            k = kind[j]
            d = dof_start[j]
            if k > 0:
                by_angle = jmode[j] == 1
                if by_angle:
                    a0 = ti.math.clamp(th[s, d] + st[s, d], lo[d], hi[d])
                    a1 = a0 * 0.0
                    a2 = a0 * 0.0
                    th[s, d] = ti.select(on, a0, th[s, d])
                    if k >= 2:
                        a1 = ti.math.clamp(th[s, d + 1] + st[s, d + 1], lo[d + 1], hi[d + 1])
                        th[s, d + 1] = ti.select(on, a1, th[s, d + 1])
                    if k == 3:
                        a2 = ti.math.clamp(th[s, d + 2] + st[s, d + 2], lo[d + 2], hi[d + 2])
                        th[s, d + 2] = ti.select(on, a2, th[s, d + 2])
                    qx, qy, qz, qw = dl.joint_quat(k, axes[j, 0], axes[j, 1], a0, a1, a2)
                else:
                    # the world rotation still holds the pose the step was computed at (FK runs after the loop)
                    ax, ay, az, aw = parent_rot(s, j, parent)
                    cx, cy, cz = lm.qrot(-ax, -ay, -az, aw, st[s, d], st[s, d + 1], st[s, d + 2])
                    qx, qy, qz, qw = lm.qnormalize(*lm.qmul(*dl.qexp(cx, cy, cz), qx, qy, qz, qw))
                if k == 3 and cone[j] > 0.0:
                    bone = first_bone(j, offset, child_start, child_list)
                    qx, qy, qz, qw, t0, t1, t2 = dl.clamp_ball(qx, qy, qz, qw, by_angle, lo, hi, lim_p, lim_h, d,
                                                               cone[j], bone, on)
                    if by_angle:
                        th[s, d] = ti.select(on, t0, th[s, d])
                        th[s, d + 1] = ti.select(on, t1, th[s, d + 1])
                        th[s, d + 2] = ti.select(on, t2, th[s, d + 2])
                lx[s, j], ly[s, j] = ti.select(on, qx, lx[s, j]), ti.select(on, qy, ly[s, j])
                lz[s, j], lw[s, j] = ti.select(on, qz, lz[s, j]), ti.select(on, qw, lw[s, j])
        fk(s, on, parent, offset)

    @ti.func
    def objective(s, eff_joint: ti.template(), eff_axis: ti.template(), eff_has_axis: ti.template(),
                  eff_lim: ti.template(), length, C):
        """dls_system.objective without its secondary terms, per lane: (F, max position error, orientation error * L);
        the full rotation targets' terms with `rot`, every target reachable with `free_root`."""
        f = V(0.0)
        perr = V(0.0)
        oerr = V(0.0)
        for e in range(eff_joint.shape[0]):
            w = tw[s, e]
            on = w > 0.0
            k = eff_joint[e]
            qx, qy, qz = px[s, k] - px[s, 0], py[s, k] - py[s, 0], pz[s, k] - pz[s, 0]
            ax, ay, az = target(s, e, C)
            dx, dy, dz = ax - px[s, k], ay - py[s, k], az - pz[s, k]
            cx, cy, cz = ax - px[s, 0], ay - py[s, 0], az - pz[s, 0]
            dist = lm.norm3(cx, cy, cz)
            reach = eff_lim[e, 0]
            if ti.static(free_root):  # the root can close any gap: F is |t - p|^2
                reach = 1e30
            qn = lm.norm3(qx, qy, qz)
            far = w * (2.0 * (dist * reach - lm.dot3(cx, cy, cz, qx, qy, qz)) - (reach - qn) * (reach + qn))
            near = w * (dx * dx + dy * dy + dz * dz)
            perr = ti.select(on, ti.max(perr, lm.norm3(dx, dy, dz)), perr)
            f = ti.select(on, f + ti.select(dist > reach, far, near), f)
            if eff_has_axis[e] != 0:
                has = on & (ox[s, e] * ox[s, e] + oy[s, e] * oy[s, e] + oz[s, e] * oz[s, e] > 0.0)
                a = eff_axis[e]
                ux_, uy_, uz_ = lm.qrot(rx[s, k], ry[s, k], rz[s, k], rw[s, k], a.x, a.y, a.z)
                ang = length * lm.norm3(*dl.swing_vector(ux_, uy_, uz_, ox[s, e], oy[s, e], oz[s, e]))
                f = ti.select(has, f + w * ang * ang, f)
                oerr = ti.select(has, ti.max(oerr, ang), oerr)
            if ti.static(rot):  # a full rotation target: rot_w (L angle)^2, angle = |log(q_target q^-1)|
                g = tqk[s, e]
                ang = length * lm.norm3(*dl.qlog(*lm.qmul(tqx[s, e], tqy[s, e], tqz[s, e], tqw[s, e], -rx[s, k],
                                                          -ry[s, k], -rz[s, k], rw[s, k])))
                f = ti.select(g > 0.0, f + g * ang * ang, f)
                oerr = ti.select(g > 0.0, ti.max(oerr, ang), oerr)
        return f, perr, oerr

    @ti.func
    def restore(s, on, J, C):
        """The pose before the step (thb, b*) back in the lanes `on`."""
        dl.copy_pose(s, on, J, C, (thb, bx, by, bz, bw), (th, lx, ly, lz, lw))

    @ti.func
    def save_or_back(s, save, back, J, C):
        """The pose saved (ths, v*) in the lanes `save`, the saved pose back in the lanes `back` (never both)."""
        for d in range(C):
            t, u = th[s, d], ths[s, d]
            ths[s, d] = ti.select(save, t, u)
            th[s, d] = ti.select(back, u, t)
        for j in range(J):
            qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
            sx, sy, sz, sw = vx[s, j], vy[s, j], vz[s, j], vw[s, j]
            vx[s, j], vy[s, j], vz[s, j], vw[s, j] = ti.select(save, qx, sx), ti.select(save, qy, sy), \
                ti.select(save, qz, sz), ti.select(save, qw, sw)
            lx[s, j], ly[s, j], lz[s, j], lw[s, j] = ti.select(back, sx, qx), ti.select(back, sy, qy), \
                ti.select(back, sz, qz), ti.select(back, sw, qw)

    # what the row builder and the secondary terms read and write
    F = dict(V=V, lx=lx, ly=ly, lz=lz, lw=lw, px=px, py=py, pz=pz, rx=rx, ry=ry, rz=rz, rw=rw, th=th, st=st, fr=fr,
             mp=mp, dax=dax, day=day, daz=daz, e0=e0, yv=yv, ga=ga, jac=jac, sys=sys, tw=tw, ox=ox, oy=oy, oz=oz,
             tqx=tqx, tqy=tqy, tqz=tqz, tqw=tqw, tqk=tqk, target=target, parent_rot=parent_rot)
    build = row_builder(F, rot, free_root)
    null_start = null_terms = null_rows = null_step = None  # (with `sec`: kernels/dls_lane_null.py's functions)
    if sec:
        null_start, null_terms, null_rows, null_step = dls_lane_null.secondary(F, S, max_joints, max_cols)

    @compiled_with(fast_math=False)  # sums in the order written: zero rows change no bits (see the docstring)
    @ti.kernel
    def solve(
        parent: ndarray(dtype=ti.i32, ndim=1), offset: ndarray(dtype=vec3, ndim=1), kind: ndarray(dtype=ti.i32, ndim=1),
        jmode: ndarray(dtype=ti.i32, ndim=1), axes: ndarray(dtype=vec3, ndim=2), lo: ndarray(ndim=1),
        hi: ndarray(ndim=1), lim_p: ndarray(ndim=2), lim_h: ndarray(ndim=2), cone: ndarray(ndim=1),
        dof_start: ndarray(dtype=ti.i32, ndim=1), child_start: ndarray(dtype=ti.i32, ndim=1),
        child_list: ndarray(dtype=ti.i32, ndim=1), eff_joint: ndarray(dtype=ti.i32, ndim=1),
        eff_axis: ndarray(dtype=vec3, ndim=1), eff_has_axis: ndarray(dtype=ti.i32, ndim=1), eff_lim: ndarray(ndim=2),
        eff_rows: ndarray(dtype=ti.i32, ndim=1), grp_eff: ndarray(dtype=ti.i32, ndim=1),
        run_count: ndarray(dtype=ti.i32, ndim=2), runs: ndarray(dtype=ti.i32, ndim=4),
        joint_w: ndarray(ndim=1), com_w: ndarray(ndim=1), support_w: ndarray(ndim=1),
        root_pos: ndarray(dtype=vec3, ndim=1),
        root_yaw: ndarray(ndim=1), local_rot: ndarray(dtype=vec4, ndim=2), world_pos: ndarray(dtype=vec3, ndim=2),
        world_rot: ndarray(dtype=vec4, ndim=2), targets: ndarray(dtype=vec3, ndim=2), weights: ndarray(ndim=2),
        orient: ndarray(dtype=vec3, ndim=2), rot_t: ndarray(dtype=vec4, ndim=2), rot_w: ndarray(ndim=2),
        n_groups: ti.i32, n_streams: ti.i32, max_iterations: ti.i32,
        tolerance: ti.f32, damping: ti.f32, length: ti.f32, rest_w: ti.f32, vel_w: ti.f32, bal_w: ti.f32,
        error: ndarray(ndim=1),
        iterations: ndarray(dtype=ti.i32, ndim=1), stalled: ndarray(dtype=ti.i32, ndim=1),
    ):
        """Solve the N = root_pos.shape[0] characters in place as dls.dls_solve does with extra = 0, or with `rot` extra
        bit 1 (full rotation targets rot_t (N, E, 4) weighted by rot_w (N, E); not read without `rot`), `free_root`
        bit 4, `sec` bit 2 (rest_w, vel_w, bal_w, com_w, support_w; not read without `sec`). Rig and settings as
        there (joint_w (C,): C = DOFs + 1 columns); eff_rows (E,) the row layout, bits: 1 its 3 position rows, 2 its
        2 axis rows and a zero row, 4 its 3 rotation rows (0: no rows, no character weights the effector); n_groups =
        R / 3 blocks of three rows, grp_eff (n_groups,) each block's effector; run_count (E, E), runs (E, E, K, 2) the
        runs [start, end) of DOF columns two effectors' paths share (solvers/dls.shared_runs)."""
        N = root_pos.shape[0]
        J = parent.shape[0]
        E = eff_joint.shape[0]
        C = joint_w.shape[0]
        G = n_groups
        R = 3 * G
        max_attempts = 2 * max_iterations + 8
        mu2 = (DAMPING_MIN * length) * (DAMPING_MIN * length)  # the null-space projector's damping
        stride = spread_stride(n_streams)
        for slot in range(n_streams * stride):  # (kernels/work_split.py: the streams on every thread)
            if skipped(slot, stride):
                continue
            s, nxt, end = ls.stream_range(slot, stride, N, n_streams)
            cur = Vi(-1)  # each lane's character, -1 for none
            live = V(0.0)
            pending = V(1.0)  # lanes to hand their character's result out and take the next one
            # dls_solve's per-character state, one lane each: (f, perr, oerr, sv, o4) the objective (dls_system:
            # F, max position error, max(orientation error, balance error), S, orientation error), (sf, sperr, soerr,
            # ssv, so4) and s_acc the pose saved before a kick; zon 0 once the secondary terms are dropped
            f, perr, oerr, sf, sperr, soerr = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
            sv, o4, ssv, so4, ref_s, zon = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
            lam, accepted, attempts, bad, stop, failed = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
            first, kick, esc, esc_left, escapes, s_acc = V(0.0), V(0.0), V(0.0), V(0.0), V(0.0), V(0.0)
            ref_f, ref_acc = V(0.0), V(0.0)
            while pending.max() + live.max() > 0.0:
                for l in range(L):
                    if pending[l] > 0.0:
                        i = cur[l]
                        if i >= 0:
                            error[i] = perr[l]
                            iterations[i] = ti.cast(accepted[l], ti.i32)
                            stalled[i] = ti.cast(stop[l], ti.i32)
                            rp = root_pos[i]
                            if ti.static(free_root):  # dls_pose.root_point, moved in place
                                rp += vec3(th[s, C - 3][l], th[s, C - 2][l], th[s, C - 1][l])
                                root_pos[i] = rp
                            for j in range(J):
                                local_rot[i, j] = vec4(lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l])
                                world_pos[i, j] = rp + vec3(px[s, j][l], py[s, j][l], pz[s, j][l])
                                world_rot[i, j] = vec4(rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l])
                        cur[l] = -1
                        live[l] = 0.0
                        if nxt < end:  # take the stream's next character: dls.read_angles and a zero step
                            i = nxt
                            nxt += 1
                            cur[l] = i
                            live[l] = 1.0
                            y = yaw_quat(root_yaw[i])
                            rx[s, J][l], ry[s, J][l], rz[s, J][l], rw[s, J][l] = y.x, y.y, y.z, y.w
                            px[s, J][l], py[s, J][l], pz[s, J][l] = 0.0, 0.0, 0.0
                            for d in range(C):
                                th[s, d][l] = 0.0
                                st[s, d][l] = 0.0
                            for j in range(J):
                                q = local_rot[i, j]
                                g = world_rot[i, j]
                                lx[s, j][l], ly[s, j][l], lz[s, j][l], lw[s, j][l] = q.x, q.y, q.z, q.w
                                rx[s, j][l], ry[s, j][l], rz[s, j][l], rw[s, j][l] = g.x, g.y, g.z, g.w
                                k = kind[j]
                                if jmode[j] == 1:
                                    a = joint_angles(k, axes[j, 0], axes[j, 1], q)
                                    for c in range(k):
                                        th[s, dof_start[j] + c][l] = a[c]
                            rp = root_pos[i]
                            if ti.static(free_root):  # world targets: the root point moves
                                rootx[s][l], rooty[s][l], rootz[s][l] = rp.x, rp.y, rp.z
                                rp = vec3(0.0)
                            for e in range(E):
                                t = targets[i, e] - rp
                                o = orient[i, e]
                                tx[s, e][l], ty[s, e][l], tz[s, e][l], tw[s, e][l] = t.x, t.y, t.z, weights[i, e]
                                ox[s, e][l], oy[s, e][l], oz[s, e][l] = o.x, o.y, o.z
                                if ti.static(rot):
                                    g = rot_t[i, e]
                                    tqx[s, e][l], tqy[s, e][l], tqz[s, e][l], tqw[s, e][l] = g.x, g.y, g.z, g.w
                                    tqk[s, e][l] = rot_w[i, e]
                            f[l], perr[l], oerr[l], lam[l], accepted[l], attempts[l] = 0.0, 0.0, 0.0, damping, 0.0, 0.0
                            bad[l], stop[l], failed[l], first[l], kick[l], esc[l] = 0.0, 0.0, 0.0, 1.0, 0.0, 0.0
                            esc_left[l], escapes[l], ref_f[l], ref_acc[l], zon[l] = 0.0, 0.0, 0.0, 0.0, 1.0
                pending = V(0.0)
                if live.max() > 0.0:
                    go = live > 0.0
                    apply_step(s, go, parent, offset, kind, jmode, axes, lo, hi, lim_p, lim_h, cone, dof_start,
                               child_start, child_list, C)
                    fst = go & (first > 0.0)
                    nf, npe, no4 = objective(s, eff_joint, eff_axis, eff_has_axis, eff_lim, length, C)
                    nsv, noe = nf * 0.0, no4
                    if ti.static(sec):
                        if lm.any_lane(fst):  # the projected start pose is the velocity term's reference
                            null_start(s, fst, J, C)
                        nsv, nbe = null_terms(s, parent, kind, jmode, dof_start, com_w, support_w, rest_w, vel_w,
                                              bal_w)
                        noe = ti.max(no4, nbe)
                    kck = go & (first == 0.0) & (kick > 0.0)
                    nrm = go & (first == 0.0) & (kick == 0.0)
                    better = nf < f
                    flat = f - nf < FLAT * f
                    band = NULL_BAND * tolerance
                    in_band = (npe <= band) & (no4 <= band)
                    if ti.static(sec):  # also taken when S falls while every target error stays in the band
                        better = better | ((nsv < sv) & in_band)
                        flat = flat & (sv - nsv < FLAT * sv)
                    acc = nrm & better & (failed == 0.0)
                    rej = nrm & (acc == 0)
                    take = fst | kck | acc
                    f, perr, oerr = ti.select(take, nf, f), ti.select(take, npe, perr), ti.select(take, noe, oerr)
                    sv, o4 = ti.select(take, nsv, sv), ti.select(take, no4, o4)
                    zon = ti.select(acc & in_band, 1.0, zon)  # back in the band: the secondary step resumes
                    first = ti.select(fst, 0.0, first)
                    accepted = ti.select(kck | acc, accepted + 1.0, accepted)
                    lam = ti.select(kck, damping, ti.select(acc, ti.max(0.5 * lam, damping),
                                                            ti.select(rej, 4.0 * lam, lam)))
                    bad = ti.select(kck, 0.0, ti.select(acc & (flat == 0), 0.0, ti.select(acc | rej, bad + 1.0, bad)))
                    kick = ti.select(kck, 0.0, kick)
                    esc_left = ti.select(kck, ESCAPES_F, esc_left)
                    esc = ti.select(kck, 1.0, esc)
                    win = acc & (accepted - ref_acc >= WINDOW)  # too slow: F (and S) fell by less than PROGRESS
                    slow = f > (1.0 - PROGRESS) * ref_f
                    if ti.static(sec):  # S's progress counts once the targets are within tolerance
                        slow = slow & ((sv >= (1.0 - PROGRESS) * ref_s) | (perr > tolerance) | (o4 > tolerance))
                    bad = ti.select(win & slow, STALL_F, bad)
                    ref_f = ti.select(fst | kck | win, f, ref_f)
                    ref_s = ti.select(fst | kck | win, sv, ref_s)
                    ref_acc = ti.select(kck | win, accepted, ref_acc)
                    if lm.any_lane(rej):
                        restore(s, rej, J, C)
                    ec = nrm & (esc > 0.0)  # on probation: kept once it beats the pose before the kick
                    esc = ti.select(ec & ((f < sf) | ((perr <= tolerance) & (oerr <= tolerance))), 0.0, esc)
                    esc_left = ti.select(ec, esc_left - 1.0, esc_left)
                    stall = go & ((bad >= STALL_AFTER) | (lam > LAM_CAP * length))
                    stop = ti.select(stall, 1.0, stop)
                    back = stall & (esc > 0.0)
                    # the secondary step held the targets off: go on with the targets alone
                    drop = stall & (back == 0) & (zon > 0.0) & ((perr > tolerance) | (o4 > tolerance))
                    if ti.static(not sec):
                        drop = drop & (drop == 0)
                    zon = ti.select(drop, 0.0, zon)
                    bad, lam = ti.select(drop, 0.0, bad), ti.select(drop, damping, lam)
                    stop = ti.select(drop, 0.0, stop)
                    try_kick = stall & (esc == 0.0) & (drop == 0) & (escapes < MAX_ESCAPES)
                    kicked = try_kick & (try_kick == 0)
                    if lm.any_lane(try_kick):
                        kicked = try_kick & (dsys.kick_step(s, try_kick, parent, kind, jmode, lo, hi, dof_start,
                                                            joint_w, C, th, st, fr) > 0.0)
                    sf, sperr, soerr = ti.select(kicked, f, sf), ti.select(kicked, perr, sperr), \
                        ti.select(kicked, oerr, soerr)
                    ssv, so4, s_acc = ti.select(kicked, sv, ssv), ti.select(kicked, o4, so4), \
                        ti.select(kicked, accepted, s_acc)
                    kick = ti.select(kicked, 1.0, kick)
                    escapes = ti.select(kicked, escapes + 1.0, escapes)
                    bad = ti.select(kicked, 0.0, bad)
                    lam = ti.select(kicked, damping, lam)
                    stop = ti.select(kicked, 0.0, stop)
                    late = go & (esc > 0.0) & (esc_left <= 0.0) & (back == 0)
                    stop = ti.select(late, 1.0, stop)
                    back = back | late
                    converged = (perr <= tolerance) & (oerr <= tolerance)
                    cont = go & (accepted < max_iterations) & (attempts < max_attempts) & (stop == 0.0) & \
                        (converged == 0)
                    back = back | (go & (cont == 0) & (esc > 0.0))
                    if lm.any_lane(kicked | back):
                        save_or_back(s, kicked, back, J, C)
                    f, perr, oerr = ti.select(back, sf, f), ti.select(back, sperr, perr), ti.select(back, soerr, oerr)
                    sv, o4 = ti.select(back, ssv, sv), ti.select(back, so4, o4)
                    accepted = ti.select(back, s_acc, accepted)
                    esc = ti.select(back, 0.0, esc)
                    ref_f = ti.select(back, f, ref_f)
                    ref_s = ti.select(back, sv, ref_s)
                    ref_acc = ti.select(back, accepted, ref_acc)
                    if lm.any_lane(rej | back):
                        fk(s, rej | back, parent, offset)
                    # attempts ran out: too many rejected steps
                    stop = ti.select(go & (cont == 0) & (stop == 0.0) & (accepted < max_iterations)
                                     & ((perr > tolerance) | (oerr > tolerance)), 1.0, stop)
                    attempts = ti.select(cont, attempts + 1.0, attempts)
                    building = cont & (kick == 0.0)
                    if lm.any_lane(building):
                        build(s, parent, kind, jmode, axes, dof_start, eff_joint, eff_axis, eff_lim, eff_rows, length,
                              R, C)
                        if ti.static(sec):
                            null_rows(s, parent, kind, jmode, axes, dof_start, com_w, support_w, rest_w, vel_w, bal_w,
                                      C)
                        for d in range(C):
                            fr[s, d] = ti.select(building, 1.0, fr[s, d])
                        failed = ti.select(building, 0.0, failed)
                        frozen = ti.select(building, 1.0, 0.0)
                        rounds = 0
                        while frozen.max() > 0.0 and rounds <= C:
                            act = frozen > 0.0
                            ok = act * 0.0
                            if ti.static(sec):
                                ok = null_step(s, act, lam * lam, mu2, zon * NULL_STEP * damping / lam, rest_w, vel_w,
                                               bal_w, joint_w, grp_eff, run_count, runs, G, C)
                            else:
                                ok = dsys.solve_step(s, act, lam * lam, joint_w, grp_eff, run_count, runs, G, C, jac,
                                                     sys, e0, yv, mp, fr, ga, st)
                            failed = ti.select(act, 1.0 - ok, failed)
                            frozen = ti.select(act, dsys.freeze_outward(s, act, parent, kind, jmode, lo, hi, dof_start,
                                                                             th, st, fr), 0.0)
                            rounds += 1
                        for d in range(C):
                            st[s, d] = ti.select(building & (failed > 0.0), 0.0, st[s, d])
                    done = go & (cont == 0)
                    pending = ti.select(done, 1.0, 0.0)
                    live = ti.select(done, 0.0, live)

    return solve
