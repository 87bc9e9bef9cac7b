"""FABRIK on a joint-limited rig solved in windows of iterations, with restarts and extrapolated starts (issue 15).

FABRIK with joint limits converges linearly, and near a limit it can stop at a pose that is not a solution: from
rest to in-limit poses of the humanoid 8 % of the characters stalled or crept to max_iterations. A solve with more
than WINDOW iterations therefore runs its reachable characters in windows of WINDOW iterations, and at the end of a
window each character that is not yet within tolerance either
- goes on from where it stands: after a fast window (one that left at most SLOW of the error it started with; the
  first window counts as slow), inside the same launch;
- restarts, when it stalled, RESTART_LEFT iterations are left, it is within RESTART_NEAR tolerances of
  its targets and has restarted fewer than MAX_RESTARTS times: from the best pose it has had, the
  joint angles that sit at a limit pulled PULL rad inside it, and from the second restart on a kick of KICK rad
  (a fixed sequence of normal draws, the k-th restart of every character takes the k-th: no character depends on
  another, so a batch solves as its characters one at a time);
- or jumps, when its last three windows were slow and moved its angles by steps d shrinking by a ratio r in
  JUMP_RATIO: to the limit of that geometric sequence (angles + d r / (1 - r), at most JUMP_FACTOR d), clipped to
  the limits;
- or gives up (GIVE_UP_*), once it has restarted or jumped, when it is still far from its targets.
The windows are kernels/fabrik.py's fabrik_solve in its windowed mode (recover_each_iteration 2): one launch per
round for the characters listed, each with its own budget (what it has left), a slow window or a stall ending a
character's launch; the host then reads the slow ones' angles and moves the starts (kernels/fabrik_restart.py).
Characters with a target beyond their reach (Crowd's UNREACHABLE rule) get one plain solve of all their
iterations, as without windows, on the joint-limited lanes where fabrik.solve would use them. Every character keeps
the pose with the lowest error it has had. The report counts every update applied, restarts and jumps included,
never more than max_iterations; STALLED means the last attempt stopped improving (or gave up), MAX_ITERATIONS
that it was still improving when the clock ran out. Solves of at most WINDOW iterations (the game's warm
4-iteration frames), rigs without limits, and solves with orientation or rotation targets are solvers/fabrik.solve
unchanged (which may run them on the limited lanes); the windows of the reachable characters always run the
one-character kernel.
"""

from __future__ import annotations

import functools

import numpy as np

from crowd_ik.kernels.serial_loops import JOINT, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, fabrik
from crowd_ik.solvers.ccd import moving_joints
from crowd_ik.solvers.settings import FABRIK_SLOW as SLOW, FABRIK_WINDOW as WINDOW  # noqa: F401 (SLOW: docs, tests)

MAX_RESTARTS = 3  # restarts per character at most
RESTART_NEAR = 20.0  # a stalled character restarts only within this many tolerances of its targets
RESTART_LEFT = 10  # a stalled character restarts only with at least this many iterations left
PULL = 0.3  # rad: how far a restart moves an angle that sits at a limit inside it
KICK = 0.15  # rad: the standard deviation of the restarts' kicks (the first restart has none)
KICK_SEED = 1000  # the k-th restart's kick is np.random.default_rng(KICK_SEED + k).normal(0, KICK, DOF)
JUMP_RATIO = (0.3, 1.0)  # the shrink ratio of the last two window steps that allows a jump
JUMP_FACTOR = 9.0  # a jump is at most this many times the last window's step
JUMP_MIN_STEP = 1e-4  # rad: a last window's step below this makes no jump
AT_LIMIT = 1e-3  # rad: an angle this close to a limit sits at it
# a character that has restarted or jumped gives up (stops, STALLED) when its best pose is more than GIVE_UP_BEST
# tolerances off and it stands more than GIVE_UP_NOW off, or after GIVE_UP_LATE updates with its best more than
# GIVE_UP_LATE_BEST off: on the bench's humanoids (targets that no pose meets) such characters converged 1 in 25
GIVE_UP_BEST, GIVE_UP_NOW = 10.0, 15.0
GIVE_UP_LATE, GIVE_UP_LATE_BEST = 60, 5.0


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


@functools.lru_cache(maxsize=64)
def _kick(k: int, n_dof: int) -> np.ndarray:
    """The k-th restart's kick (DOF,) float32 (zeros for the first); shared, not to be written."""
    if k == 0:
        return np.zeros(n_dof, np.float32)
    return np.random.default_rng(KICK_SEED + k).normal(0.0, KICK, n_dof).astype(np.float32)


