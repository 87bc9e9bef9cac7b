"""NumPy reference maths of one planar chain: the seeds' homework and lab API.

The chain has n bones (unit length unless ``lengths`` is given), its root at the origin; theta_1 is
the bone's angle to the x axis and every later theta_i is relative to the previous bone (homework
4, CS328). Angles in radians, positions in bone-length units, everything float64.

- ``chain``, ``chain_all``, ``dchain``: forward kinematics and the analytic 2 x n Jacobian.
- ``newton``: the homework's Newton iteration with the pseudoinverse (8 iterations).
- ``dls``: damped least squares with adaptive damping, error clamping, joint limits and per-joint
  rates (the coursework's loop, made safe).
- ``regularized``: argmin alpha*|p - target|^2 + sum(theta^2) or sum|theta| (homework part 3).
- ``follow``: the lab's ``move(dP, depth)`` with its residual check and recursive half steps.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["chain", "chain_all", "dchain", "newton", "dls", "regularized", "follow"]

# Buss & Kim (2005), "Selectively damped least squares for IK", sec. 4: clamp the error vector a
# step aims for, |e| <= D_max, so a step never aims farther than the linearisation holds. We use
# D_max = 0.4 * mean bone length (plus the part of |target| beyond the reach, see dls).
ERROR_CLAMP = 0.4


# ---------------------------------------------------------------------------------------------
# validation


def _floats(name: str, value, shape: tuple | None = None, allow_inf: bool = False) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers (got {value!r})") from None
    if shape is not None and a.shape != shape:
        raise ValueError(f"{name}: expected shape {shape} (got shape {a.shape}: {value!r})")
    bad = np.isnan(a) if allow_inf else ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{name}: expected finite numbers (got {value!r})")
    return a


def _pose(thetas, lengths) -> tuple[np.ndarray, np.ndarray]:
    t = _floats("thetas", thetas)
    if t.ndim != 1:
        raise ValueError(f"thetas: expected a 1-D array of angles (got shape {t.shape}: {thetas!r})")
    if lengths is None:
        return t, np.ones(t.size)
    l = _floats("lengths", lengths, (t.size,))
    if (l <= 0).any():
        raise ValueError(f"lengths: expected positive bone lengths (got {lengths!r})")
    return t, l


def _positive(name: str, value, integer: bool = False, allow_zero: bool = False):
    ok_type = isinstance(value, numbers.Integral) if integer else isinstance(value, numbers.Real)
    if isinstance(value, bool) or not ok_type or not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        kind = "integer" if integer else "number"
        sign = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name}: expected a {sign} finite {kind} (got {value!r})")
    return int(value) if integer else float(value)


# ---------------------------------------------------------------------------------------------
# forward kinematics and derivatives (no validation: internal, trusted arrays)


def _bones(t: np.ndarray, l: np.ndarray) -> np.ndarray:
    """(n, 2) bone vectors: bone k points along the accumulated angle phi_k = theta_1 + ... + theta_k."""
    phi = np.cumsum(t)
    return l[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1)


def _tip(t, l) -> np.ndarray:
    return _bones(t, l).sum(axis=0) if t.size else np.zeros(2)


def _tails(t, l) -> np.ndarray:
    """(n, 2) S_j = p_n - p_{j-1}: from joint j to the tip (reverse cumulative sum of bones)."""
    return np.cumsum(_bones(t, l)[::-1], axis=0)[::-1]


def _jacobian(t, l) -> np.ndarray:
    # Turning joint j rotates everything beyond it: dp/dtheta_j = R(90 deg) S_j = (-S_jy, S_jx).
    s = _tails(t, l)
    return np.stack([-s[:, 1], s[:, 0]])


def _hessian_terms(t, l, r) -> np.ndarray:
    """(n, n) sum_i r_i d2p_i/dtheta_j dtheta_k = -r . S_max(j,k): the second-order part of a Hessian."""
    rs = _tails(t, l) @ r
    idx = np.arange(t.size)
    return -rs[np.maximum(idx[:, None], idx[None, :])]


def chain_all(thetas, *, lengths=None) -> np.ndarray:
    """All joint positions, (n+1, 2): row 0 is the root (0, 0), row n the end effector."""
    t, l = _pose(thetas, lengths)
    return np.vstack([np.zeros((1, 2)), np.cumsum(_bones(t, l), axis=0)])


def chain(thetas, *, lengths=None) -> np.ndarray:
    """End-effector position, (2,); chain([]) is the root (0, 0)."""
    t, l = _pose(thetas, lengths)
    return _tip(t, l)


def dchain(thetas, *, lengths=None) -> np.ndarray:
    """Analytic Jacobian dp/dtheta, (2, n): column j is the tip's velocity when theta_j turns."""
    t, l = _pose(thetas, lengths)
    return _jacobian(t, l)


