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
from crowd_ik.checks import (
    MAX_ITERATIONS, as_array as _as_array, is_number, non_negative as _non_negative, positive_int as _positive_int,
)
from crowd_ik.rig import MAX_EXTENT, Rig
from crowd_ik.solvers.registry import DEFAULT as DEFAULT_METHOD, METHODS

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

    @property
    def converged(self) -> np.ndarray:
        return self.status == Status.CONVERGED

    def summary(self) -> dict:
        counts = {s.name.lower(): int(np.count_nonzero(self.status == s)) for s in Status}
        return dict(method=self.method, n=int(self.error.size), mean_error=float(self.error.mean()),
                    max_error=float(self.error.max()), mean_iterations=float(self.iterations.mean()), **counts)


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

        self._ti = ti
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
        self._angles = ti.ndarray(ti.f32, shape=(N, max(D, 1)))
        # Solver inputs and outputs, reused by every solve: host arrays that the kernels take as they are (on
        # the CPU without a copy; on a GPU Taichi copies them around the launch, as from_numpy would). A copy
        # into a ti.ndarray cost 0.8 ms per (10,000, 5, 3) array.
        self._targets = np.zeros((N, E, 3), np.float32)
        self._orient = np.zeros((N, E, 3), np.float32)
        self._orient_zero = True  # True while self._orient holds zeros
        self._weights = np.zeros((N, E), np.float32)
        self._error = np.zeros(N, np.float32)
        self._iters = np.zeros(N, np.int32)
        self._stalled = np.zeros(N, np.int32)
        self._scratch: dict[str, object] = {}
        self._every = np.arange(N, dtype=np.int32)
        self._roots_host = self._yaw_host = None  # the roots as last set (set_roots redoes FK of the moved ones)
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
            arr = self._ti.ndarray(dtype, shape=shape)
            self._scratch[name] = arr
        return arr

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
        # host copy of the root joints' world positions (they never move in a solve): the UNREACHABLE test
        off = self.rig.arrays["offset"][0].astype(np.float64)
        c, s = np.cos(yaw_arr), np.sin(yaw_arr)
        self._base = (full + np.stack([c * off[0] + s * off[2], np.full_like(c, off[1]), -s * off[0] + c * off[2]],
                                      -1)).astype(np.float32)
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

    def set_angles(self, a) -> None:
        """Set every joint angle: a (N, DOF) or (DOF,) radians; zeros = the rest pose."""
        D = self.rig.n_dof
        arr = _as_array(a, "angles", (self.n, D))
        from crowd_ik.kernels import fk

        if D == 0:
            arr = np.zeros((self.n, 1), np.float32)
        self._angles.from_numpy(arr)
        ra = self.rig_arrays
        fk.angles_to_rotations(ra["kind"], ra["axes"], ra["dof_start"], self._angles, self.local_rot)
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
        if which is None:
            which = self._every
        fk.forward_kinematics(ra["parent"], ra["offset"], self.root_pos, self.root_yaw, self.local_rot,
                              self.world_pos, self.world_rot, which, self.rig.n_joints)

    # ---------------------------------------------------------------- state out
    def angles(self) -> np.ndarray:
        """(N, DOF) float32 radians (ball joints: intrinsic XYZ Euler)."""
        from crowd_ik.kernels import fk

        ra = self.rig_arrays
        fk.rotations_to_angles(ra["kind"], ra["axes"], ra["dof_start"], self.local_rot, self._angles)
        return self._angles.to_numpy()[:, : self.rig.n_dof].copy()

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
        out = self.scratch("jacobian", self._ti.f32, (self.n, 6 * self.rig.n_effectors, max(self.rig.n_dof, 1)))
        jacobian.compute_jacobian(ra["parent"], ra["kind"], ra["axes"], ra["dof_start"], ra["eff_joint"],
                                  self.root_yaw, self.local_rot, self.world_pos, self.world_rot,
                                  0 if ball_mode == "euler" else 1, out)
        return out.to_numpy()[:, :, : self.rig.n_dof]

    # ---------------------------------------------------------------- solve
    def solve(self, targets, method: str = DEFAULT_METHOD, max_iterations: int = 20, tolerance: float = 1e-3,
              weights=None, orientations=None, rest_weight: float = 0.0, velocity_weight: float = 0.0,
              damping=None, joint_weights=None, balance_weight: float = 0.0) -> SolveReport:
        """Move every character's effectors toward ``targets`` (N, E, dim) world; warm-starts from the current pose.

        weights (E,) or (N, E) >= 0; orientations (N, E, 3) world directions for the effectors' local
        axes (or None); method "fabrik" | "dls" | "ccd". rest_weight, velocity_weight, damping and
        joint_weights (DOF,) shape the DLS objective. balance_weight >= 0 adds static balance to it:
        balance_weight * |(c - s)_xz|^2, c the centre of mass (bones' midpoints, mass ~ length x
        radius^2), s the mean of the foot effectors (names "foot..."; a rig without them refuses
        balance_weight > 0), and with it the solve also waits for |(c - s)_xz| <= tolerance (see
        crowd_ik/reference/dls.py). Balance is a DLS objective: FABRIK and CCD ignore it. The result
        stays in the crowd.
        """
        if method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)} (got {method!r})")
        max_iterations = _positive_int(max_iterations, "max_iterations", MAX_ITERATIONS)
        if not is_number(tolerance) or not (math.isfinite(tolerance) and tolerance > 0):
            raise ValueError(f"tolerance: expected a positive number (got {tolerance!r})")
        N, E, dim = self.n, self.rig.n_effectors, self.dim
        if np.ndim(targets) == 2 and np.shape(targets) == (E, dim) and N == 1:
            targets = np.asarray(targets)[None]
        tgt = _as_array(targets, "targets", (N, E, dim), limit=MAX_EXTENT)
        if np.shape(targets) != (N, E, dim):
            raise ValueError(f"targets: expected shape {(N, E, dim)} (got {np.shape(targets)})")
        w = np.ones((N, E), np.float32) if weights is None else _as_array(weights, "weights", (N, E))
        if np.any(w < 0):
            raise ValueError(f"weights: must be >= 0 (got {float(w.min())})")
        if not np.any(w > 0):
            raise ValueError("weights: at least one effector needs a positive weight")
        if orientations is not None:
            orient = _as_array(orientations, "orientations", (N, E, 3))
            norms = np.sqrt(np.einsum("nek,nek->ne", orient, orient))
            has = norms > 0
            no_axis = np.nonzero(np.any(has, axis=0) & (self.rig.arrays["eff_has_axis"] == 0))[0]
            if no_axis.size:
                name = self.rig.effector_names[no_axis[0]]
                raise ValueError(f"orientations: effector {name!r} has no local axis to orient (give zeros for it)")
            orient = orient / np.maximum(norms, 1e-30)[..., None]  # zero rows stay zero
        else:
            orient = None
        params = dict(
            rest_weight=_non_negative(rest_weight, "rest_weight"),
            velocity_weight=_non_negative(velocity_weight, "velocity_weight"),
            damping=None if damping is None else _non_negative(damping, "damping"),
            joint_weights=None if joint_weights is None
            else _as_array(joint_weights, "joint_weights", (self.rig.n_dof,)),
            balance_weight=_non_negative(balance_weight, "balance_weight"),
        )
        if params["balance_weight"] > 0 and not any(e.name.startswith("foot") for e in self.rig.effectors):
            raise ValueError("balance_weight: the rig has no foot effectors")
        if params["joint_weights"] is not None and np.any(params["joint_weights"] < 0):
            raise ValueError(f"joint_weights: must be >= 0 (got {float(params['joint_weights'].min())})")
        full = self._targets
        full[..., :dim] = tgt
        np.copyto(self._weights, w)
        if orient is not None:
            np.copyto(self._orient, orient)
        elif not self._orient_zero:
            self._orient.fill(0.0)
        self._orient_zero = orient is None
        launch = getattr(self, f"_solve_{method}")
        launch(max_iterations, float(tolerance), params)
        return self._report(full, w, float(tolerance), method)

    def _report(self, targets: np.ndarray, w: np.ndarray, tolerance: float, method: str) -> SolveReport:
        error = self._error.copy()
        iters = self._iters.copy()
        stalled = self._stalled.astype(bool)
        status = np.full(self.n, Status.CONVERGED, np.int8)
        left = np.flatnonzero(error > tolerance)  # the others converged (in a game step, nearly all of them)
        d = targets[left] - self._base[left, None, :]
        far = np.einsum("nek,nek->ne", d, d) > np.square(self.rig.reach[None, :] * (1 + 1e-6) + 1e-7)
        status[left] = np.where(np.any(far & (w[left] > 0), axis=1), Status.UNREACHABLE,
                                np.where(stalled[left], Status.STALLED, Status.MAX_ITERATIONS))
        return SolveReport(error=error, iterations=iters, status=status, method=method)

    def _solve_fabrik(self, max_iterations: int, tolerance: float, params: dict) -> None:
        if self.rig.constraint_free and self._orient_zero:
            self._solve_fabrik_free(max_iterations, tolerance)
        else:
            self._solve_fabrik_general(max_iterations, tolerance, recover_each_iteration=1)

    def _solve_fabrik_general(self, max_iterations: int, tolerance: float, recover_each_iteration: int) -> None:
        """kernels/fabrik.py: one character per thread, any rig and target; recover_each_iteration 0 only for
        constraint-free rigs without orientation targets (the rotations of the final positions, once)."""
        from crowd_ik.kernels import fabrik

        ra, ti = self.rig_arrays, self._ti
        work = self.scratch("fabrik_pos", ti.math.vec3, (self.n, self.rig.n_joints))
        acc_w = self.scratch("fabrik_w", ti.f32, (self.n, self.rig.n_joints))
        fabrik.fabrik_solve(
            ra["parent"], ra["offset"], ra["kind"], ra["axes"], ra["lo"], ra["hi"], ra["lim_p"], ra["cone"],
            ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"], ra["eff_axis"],
            self.root_pos, self.root_yaw, self.local_rot, self.world_pos, self.world_rot,
            self._targets, self._weights, self._orient, work, acc_w,
            max_iterations, tolerance, recover_each_iteration, int(not self._orient_zero),
            self._error, self._iters, self._stalled,
        )

    def _solve_fabrik_free(self, max_iterations: int, tolerance: float) -> None:
        """FABRIK on a constraint-free rig: characters as SIMD lanes (kernels/fabrik_lanes.py), then the rotations."""
        from crowd_ik.kernels import fabrik_lanes, lane_plan
        from crowd_ik.solvers import settings

        ra, ti, L = self.rig_arrays, self._ti, settings.lanes()
        J, E = self.rig.n_joints, self.rig.n_effectors
        if L == 1:  # CUDA: one character per GPU thread, the general kernel with the rotations recovered once
            self._solve_fabrik_general(max_iterations, tolerance, recover_each_iteration=0)
            return
        LP = lane_plan.pass_lanes(L)
        P = lane_plan.packets(self.n, L)
        V = ti.types.vector(L, ti.f32)
        proposals = [self.scratch(f"fabrik_lanes_{k}", V, (P, J)) for k in ("gx", "gy", "gz", "ga")]
        fabrik_lanes.free_solver(LP, L, lane_plan.capacity(J), lane_plan.capacity(E))(
            ra["parent"], ra["bone"], ra["eff_joint"], self.world_pos, self._targets, self._weights,
            lane_plan.streams(self.n, LP), *proposals, max_iterations, tolerance, self._error, self._iters,
            self._stalled,
        )
        fabrik_lanes.free_recover(L, lane_plan.capacity(J))(
            ra["parent"], ra["offset"], ra["bone"], ra["kind"], ra["child_start"], ra["child_list"], ra["eff_joint"],
            self.root_pos, self.root_yaw, self.local_rot, self.world_pos, self.world_rot, self._targets,
            self._weights, *proposals, min(P, lane_plan.MAX_STREAMS), self._error, self._iters,
        )

    def _solve_dls(self, max_iterations: int, tolerance: float, params: dict) -> None:
        """Damped least squares with LM damping and a joint-limit active set (kernels/dls.py), one launch."""
        from crowd_ik.kernels import dls
        from crowd_ik.solvers.dls_setup import dls_settings
        from crowd_ik.solvers.limits import limit_pseudo_angles

        ra, ti, rig, N = self.rig_arrays, self._ti, self.rig, self.n
        if self._dls_free_applies(params):
            self._solve_dls_free(max_iterations, tolerance, params)
            return
        # rows: 3 per effector, 2 more for each effector with an axis (orientation target), 2 for balance
        D, J = max(rig.n_dof, 1), rig.n_joints
        R = 3 * rig.n_effectors + 2 * int(rig.arrays["eff_has_axis"].sum()) + 2 * int(params["balance_weight"] > 0)
        settings = dls_settings(rig, params["damping"], params["joint_weights"])
        joint_w = np.zeros(D + 1, np.float32)
        joint_w[: rig.n_dof] = 1.0 if params["joint_weights"] is None else params["joint_weights"]
        small = {}  # per-solve settings: a few dozen numbers
        for name, value in (("eff_lim", settings["eff_lim"]), ("joint_w", joint_w), ("jmode", settings["jmode"]),
                            ("lo", settings["lo32"]), ("hi", settings["hi32"]),
                            ("lim_p", limit_pseudo_angles(settings["lo32"], settings["hi32"])),
                            ("com_w", settings["com_w"].astype(np.float32)),
                            ("support_w", settings["support_w"].astype(np.float32))):
            small[name] = self.scratch(f"dls_{name}", ti.i32 if value.dtype == np.int32 else ti.f32, value.shape)
            small[name].from_numpy(value)
        dls.dls_solve(
            ra["parent"], ra["offset"], ra["kind"], small["jmode"], ra["axes"], small["lo"], small["hi"],
            small["lim_p"], ra["cone"], ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"],
            ra["eff_axis"], ra["eff_has_axis"],
            small["eff_lim"], small["joint_w"], small["com_w"], small["support_w"], self.root_pos, self.root_yaw,
            self.local_rot, self.world_pos, self.world_rot, self._targets, self._weights, self._orient,
            self.scratch("dls_rel_pos", ti.math.vec3, (N, J)),
            self.scratch("dls_qwork", ti.math.vec4, (N, dls.N_Q_SLOTS, J)),
            self.scratch("dls_work", ti.f32, (N, dls.N_DOF_SLOTS, D + 1)),
            self.scratch("dls_jac", ti.f32, (N, R, D + 1)), self.scratch("dls_rows", ti.f32, (N, 2, R)),
            self.scratch("dls_sys", ti.f32, (N, R, R)),
            max_iterations, tolerance, settings["damping"], settings["length"],
            params["rest_weight"], params["velocity_weight"], params["balance_weight"], self._error, self._iters,
            self._stalled,
        )

    def _dls_free_applies(self, params: dict) -> bool:
        """Whether dls_solve_free gives this solve: one position effector on a constraint-free rig, no extra terms."""
        return (self.rig.constraint_free and self.rig.n_effectors == 1 and self._orient_zero
                and params["rest_weight"] == 0 and params["velocity_weight"] == 0
                and params["balance_weight"] == 0 and params["joint_weights"] is None)

    def _solve_dls_free(self, max_iterations: int, tolerance: float, params: dict) -> None:
        """DLS of one effector on a constraint-free rig: a closed-form 3 x 3 system, characters as SIMD lanes."""
        from crowd_ik.kernels import dls_lanes, lane_plan
        from crowd_ik.solvers.dls_setup import dls_settings
        from crowd_ik.solvers import settings

        ra, ti, rig = self.rig_arrays, self._ti, self.rig
        dls_cfg = dls_settings(rig, params["damping"])
        on_path_np = np.zeros(rig.n_joints, np.int32)
        path = rig.path_to_root(rig.effectors[0].joint)
        on_path_np[path] = rig.arrays["kind"][path] > 0
        on_path = self.scratch("dls_on_path", ti.i32, (rig.n_joints,))
        on_path.from_numpy(on_path_np)
        eff_lim = self.scratch("dls_eff_lim", ti.f32, dls_cfg["eff_lim"].shape)
        eff_lim.from_numpy(dls_cfg["eff_lim"])
        L = settings.lanes()
        if L == 1:  # CUDA: one character per GPU thread, each pose in local arrays
            from crowd_ik.kernels import dls_free

            dls_free.dls_solve_free(
                ra["parent"], ra["offset"], ra["kind"], on_path, ra["eff_joint"], eff_lim, self.root_pos,
                self.root_yaw, self.local_rot, self.world_pos, self.world_rot, self._targets, self._weights,
                max_iterations, tolerance, dls_cfg["damping"], dls_cfg["length"], self._error, self._iters,
                self._stalled, rig.n_joints,
            )
            return
        # one vector per value (L lanes): 2L ran 12 % faster but took 31 s instead of ~10 s to compile
        dls_lanes.free_solver(L, lane_plan.capacity(rig.n_joints))(
            ra["parent"], ra["offset"], ra["kind"], on_path, ra["eff_joint"], eff_lim, self.root_pos, self.root_yaw,
            self.local_rot, self.world_pos, self.world_rot, self._targets, self._weights,
            lane_plan.streams(self.n, L), max_iterations, tolerance, dls_cfg["damping"], dls_cfg["length"],
            self._error, self._iters, self._stalled,
        )

    def _solve_ccd(self, max_iterations: int, tolerance: float, params: dict) -> None:
        """Cyclic coordinate descent (kernels/ccd.py): one sweep per iteration, deepest joint to the root."""
        from crowd_ik.kernels import ccd

        ra, ti, rig = self.rig_arrays, self._ti, self.rig
        # below[j, e] = 1 where effector e's joint lies in joint j's subtree (j included)
        below_np = np.zeros((rig.n_joints, rig.n_effectors), np.int32)
        for e, eff in enumerate(rig.effectors):
            below_np[rig.path_to_root(eff.joint), e] = 1
        below = self.scratch("ccd_below", ti.i32, below_np.shape)
        below.from_numpy(below_np)
        reach = self.scratch("ccd_reach", ti.f32, (rig.n_effectors,))
        reach.from_numpy(rig.reach.astype(np.float32))
        ccd.ccd_solve(
            ra["parent"], ra["offset"], ra["kind"], ra["axes"], ra["lo"], ra["hi"], ra["lim_p"], ra["cone"],
            ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"], ra["eff_axis"], below, reach,
            self.root_pos, self.root_yaw, self.local_rot, self.world_pos, self.world_rot,
            self._targets, self._weights, self._orient,
            self.scratch("ccd_rel_t", ti.math.vec3, (self.n, rig.n_effectors)),
            self.scratch("ccd_eff_pos", ti.math.vec3, (self.n, rig.n_effectors)),
            max_iterations, tolerance, self._error, self._iters, self._stalled,
        )


__all__ = ["Crowd", "SolveReport", "Status", "METHODS", "grid_positions"]
