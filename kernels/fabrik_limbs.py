"""FABRIK's limb steps inside the rotation recovery (kernels/fabrik.py's recover_and_constrain), one character per
thread: the twist of a joint above a hinge child, which turns the hinge's bend plane toward what FABRIK proposed, and
the two-bone step that solves hip-knee-ankle and shoulder-elbow-hand in closed form (docs/ARCHITECTURE.md,
"Solvers"). kernels/fabrik_limited_lanes.py has their per-lane twins.
"""

import taichi as ti

from crowd_ik.kernels.quat import (
    axis_angle, best_angle_about, constrain_rotation, qconj, qmul, qnormalize, qrot, swing, twist_angle, wrap_angle,
    vec3, vec4,
)
from crowd_ik.solvers.settings import TWIST_FULL_BEND, TWIST_MIN_BEND


@ti.func
def active_child(i, j, child_start: ti.template(), child_list: ti.template(), acc_w: ti.template()):
    """(the last child of joint j with an active chain below it (acc_w > 0), or -1; how many children have one)."""
    c = -1
    k = 0
    for cc in range(child_start[j], child_start[j + 1]):
        if acc_w[i, child_list[cc]] > 0.0:
            c = child_list[cc]
            k += 1
    return ti.Vector([c, k])


@ti.func
def twist_for_hinge_child(i, j, q, inv_base, pos_j, kind: ti.template(), axes: ti.template(), offset: ti.template(),
                          lo: ti.template(), hi: ti.template(), dof_start: ti.template(), child_start: ti.template(),
                          child_list: ti.template(), work: ti.template(), acc_w: ti.template()):
    """Twist a ball joint about its bone so that its hinge child can bend in the plane FABRIK proposes.

    A hinge bends only about its axis, so the ball joint above it (hip above knee, shoulder above
    elbow) must turn that axis onto the normal of the plane through the proposed joint, hinge and
    hinge-child positions; the sign follows the hinge's range (a knee bends one way only).
    """
    out = q
    c = active_child(i, j, child_start, child_list, acc_w)[0]
    if c >= 0 and kind[c] == 1:
        g = active_child(i, c, child_start, child_list, acc_w)[0]
        if g >= 0:
            b = qrot(out, offset[c]).normalized()
            u = qrot(inv_base, work[i, c] - pos_j)
            v = qrot(inv_base, work[i, g] - work[i, c])
            n = ti.math.cross(u, v)
            bend = n.norm() / ti.max(u.norm() * v.norm(), 1e-12)  # sine of the proposed bend
            if bend > TWIST_MIN_BEND:
                n = n.normalized()
                s = dof_start[c]
                axis = qrot(out, axes[c, 0])
                sign = 1.0
                if lo[s] >= 0.0:
                    sign = 1.0
                elif hi[s] <= 0.0:
                    sign = -1.0
                elif axis.dot(n) < 0.0:
                    sign = -1.0
                n = sign * n
                a_p = axis - axis.dot(b) * b
                n_p = n - n.dot(b) * b
                if a_p.norm() > 1e-6 and n_p.norm() > 1e-6:
                    # full twist once the bend is clear; fading out toward nearly straight limbs, whose
                    # plane is numerical noise
                    ramp = ti.min(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
                    ang = ramp * ti.atan2(b.dot(ti.math.cross(a_p, n_p)), a_p.dot(n_p))
                    h = 0.5 * ang
                    sh = ti.sin(h)
                    out = qnormalize(qmul(vec4(b.x * sh, b.y * sh, b.z * sh, ti.cos(h)), out))
    return out


@ti.func
def two_bone_swing(i, j, q, inv_base, pos_j, kind: ti.template(), axes: ti.template(), offset: ti.template(),
                   lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
                   dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                   local_rot: ti.template(), work: ti.template(), acc_w: ti.template()):
    """Ball joint j above a hinge c above joint g (hip-knee-ankle, shoulder-elbow-wrist): put the limb's end exactly
    on its proposed position. The end is g, or a rigid leaf past g (the hand past the wrist), carried at g's
    current angles; g's place is then written back as its proposal. Returns (rotation of j, 1) or (q, 0) when
    j's limb is not of that shape.

    The hinge angle t that makes |a + R(ax, t) b| equal the distance to the proposal is closed form (law of
    cosines): with b split along and across ax, a.R(t)b = C + A cos t + B sin t, so
    t = atan2(B, A) +- acos((D - C) / sqrt(A^2 + B^2)), D = (d^2 - |a|^2 - |b|^2) / 2; of the two, the one
    inside the hinge's limits (then the one nearer the current angle). j then takes the minimal swing that
    aims a + R(t) b at the proposal, so it keeps its twist and the limb's bend plane does not flip. The
    hinge itself recovers t afterwards from the same proposal.
    """
    out = q
    ok = 0
    c = active_child(i, j, child_start, child_list, acc_w)[0]
    if c >= 0 and kind[c] == 1:
        found = active_child(i, c, child_start, child_list, acc_w)
        g = found[0]
        if found[1] == 1:
            # a rigid leaf past g (the hand past the wrist) ends the limb instead, at g's current angles
            end = g
            b = offset[g]
            leaf = active_child(i, g, child_start, child_list, acc_w)
            h = leaf[0]
            if leaf[1] == 1 and kind[h] == 0 and child_start[h + 1] == child_start[h]:
                end = h
                b = offset[g] + qrot(local_rot[i, g], offset[h])
            ax = axes[c, 0]
            a = offset[c]
            b_par = b.dot(ax) * ax
            b_perp = b - b_par
            A = a.dot(b_perp)
            B = a.dot(ti.math.cross(ax, b_perp))
            C = a.dot(b_par)
            want = qrot(inv_base, work[i, end] - pos_j)
            D = 0.5 * (want.norm_sqr() - a.norm_sqr() - b.norm_sqr())
            R = ti.sqrt(A * A + B * B)
            if R > 1e-9 and want.norm_sqr() > 1e-12:
                s = dof_start[c]
                phi = ti.atan2(B, A)
                spread = ti.acos(ti.math.clamp((D - C) / R, -1.0, 1.0))
                now = twist_angle(local_rot[i, c], ax)
                t = 0.0
                best = 1e30
                for k in ti.static(range(2)):
                    cand = ti.math.clamp(wrap_angle(phi + (1.0 - 2.0 * k) * spread), lo[s], hi[s])
                    score = ti.abs(C + A * ti.cos(cand) + B * ti.sin(cand) - D) * 1e3 + ti.abs(cand - now)
                    if score < best:
                        best = score
                        t = cand
                w = want.normalized()
                v = a + qrot(axis_angle(ax, t), b)
                out = qnormalize(qmul(swing(qrot(q, v).normalized(), w), q))
                # swivel about the line j -> g to bring the hinge toward its proposed position (the pole), as
                # twist_for_hinge_child does, fading out where the proposed or the solved limb is nearly straight
                u_now = qrot(out, a)
                u_now = u_now - u_now.dot(w) * w
                u_want = qrot(inv_base, work[i, c] - pos_j)
                bend = ti.math.cross(u_want, qrot(inv_base, work[i, end] - work[i, c])).norm() / ti.max(
                    u_want.norm() * (work[i, end] - work[i, c]).norm(), 1e-12)
                u_want = u_want - u_want.dot(w) * w
                bend = ti.min(bend, u_now.norm() / a.norm())
                if bend > TWIST_MIN_BEND and u_want.norm() > 1e-9:
                    ramp = ti.min(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
                    turn = ramp * best_angle_about(w, u_now, u_want)
                    if ti.abs(turn) > 1e-5:  # warm-started frames mostly need none
                        poled = qnormalize(qmul(axis_angle(w, turn), out))
                        # the swivel is free for the position of g but not for j's limits: keep it only if, once
                        # both are clamped to the limits, it lands g no farther from its proposal than no swivel
                        first = a.normalized()
                        off = vec3(0.0)  # how far g lands from its proposal, without and with the swivel
                        for which in range(2):  # a loop, not two calls: each inlined copy costs compile time
                            cand = out
                            if which == 1:
                                cand = poled
                            clamped = constrain_rotation(3, ax, ax, cand, lo, hi, lim_p, dof_start[j], cone[j], first)
                            off[which] = (qrot(clamped, v) - want).norm()
                        if off[1] <= off[0] + 1e-4:
                            out = poled
                if end != g:  # where g goes, so that the hinge recovers t and g keeps its angles
                    work[i, g] = pos_j + qrot(qconj(inv_base), qrot(out, a + qrot(axis_angle(ax, t), offset[g])))
                ok = 1
    return out, ok