# ---------------------------------------------------------------------------------------------
# Newton (homework 2.2)


def newton(thetas, target, iterations: int = 8, *, lengths=None) -> np.ndarray:
    """Homework 2.2: theta <- theta + pinv(J) (target - p), a fixed number of times; returns (n,)."""
    t, l = _pose(thetas, lengths)
    goal = _floats("target", target, (2,))
    iterations = _positive("iterations", iterations, integer=True)
    for _ in range(iterations):
        t = t + np.linalg.pinv(_jacobian(t, l)) @ (goal - _tip(t, l))
    return t


# ---------------------------------------------------------------------------------------------
# damped least squares (coursework 3.3 / 4.1 / 4.3)


def _weighted_dls_step(jac, e, lam, w):
    # Weighted DLS (Buss 2004, eq. 11 with a joint weighting W = diag(w)):
    #   dtheta = W J^T (J W J^T + lambda^2 I)^-1 e
    a = (jac * w) @ jac.T + lam * lam * np.eye(2)
    return w * (jac.T @ np.linalg.solve(a, e))


def _escape_saddle(t, l, goal, e, err, w, lo, hi):
    """Leave a stationary point that is not a minimum of |e|^2 (e.g. a straight chain pointing away).

    Steps along the Hessian's most negative curvature direction (scaled by sqrt(W)), halving until
    the error drops; returns the new angles or None at a true (local) minimum.
    """
    jac = _jacobian(t, l)
    d = np.sqrt(w)
    hess = jac.T @ jac - _hessian_terms(t, l, e)  # Hessian of 0.5|target - p|^2
    vals, vecs = np.linalg.eigh(d[:, None] * hess * d[None, :])
    if vals[0] >= -1e-9 * max(1.0, abs(vals[-1])):
        return None
    v = d * vecs[:, 0]
    v /= np.abs(v).max()
    step = 0.5
    for _ in range(40):
        for sign in (1.0, -1.0):
            trial = np.clip(t + sign * step * v, lo, hi)
            if np.linalg.norm(goal - _tip(trial, l)) < err:
                return trial
        step *= 0.5
    return None


