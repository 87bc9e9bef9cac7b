"""CCD's per-joint steps (kernels/ccd.py explains them): the aim of a hinge or ball joint at its
effectors, the reach step, the straighten step, the limit clamp, and FK below a joint."""

import taichi as ti

from crowd_ik.kernels.quat import constrain_rotation, qmul, qnormalize, qrot, swing, twist_angle, vec3, vec4, wrap_angle
from crowd_ik.solvers.settings import CCD_MULTI_ROUNDS as MULTI_ROUNDS

ndarray = ti.types.ndarray


@ti.func
def joint_active(i, j, below: ti.template(), weights: ti.template()):
    """1 if an effector with positive weight lies in joint j's subtree (j included), else 0."""
    active = 0
    for e in range(below.shape[1]):
        if below[j, e] != 0 and weights[i, e] > 0.0:
            active = 1
    return active


@ti.func
def relative_error(i, eff_joint: ti.template(), rel_t: ti.template(), weights: ti.template(),
                   world_pos: ti.template()):
    """Max over effectors with positive weight of |effector - target|, world_pos relative to the root."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if weights[i, e] > 0.0:
            err = ti.max(err, (world_pos[i, eff_joint[e]] - rel_t[i, e]).norm())
    return err


@ti.func
def turn_about(ax, angle, q):
    """R(ax, angle) q."""
    h = 0.5 * angle
    sh = ti.sin(h)
    return qnormalize(qmul(vec4(ax.x * sh, ax.y * sh, ax.z * sh, ti.cos(h)), q))


@ti.func
def fk_after(i, j0, parent: ti.template(), offset: ti.template(), local_rot: ti.template(),
             world_pos: ti.template(), world_rot: ti.template()):
    """Recompute world transforms of joints j0+1 .. J-1 from their (already current) parents."""
    for j in range(j0 + 1, parent.shape[0]):
        p = parent[j]
        world_pos[i, j] = world_pos[i, p] + qrot(world_rot[i, p], offset[j])
        world_rot[i, j] = qmul(world_rot[i, p], local_rot[i, j])


@ti.func
def hinge_step(i, j, q, ax, inv_base, pos_j, below: ti.template(), eff_joint: ti.template(),
               rel_t: ti.template(), weights: ti.template(), eff_pos: ti.template()):
    """q turned about the hinge axis ax (parent frame) by the best angle for the effectors below j."""
    s_cross = 0.0
    s_dot = 0.0
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        if below[j, e] != 0 and w > 0.0:
            u = qrot(inv_base, eff_pos[i, e] - pos_j)
            v = qrot(inv_base, rel_t[i, e] - pos_j)
            u = u - u.dot(ax) * ax
            v = v - v.dot(ax) * ax
            s_cross += w * ax.dot(ti.math.cross(u, v))
            s_dot += w * u.dot(v)
    out = q
    if s_cross != 0.0 or s_dot != 0.0:
        out = turn_about(ax, ti.atan2(s_cross, s_dot), q)
    return out


@ti.func
def hinge_reach_step(i, q, ax, lo_j, hi_j, inv_base, pos_j, pos_p, e, eff_joint: ti.template(),
                     rel_t: ti.template(), eff_pos: ti.template()):
    """q turned about the hinge axis so that |effector - parent| = |target - parent| (clamped to what it spans).

    Of the two bends (+-phi) it takes the one inside the hinge's limits, else the one nearer to them,
    and on a tie the smaller turn.
    """
    r = qrot(inv_base, pos_j - pos_p)
    u = qrot(inv_base, eff_pos[i, e] - pos_j)
    d_t = (rel_t[i, e] - pos_p).norm()
    r_par = r.dot(ax)
    u_par = u.dot(ax)
    r_perp = r - r_par * ax
    u_perp = u - u_par * ax
    m = 2.0 * r_perp.norm() * u_perp.norm()
    out = q
    if m > 1e-12:
        # |r + R u|^2 = |r|^2 + |u|^2 + 2 r_par u_par + m cos(phi), phi = angle from r_perp to R u_perp about ax
        c = ti.math.clamp((d_t * d_t - r.dot(r) - u.dot(u) - 2.0 * r_par * u_par) / m, -1.0, 1.0)
        phi = ti.acos(c)
        phi0 = ti.atan2(ax.dot(ti.math.cross(r_perp, u_perp)), r_perp.dot(u_perp))
        theta0 = twist_angle(q, ax)
        d1 = wrap_angle(phi - phi0)
        d2 = wrap_angle(-phi - phi0)
        t1 = wrap_angle(theta0 + d1)
        t2 = wrap_angle(theta0 + d2)
        v1 = ti.max(lo_j - t1, 0.0) + ti.max(t1 - hi_j, 0.0)
        v2 = ti.max(lo_j - t2, 0.0) + ti.max(t2 - hi_j, 0.0)
        dlt = d1
        if v2 < v1 or (v2 == v1 and ti.abs(d2) < ti.abs(d1)):
            dlt = d2
        out = turn_about(ax, dlt, q)
    return out


@ti.func
def swing_step(i, j, q, inv_base, pos_j, below: ti.template(), eff_joint: ti.template(), rel_t: ti.template(),
               weights: ti.template(), eff_pos: ti.template()):
    """q preceded by the (averaged) swing turning the effectors below j toward their targets (parent frame)."""
    n_eff = 0
    for e in range(eff_joint.shape[0]):
        if below[j, e] != 0 and weights[i, e] > 0.0:
            if (eff_pos[i, e] - pos_j).norm_sqr() > 1e-18:
                n_eff += 1
    delta = vec4(0.0, 0.0, 0.0, 1.0)
    rounds = 1
    if n_eff > 1:
        rounds = MULTI_ROUNDS
    if n_eff > 0:
        for _ in range(rounds):
            acc = vec4(0.0)
            for e in range(eff_joint.shape[0]):
                w = weights[i, e]
                if below[j, e] != 0 and w > 0.0:
                    u = qrot(delta, qrot(inv_base, eff_pos[i, e] - pos_j))
                    v = qrot(inv_base, rel_t[i, e] - pos_j)
                    nu = u.norm()
                    nv = v.norm()
                    if nu > 1e-9 and nv > 1e-9:
                        sw = swing(u / nu, v / nv)
                        if sw.w < 0.0:
                            sw = -sw
                        acc += (w * nu * nv) * sw
            if acc.norm_sqr() > 0.0:
                delta = qnormalize(qmul(qnormalize(acc), delta))
    return qnormalize(qmul(delta, q))


@ti.func
def straighten_step(k, q, ax, u, v):
    """q turned so that the child bone u lines up with the parent bone v (both in the parent frame)."""
    out = q
    if k == 1:
        u_p = u - u.dot(ax) * ax
        v_p = v - v.dot(ax) * ax
        s_cross = ax.dot(ti.math.cross(u_p, v_p))
        s_dot = u_p.dot(v_p)
        if s_cross != 0.0 or s_dot != 0.0:
            out = turn_about(ax, ti.atan2(s_cross, s_dot), q)
    elif u.norm_sqr() > 0.0 and v.norm_sqr() > 0.0:
        out = qnormalize(qmul(swing(u.normalized(), v.normalized()), q))
    return out


@ti.func
def constrain_joint(i, j, q, offset: ti.template(), kind: ti.template(), axes: ti.template(), lo: ti.template(),
                    hi: ti.template(), lim_p: ti.template(), cone: ti.template(), dof_start: ti.template(),
                    child_start: ti.template(), child_list: ti.template(), below: ti.template(),
                    weights: ti.template()):
    """q clamped to joint j's limits; the cone limits the first child bone leading to an active effector."""
    first_bone = vec3(0.0)
    found = 0
    for cc in range(child_start[j], child_start[j + 1]):
        c = child_list[cc]
        if found == 0 and joint_active(i, c, below, weights) != 0:
            first_bone = offset[c].normalized()
            found = 1
    return constrain_rotation(kind[j], axes[j, 0], axes[j, 1], q, lo, hi, lim_p, dof_start[j], cone[j], first_bone)
