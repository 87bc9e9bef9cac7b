"""A solve's arguments checked at the edge: Crowd.solve's inputs turned into what the kernels honour.

Every problem is a ValueError naming the argument and the value (DESIGN "Public API", bounds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crowd_ik.checks import MAX_ITERATIONS, as_array, is_number, non_negative, positive_int
from crowd_ik.rig import MAX_EXTENT, Rig
from crowd_ik.solvers.registry import METHODS


@dataclass
class SolveRequest:
    """One solve: targets (N, E, dim), weights (N, E) float32, orientations (N, E, 3) unit rows or None,
    and the secondary terms (DLS objectives and settings)."""

    method: str
    max_iterations: int
    tolerance: float
    targets: np.ndarray
    weights: np.ndarray
    orientations: np.ndarray | None
    rest_weight: float = 0.0
    velocity_weight: float = 0.0
    damping: float | None = None
    joint_weights: np.ndarray | None = None
    balance_weight: float = 0.0
    poles: np.ndarray | None = None  # (N, E, dim) world points, NaN rows (no pole) kept NaN
    rotation_tolerance: float = 1e-2
    # full rotation targets: (N, E, 4) unit quaternions x y z w (zero rows where none) and their weights (N, E)
    # (0 where none), or None for no rotation target at all
    rotations: np.ndarray | None = None
    rotation_weights: np.ndarray | None = None
    root_weight: float | None = None  # None: the root stays; w > 0: it moves (DLS: 3 unknowns weighted w)

    @property
    def plain(self) -> bool:
        """True when no secondary term shapes the solve (only targets and weights)."""
        return (self.orientations is None and self.rest_weight == 0 and self.velocity_weight == 0
                and self.balance_weight == 0 and self.joint_weights is None and self.poles is None
                and self.rotations is None)


def rows_or_nan(value, name: str, shape: tuple, limit: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(array, has (N, E) bool): a per-effector input of `shape` (N, E, k) whose all-NaN rows mean "none" (they
    come back as zeros); a partly NaN row, an inf or a value beyond `limit` is a ValueError."""
    arr = np.asarray(value)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name}: expected real numbers (got dtype {arr.dtype})")
    try:
        arr = np.array(np.broadcast_to(arr, shape), dtype=np.float64)
    except ValueError:
        raise ValueError(f"{name}: expected shape {shape} (got {np.shape(value)})") from None
    nan = np.isnan(arr)
    if not nan.any():  # every row given (a game's orientations): nothing to sort out
        return as_array(arr, name, shape, limit=limit), np.ones(shape[:-1], bool)
    none, some = nan[..., 0].copy(), nan[..., 0].copy()  # column by column: np.all(axis=-1) of 3 is ~10x slower
    for c in range(1, shape[-1]):
        none &= nan[..., c]
        some |= nan[..., c]
    partly = some & ~none
    if np.any(partly):
        n, e = np.argwhere(partly)[0]
        raise ValueError(f"{name}: row [{n}, {e}] is partly NaN (all NaN means none; got {arr[n, e].tolist()})")
    arr[none] = 0.0
    return as_array(arr, name, shape, limit=limit), ~none