def dls(
    thetas,
    target,
    damping: float = 0.1,
    iterations: int = 100,
    tolerance: float = 1e-6,
    *,
    lengths=None,
    limits=None,
    rates=None,
    history: list | None = None,
) -> np.ndarray:
    """Damped least squares IK; returns the final angles (n,).

    Each iteration aims for the error e = target - p clamped to ``ERROR_CLAMP`` * mean bone length
    and takes dtheta = W J^T (J W J^T + lambda^2 I)^-1 e, W = diag(rates) (the coursework's per-joint
    rate constants a, b, c; default ones; a zero rate freezes its joint). lambda starts at
    ``damping`` and adapts Levenberg-Marquardt style: a step that does not lower |e| is rejected
    (lambda x4); an accepted step that achieves under a quarter of the linearly predicted decrease
    doubles lambda, one that achieves over three quarters halves it, never below ``damping``. So
    |e| never increases and the chain does not flip back and forth. ``limits`` =
    (lo, hi) arrays clamp the angles; a DOF at a limit whose step points outward is frozen for that
    step (active set). At a stationary point that is a saddle (a straight chain pointing away from
    its target) the solver steps along negative curvature; at a true minimum it stops, so an
    unreachable target ends with the chain stretched toward it. It also stops when |e| <=
    ``tolerance``, when lambda passes 1e8 (stalled), or after ``iterations`` iterations.
    ``history``: if a list, |e| is appended at the start and after every iteration.
    """
    t, l = _pose(thetas, lengths)
    goal = _floats("target", target, (2,))
    damping = _positive("damping", damping)
    iterations = _positive("iterations", iterations, integer=True)
    tolerance = _positive("tolerance", tolerance, allow_zero=True)
    n = t.size
    if limits is None:
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    else:
        if not isinstance(limits, (tuple, list)) or len(limits) != 2:
            raise ValueError(f"limits: expected a pair (lo, hi) of arrays (got {limits!r})")
        lo = _floats("limits[0]", limits[0], (n,), allow_inf=True)
        hi = _floats("limits[1]", limits[1], (n,), allow_inf=True)
        if (lo > hi).any():
            raise ValueError(f"limits: expected lo <= hi for every joint (got {limits!r})")
    w = np.ones(n) if rates is None else _floats("rates", rates, (n,))
    if (w < 0).any():
        raise ValueError(f"rates: expected non-negative rate constants (got {rates!r})")
    if history is not None and not isinstance(history, list):
        raise ValueError(f"history: expected a list or None (got {history!r})")

    t = np.clip(t, lo, hi)
    clamp = ERROR_CLAMP * float(l.mean()) if n else 0.0
    # Steps aim at the target pulled in along its ray to at most reach + clamp from the root: a far
    # target's unremovable excess would otherwise make this a large-residual problem, on which DLS
    # (Gauss-Newton) converges slowly. Acceptance still uses the true error.
    dist = float(np.linalg.norm(goal))
    aim_goal = goal * min(1.0, (l.sum() + clamp) / dist) if dist > 0 else goal
    lam = damping
    e = goal - _tip(t, l)
    err = float(np.linalg.norm(e))
    if history is not None:
        history.append(err)
    for _ in range(iterations if n else 0):
        if err <= tolerance:
            break
        jac = _jacobian(t, l)
        aim = aim_goal - (goal - e)
        aim *= min(1.0, clamp / max(np.linalg.norm(aim), 1e-300))
        free = w > 0
        for _ in range(n + 1):  # active set: freeze DOFs pinned at a limit and pushed outward
            step = _weighted_dls_step(jac, aim, lam, w * free)
            out = free & (((t <= lo) & (step < 0)) | ((t >= hi) & (step > 0)))
            if not out.any():
                break
            free &= ~out
        wf = w * free
        if np.linalg.norm(wf * (jac.T @ e)) <= 1e-12 * (1.0 + err):  # stationary
            escaped = _escape_saddle(t, l, goal, e, err, wf, lo, hi)
            if escaped is None:
                break
            t = escaped
            e = goal - _tip(t, l)
            err = float(np.linalg.norm(e))
        else:
            trial = np.clip(t + step, lo, hi)
            e_trial = goal - _tip(trial, l)
            err_trial = float(np.linalg.norm(e_trial))
            # Gain ratio rho = actual / linearly predicted decrease of |e|^2 (Nielsen 1999): a step
            # that only just helps (say it jumps to the mirrored bend) is taken but raises lambda.
            predicted = err * err - float(np.sum((e - jac @ (trial - t)) ** 2))
            rho = (err * err - err_trial * err_trial) / max(predicted, 1e-300)
            if err_trial < err:
                t, e, err = trial, e_trial, err_trial
            if rho > 0.75:
                lam = max(damping, 0.5 * lam)
            elif rho < 0.25:
                lam *= 2.0 if rho > 0 else 4.0
        if history is not None:
            history.append(err)
        if lam > 1e8:
            break
    return t


# ---------------------------------------------------------------------------------------------
# regularised IK (homework part 3)


def _objective(t, l, goal, alpha, l1) -> float:
    r = _tip(t, l) - goal
    return float(alpha * (r @ r) + (np.abs(t).sum() if l1 else t @ t))


def _minimise(t, l, goal, alpha, l1, iterations=200) -> np.ndarray:
    """Newton with exact Hessian and Levenberg-Marquardt damping mu (H + mu I) on
    F = alpha |p - target|^2 + penalty.

    For L1 it works orthant-wise (Andrew & Gao 2007, OWL-QN, with Newton instead of L-BFGS): the
    pseudo-gradient replaces the gradient, a zero angle leaves zero only if |dg/dtheta_i| > 1 (g
    the smooth part), inside the orthant F is smooth, and a step that crosses zero stops at zero.
    Every accepted step lowers F; it stops where the (pseudo-)gradient vanishes (a true local
    minimum) or when no step lowers F in floating point.
    """
    f = _objective(t, l, goal, alpha, l1)
    mu = 1e-3
    for _ in range(iterations):
        r = _tip(t, l) - goal
        jac = _jacobian(t, l)
        grad = 2 * alpha * (jac.T @ r)  # of the smooth part alpha |r|^2
        hess = 2 * alpha * (jac.T @ jac + _hessian_terms(t, l, r))
        if l1:
            sign = np.sign(t)
            pg = grad + sign
            zero = sign == 0
            pg[zero] = np.where(grad[zero] + 1 < 0, grad[zero] + 1, np.where(grad[zero] - 1 > 0, grad[zero] - 1, 0.0))
            orthant = np.where(zero, -np.sign(pg), sign)
        else:
            pg = grad + 2 * t
            hess = hess + 2 * np.eye(t.size)
        free = pg != 0 if l1 else np.ones(t.size, bool)
        if np.abs(pg).max() <= 1e-12 * max(1.0, f):
            break
        hf = hess[np.ix_(free, free)]
        while True:
            try:
                c = np.linalg.cholesky(hf + mu * np.eye(hf.shape[0]))
            except np.linalg.LinAlgError:
                mu *= 4.0
                continue
            d = np.zeros(t.size)
            d[free] = -np.linalg.solve(c.T, np.linalg.solve(c, pg[free]))
            trial = t + d
            if l1:
                trial[trial * orthant < 0] = 0.0
            f_trial = _objective(trial, l, goal, alpha, l1)
            if f_trial < f:
                t, f = trial, f_trial
                mu = max(mu / 3.0, 1e-12)
                break
            mu *= 4.0
            if mu > 1e12:
                return t
    return t


