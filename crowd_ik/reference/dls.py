"""NumPy twin of kernels/dls.py: damped least squares with LM damping and an active set, batched over characters.

The same algorithm as the kernel (read its docstring for the maths), vectorised over N with the
R x R systems solved by np.linalg.solve on (N, R, R) stacks; loops run over joints, effectors and
iterations only. Used by the tests as the kernel's oracle and by the benchmark as the NumPy
baseline. :func:`dls_settings` holds the constants both share (so they cannot drift apart).

Static balance (the lecture's g(q) = |f_com(q) - f_feet(q)|^2): the centre of mass c = sum_b m_b
midpoint_b / sum_b m_b over the bones (bone b from joint b's parent to joint b; its mass taken
proportional to its length times rig.joints[b].radius^2, a uniform-density cylinder), the support
point s = the mean of the foot effectors' positions (effectors named "foot..."), and the balance
error the horizontal (x, z) part of c - s. With balance_weight = beta_b > 0 the objective gains
beta_b |(c - s)_xz|^2 and the system two rows sqrt(beta_b) (d(c - s)/dq)_x,z aiming at -(c - s)_x,z.
Both c and s are weighted sums of joint positions (:func:`balance_weights`), so one walk up the tree
gives, per joint n, the lever sum_j a_j (p_j - p_n) over the points below it, and the column of a
DOF with world axis w at joint n is w x lever (the support moves with the feet: its rows are
subtracted, not held fixed). The solve also waits for |(c - s)_xz| <= tolerance, like an orientation.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.fk import forward_kinematics
from crowd_ik.geometry.quat import (
    axis_angle, constrain_rotation, joint_angles, joint_quat, qconj, qmul, qnormalize, qrot, quat_to_euler_xyz,
)
from crowd_ik.rig import Rig
from crowd_ik.solvers.dls_setup import balance_weights, dls_settings  # noqa: F401  (the tests' too)

# The solver's constants live in crowd_ik/solvers/settings.py, shared with kernels/dls.py.
from crowd_ik.solvers.settings import (
    DLS_STALL_AFTER as STALL_AFTER, DLS_FLAT as FLAT, DLS_WINDOW as WINDOW, DLS_PROGRESS as PROGRESS,
    DLS_LAM_CAP as LAM_CAP, DLS_LIMIT_EPS as LIMIT_EPS, DLS_ORI_CLAMP as ORI_CLAMP, DLS_KICK as KICK,
    DLS_MAX_ESCAPES as MAX_ESCAPES, DLS_ESCAPE_ATTEMPTS as ESCAPE_ATTEMPTS,
)


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

    def __init__(self, rig: Rig, settings: dict):
        self.rig = rig
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


def _objective(R: _Rig, st, tgt, weights, orient, eff_lim, length, rest_w, vel_w, bal_w=0.0, rot_t=None, rot_w=None):
    """(F, max position error, max(orientation error * L, balance error)); F's position terms as in the kernel.

    rot_t (n, E, 4), rot_w (n, E) or None: full rotation targets, each adding rot_w (L angle)^2 to F and
    L angle to the orientation error."""
    rig = R.rig
    n = tgt.shape[0]
    f = np.zeros(n)
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
        f += np.where(on, w * np.where(dist > reach, far, dd), 0.0)
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
                f += rest_w * np.sum(th * th, -1) + vel_w * np.sum(dv * dv, -1)
            else:
                q = st["rot"][:, j]
                f += rest_w * np.sum(qlog(q) ** 2, -1) + vel_w * np.sum(qlog(qmul(q, qconj(st["q0"][:, j]))) ** 2, -1)
    if bal_w > 0:
        b = _com_minus_support(R.com_w, R.support_w, R.parent, st["pos"])[:, [0, 2]]
        bb = np.sum(b * b, -1)
        f += bal_w * bb
        oerr = np.maximum(oerr, np.sqrt(bb))
    return f, perr, oerr


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
    ORI_CLAMP), columns sqrt(rot_w) L (world DOF axis).
    """
    rig = R.rig
    n, D, E = tgt.shape[0], rig.n_dof, rig.n_effectors
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


def _solve(jac, err, g, lam2, free, joint_w, rest_w, vel_w):
    """Step (n, D) = M g + M' J^T (J M' J^T + lam^2 I)^-1 (e - J M g)."""
    w = joint_w[None, :] * free
    den = lam2[:, None] + w * (rest_w + vel_w)
    mp = w * lam2[:, None] / den
    mg = w * g / den
    a = np.einsum("nrd,nd,nsd->nrs", jac, mp, jac) + lam2[:, None, None] * np.eye(jac.shape[1])
    b = err - np.einsum("nrd,nd->nr", jac, mg)
    y = np.linalg.solve(a, b[..., None])[..., 0]
    return mg + mp * np.einsum("nrd,nr->nd", jac, y)


