"""FABRIK on a joint-limited rig solved in windows of iterations, with restarts and extrapolated starts (issue 15).

FABRIK with joint limits converges linearly, and near a limit it can stop at a pose that is not a solution: from
rest to in-limit poses of the humanoid 8 % of the characters stalled or crept to max_iterations. A solve with more
than WINDOW iterations therefore runs as windows of at most WINDOW iterations (launches of solvers/fabrik.solve,
the same kernels, the characters that are done masked out by a zero weight), and between windows each character
that is not yet within tolerance either
- goes on from where it stands;
- restarts, when its last window stalled and RESTART_LEFT iterations are left: from the best pose it has had, the
  joint angles that sit at a limit pulled PULL rad inside it, and from the second restart on a kick of KICK rad
  (a fixed sequence of normal draws, the k-th restart of every character takes the k-th: no character depends on
  another, so a batch solves as its characters one at a time);
- or jumps, when its last three window ends moved its angles by steps shrinking by a ratio r in JUMP_RATIO: to the
  limit of that geometric sequence (angles + d r / (1 - r), at most JUMP_FACTOR d), clipped to the limits.
Every character keeps the pose with the lowest error it has had. The report counts every update applied, restarts
and jumps included, and no character gets more than max_iterations of them (the windows share one clock: a window
gets min(WINDOW, what is left)); STALLED means the last attempt stopped improving, MAX_ITERATIONS that it was still
improving when the clock ran out. Solves of at most WINDOW iterations (the game's warm 4-iteration frames), rigs
without limits, and solves with orientation or rotation targets are solvers/fabrik.solve unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from crowd_ik.solvers import fabrik

WINDOW = 10  # iterations per window; a solve of at most this many is one launch, as without windows
RESTART_LEFT = 10  # a stalled character restarts only with at least this many iterations left
PULL = 0.3  # rad: how far a restart moves an angle that sits at a limit inside it
KICK = 0.15  # rad: the standard deviation of the restarts' kicks (the first restart has none)
KICK_SEED = 1000  # the k-th restart's kick is np.random.default_rng(KICK_SEED + k).normal(0, KICK, DOF)
JUMP_RATIO = (0.3, 1.0)  # the shrink ratio of the last two window steps that allows a jump
JUMP_FACTOR = 9.0  # a jump is at most this many times the last window's step
JUMP_MIN_STEP = 1e-4  # rad: a last window's step below this makes no jump
AT_LIMIT = 1e-3  # rad: an angle this close to a limit sits at it


def windowed(crowd, req) -> bool:
    """True when `req` is solved in windows: more than WINDOW iterations, a rig with limits (some joint not a free
    ball), no orientation or rotation targets."""
    return (req.max_iterations > WINDOW and not crowd.rig.constraint_free and crowd.buffers.orient_zero
            and req.rotations is None)


def solve(crowd, req) -> None:
    """Crowd.solve's FABRIK: in windows when `windowed`, else solvers/fabrik.solve as it is."""
    if not windowed(crowd, req):
        fabrik.solve(crowd, req)
        return
    _Windows(crowd, req).run()


def _kick(k: int, n_dof: int) -> np.ndarray:
    """The k-th restart's kick (DOF,) float32 (zeros for the first)."""
    if k == 0:
        return np.zeros(n_dof, np.float32)
    return np.random.default_rng(KICK_SEED + k).normal(0.0, KICK, n_dof).astype(np.float32)