def _starts(t0, l, goal) -> list[np.ndarray]:
    """Start poses: the caller's, the rest pose, the chain pointing at the target, and the two
    uniform arcs (theta_2..n = +-c) whose tip reaches |target|, found by bisection on c."""
    n = t0.size
    heading = np.arctan2(goal[1], goal[0])
    starts = [t0, np.zeros(n), np.r_[heading, np.zeros(n - 1)]]
    dist = np.linalg.norm(goal)
    if n > 1 and dist < l.sum():
        arc = np.zeros(n)
        a, b = 0.0, 2 * np.pi / n  # |tip| shrinks from the full reach at c=0 toward 0
        for _ in range(40):
            arc[1:] = 0.5 * (a + b)
            a, b = (arc[1], b) if np.linalg.norm(_tip(arc, l)) > dist else (a, arc[1])
        for s in (1.0, -1.0):
            pose = s * arc
            tip = _tip(pose, l)
            pose[0] += heading - np.arctan2(tip[1], tip[0])
            starts.append(pose)
    return starts


def regularized(thetas, target, alpha: float = 10.0, penalty: str = "l2", *, lengths=None) -> np.ndarray:
    """Homework part 3: argmin_theta alpha*|p(theta) - target|^2 + sum theta_i^2 ("l2") or
    sum |theta_i| ("l1"); returns (n,).

    Runs the exact-Hessian Newton/LM of ``_minimise`` from several starts (the given angles first;
    see ``_starts``) and returns the best local minimum found.
    """
    t, l = _pose(thetas, lengths)
    goal = _floats("target", target, (2,))
    alpha = _positive("alpha", alpha)
    if penalty not in ("l2", "l1"):
        raise ValueError(f"penalty: expected 'l2' or 'l1' (got {penalty!r})")
    if t.size == 0:
        return t
    l1 = penalty == "l1"
    results = [_minimise(s, l, goal, alpha, l1) for s in _starts(t, l, goal)]
    return min(results, key=lambda r: _objective(r, l, goal, alpha, l1))


# ---------------------------------------------------------------------------------------------
# the lab's move(dP, depth)


def follow(thetas, delta, threshold: float = 0.05, max_depth: int = 10, *, lengths=None, history: list | None = None):
    """CS157 IK lab 2, ``move(dP, depth)``: move the end effector by ``delta`` (2,).

    One pseudoinverse step dtheta = J^+ delta; residual = |actual change - delta|_1. Accepted when
    residual < ``threshold``; otherwise rejected and replaced by two moves of delta/2 at depth+1.
    Beyond ``max_depth`` it gives up ("target lost"). Returns (angles, reached): on failure the
    angles after the last accepted sub-step. ``history``: if a list, each accepted sub-step's
    angles are appended.

    Besides the lab's rule, reached is False when the tip ends farther than ``threshold`` (Euclidean,
    metres) from the goal tip + ``delta``: on a straight chain pulled along its axis J^+ delta is zero,
    so every sub-step passes the residual test while nothing moves (issue 15).
    """
    t, l = _pose(thetas, lengths)
    dp = _floats("delta", delta, (2,))
    threshold = _positive("threshold", threshold)
    max_depth = _positive("max_depth", max_depth, integer=True, allow_zero=True)
    if history is not None and not isinstance(history, list):
        raise ValueError(f"history: expected a list or None (got {history!r})")
    state = [t]

    def move(d: np.ndarray, depth: int) -> bool:
        if depth > max_depth:
            return False
        cur = state[0]
        trial = cur + np.linalg.pinv(_jacobian(cur, l)) @ d
        residual = np.abs((_tip(trial, l) - _tip(cur, l)) - d).sum()
        if residual < threshold:
            state[0] = trial
            if history is not None:
                history.append(trial.copy())
            return True
        return move(0.5 * d, depth + 1) and move(0.5 * d, depth + 1)

    reached = move(dp, 0) if t.size else bool(np.abs(dp).sum() < threshold)
    if reached and t.size:
        goal = _tip(t, l) + dp
        reached = bool(np.linalg.norm(_tip(state[0], l) - goal) <= threshold)
    return state[0], reached
