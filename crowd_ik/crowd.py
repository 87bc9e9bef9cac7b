"""Crowd: N characters of one rig in Taichi ndarrays, posed by batched FK and solved by batched IK.

All state is allocated once in the constructor. Kernels work relative to each character's root, so
a batch gives the same result as the same characters solved one at a time, wherever they stand.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from crowd_ik import runtime
from crowd_ik.checks import as_array as _as_array, is_number, positive_int as _positive_int
from crowd_ik.prepared import prepared
from crowd_ik.rig import MAX_EXTENT, Rig
from crowd_ik.solvers import ccd, dls, fabrik_restart, poles as pole_hints
from crowd_ik.solvers.bundles import SolveBuffers
from crowd_ik.solvers.errors import effector_rotation_error, measured
from crowd_ik.solvers.registry import CCD, DEFAULT as DEFAULT_METHOD, DLS, FABRIK, METHODS
from crowd_ik.solvers.request import SolveRequest, check_request

# Bytes of Taichi state per joint and per DOF of one character (positions, rotations, scratch).
_BYTES_PER_JOINT = 4 * (3 + 4 + 4 + 3 + 3 + 1)
_BYTES_PER_DOF = 4 * 4


class Status(enum.IntEnum):
    """Outcome of a solve per character, in order of precedence."""

    CONVERGED = 0
    UNREACHABLE = 1
    STALLED = 2
    MAX_ITERATIONS = 3


@dataclass(frozen=True)
class SolveReport:
    """Per-character result of :meth:`Crowd.solve`."""

    error: np.ndarray  # (N,) float32, metres: max over effectors of |effector - target|
    iterations: np.ndarray  # (N,) int32: updates applied
    status: np.ndarray  # (N,) int8 of Status
    method: str = DEFAULT_METHOD
    # (N,) float32 radians from the final pose: max over effectors with an axis (orientation) target of the angle
    # between its world axis and the target; 0 for a character with none (solvers/errors.py)
    rotation_error: np.ndarray | None = None

    @property
    def converged(self) -> np.ndarray:
        return self.status == Status.CONVERGED

    def summary(self) -> dict:
        counts = {s.name.lower(): int(np.count_nonzero(self.status == s)) for s in Status}
        turn = self.rotation_error if self.rotation_error is not None else np.zeros(1)
        return dict(method=self.method, n=int(self.error.size), mean_error=float(self.error.mean()),
                    max_error=float(self.error.max()), max_rotation_error=float(turn.max()),
                    mean_iterations=float(self.iterations.mean()), **counts)


def grid_positions(n: int, spacing: float, dim: int) -> np.ndarray:
    """(n, dim) roots on a centred square grid: the x-z plane in 3D (y = 0), the x-y plane in 2D."""
    cols = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / cols))
    idx = np.arange(n)
    u = (idx % cols - (cols - 1) / 2.0) * spacing
    v = (idx // cols - (rows - 1) / 2.0) * spacing
    out = np.zeros((n, dim), np.float32)
    out[:, 0] = u
    out[:, 2 if dim == 3 else 1] = v
    return out


class Crowd:
    """N characters of one rig: roots, joint rotations, world transforms, and batched solvers."""

    def __init__(self, rig: Rig, n: int = 1, seed: int = 0, spacing: float = 1.0):
        if not isinstance(rig, Rig):
            raise ValueError(f"rig: expected a crowd_ik.Rig (got {type(rig).__name__})")
        self.n = _positive_int(n, "n")
        need = self.bytes_per_character(rig) * self.n
        if need > 16 * 2**30:
            raise ValueError(f"n: {self.n} characters of {rig.name} need about {need / 2**30:.1f} GiB (limit 16 GiB)")
        if not is_number(spacing) or not (math.isfinite(spacing) and 0 <= spacing * math.sqrt(self.n) <= MAX_EXTENT):
            raise ValueError(f"spacing: expected a number >= 0 that keeps the grid within {MAX_EXTENT:g} m "
                             f"(got {spacing!r})")
        self.rig, self.seed, self.dim = rig, int(seed), rig.dim
        runtime.ensure_init()
        import taichi as ti

        self.ti = ti
        J, D, E, N = rig.n_joints, rig.n_dof, rig.n_effectors, self.n
        self.rig_arrays = {}
        for key, value in rig.arrays.items():
            dtype = ti.i32 if value.dtype == np.int32 else ti.f32
            shape = value.shape
            if key in ("offset", "eff_axis"):
                arr = ti.ndarray(ti.math.vec3, shape=shape[:1])
            elif key == "bone":
                arr = ti.ndarray(ti.math.vec4, shape=shape[:1])
            elif key == "axes":
                arr = ti.ndarray(ti.math.vec3, shape=shape[:2])
            else:
                arr = ti.ndarray(dtype, shape=shape)
            arr.from_numpy(value)
            self.rig_arrays[key] = arr
        vec3, vec4 = ti.math.vec3, ti.math.vec4
        self.root_pos = np.zeros((N, 3), np.float32)  # host arrays, as the solvers' inputs below
        self.root_yaw = np.zeros(N, np.float32)
        self.local_rot = ti.ndarray(vec4, shape=(N, J))
        self.world_pos = ti.ndarray(vec3, shape=(N, J))
        self.world_rot = ti.ndarray(vec4, shape=(N, J))
        self._angles = np.zeros((N, max(D, 1)), np.float32)  # set_angles' and angles()' host buffer
        self.buffers = SolveBuffers(N, E)  # the solvers' inputs and outputs, reused by every solve
        self._scratch: dict[str, object] = {}
        self._every = np.arange(N, dtype=np.int32)
        self._roots_host = self._yaw_host = None  # the roots as last set (set_roots redoes FK of the moved ones)
        self._base = np.zeros((N, 3), np.float32)  # the root joints' world positions (_set_base)
        self.set_roots(grid_positions(N, float(spacing), self.dim))
        self.set_angles(np.zeros(D, np.float32))

    # ---------------------------------------------------------------- sizes
    @staticmethod
    def bytes_per_character(rig: Rig) -> int:
        """Approximate bytes of Taichi state one character of ``rig`` needs (solver scratch included)."""
        E = rig.n_effectors
        return _BYTES_PER_JOINT * rig.n_joints + _BYTES_PER_DOF * rig.n_dof + 4 * (3 + 3 + 1) * E + 4 * 4

    def scratch(self, name: str, dtype, shape: tuple):
        """A named solver scratch ndarray, allocated on first use and kept (solvers reuse it each call)."""
        arr = self._scratch.get(name)
        if arr is None or tuple(arr.shape) != tuple(shape):
            arr = self.ti.ndarray(dtype, shape=shape)
            self._scratch[name] = arr
        return arr

    def constants(self, names: tuple[str, ...], compute) -> tuple:
        """Named solver constants (arrays that depend on the rig, or on a pattern the name spells out), uploaded once:
        on first use compute() gives their values in the order of names (int32 arrays as i32, others as f32); later
        calls return the uploaded ndarrays without calling it."""
        if any(self._scratch.get(name) is None for name in names):
            for name, value in zip(names, compute()):
                dtype = self.ti.i32 if value.dtype == np.int32 else self.ti.f32
                self.scratch(name, dtype, value.shape).from_numpy(value)
        return tuple(self._scratch[name] for name in names)

    # ---------------------------------------------------------------- state in
    def set_roots(self, positions, yaw=None) -> None:
        """Place the characters: positions (N, dim) world metres; yaw (N,) radians about +y (3D only)."""
        pos = _as_array(positions, "positions", (self.n, self.dim), limit=MAX_EXTENT)
        full = np.zeros((self.n, 3), np.float32)
        full[:, : self.dim] = pos
        if yaw is not None and self.dim == 2:
            raise ValueError("yaw: planar (dim=2) characters have no yaw")
        yaw_arr = np.zeros(self.n, np.float32) if yaw is None else _as_array(yaw, "yaw", (self.n,))
        np.copyto(self.root_pos, full)
        np.copyto(self.root_yaw, yaw_arr)
        self._set_base()
        # FK of the characters whose root moved or turned (the others' world pose already follows their
        # rotations: every solver and setter keeps it so); in the game a step moves a few percent of them
        moved = None
        if self._roots_host is not None:
            moved = np.flatnonzero(np.any(full != self._roots_host, axis=1) | (yaw_arr != self._yaw_host))
        self._roots_host, self._yaw_host = full, self.root_yaw.copy()
        if moved is None or 2 * moved.size > self.n:
            self._fk()
        elif moved.size:
            self._fk(moved.astype(np.int32))

    def _set_base(self) -> None:
        """Host copy of the root joints' world positions (they move in a solve only with root_weight): the
        UNREACHABLE test and the free root's sub-base rule read it."""
        # kept in one buffer: the root shift's launch is prepared on it (crowd_ik/prepared.py)
        np.copyto(self._base, self.rig.root_joints(self.root_pos, self.root_yaw), casting="same_kind")

    def _roots_moved(self) -> None:
        """After a solve moved root_pos in place (root_weight): what set_roots derives from the roots."""
        self._set_base()
        self._roots_host = self.root_pos.copy()

    def set_angles(self, a) -> None:
        """Set every joint angle: a (N, DOF) or (DOF,) radians; zeros = the rest pose."""
        D = self.rig.n_dof
        arr = _as_array(a, "angles", (self.n, D))
        from crowd_ik.kernels import fk

        self._angles[:, :D] = arr
        ra = self.rig_arrays
        prepared(fk.angles_to_rotations)(ra["kind"], ra["axes"], ra["dof_start"], self._angles, self.local_rot,
                                         self._serial_fk())
        self._fk()

    def set_rotations(self, q) -> None:
        """Set local joint rotations directly: q (N, J, 4) unit quaternions (x, y, z, w)."""
        arr = _as_array(q, "rotations", (self.n, self.rig.n_joints, 4))
        norms = np.linalg.norm(arr, axis=-1, keepdims=True)
        if np.any(norms < 1e-6):
            raise ValueError("rotations: quaternions must be non-zero")
        self.local_rot.from_numpy((arr / norms).astype(np.float32))
        self._fk()

    def _fk(self, which: np.ndarray | None = None) -> None:
        """World pose from the rotations and roots: of every character, or of the characters `which` (K,) int32."""
        from crowd_ik.kernels import fk

        ra = self.rig_arrays
        if which is None:  # every character: the crowd's own arrays, a prepared launch
            prepared(fk.fk_kernel)(ra["parent"], ra["offset"], self.root_pos, self.root_yaw, self.local_rot,
                                   self.world_pos, self.world_rot, self._every, self.rig.n_joints, self._serial_fk())
            return
        fk.forward_kinematics(ra["parent"], ra["offset"], self.root_pos, self.root_yaw, self.local_rot,
                              self.world_pos, self.world_rot, which, self.rig.n_joints)

    def _serial_fk(self) -> bool:
        """Whether a per-joint launch over the whole crowd (FK, angle conversions) runs on the launching thread."""
        from crowd_ik.kernels.serial_loops import JOINT, serial_for

        return serial_for(self.n * self.rig.n_joints, JOINT)

    # ---------------------------------------------------------------- state out
    def angles(self) -> np.ndarray:
        """(N, DOF) float32 radians (ball joints: intrinsic XYZ Euler)."""
        from crowd_ik.kernels import fk

        ra = self.rig_arrays
        prepared(fk.rotations_to_angles)(ra["kind"], ra["axes"], ra["dof_start"], self.local_rot, self._angles,
                                         self._serial_fk())
        return self._angles[:, : self.rig.n_dof].copy()

    def rotations(self) -> np.ndarray:
        """(N, J, 4) float32 local joint rotations (x, y, z, w)."""
        return self.local_rot.to_numpy()

    def world_rotations(self) -> np.ndarray:
        """(N, J, 4) float32 world rotations of the joints' frames."""
        return self.world_rot.to_numpy()

    def roots(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (N, dim), yaw (N,))."""
        return self.root_pos[:, : self.dim].copy(), self.root_yaw.copy()

    def joint_positions(self) -> np.ndarray:
        """(N, J, dim) float32 world positions of every joint."""
        return self.world_pos.to_numpy()[..., : self.dim]

    def effector_positions(self) -> np.ndarray:
        """(N, E, dim) float32 world positions of the effectors."""
        return self.joint_positions()[:, self.rig.arrays["eff_joint"]]

    def jacobian(self, ball_mode: str = "euler") -> np.ndarray:
        """(N, 6E, DOF) analytic Jacobian at the current pose: per effector 3 position then 3 orientation rows.

        ball_mode "euler": columns are d/d(Euler XYZ angles) of ball joints; "quaternion": d/d(rotation
        about the world x, y, z axes), the update a quaternion solver applies.
        """
        if ball_mode not in ("euler", "quaternion"):
            raise ValueError(f"ball_mode: expected 'euler' or 'quaternion' (got {ball_mode!r})")
        from crowd_ik.kernels import jacobian

        ra = self.rig_arrays
        out = self.scratch("jacobian", self.ti.f32, (self.n, 6 * self.rig.n_effectors, max(self.rig.n_dof, 1)))
        jacobian.compute_jacobian(ra["parent"], ra["kind"], ra["axes"], ra["dof_start"], ra["eff_joint"],
                                  self.root_yaw, self.local_rot, self.world_pos, self.world_rot,
                                  0 if ball_mode == "euler" else 1, out)
        return out.to_numpy()[:, :, : self.rig.n_dof]

    # ---------------------------------------------------------------- solve
    def solve(self, targets, method: str = DEFAULT_METHOD, max_iterations: int = 20, tolerance: float = 1e-3,
              weights=None, orientations=None, rest_weight: float = 0.0, velocity_weight: float = 0.0,
              damping=None, joint_weights=None, balance_weight: float = 0.0, poles=None,
              rotation_tolerance: float = 1e-2, rotations=None, rotation_weights=None,
              root_weight=None) -> SolveReport:
        """Move every character's effectors toward ``targets`` (N, E, dim) world; warm-starts from the current pose.

        weights (E,) or (N, E) >= 0; orientations (N, E, 3) world directions for the effectors' local
        axes (or None); method "fabrik" | "dls" | "ccd". rest_weight, velocity_weight, damping and
        joint_weights (DOF,) shape the DLS objective. balance_weight >= 0 adds static balance to it:
        balance_weight * |(c - s)_xz|^2, c the centre of mass (bones' midpoints, mass ~ length x
        radius^2), s the mean of the foot effectors (names "foot..."; a rig without them refuses
        balance_weight > 0), and with it the solve also waits for |(c - s)_xz| <= tolerance (see
        crowd_ik/reference/dls.py). Balance is a DLS objective: FABRIK and CCD ignore it. The result
        stays in the crowd.

        poles (N, E, dim) world points (a row of NaN: none; 3D rigs): after the solve the limb above each
        such effector swivels about the line from its pivot to the effector so that its bend joint turns
        toward the pole (kernels/poles.py). CONVERGED needs error <= tolerance and, with orientation targets,
        rotation_error <= rotation_tolerance (radians); orientations accept NaN rows as zero rows (none).

        rotations (N, E, 4) unit quaternions x y z w (a row of NaN: none; 3D rigs): rotations[n, e] is the target
        of world_rotations()[n, eff_joint[e]], weighted by rotation_weights (E,) or (N, E) >= 0 (default ones)
        apart from the positions; report.rotation_error counts 2 acos |<q, q_target>| for them.

        rest_weight, velocity_weight and balance_weight act in the null space of the targets (task priority):
        they choose among the poses that reach the targets and never hold a reachable target off.

        root_weight None (default): the roots stay. A number w > 0 frees each root's translation (the first dim
        components), and roots() returns where the solve moved them; no character is then UNREACHABLE. DLS
        solves it as 3 more unknowns weighted w like joint_weights (bigger moves more); FABRIK and CCD first
        move the root by the sub-base rule of kernels/root_shift.py (by min(w, 1) x the weighted mean of how
        far targets lie beyond their chains' reach), then solve from there with it fixed.

        FABRIK on a rig with joint limits, with more than 8 iterations and no orientation or rotation targets, runs
        in windows of 8 between which stalled characters restart and slowly converging ones jump ahead
        (solvers/fabrik_restart.py); each keeps its best pose, and report.iterations counts every update, restarts
        included, never more than max_iterations.
        """
        req = check_request(self.rig, self.n, targets, method, max_iterations, tolerance, weights, orientations,
                            rest_weight, velocity_weight, damping, joint_weights, balance_weight, poles,
                            rotation_tolerance=rotation_tolerance, rotations=rotations,
                            rotation_weights=rotation_weights, root_weight=root_weight)
        return self.solve_request(req)

    def solve_request(self, req: SolveRequest, report: bool = True) -> SolveReport | None:
        """`solve` of a SolveRequest that solvers.request.check_request made for this crowd (solve's arguments,
        checked), perhaps refilled in place since (solvers.request.refill): nothing is checked again. For callers
        that solve the same kind of request every step (the game). report=False skips the report (its rotation
        errors read the pose back) and returns None."""
        if req.poles is not None and self.dim == 2:
            raise ValueError("poles: a planar (dim=2) rig bends in its plane; poles need a 3D rig")
        self.buffers.load(req)
        if req.root_weight is not None and req.method != DLS:
            self._shift_roots(req)
        SOLVERS[req.method](self, req)
        if req.root_weight is not None and req.method == DLS:  # DLS moved root_pos in place
            self._roots_moved()
        if req.poles is not None:
            pole_hints.apply(self, req)
        return self._report(req) if report else None

    def _shift_roots(self, req: SolveRequest) -> None:
        """FABRIK's and CCD's free root: kernels/root_shift.py moves root_pos, then FK follows."""
        from crowd_ik.kernels import root_shift

        reach = self._scratch.get("root_reach")
        if reach is None:  # the rig's reach, uploaded once per crowd
            reach = self.scratch("root_reach", self.ti.f32, (self.rig.n_effectors,))
            reach.from_numpy(np.asarray(self.rig.reach, np.float32))
        prepared(root_shift.shift_roots)(reach, self.root_pos, self._base, self.buffers.targets, self.buffers.weights,
                                         min(req.root_weight, 1.0), self.dim)
        self._roots_moved()
        self._fk()

    def _effector_rotations(self, cols: np.ndarray) -> np.ndarray:
        """(N, K, 4) float32: world_rot of the effectors cols (K,) read back into a kept host buffer (one launch
        of kernels/report_rows.py; for a small crowd on the launching thread)."""
        from crowd_ik.kernels import report_rows
        from crowd_ik.kernels.serial_loops import JOINT, serial_for

        kept = self.__dict__.setdefault("_report_rows", {})
        key = cols.tobytes()
        rows = kept.get(key)
        if rows is None:  # per set of effectors (a game asks for the same one every step)
            joints = np.ascontiguousarray(self.rig.arrays["eff_joint"][cols], np.int32)
            rows = kept[key] = (joints, np.zeros((self.n, len(cols), 4), np.float32))
        joints, out = rows
        prepared(report_rows.joint_rotations)(self.world_rot, joints, out, serial_for(out.size // 4, JOINT))
        return out

    def _report(self, req: SolveRequest) -> SolveReport:
        """The report of the solve just run: errors, iterations and statuses (kernels/report_rows.py statuses,
        the rule of Status: a character not within both tolerances is UNREACHABLE when a weighted target lies
        beyond Rig.beyond_reach's bound, else STALLED or MAX_ITERATIONS), rotation errors where asked for."""
        from crowd_ik.kernels import report_rows
        from crowd_ik.kernels.serial_loops import CHEAP, serial_for

        b = self.buffers
        if req.orientations is not None or req.rotations is not None:
            cols = np.flatnonzero(measured(req))
            turn = effector_rotation_error(self.rig, self._effector_rotations(cols), req, cols)
        else:
            turn = np.zeros(self.n, np.float32)
        kept = self.__dict__.get("_report_status")
        if kept is None:  # buffers the status launch keeps bound
            kept = self._report_status = (np.zeros(self.n, np.float32), np.zeros(self.n, np.int8),
                                          np.ascontiguousarray(self.rig.reach_bound_sq, np.float64))
        turn_buf, status, bound_sq = kept
        np.copyto(turn_buf, turn, casting="same_kind")
        prepared(report_rows.statuses)(b.error, turn_buf, req.tolerance, req.rotation_tolerance, b.targets, b.weights,
                                       self._base, bound_sq, b.stalled, int(req.root_weight is not None), status,
                                       serial_for(self.n, CHEAP))
        return SolveReport(error=b.error.copy(), iterations=b.iterations.copy(), status=status.copy(),
                           method=req.method, rotation_error=turn)


# one adapter per method (crowd_ik/solvers/); FABRIK's solves of more than a window of iterations on a limited rig
# run in windows with restarts (solvers/fabrik_restart.py), the others are solvers/fabrik.solve
SOLVERS = {FABRIK: fabrik_restart.solve, DLS: dls.solve, CCD: ccd.solve}


__all__ = ["Crowd", "SolveReport", "Status", "METHODS", "grid_positions"]