class _Windows:
    """One windowed solve: per character its iterations used, current error, last window's stall flag, the best
    earlier pose (saved rotations and its error), its restarts, and its last three window ends' angles."""

    def __init__(self, crowd, req):
        self.crowd, self.req = crowd, req
        rig, N = crowd.rig, crowd.n
        lo, hi = rig.angle_limits()
        self.lo, self.hi = lo.astype(np.float32), hi.astype(np.float32)
        self.used = np.zeros(N, np.int32)
        self.err = np.zeros(N, np.float32)
        self.stalled = np.zeros(N, bool)
        self.best_err = np.full(N, np.inf, np.float32)  # of the pose saved in best_rot (inf: none saved)
        self.best_rot = None  # (N, J) vec4 ndarray, allocated at the first save
        self.restarts = np.zeros(N, np.int32)
        self.hist = np.zeros((3, N, rig.n_dof), np.float32)  # the last three window ends' angles, oldest first
        self.n_hist = np.zeros(N, np.int32)

    def run(self) -> None:
        crowd, req, b = self.crowd, self.req, self.crowd.buffers
        M, tol = req.max_iterations, req.tolerance
        weights = b.weights.copy()
        self._window(np.arange(crowd.n), WINDOW)
        clock = WINDOW
        try:
            while clock < M:
                left = M - clock
                live = self.err > tol
                restart = live & self.stalled & (left >= RESTART_LEFT)
                act = np.flatnonzero((live & ~self.stalled) | restart)
                if act.size == 0:
                    break
                moved = self._between(act, restart[act])
                on = np.zeros(crowd.n, bool)
                on[act] = True
                np.multiply(weights, on[:, None], out=b.weights)
                self._window(act, min(WINDOW, left))
                # a moved start already within tolerance got no update, so no clamp to the limits: undo the move
                undo = moved[b.iterations[moved] == 0]
                if undo.size:
                    self._restore(undo)
                    self.err[undo] = self.best_err[undo]
                    self.stalled[undo] = True
                clock += min(WINDOW, left)
        finally:
            np.copyto(b.weights, weights)
        back = np.flatnonzero(self.best_err < self.err)
        if back.size:
            self._restore(back)
            self.err[back] = self.best_err[back]
        np.copyto(b.error, self.err)
        np.copyto(b.iterations, self.used)
        np.copyto(b.stalled, (self.err > tol) & self.stalled, casting="unsafe")

    def _window(self, act: np.ndarray, iterations: int) -> None:
        """One launch of at most `iterations` updates; the characters act (K,) take its results (the others are
        masked out by their weights)."""
        b = self.crowd.buffers
        fabrik.solve(self.crowd, replace(self.req, max_iterations=iterations))
        self.used[act] += b.iterations[act]
        self.err[act] = b.error[act]
        self.stalled[act] = b.stalled[act] != 0

    def _between(self, act: np.ndarray, restart: np.ndarray) -> np.ndarray:
        """The characters act (K,) before their next window: restart (K,) bool ones restart, the others go on or
        jump. Returns the characters given a new start (restarted or jumped)."""
        from crowd_ik.kernels import fabrik_restart as k

        crowd, ra = self.crowd, self.crowd.rig_arrays
        which = act.astype(np.int32)
        now = np.zeros((act.size, crowd.rig.n_dof), np.float32)
        k.read_angles(ra["kind"], ra["axes"], ra["dof_start"], crowd.local_rot, which, now)
        h, n = self.hist, self.n_hist
        h[0, act], h[1, act], h[2, act] = h[1, act], h[2, act], now
        n[act] = np.minimum(n[act] + 1, 3)
        start = now.copy()
        moved = restart.copy()
        # jumps: the limit of the window steps' geometric sequence
        d1 = h[2, act] - h[1, act]
        s1 = np.linalg.norm(d1, axis=1)
        r = s1 / np.maximum(np.linalg.norm(h[1, act] - h[0, act], axis=1), 1e-9)
        jump = ~restart & (n[act] >= 3) & (r > JUMP_RATIO[0]) & (r < JUMP_RATIO[1]) & (s1 > JUMP_MIN_STEP)
        if jump.any():
            f = np.minimum(r[jump] / (1.0 - r[jump]), JUMP_FACTOR)
            start[jump] = now[jump] + f[:, None] * d1[jump]
            moved |= jump
        if restart.any():
            ri = act[restart]
            base = now[restart]
            older = self.best_err[ri] < self.err[ri]  # an earlier attempt was better: restart from it
            if older.any():
                kept = np.zeros((int(older.sum()), crowd.rig.n_dof), np.float32)
                k.read_angles(ra["kind"], ra["axes"], ra["dof_start"], self.best_rot, which[restart][older], kept)
                base[older] = kept
            lo, hi = self.lo, self.hi
            base = np.where(np.abs(base - lo) < AT_LIMIT, lo + PULL, np.where(np.abs(base - hi) < AT_LIMIT,
                                                                             hi - PULL, base))
            kicks = np.stack([_kick(int(c), crowd.rig.n_dof) for c in self.restarts[ri]])
            start[restart] = base + kicks
            self.restarts[ri] += 1
        if not moved.any():
            return act[:0]
        mi = act[moved]
        self._save(mi)
        start = np.clip(start[moved], self.lo, self.hi).astype(np.float32)
        k.write_angles(ra["kind"], ra["axes"], ra["dof_start"], start, mi.astype(np.int32), crowd.local_rot)
        crowd._fk(mi.astype(np.int32))
        h[2, mi] = start
        n[mi] = 1
        return mi

    def _save(self, idx: np.ndarray) -> None:
        """Keep the current pose of the characters idx whose error beats their saved best."""
        from crowd_ik.kernels import fabrik_restart as k

        better = idx[self.err[idx] < self.best_err[idx]]
        if better.size == 0:
            return
        if self.best_rot is None:
            crowd = self.crowd
            self.best_rot = crowd.scratch("fabrik_best_rot", crowd.ti.math.vec4, (crowd.n, crowd.rig.n_joints))
        k.gather_rows(self.crowd.local_rot, better.astype(np.int32), self.best_rot)
        self.best_err[better] = self.err[better]

    def _restore(self, idx: np.ndarray) -> None:
        """Put the saved best pose of the characters idx back (rotations, then FK)."""
        from crowd_ik.kernels import fabrik_restart as k

        which = idx.astype(np.int32)
        k.scatter_rows(self.best_rot, which, self.crowd.local_rot)
        self.crowd._fk(which)