def _freeze(R: _Rig, theta, step, free):
    """Freeze free angle DOFs on a limit whose step points outward; returns which characters changed."""
    changed = np.zeros(theta.shape[0], bool)
    for jt in R.joints:
        if jt["k"] == 0 or not jt["angle"]:
            continue
        for c in range(jt["k"]):
            d = jt["s"] + c
            out = (free[:, d] > 0) & (((theta[:, d] <= jt["lo"][c] + LIMIT_EPS) & (step[:, d] < 0))
                                      | ((theta[:, d] >= jt["hi"][c] - LIMIT_EPS) & (step[:, d] > 0)))
            free[:, d] = np.where(out, 0.0, free[:, d])
            changed |= out
    return changed


def _apply(R: _Rig, st, step):
    """New (theta, rot, pos, wrot) after the step: clamped, cones projected, FK."""
    theta = st["theta"] + 0.0
    rot = st["rot"].copy()
    q_root = _yaw(st["yaw"])
    for j, jt in enumerate(R.joints):
        k, s = jt["k"], jt["s"]
        if k == 0:
            continue
        if jt["angle"]:
            theta[:, s : s + k] += step[:, s : s + k]
            _set_joint(jt, theta, rot, j)
        else:
            base = _parent_rot(jt, q_root, st["wrot"])
            q = qnormalize(qmul(qexp(qrot(qconj(base), step[:, s : s + 3])), rot[:, j]))
            if jt["cone"] > 0:
                q = constrain_rotation(3, jt["axes"], q, jt["lo"], jt["hi"], jt["cone"], jt["bone"])
            rot[:, j] = q
    pos, wrot = _fk(R.rig, st["yaw"], rot)
    return dict(st, theta=theta, rot=rot, pos=pos, wrot=wrot)


def _take(st, idx):
    return {k: v[idx] for k, v in st.items()}


def _kick(R: _Rig, theta, free, joint_w):
    """Escape step (n, D): every weighted angle DOF frozen on a limit moves inward by min(KICK, half its range)."""
    step = np.zeros_like(theta)
    for jt in R.joints:
        if jt["k"] == 0 or not jt["angle"]:
            continue
        for c in range(jt["k"]):
            d = jt["s"] + c
            lo, hi = jt["lo"][c], jt["hi"][c]
            size = min(KICK, 0.5 * (hi - lo))
            frozen = (free[:, d] == 0) & (joint_w[d] > 0) & (size > 0)
            step[:, d] = np.where(frozen & (theta[:, d] <= lo + LIMIT_EPS), size,
                                  np.where(frozen & (theta[:, d] >= hi - LIMIT_EPS), -size, 0.0))
    return step


