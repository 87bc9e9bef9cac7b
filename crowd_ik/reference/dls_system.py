"""NumPy twin of kernels/dls_pose.py and kernels/dls_system.py: one character's pose helpers, the
objective F and the DLS step's linear system (crowd_ik/reference/dls.py runs the solve with them)."""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.fk import forward_kinematics
from crowd_ik.geometry.quat import (
    axis_angle, constrain_rotation, joint_quat, qconj, qmul, qnormalize, qrot, quat_to_euler_xyz,
)
from crowd_ik.rig import Rig
from crowd_ik.solvers.dls_setup import balance_weights
from crowd_ik.solvers.settings import DLS_ORI_CLAMP as ORI_CLAMP  # shared with kernels/dls_system.py


def _com_minus_support(com_w, support_w, parent, pos):
    mid = 0.5 * (pos[..., np.maximum(parent, 0), :] + pos)
    return np.einsum("j,...jc->...c", com_w, mid) - np.einsum("j,...jc->...c", support_w, pos)


def balance_offset(rig: Rig, pos: np.ndarray) -> np.ndarray:
    """(..., 3) c - s, the centre of mass minus the support point, of joint positions pos (..., J, 3) metres."""
    return _com_minus_support(*balance_weights(rig), np.array([j.parent for j in rig.joints]), np.asarray(pos))


