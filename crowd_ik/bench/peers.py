"""The bench's compiled yardstick: FABRIK and DLS for chains written in numba as a competent user writes them.

One chain per thread (``prange`` over chains), float64 or float32, positions in an (N, J, 3) array, no
SIMD tricks: the bar crowd_ik's kernels must clear, not a strawman. Both solve the bench's chain16
workload (all bones on one chain from the root, one effector at the tip, unlimited ball joints):

- ``fabrik``: Aristidou & Lasenby (2011) algorithm 1 for one chain: while the tip is farther than the
  tolerance from the target, put the tip on the target and walk back to the root keeping bone lengths,
  then pin the root and walk forward.
- ``dls``: damped least squares (Buss 2004, eq. 11) with each ball joint turning about the world axes:
  the tip's Jacobian columns for joint n are ``e_k x (tip - p_n)``, so the 3 x 3 system is
  ``(J J^T + lambda^2 I) y = e``, the step of joint n is ``(tip - p_n) x y`` (that is J^T y), fixed
  damping lambda = 0.1, no error clamp, and each joint's world frame turns by its step.

numba is an optional extra (``pip install -e '.[peers]'``); importing this module without it is fine,
:func:`available` says whether the peers can run.
"""

from __future__ import annotations

import importlib.util
import time

import numpy as np

from crowd_ik.solvers.registry import DLS, FABRIK

DLS_LAMBDA = 0.1


def available() -> bool:
    return importlib.util.find_spec("numba") is not None


def _build():
    import numba as nb

    @nb.njit(parallel=True, cache=True)
    def fabrik(pos, lengths, targets, tol, max_it, iters, err):
        n, J = pos.shape[0], pos.shape[1]
        for c in nb.prange(n):
            p = pos[c]
            bx, by, bz = p[0, 0], p[0, 1], p[0, 2]
            tx, ty, tz = targets[c, 0], targets[c, 1], targets[c, 2]
            it = 0
            while True:
                dx, dy, dz = p[J - 1, 0] - tx, p[J - 1, 1] - ty, p[J - 1, 2] - tz
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                if d <= tol or it >= max_it:
                    break
                p[J - 1, 0], p[J - 1, 1], p[J - 1, 2] = tx, ty, tz
                for j in range(J - 2, -1, -1):  # backward: from the target to the root
                    ux, uy, uz = p[j, 0] - p[j + 1, 0], p[j, 1] - p[j + 1, 1], p[j, 2] - p[j + 1, 2]
                    s = lengths[j] / np.sqrt(ux * ux + uy * uy + uz * uz)
                    p[j, 0], p[j, 1], p[j, 2] = p[j + 1, 0] + s * ux, p[j + 1, 1] + s * uy, p[j + 1, 2] + s * uz
                p[0, 0], p[0, 1], p[0, 2] = bx, by, bz
                for j in range(1, J):  # forward: from the pinned root to the tip
                    ux, uy, uz = p[j, 0] - p[j - 1, 0], p[j, 1] - p[j - 1, 1], p[j, 2] - p[j - 1, 2]
                    s = lengths[j - 1] / np.sqrt(ux * ux + uy * uy + uz * uz)
                    p[j, 0], p[j, 1], p[j, 2] = p[j - 1, 0] + s * ux, p[j - 1, 1] + s * uy, p[j - 1, 2] + s * uz
                it += 1
            iters[c] = it
            err[c] = d

    @nb.njit(cache=True)
    def _rodrigues(rx, ry, rz, out):
        """out = the rotation matrix of the rotation vector (rx, ry, rz)."""
        a = np.sqrt(rx * rx + ry * ry + rz * rz)
        c, s = np.cos(a), np.sin(a)
        if a < 1e-12:
            kx, ky, kz, c1 = 0.0, 0.0, 0.0, 0.0
        else:
            kx, ky, kz, c1 = rx / a, ry / a, rz / a, 1.0 - c
        out[0, 0], out[0, 1], out[0, 2] = c + kx * kx * c1, kx * ky * c1 - kz * s, kx * kz * c1 + ky * s
        out[1, 0], out[1, 1], out[1, 2] = ky * kx * c1 + kz * s, c + ky * ky * c1, ky * kz * c1 - kx * s
        out[2, 0], out[2, 1], out[2, 2] = kz * kx * c1 - ky * s, kz * ky * c1 + kx * s, c + kz * kz * c1

    @nb.njit(parallel=True, cache=True)
    def dls(pos, targets, tol, max_it, lam, iters, err):
        n, J = pos.shape[0], pos.shape[1]
        for c in nb.prange(n):
            p = pos[c]
            it = 0
            step = np.empty((J - 1, 3), pos.dtype)
            bone = np.empty((J - 1, 3), pos.dtype)
            m = np.empty((3, 3), pos.dtype)
            rot = np.empty((3, 3), pos.dtype)
            while True:
                ex, ey, ez = targets[c, 0] - p[J - 1, 0], targets[c, 1] - p[J - 1, 1], targets[c, 2] - p[J - 1, 2]
                d = np.sqrt(ex * ex + ey * ey + ez * ez)
                if d <= tol or it >= max_it:
                    break
                # A = J J^T + lambda^2 I = sum over joints of (|r|^2 I - r r^T) + lambda^2 I, r = tip - joint
                a00 = a11 = a22 = lam * lam
                a01 = a02 = a12 = 0.0
                for j in range(J - 1):
                    rx, ry, rz = p[J - 1, 0] - p[j, 0], p[J - 1, 1] - p[j, 1], p[J - 1, 2] - p[j, 2]
                    a00 += ry * ry + rz * rz
                    a11 += rx * rx + rz * rz
                    a22 += rx * rx + ry * ry
                    a01 -= rx * ry
                    a02 -= rx * rz
                    a12 -= ry * rz
                # y = A^-1 e by the adjugate (A is symmetric positive definite)
                c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
                c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
                det = a00 * c00 + a01 * c01 + a02 * c02
                yx = (c00 * ex + c01 * ey + c02 * ez) / det
                yy = (c01 * ex + c11 * ey + c12 * ez) / det
                yz = (c02 * ex + c12 * ey + c22 * ez) / det
                for j in range(J - 1):  # J^T y: joint j turns by r_j x y
                    rx, ry, rz = p[J - 1, 0] - p[j, 0], p[J - 1, 1] - p[j, 1], p[J - 1, 2] - p[j, 2]
                    step[j, 0], step[j, 1], step[j, 2] = ry * yz - rz * yy, rz * yx - rx * yz, rx * yy - ry * yx
                    for u in range(3):
                        bone[j, u] = p[j + 1, u] - p[j, u]
                # joint j's world frame turns by step j, carrying the joints below it: bone k turns by
                # M_k = R_0 R_1 ... R_k, accumulated from the root
                m[:, :] = 0.0
                for u in range(3):
                    m[u, u] = 1.0
                for j in range(J - 1):
                    _rodrigues(step[j, 0], step[j, 1], step[j, 2], rot)
                    for u in range(3):
                        m0, m1, m2 = m[u, 0], m[u, 1], m[u, 2]
                        for v in range(3):
                            m[u, v] = m0 * rot[0, v] + m1 * rot[1, v] + m2 * rot[2, v]
                    for u in range(3):
                        p[j + 1, u] = p[j, u] + m[u, 0] * bone[j, 0] + m[u, 1] * bone[j, 1] + m[u, 2] * bone[j, 2]
                it += 1
            iters[c] = it
            err[c] = d

    return fabrik, dls