def dls_solve(rig: Rig, root_pos, root_yaw, rot, targets, weights=None, orientations=None, max_iterations=20,
              tolerance=1e-3, damping=None, rest_weight=0.0, velocity_weight=0.0, joint_weights=None,
              balance_weight=0.0, rotations=None, rotation_weights=None):
    """Solve N characters from local rotations rot (N, J, 4); returns (rot, world_pos, error, iterations, stalled).

    root_pos (N, 3), root_yaw (N,), targets (N, E, 3) world metres; weights (N, E) (default ones);
    orientations (N, E, 3) unit directions or zero; joint_weights (D,) (default ones). The other
    arguments as in Crowd.solve(method="dls"). Float64 throughout; each pass of the loop below is
    one pass of the kernel's per-character loop, over every character still running. (The kernel
    also voids a step whose float32 Cholesky meets a non-positive pivot; in float64 with lam > 0
    that cannot happen.) rotations (N, E, 4) x y z w full rotation targets of the effector joints' world
    rotations with rotation_weights (N, E) (0 or a zero row: none), or None.
    """
    joint_w = np.ones(rig.n_dof) if joint_weights is None else np.asarray(joint_weights, np.float64)
    settings = dls_settings(rig, damping, joint_w)
    R = _Rig(rig, settings)
    root_pos = np.asarray(root_pos, np.float64)
    N, E, D = root_pos.shape[0], rig.n_effectors, rig.n_dof
    yaw = np.asarray(root_yaw, np.float64)
    tgt = np.asarray(targets, np.float64) - root_pos[:, None, :]
    weights = np.ones((N, E)) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (N, E))
    orient = np.zeros((N, E, 3)) if orientations is None else np.asarray(orientations, np.float64)
    length, lam0, eff_lim = settings["length"], settings["damping"], settings["eff_lim"].astype(np.float64)
    rest_w, vel_w, bal_w = float(rest_weight), float(velocity_weight), float(balance_weight)
    if bal_w > 0 and not settings["has_feet"]:
        raise ValueError("balance_weight: the rig has no foot effectors")
    rot_t = rot_w = None
    if rotations is not None:
        rot_t = np.asarray(rotations, np.float64).reshape(N, E, 4)
        rot_w = np.ones((N, E)) if rotation_weights is None else np.broadcast_to(
            np.asarray(rotation_weights, np.float64), (N, E))
        rot_w = np.where(np.sum(rot_t * rot_t, -1) > 0, rot_w, 0.0)
    obj_args = (tgt, weights, orient, eff_lim, length, rest_w, vel_w, bal_w)

    def rot_of(ids):
        return (None, None) if rot_w is None else (rot_t[ids], rot_w[ids])

    rot = np.array(rot, np.float64)
    theta = np.zeros((N, D))
    for j, jt in enumerate(R.joints):
        if jt["angle"]:
            theta[:, jt["s"] : jt["s"] + jt["k"]] = joint_angles(jt["k"], jt["axes"], rot[:, j])
    pos, wrot = _fk(rig, yaw, rot)
    # the first pass applies a zero step: the start pose projected onto the DOFs and limits
    st = _apply(R, dict(theta=theta, theta0=theta, rot=rot, q0=rot, pos=pos, wrot=wrot, yaw=yaw), np.zeros((N, D)))
    st["theta0"], st["q0"] = st["theta"].copy(), st["rot"].copy()
    # (N, 3): F, max position error, max(orientation error * L, balance error)
    obj = np.stack(_objective(R, st, *obj_args, *rot_of(slice(None))), axis=1)
    ref_f, ref_acc = obj[:, 0].copy(), np.zeros(N, np.int32)
    lam = np.full(N, lam0)
    accepted = np.zeros(N, np.int32)
    attempts = np.zeros(N, np.int32)
    bad = np.zeros(N, np.int32)
    stop = np.zeros(N, bool)
    kick = np.zeros(N, bool)  # the pending step is an escape kick
    esc = np.zeros(N, bool)  # on probation after a kick
    esc_left = np.zeros(N, np.int32)
    escapes = np.zeros(N, np.int32)
    saved = dict(theta=st["theta"].copy(), rot=st["rot"].copy(), obj=obj.copy(), accepted=accepted.copy())
    free = np.ones((N, D))
    step = np.zeros((N, D))
    max_attempts = 2 * max_iterations + 8
    go = np.zeros(N, bool)

    def restore_saved(ids):
        st["theta"][ids], st["rot"][ids] = saved["theta"][ids], saved["rot"][ids]
        st["pos"][ids], st["wrot"][ids] = _fk(rig, yaw[ids], st["rot"][ids])
        obj[ids], accepted[ids] = saved["obj"][ids], saved["accepted"][ids]
        esc[ids] = False
        ref_f[ids], ref_acc[ids] = obj[ids, 0], accepted[ids]

    def plan(ids):
        """Next step of the characters ids: an escape kick, or the LM step with the active set."""
        attempts[ids] += 1
        k = ids[kick[ids]]
        step[k] = _kick(R, st["theta"][k], free[k], joint_w)
        m = ids[~kick[ids]]
        if m.size == 0:
            return
        sub = _take(st, m)
        jac, err, g = _build(R, sub, tgt[m], weights[m], orient[m], eff_lim, length, rest_w, vel_w, bal_w,
                             *rot_of(m))
        fr = np.ones((m.size, D))
        lam2 = lam[m] ** 2
        stp = _solve(jac, err, g, lam2, fr, joint_w, rest_w, vel_w)
        for _ in range(D + 1):
            changed = _freeze(R, sub["theta"], stp, fr)
            if not changed.any():
                break
            c = np.flatnonzero(changed)
            stp[c] = _solve(jac[c], err[c], g[c], lam2[c], fr[c], joint_w, rest_w, vel_w)
        step[m], free[m] = stp, fr

    def decide(ids):
        """Stall and escape bookkeeping, the stopping test, and the next step for those that go on."""
        stalled_now = (bad[ids] >= STALL_AFTER) | (lam[ids] > LAM_CAP * length)
        back = stalled_now & esc[ids]  # a stalled escape goes back to the pose before its kick
        stop[ids[back]] = True
        fresh = ids[stalled_now & ~esc[ids] & (escapes[ids] < MAX_ESCAPES)]
        can = fresh[np.any(_kick(R, st["theta"][fresh], free[fresh], joint_w) != 0, axis=1)]
        for key in ("theta", "rot"):
            saved[key][can] = st[key][can]
        saved["obj"][can], saved["accepted"][can] = obj[can], accepted[can]
        kick[can], escapes[can], bad[can], lam[can] = True, escapes[can] + 1, 0, lam0
        stop[np.setdiff1d(ids[stalled_now & ~esc[ids]], can)] = True
        spent = esc[ids] & (esc_left[ids] <= 0) & ~back
        stop[ids[spent]] = True
        back |= spent
        conv = (obj[ids, 1] <= tolerance) & (obj[ids, 2] <= tolerance)
        cont = (accepted[ids] < max_iterations) & (attempts[ids] < max_attempts) & ~stop[ids] & ~conv
        back |= ~cont & esc[ids]
        restore_saved(ids[back])
        conv = (obj[ids, 1] <= tolerance) & (obj[ids, 2] <= tolerance)
        stop[ids[~cont & ~stop[ids] & ~conv & (accepted[ids] < max_iterations)]] = True  # attempts ran out
        go[:] = False
        go[ids[cont]] = True
        plan(ids[cont])

    decide(np.arange(N))
    while go.any():
        idx = np.flatnonzero(go)
        trial = _apply(R, _take(st, idx), step[idx])
        new = np.stack(_objective(R, trial, tgt[idx], weights[idx], orient[idx], *obj_args[3:], *rot_of(idx)),
                       axis=1)
        kicked = kick[idx]
        better = kicked | (new[:, 0] < obj[idx, 0])
        flat = ~kicked & better & (obj[idx, 0] - new[:, 0] < FLAT * obj[idx, 0])
        acc = idx[better]
        for key in ("theta", "rot", "pos", "wrot"):
            st[key][acc] = trial[key][better]
        obj[acc] = new[better]
        accepted[acc] += 1
        lam[acc] = np.where(kicked[better], lam0, np.maximum(0.5 * lam[acc], lam0))
        bad[idx] = np.where(better & ~flat, 0, bad[idx] + 1)
        lam[idx[~better]] *= 4.0
        esc[idx[kicked]], esc_left[idx[kicked]], kick[idx] = True, ESCAPE_ATTEMPTS, False
        # too slow: F fell by less than PROGRESS over the last WINDOW accepted steps
        plain = idx[better & ~kicked]
        due = plain[accepted[plain] - ref_acc[plain] >= WINDOW]
        slow = due[obj[due, 0] > (1.0 - PROGRESS) * ref_f[due]]
        bad[slow] = STALL_AFTER
        ref_f[due], ref_acc[due] = obj[due, 0], accepted[due]
        ref_f[idx[kicked]], ref_acc[idx[kicked]] = obj[idx[kicked], 0], accepted[idx[kicked]]
        # on probation: kept once it beats the pose before the kick (or converges)
        probe = idx[esc[idx] & ~kicked]
        conv = (obj[probe, 1] <= tolerance) & (obj[probe, 2] <= tolerance)
        esc[probe[(obj[probe, 0] < saved["obj"][probe, 0]) | conv]] = False
        esc_left[probe] -= 1
        decide(idx)
    world_pos = st["pos"] + root_pos[:, None, :]
    return st["rot"], world_pos, obj[:, 1].copy(), accepted, stop.astype(np.int32)