def qlog(q: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors of unit quaternions (..., 4)."""
    q = np.where(q[..., 3:] < 0, -q, q)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    scale = np.where(s > 1e-7, 2.0 * np.arctan2(s, q[..., 3:]) / np.maximum(s, 1e-30), 2.0)
    return v * scale


def qexp(r: np.ndarray) -> np.ndarray:
    a = np.linalg.norm(r, axis=-1, keepdims=True)
    s = np.where(a > 1e-7, np.sin(0.5 * a) / np.maximum(a, 1e-30), 0.5)
    c = np.where(a > 1e-7, np.cos(0.5 * a), 1.0)
    return qnormalize(np.concatenate([r * s, c], axis=-1))


def perpendicular(a: np.ndarray) -> np.ndarray:
    u = np.cross(a, np.array([1.0, 0.0, 0.0]))
    alt = np.cross(a, np.array([0.0, 1.0, 0.0]))
    u = np.where(np.sum(u * u, -1, keepdims=True) < 0.01, alt, u)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def swing_vector(a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotation vectors of the minimal rotations taking unit a to unit t."""
    c = np.cross(a, t)
    s = np.linalg.norm(c, axis=-1, keepdims=True)
    dot = np.sum(a * t, -1, keepdims=True)
    ang = np.arctan2(s, dot)
    axis = np.where(s > 1e-7, c / np.maximum(s, 1e-30), np.where(dot < 0, perpendicular(a), 0.0))
    return axis * ang


class _Rig:
    """Per-joint facts the solver loops over."""

    def __init__(self, rig: Rig, settings: dict, root: bool = False):
        self.rig = rig
        # a free root: 3 more columns after the DOFs (theta holds the root's translation there)
        self.root = root
        self.n_col = rig.n_dof + (3 if root else 0)
        jmode, lo, hi = settings["jmode"], settings["lo"], settings["hi"]
        self.com_w, self.support_w = settings["com_w"], settings["support_w"]
        self.parent = np.array([j.parent for j in rig.joints])
        self.joints = []
        for j, joint in enumerate(rig.joints):
            k, s = joint.dof, int(rig.dof_start[j])
            kids = rig.children[j]
            bone = np.array(rig.joints[kids[0]].offset) / rig.bone_lengths[kids[0]] if kids else np.zeros(3)
            self.joints.append(dict(
                k=k, s=s, parent=joint.parent, angle=bool(jmode[j] == 1),
                axes=np.array(joint.axes or [(0.0, 0.0, 1.0)] * 2), cone=joint.cone or 0.0, bone=bone,
                lo=lo[s : s + k], hi=hi[s : s + k],
            ))


def _parent_rot(jt, q_root, wrot):
    return q_root if jt["parent"] < 0 else wrot[:, jt["parent"]]


def _yaw(yaw):
    return axis_angle(np.array([0.0, 1.0, 0.0]), yaw)


def _set_joint(jt, theta, rot, j):
    """Rotation of an angle-mode joint from its clamped angles; a cone projects a ball joint (angles re-read)."""
    k, s = jt["k"], jt["s"]
    a = np.clip(theta[:, s : s + k], jt["lo"], jt["hi"])
    q = joint_quat(k, jt["axes"], a)
    if k == 3 and jt["cone"] > 0:
        q = constrain_rotation(3, jt["axes"], q, jt["lo"], jt["hi"], jt["cone"], jt["bone"])
        a = quat_to_euler_xyz(q)
    theta[:, s : s + k] = a
    rot[:, j] = q


def _fk(rig, yaw, rot):
    return forward_kinematics(rig, np.zeros((rot.shape[0], 3)), yaw, rot)


def _balance_sums(R: _Rig, pos):
    """(c - s (n, 3), levers (n, J, 3)): per joint n, sum_j a_j (p_j - p_n) over the points j below it.

    The points are the bones' midpoints (a_j = com_w[j]) and the feet (a_j = -support_w[j]); the bone
    ending at n and a foot at n are not below n (a rotation at n does not move them).
    """
    n, J = pos.shape[0], pos.shape[1]
    acc = np.zeros((n, J, 4))  # per joint: sum a_j p_j (xyz) and sum a_j (w) over the points strictly below
    own = np.zeros((n, J, 4))
    for j, jt in enumerate(R.joints):
        p = pos[:, jt["parent"]] if jt["parent"] >= 0 else pos[:, j]
        own[:, j, :3] = R.com_w[j] * 0.5 * (p + pos[:, j]) - R.support_w[j] * pos[:, j]
        own[:, j, 3] = R.com_w[j] - R.support_w[j]
    for j in range(J - 1, 0, -1):
        acc[:, R.joints[j]["parent"]] += own[:, j] + acc[:, j]
    total = acc[:, 0, :3] + own[:, 0, :3]
    return total, acc[..., :3] - acc[..., 3:] * pos


def _rotation_vector(rot_t, q):
    """(n, 3) world rotation vectors log(q_target q^-1): the turn that takes world rotation q onto rot_t."""
    return qlog(qmul(rot_t, qconj(q)))


def _root_shift(R: _Rig, st):
    """(n, 3) the free root's translation so far (zeros for a fixed root)."""
    return st["theta"][:, R.rig.n_dof :] if R.root else np.zeros((st["theta"].shape[0], 3))


def _objective(R: _Rig, st, tgt, weights, orient, eff_lim, length, rest_w, vel_w, bal_w=0.0, rot_t=None, rot_w=None):
    """(F, max position error, max(orientation error * L, balance error), S, orientation error * L), as the kernel.

    F: the targets (position terms as in the kernel; with a free root |t - p|^2 for every target); S the
    secondary terms (rest, velocity, balance). rot_t (n, E, 4), rot_w (n, E) or None: full rotation targets,
    each adding rot_w (L angle)^2 to F and L angle to the orientation error."""
    rig = R.rig
    n = tgt.shape[0]
    tgt = tgt - _root_shift(R, st)[:, None]
    f = np.zeros(n)
    sec = np.zeros(n)
    berr = np.zeros(n)
    perr = np.zeros(n)
    oerr = np.zeros(n)
    eff_axis = rig.arrays["eff_axis"].astype(np.float64)
    for e, eff in enumerate(rig.effectors):
        w = weights[:, e]
        on = w > 0
        d = tgt[:, e] - st["pos"][:, eff.joint]
        dd = np.sum(d * d, -1)
        r = tgt[:, e] - st["pos"][:, 0]
        dist = np.linalg.norm(r, axis=-1)
        reach = float(eff_lim[e, 0])
        q = st["pos"][:, eff.joint] - st["pos"][:, 0]
        qn = np.linalg.norm(q, axis=-1)
        far = 2.0 * (dist * reach - np.sum(r * q, -1)) - (reach - qn) * (reach + qn)
        f += np.where(on, w * np.where((dist > reach) & (not R.root), far, dd), 0.0)
        perr = np.where(on, np.maximum(perr, np.sqrt(dd)), perr)
        has = on & (eff.axis is not None) & (np.sum(orient[:, e] ** 2, -1) > 0)
        if np.any(has):
            a = qrot(st["wrot"][:, eff.joint], np.broadcast_to(eff_axis[e], (n, 3)))
            ang = length * np.linalg.norm(swing_vector(a, orient[:, e]), axis=-1)
            f += np.where(has, w * ang * ang, 0.0)
            oerr = np.where(has, np.maximum(oerr, ang), oerr)
        if rot_w is not None:
            hr = rot_w[:, e] > 0
            ang = length * np.linalg.norm(_rotation_vector(rot_t[:, e], st["wrot"][:, eff.joint]), axis=-1)
            f += np.where(hr, rot_w[:, e] * ang * ang, 0.0)
            oerr = np.where(hr, np.maximum(oerr, ang), oerr)
    if rest_w > 0 or vel_w > 0:
        for j, jt in enumerate(R.joints):
            k, s = jt["k"], jt["s"]
            if k == 0:
                continue
            if jt["angle"]:
                th = st["theta"][:, s : s + k]
                dv = th - st["theta0"][:, s : s + k]
                sec += rest_w * np.sum(th * th, -1) + vel_w * np.sum(dv * dv, -1)
            else:
                q = st["rot"][:, j]
                sec += (rest_w * np.sum(qlog(q) ** 2, -1)
                        + vel_w * np.sum(qlog(qmul(q, qconj(st["q0"][:, j]))) ** 2, -1))
    if bal_w > 0:
        b = _com_minus_support(R.com_w, R.support_w, R.parent, st["pos"])[:, [0, 2]]
        bb = np.sum(b * b, -1)
        sec += bal_w * bb
        berr = np.sqrt(bb)
    return f, perr, np.maximum(oerr, berr), sec, oerr


def _axes(jt, base, theta):
    """World DOF axes of a joint: list of (n, 3)."""
    n = base.shape[0]
    k, s = jt["k"], jt["s"]
    ex, ey, ez = (np.broadcast_to(v, (n, 3)) for v in np.eye(3))
    if not jt["angle"]:
        return [ex, ey, ez]
    ax = jt["axes"]
    if k == 1:
        return [qrot(base, np.broadcast_to(ax[0], (n, 3)))]
    if k == 2:
        return [qrot(base, np.broadcast_to(ax[0], (n, 3))),
                qrot(qmul(base, axis_angle(ax[0], theta[:, s])), np.broadcast_to(ax[1], (n, 3)))]
    rx = qmul(base, axis_angle(np.eye(3)[0], theta[:, s]))
    return [qrot(base, ex), qrot(rx, ey), qrot(qmul(rx, axis_angle(np.eye(3)[1], theta[:, s + 1])), ez)]


def _build(R: _Rig, st, tgt, weights, orient, eff_lim, length, rest_w, vel_w, bal_w=0.0, rot_t=None, rot_w=None):
    """(jac (n, 5E [+ 2] [+ 3E], D), aimed error (n, ...), g (n, D)); rows of inactive effectors/orientations are zero.

    With bal_w > 0 the two rows after the effectors' 5E are the balance rows (x, z of c - s); with rotation
    targets (rot_w not None) 3 rows per effector follow: sqrt(rot_w) L log(q_target q^-1) (clamped to
    ORI_CLAMP), columns sqrt(rot_w) L (world DOF axis). A free root (R.root): 3 more columns, identity times
    sqrt(w) in each effector's position rows.
    """
    rig = R.rig
    n, D, E = tgt.shape[0], R.n_col, rig.n_effectors
    tgt = tgt - _root_shift(R, st)[:, None]
    nb = 2 if bal_w > 0 else 0
    nr = 3 * E if rot_w is not None else 0
    jac = np.zeros((n, 5 * E + nb + nr, D))
    err = np.zeros((n, 5 * E + nb + nr))
    pos, wrot, theta = st["pos"], st["wrot"], st["theta"]
    q_root = _yaw(st["yaw"])
    eff_axis = rig.arrays["eff_axis"].astype(np.float64)
    axes_of = {}
    for e, eff in enumerate(rig.effectors):
        w = weights[:, e]
        on = w > 0
        sw = np.sqrt(np.maximum(w, 0.0))[:, None]
        reach, dmax = float(eff_lim[e, 0]), float(eff_lim[e, 1])
        p_eff = pos[:, eff.joint]
        v = tgt[:, e] - pos[:, 0]
        dist = np.linalg.norm(v, axis=-1, keepdims=True)
        aim = np.where(dist > reach + dmax, pos[:, 0] + v * ((reach + dmax) / np.maximum(dist, 1e-30)), tgt[:, e])
        d = aim - p_eff
        dn = np.linalg.norm(d, axis=-1, keepdims=True)
        d = np.where(dn > dmax, d * (dmax / np.maximum(dn, 1e-30)), d)
        r = 5 * e
        err[:, r : r + 3] = np.where(on[:, None], sw * d, 0.0)
        if R.root:
            jac[:, r : r + 3, rig.n_dof :] = np.where(on[:, None, None], sw[:, :, None] * np.eye(3), 0.0)
        has = on & (eff.axis is not None) & (np.sum(orient[:, e] ** 2, -1) > 0)
        if np.any(has):
            a = qrot(wrot[:, eff.joint], np.broadcast_to(eff_axis[e], (n, 3)))
            a = a / np.linalg.norm(a, axis=-1, keepdims=True)
            rv = swing_vector(a, orient[:, e])
            ang = np.linalg.norm(rv, axis=-1, keepdims=True)
            rv = np.where(ang > ORI_CLAMP, rv * (ORI_CLAMP / np.maximum(ang, 1e-30)), rv)
            u1 = perpendicular(a)
            u2 = np.cross(a, u1)
            scale = np.where(has, sw[:, 0] * length, 0.0)
            err[:, r + 3] = scale * np.sum(rv * u1, -1)
            err[:, r + 4] = scale * np.sum(rv * u2, -1)
        rr = 5 * E + nb + 3 * e
        if rot_w is not None:
            sr = np.sqrt(np.maximum(rot_w[:, e], 0.0))[:, None] * length
            rq = _rotation_vector(rot_t[:, e], wrot[:, eff.joint])
            ang = np.linalg.norm(rq, axis=-1, keepdims=True)
            rq = np.where(ang > ORI_CLAMP, rq * (ORI_CLAMP / np.maximum(ang, 1e-30)), rq)
            err[:, rr : rr + 3] = sr * rq
        for jn in rig.path_to_root(eff.joint):
            jt = R.joints[jn]
            if jt["k"] == 0:
                continue
            if jn not in axes_of:
                axes_of[jn] = _axes(jt, _parent_rot(jt, q_root, wrot), theta)
            lever = p_eff - pos[:, jn]
            for c, col in enumerate(axes_of[jn]):
                if rot_w is not None:
                    jac[:, rr : rr + 3, jt["s"] + c] = sr * col
                jac[:, r : r + 3, jt["s"] + c] = np.where(on[:, None], sw * np.cross(col, lever), 0.0)
                if np.any(has):
                    scale = np.where(has, sw[:, 0] * length, 0.0)
                    jac[:, r + 3, jt["s"] + c] = scale * np.sum(col * u1, -1)
                    jac[:, r + 4, jt["s"] + c] = scale * np.sum(col * u2, -1)
    if bal_w > 0:
        sb = np.sqrt(bal_w)
        total, lever = _balance_sums(R, pos)
        err[:, 5 * E] = -sb * total[:, 0]
        err[:, 5 * E + 1] = -sb * total[:, 2]
        for jn, jt in enumerate(R.joints):
            if jt["k"] == 0:
                continue
            if jn not in axes_of:
                axes_of[jn] = _axes(jt, _parent_rot(jt, q_root, wrot), theta)
            for c, col in enumerate(axes_of[jn]):
                dc = np.cross(col, lever[:, jn])
                jac[:, 5 * E, jt["s"] + c] = sb * dc[:, 0]
                jac[:, 5 * E + 1, jt["s"] + c] = sb * dc[:, 2]
    g = np.zeros((n, D))
    if rest_w > 0 or vel_w > 0:
        for j, jt in enumerate(R.joints):
            k, s = jt["k"], jt["s"]
            if k == 0:
                continue
            if jt["angle"]:
                th = theta[:, s : s + k]
                g[:, s : s + k] = -(rest_w * th + vel_w * (th - st["theta0"][:, s : s + k]))
            else:
                base = _parent_rot(jt, q_root, wrot)
                q = st["rot"][:, j]
                rho = qrot(base, qlog(q))
                nu = qrot(base, qlog(qmul(q, qconj(st["q0"][:, j]))))
                g[:, s : s + 3] = -(rest_w * rho + vel_w * nu)
    return jac, err, g


def _solve(jac, err, g, lam2, free, joint_w, rest_w, vel_w, bal_row=None, zmax=None, mu2=None):
    """Step (n, D). Without secondary terms (zmax None): W J^T (J W J^T + lam^2 I)^-1 e, W = diag(joint_w free).

    With them (kernels/dls_system.solve_step: task priority with damped pseudo-inverses) the two balance rows
    from bal_row on (None: no balance) and the rest / velocity terms act in the null space of the other
    (target) rows J1: d = d1 + N1 z, d1 = J1^+ e1, N1 = I - W J1^T (J1 W J1^T + mu2 I)^-1 J1,
    z = M g + M' Hb^T (Hb M' Hb^T + lam^2 I)^-1 (eb - Jb d1 - Hb M g), Hb = Jb N1, z scaled to at most zmax
    (n,) per column.
    """
    w = joint_w[None, :] * free
    if zmax is None:
        a = np.einsum("nrd,nd,nsd->nrs", jac, w, jac) + lam2[:, None, None] * np.eye(jac.shape[1])
        y = np.linalg.solve(a, err[..., None])[..., 0]
        return w * np.einsum("nrd,nr->nd", jac, y)
    prim = np.ones(jac.shape[1], bool)
    if bal_row is not None:
        prim[bal_row : bal_row + 2] = False
    j1, e1 = jac[:, prim], err[:, prim]
    jwj = np.einsum("nrd,nd,nsd->nrs", j1, w, j1)
    eye = np.eye(j1.shape[1])
    d1 = w * np.einsum("nrd,nr->nd", j1, np.linalg.solve(jwj + lam2[:, None, None] * eye, e1[..., None])[..., 0])

    def solve_a1(v):  # (J1 W J1^T + mu^2 I)^-1 v: N1's
        return np.linalg.solve(jwj + mu2 * eye, v[..., None])[..., 0]

    den = lam2[:, None] + w * (rest_w + vel_w)
    mg = w * g / den
    z = mg
    if bal_row is not None:
        jb, eb = jac[:, bal_row : bal_row + 2], err[:, bal_row : bal_row + 2]
        hb = np.stack([jb[:, b] - np.einsum("nr,nrd->nd", solve_a1(np.einsum("nrd,nd,nd->nr", j1, w, jb[:, b])), j1)
                       for b in range(2)], axis=1)
        mp = w * lam2[:, None] / den
        s2 = np.einsum("nbd,nd,ncd->nbc", hb, mp, hb) + lam2[:, None, None] * np.eye(2)
        rhs = eb - np.einsum("nbd,nd->nb", jb, d1) - np.einsum("nbd,nd->nb", hb, mg)
        z = mg + mp * np.einsum("nbd,nb->nd", hb, np.linalg.solve(s2, rhs[..., None])[..., 0])
    zm = np.max(np.abs(z), axis=1)
    z = z * np.where(zm > zmax, zmax / np.maximum(zm, 1e-30), 1.0)[:, None]
    return d1 + z - w * np.einsum("nrd,nr->nd", j1, solve_a1(np.einsum("nrd,nd->nr", j1, z)))