_KERNELS: dict = {}


def _kernels():
    if not _KERNELS:
        _KERNELS[FABRIK], _KERNELS[DLS] = _build()
    return _KERNELS


def solve(method: str, start: np.ndarray, targets: np.ndarray, tolerance: float, max_iterations: int,
          dtype=np.float64) -> dict:
    """Solve chains from joint positions `start` (N, J, 3) toward `targets` (N, 3): time, error, iterations."""
    k = _kernels()[method]
    pos = np.array(start, dtype, order="C")  # a copy: the solve moves it
    tg = np.ascontiguousarray(targets, dtype)
    iters = np.zeros(pos.shape[0], np.int32)
    err = np.zeros(pos.shape[0], dtype)
    t0 = time.perf_counter()
    if method == FABRIK:
        lengths = np.linalg.norm(np.diff(pos[0], axis=0), axis=-1).astype(dtype)
        k(pos, lengths, tg, dtype(tolerance), max_iterations, iters, err)
    else:
        k(pos, tg, dtype(tolerance), max_iterations, dtype(DLS_LAMBDA), iters, err)
    return dict(time_s=time.perf_counter() - t0, error=err.astype(np.float64), iterations=iters, positions=pos)


PEER_METHODS = (FABRIK, DLS)  # the solvers that have a numba peer
PEER_RIG = "chain16"              # the workload the peers solve (one chain, one effector)
DTYPES = {"f64": np.float64, "f32": np.float32}


def _peer_inputs(wl) -> tuple[np.ndarray, np.ndarray]:
    """The peers' start (N, J, 3) float64 joint positions and (N, 3) targets for a chain16 workload."""
    from crowd_ik.geometry.fk import forward_kinematics

    start, _ = forward_kinematics(wl.rig, wl.roots.astype(np.float64), np.zeros(wl.n), wl.rotations())
    return start, wl.targets[:, 0].astype(np.float64)


def _fill(record: dict, wl, runs: dict) -> None:
    """Add the peers' best runs (per dtype name, lists of solve() results) and the ratios to a record."""
    for name, done in runs.items():
        best = min(done, key=lambda x: x["time_s"])
        rate = wl.n / best["time_s"]
        record[f"numba_{name}_solves_per_s"] = rate
        record[f"numba_{name}_success_rate"] = float(np.mean(best["error"] <= wl.tolerance))
        record[f"numba_{name}_mean_iterations"] = float(np.mean(best["iterations"]))
        record[f"vs_numba_{name}"] = record["solves_per_s"] / rate