class _Rows:
    """A crowd's buffers for the windows' launches, kept across solves so that they are prepared: the listed
    characters, their save flags, their angles, the saved rotations, each character's mode (1: windows) and the
    solver's scratch."""

    def __init__(self, crowd):
        N, D = crowd.n, crowd.rig.n_dof
        self.which = np.zeros(N, np.int32)
        self.save = np.zeros(N, np.int32)
        self.angles = np.zeros((N, D), np.float32)
        self.saved = crowd.scratch("fabrik_saved_rot", crowd.ti.math.vec4, (N, crowd.rig.n_joints))
        self.mode = np.zeros(N, np.int32)  # 1: solved in windows (reachable), 0: plainly
        self.work = crowd.scratch("fabrik_pos", crowd.ti.math.vec3, (N, crowd.rig.n_joints))
        self.acc_w = crowd.scratch("fabrik_w", crowd.ti.f32, (N, crowd.rig.n_joints))
        self.move = moving_joints(crowd.rig)


class _Windows:
    """One windowed solve: per character its iterations used, current error, last window's stall flag, the best
    earlier pose (saved rotations and its error), its restarts, and its last three window ends' angles."""

    def __init__(self, crowd, req):
        self.crowd, self.req = crowd, req
        rig, N = crowd.rig, crowd.n
        self.n_joints, self.n_dof = rig.n_joints, rig.n_dof
        lo, hi = rig.angle_limits()
        self.lo, self.hi = lo.astype(np.float32), hi.astype(np.float32)
        self.used = np.zeros(N, np.int32)
        self.last = np.zeros(N, np.int32)  # updates of each character's last window
        self.err = np.zeros(N, np.float32)
        self.stalled = np.zeros(N, bool)  # its last solve stalled
        self.slow = np.zeros(N, bool)  # its last solve ended with a slow window
        self.best_err = np.full(N, np.inf, np.float32)  # of the pose saved in rows.saved (inf: none saved)
        self.restarts = np.zeros(N, np.int32)
        self.tried = np.zeros(N, bool)  # restarted or jumped at least once
        self.hist = np.zeros((3, N, self.n_dof), np.float32)  # the last three window ends' angles, oldest first
        self.n_hist = np.zeros(N, np.int32)
        rows = crowd.__dict__.get("_fabrik_rows")
        if rows is None:
            rows = crowd.__dict__["_fabrik_rows"] = _Rows(crowd)
        self.rows = rows

    def run(self) -> None:
        req, b = self.req, self.crowd.buffers
        M, tol = req.max_iterations, req.tolerance
        reachable = self._reachable(b.weights)
        self.rows.mode[:] = reachable  # the unreachable only go on: one plain solve of all their updates
        first = self._plain_on_lanes(reachable)
        # every first window is judged against 0, so slow: its end's angles start the tracking for jumps
        if first.size:
            self._solve(first, np.full(first.size, M, np.int32))
        while True:
            left = M - self.used
            live = self.err > tol
            restart = (live & self.stalled & reachable & (left >= RESTART_LEFT) & (self.restarts < MAX_RESTARTS)
                       & (self.err <= RESTART_NEAR * tol))
            act = np.flatnonzero(live & (left > 0) & (self.slow | restart))
            best = np.minimum(self.best_err[act], self.err[act])
            give_up = self.tried[act] & (((best > GIVE_UP_BEST * tol) & (self.err[act] > GIVE_UP_NOW * tol))
                                         | ((self.used[act] >= GIVE_UP_LATE) & (best > GIVE_UP_LATE_BEST * tol)))
            if give_up.any():
                self.stalled[act[give_up]] = True
                act = act[~give_up]
            if act.size == 0:
                break
            # a solve that passed a fast window's end (more than one window) starts the slow windows' count afresh
            self.n_hist[act[self.last[act] > WINDOW]] = 0
            moved = self._between(act, restart[act])
            self._solve(act, left[act])
            # a moved start already within tolerance got no update, so no clamp to the limits: undo the move
            undo = moved[self.last[moved] == 0]
            if undo.size:
                self._put_back(undo)
                self.err[undo] = self.best_err[undo]
                self.stalled[undo] = True
        back = np.flatnonzero(self.best_err < self.err)
        if back.size:
            self._put_back(back)
            self.err[back] = self.best_err[back]
        np.copyto(b.error, self.err)
        np.copyto(b.iterations, self.used)
        np.copyto(b.stalled, (self.err > tol) & self.stalled, casting="unsafe")

    def _plain_on_lanes(self, reachable: np.ndarray) -> np.ndarray:
        """The unreachable characters' plain solve on the joint-limited lanes (kernels/fabrik_limited_lanes.py), the
        reachable ones' weights zeroed for that launch (they do no iterations there), when fabrik.lane_active says
        the lanes reproduce the request; they are most of a cold crowd solve's updates (the bench's humanoids: two
        thirds of the characters, 70 % of the updates). Returns the characters left for the windows' first launch:
        the reachable ones, or all of them when the lanes do not apply."""
        crowd, req, b = self.crowd, self.req, self.crowd.buffers
        if reachable.all():
            return np.arange(crowd.n)
        keep = b.weights[reachable]
        b.weights[reachable] = 0.0
        try:
            active = fabrik.lane_active(crowd, req)
            if active is not None:
                fabrik.solve_limited(crowd, active, req.max_iterations, req.tolerance)
        finally:
            b.weights[reachable] = keep
        if active is None:
            return np.arange(crowd.n)
        far = np.flatnonzero(~reachable)
        self.used[far] = b.iterations[far]
        self.err[far] = b.error[far]
        self.stalled[far] = b.stalled[far] == 1
        return np.flatnonzero(reachable)

    def _solve(self, act: np.ndarray, budget: np.ndarray) -> None:
        """One launch of kernels/fabrik.py's fabrik_solve in its windowed mode for the characters act (K,), budget
        (K,) updates each: the reachable in windows that go on while fast, the others plainly; the rest untouched."""
        from crowd_ik.kernels import fabrik as k

        crowd, rows, b = self.crowd, self.rows, self.crowd.buffers
        b.iterations.fill(0)
        b.iterations[act] = budget
        b.stalled[act] = rows.mode[act]
        b.error[act] = self.err[act]  # the first window's reference: the error before it (0 before the first)
        prepared(k.fabrik_solve)(
            *bundles.limited_rig(crowd), *bundles.pose(crowd), *bundles.goal(crowd), rows.work, rows.acc_w,
            self.req.max_iterations, self.req.tolerance, 2, 0, *bundles.rotation_goal(crowd), rows.move, 0.0, 0,
            *bundles.result(crowd))
        self.last[act] = b.iterations[act]
        self.used[act] += self.last[act]
        self.err[act] = b.error[act]
        code = b.stalled[act]
        self.stalled[act] = code == 1
        self.slow[act] = code == 2

    def _reachable(self, weights: np.ndarray) -> np.ndarray:
        """(N,) bool: no positively weighted target beyond its chain's reach from the root joint (Crowd._report's
        UNREACHABLE test; all with a free root). Only these restart or jump: the others cannot converge."""
        crowd, b = self.crowd, self.crowd.buffers
        if self.req.root_weight is not None:
            return np.ones(crowd.n, bool)
        return ~np.any(crowd.rig.beyond_reach(b.targets, crowd._base) & (weights > 0), axis=1)

    def _read(self, rotations, idx: np.ndarray) -> np.ndarray:
        """(K, D) angles of the characters idx (K,) from rotations (N, J) (the crowd's, or the saved ones)."""
        from crowd_ik.kernels import fabrik_restart as k

        ra, rows, K = self.crowd.rig_arrays, self.rows, idx.size
        rows.which[:K] = idx
        prepared(k.read_angles)(ra["kind"], ra["axes"], ra["dof_start"], rotations, rows.which, K, rows.angles,
                                serial_for(K * self.n_joints, JOINT))
        return rows.angles[:K].copy()

    def _between(self, act: np.ndarray, restart: np.ndarray) -> np.ndarray:
        """The reachable characters act (K,) before their next window: restart (K,) bool ones restart, the others
        go on or jump. Returns the characters given a new start (restarted or jumped)."""
        now = self._read(self.crowd.local_rot, act)
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
                base[older] = self._read(self.rows.saved, ri[older])
            lo, hi = self.lo, self.hi
            base = np.where(np.abs(base - lo) < AT_LIMIT, lo + PULL, np.where(np.abs(base - hi) < AT_LIMIT,
                                                                             hi - PULL, base))
            start[restart] = base + np.stack([_kick(int(c), self.n_dof) for c in self.restarts[ri]])
            self.restarts[ri] += 1
        if not moved.any():
            return act[:0]
        mi = act[moved]
        self.tried[mi] = True
        start = np.clip(start[moved], self.lo, self.hi)
        self._write(mi, start)
        h[2, mi] = start
        n[mi] = 1
        return mi

    def _write(self, idx: np.ndarray, start: np.ndarray) -> None:
        """Start the characters idx (K,) from the angles start (K, D), first saving the current pose of those whose
        error beats their saved best."""
        from crowd_ik.kernels import fabrik_restart as k

        crowd, ra, rows, K = self.crowd, self.crowd.rig_arrays, self.rows, idx.size
        better = self.err[idx] < self.best_err[idx]
        self.best_err[idx[better]] = self.err[idx[better]]
        rows.which[:K], rows.save[:K], rows.angles[:K] = idx, better, start
        prepared(k.write_starts)(ra["parent"], ra["offset"], ra["kind"], ra["axes"], ra["dof_start"], crowd.root_pos,
                                 crowd.root_yaw, rows.angles, rows.which, rows.save, K, rows.saved, crowd.local_rot,
                                 crowd.world_pos, crowd.world_rot, self.n_joints, serial_for(K * self.n_joints, JOINT))

    def _put_back(self, idx: np.ndarray) -> None:
        """Put the saved best pose of the characters idx (K,) back (rotations, then FK)."""
        from crowd_ik.kernels import fabrik_restart as k

        crowd, ra, rows, K = self.crowd, self.crowd.rig_arrays, self.rows, idx.size
        rows.which[:K] = idx
        prepared(k.put_back)(ra["parent"], ra["offset"], crowd.root_pos, crowd.root_yaw, rows.saved, rows.which, K,
                             crowd.local_rot, crowd.world_pos, crowd.world_rot, self.n_joints,
                             serial_for(K * self.n_joints, JOINT))