def check_request(rig: Rig, n: int, targets, method, max_iterations, tolerance, weights, orientations,
                  rest_weight, velocity_weight, damping, joint_weights, balance_weight, poles=None,
                  rotation_tolerance=1e-2, rotations=None, rotation_weights=None, root_weight=None) -> SolveRequest:
    """The checked SolveRequest for n characters of `rig`, or a ValueError naming the argument."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)} (got {method!r})")
    max_iterations = positive_int(max_iterations, "max_iterations", MAX_ITERATIONS)
    if not is_number(tolerance) or not (math.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance: expected a positive number (got {tolerance!r})")
    E, dim = rig.n_effectors, rig.dim
    if np.ndim(targets) == 2 and np.shape(targets) == (E, dim) and n == 1:
        targets = np.asarray(targets)[None]
    tgt = as_array(targets, "targets", (n, E, dim), limit=MAX_EXTENT)
    if np.shape(targets) != (n, E, dim):
        raise ValueError(f"targets: expected shape {(n, E, dim)} (got {np.shape(targets)})")
    if weights is None:  # ones: positive wherever there is an effector
        w = np.ones((n, E), np.float32)
        some_positive = w.size > 0
    else:
        w = as_array(weights, "weights", (n, E))
        if np.any(w < 0):
            raise ValueError(f"weights: must be >= 0 (got {float(w.min())})")
        some_positive = bool(np.any(w > 0))
    if not some_positive:
        raise ValueError("weights: at least one effector needs a positive weight")
    orient = None
    if orientations is not None:
        orient, _ = rows_or_nan(orientations, "orientations", (n, E, 3))  # NaN rows as zero rows: none
        norms = np.sqrt(np.einsum("nek,nek->ne", orient, orient))
        no_axis = np.nonzero(np.any(norms > 0, axis=0) & (rig.arrays["eff_has_axis"] == 0))[0]
        if no_axis.size:
            name = rig.effector_names[no_axis[0]]
            raise ValueError(f"orientations: effector {name!r} has no local axis to orient (give zeros for it)")
        orient = orient / np.maximum(norms, 1e-30)[..., None]  # zero rows stay zero
    req = SolveRequest(
        method=method, max_iterations=max_iterations, tolerance=float(tolerance), targets=tgt, weights=w,
        orientations=orient,
        rest_weight=non_negative(rest_weight, "rest_weight"),
        velocity_weight=non_negative(velocity_weight, "velocity_weight"),
        damping=None if damping is None else non_negative(damping, "damping"),
        joint_weights=None if joint_weights is None else as_array(joint_weights, "joint_weights", (rig.n_dof,)),
        balance_weight=non_negative(balance_weight, "balance_weight"),
    )
    if req.balance_weight > 0 and not any(e.name.startswith("foot") for e in rig.effectors):
        raise ValueError("balance_weight: the rig has no foot effectors")
    if req.joint_weights is not None and np.any(req.joint_weights < 0):
        raise ValueError(f"joint_weights: must be >= 0 (got {float(req.joint_weights.min())})")
    if not is_number(rotation_tolerance) or not (math.isfinite(rotation_tolerance) and rotation_tolerance > 0):
        raise ValueError(f"rotation_tolerance: expected a positive number of radians (got {rotation_tolerance!r})")
    req.rotation_tolerance = float(rotation_tolerance)
    if root_weight is not None:
        if not is_number(root_weight) or not (math.isfinite(root_weight) and root_weight > 0):
            raise ValueError(f"root_weight: expected None or a positive finite number (got {root_weight!r})")
        req.root_weight = float(root_weight)
    if poles is not None:
        pole, has = rows_or_nan(poles, "poles", (n, E, dim), limit=MAX_EXTENT)
        if np.any(has):
            req.poles = np.where(has[..., None], pole, np.nan).astype(np.float32)
    if rotations is None and rotation_weights is not None:
        raise ValueError("rotation_weights: given without rotations")
    if rotations is not None:
        rot, has = rows_or_nan(rotations, "rotations", (n, E, 4))
        norms = np.sqrt(np.einsum("nek,nek->ne", rot.astype(np.float64), rot.astype(np.float64)))
        bad = has & (np.abs(norms - 1.0) > 1e-2)
        if np.any(bad):
            i, e = np.argwhere(bad)[0]
            raise ValueError(f"rotations: row [{i}, {e}] is not a unit quaternion x y z w (norm {norms[i, e]:.6g}; "
                             f"all NaN means none)")
        rw = np.ones((n, E), np.float32)
        if rotation_weights is not None:
            rw = as_array(rotation_weights, "rotation_weights", (n, E))
            if np.any(rw < 0):
                raise ValueError(f"rotation_weights: must be >= 0 (got {float(rw.min())})")
        rw = np.where(has, rw, 0.0).astype(np.float32)
        if dim == 2:
            raise ValueError("rotations: a planar (dim=2) rig has no full rotation to aim; use targets")
        if np.any(rw > 0):
            req.rotations = np.where(has[..., None], rot / np.maximum(norms, 1e-30)[..., None], 0.0).astype(np.float32)
            req.rotation_weights = rw
    return req


def refill(req: SolveRequest, targets: np.ndarray, weights: np.ndarray, poles: np.ndarray | None = None) -> bool:
    """Put a new solve's targets (N, E, dim), weights (N, E) and poles (N, E, dim) (NaN rows: none) into `req`, in
    place and unchecked. `req` is a request check_request made from arrays of the same shapes and kinds, holding
    writable arrays of its own (check_request may hand back read-only views of the caller's arrays). For callers
    that build these arrays themselves (the game, every world step): finite and in range by construction, whole
    NaN rows only, some weight > 0. The values land as check_request would leave them (float32 as given; poles
    NaN where none), so a solve of the refilled request equals one of check_request(...). Returns False, leaving
    `req` alone, when the request's form would change (poles given or not, none at all, another shape): the
    caller then checks the new arguments the ordinary way."""
    want = req.poles is not None
    if (poles is not None) != want or np.shape(targets) != req.targets.shape or np.shape(weights) != req.weights.shape:
        return False
    if want and (np.shape(poles) != req.poles.shape or np.isnan(poles[..., 0]).all()):
        return False
    np.copyto(req.targets, targets, casting="same_kind")
    np.copyto(req.weights, weights, casting="same_kind")
    if want:
        np.copyto(req.poles, poles, casting="same_kind")
    return True