def _set_threads(threads: int | None) -> None:
    import numba

    if threads is not None:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def qualifies(arch: str, rig: str, solver: str) -> bool:
    """Whether a cell has numba peers timed beside it (chain16 FABRIK and DLS on the CPU)."""
    return arch == "cpu" and rig == PEER_RIG and solver in PEER_METHODS


class Interleaved:
    """The numba peers of one chain16 cell, timed in turn with crowd_ik's repeats of it: call :meth:`run_once`
    after each timed crowd_ik solve (the bench's time_cell does), then :meth:`fill` the cell's record. The ratio
    then compares runs made moments apart in one process, so it does not depend on how the load of a shared
    machine changed between two phases of the run (on a loaded 2-core machine the same crowd_ik code measured
    1.04x the float64 peer at 16,384 characters with the peers timed after all cells, 4.0x interleaved)."""

    def __init__(self, wl, method: str, threads: int | None = None):
        _set_threads(threads)
        self.wl, self.method = wl, method
        self.start, self.targets = _peer_inputs(wl)
        self.runs: dict = {name: [] for name in DTYPES}
        for dtype in DTYPES.values():  # numba's compile (or its cache load), untimed
            solve(method, self.start[:8], self.targets[:8], wl.tolerance, wl.max_iterations, dtype)

    def run_once(self) -> None:
        for name, dtype in DTYPES.items():
            self.runs[name].append(solve(self.method, self.start, self.targets, self.wl.tolerance,
                                         self.wl.max_iterations, dtype))

    def fill(self, record: dict) -> None:
        record["numba_interleaved"] = True
        _fill(record, self.wl, self.runs)


def measure(records: list[dict], make_workload, repeats: int, threads: int | None = None) -> list[dict]:
    """Time the numba peers on the workload of every chain16 FABRIK / DLS record, in float64 and float32, and add
    to each record ``numba_<dtype>_solves_per_s`` (best of `repeats`), ``..._success_rate``,
    ``..._mean_iterations`` and ``vs_numba_<dtype>`` (crowd_ik's solves/s over the peer's). A record that already
    has them (timed by :class:`Interleaved` beside its cell) keeps them. Returns the records it filled or found
    filled. The first call of each kernel (numba's compile) is not timed."""
    _set_threads(threads)
    filled = []
    for r in records:
        if r["rig"] != PEER_RIG or r["solver"] not in PEER_METHODS:
            continue
        if "numba_f64_solves_per_s" not in r:
            wl = make_workload(PEER_RIG, r["n"])
            start, targets = _peer_inputs(wl)
            runs = {}
            for name, dtype in DTYPES.items():
                solve(r["solver"], start[:8], targets[:8], wl.tolerance, wl.max_iterations, dtype)  # compile
                runs[name] = [solve(r["solver"], start, targets, wl.tolerance, wl.max_iterations, dtype)
                              for _ in range(repeats)]
            _fill(r, wl, runs)
        filled.append(r)
    return filled


def format_table(records: list[dict]) -> str:
    """crowd_ik beside the numba peers, one row per chain16 FABRIK / DLS record."""
    rows = [r for r in records if "numba_f64_solves_per_s" in r]
    if not rows:
        return ""
    head = ("arch", "solver", "N", "crowd_ik/s", "success", "numba f64/s", "success", "vs f64", "numba f32/s",
            "vs f32")
    body = [(r["arch"], r["solver"], f"{r['n']:,}", f"{r['solves_per_s']:,.0f}", f"{100 * r['success_rate']:.1f}%",
             f"{r['numba_f64_solves_per_s']:,.0f}", f"{100 * r['numba_f64_success_rate']:.1f}%",
             f"{r['vs_numba_f64']:.2f}x", f"{r['numba_f32_solves_per_s']:,.0f}", f"{r['vs_numba_f32']:.2f}x")
            for r in rows]
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
    fmt = lambda row: "  ".join(str(c).ljust(w) if i < 2 else str(c).rjust(w)  # noqa: E731
                                for i, (c, w) in enumerate(zip(row, widths)))
    return "\n".join(["chain16 against numba peers (one chain per thread, prange; crowd_ik/bench/peers.py):",
                      fmt(head), fmt(["-" * w for w in widths]), *map(fmt, body)])


def targets(records: list[dict], isa: str) -> list[dict]:
    """The SIMD-lanes issue's goals against the float64 numba peer: FABRIK >= 3x (2x without AVX-512), DLS >= 2x
    (1.5x), each at the largest N measured."""
    out = []
    goals = {FABRIK: 3.0 if isa == "avx512" else 2.0, DLS: 2.0 if isa == "avx512" else 1.5}
    for arch in dict.fromkeys(r["arch"] for r in records):
        for solver, goal in goals.items():
            mine = [r for r in records if r["arch"] == arch and r["solver"] == solver and "vs_numba_f64" in r]
            if mine:
                top = max(mine, key=lambda r: r["n"])
                out.append(dict(name=f"chain16 {solver} vs the float64 numba peer ({isa})", arch=arch, n=top["n"],
                                goal=f">= {goal:g}x", unit="x", value=top["vs_numba_f64"],
                                met=bool(top["vs_numba_f64"] >= goal)))
    return out