def balance_rows(rig: Rig, root_yaw, rot, balance_weight: float = 1.0, joint_weights=None):
    """(aimed error (N, 2), rows (N, 2, D)): the solver's balance rows at local rotations rot (N, J, 4).

    The columns are the solver's (angle DOFs, or world-axis rotations of quaternion-mode ball joints).
    """
    settings = dls_settings(rig, None, joint_weights)
    R = _Rig(rig, settings)
    rot = np.asarray(rot, np.float64)
    N, E = rot.shape[0], rig.n_effectors
    yaw = np.asarray(root_yaw, np.float64)
    theta = np.zeros((N, rig.n_dof))
    for j, jt in enumerate(R.joints):
        if jt["angle"]:
            theta[:, jt["s"] : jt["s"] + jt["k"]] = joint_angles(jt["k"], jt["axes"], rot[:, j])
    pos, wrot = _fk(rig, yaw, rot)
    st = dict(theta=theta, theta0=theta, rot=rot, q0=rot, pos=pos, wrot=wrot, yaw=yaw)
    jac, err, _ = _build(R, st, np.zeros((N, E, 3)), np.zeros((N, E)), np.zeros((N, E, 3)),
                         settings["eff_lim"].astype(np.float64), settings["length"], 0.0, 0.0, float(balance_weight))
    return err[:, 5 * E :], jac[:, 5 * E :]


__all__ = ["dls_solve", "dls_settings", "balance_weights", "balance_offset", "balance_rows", "qlog", "qexp",
           "swing_vector"]
