"""Analytic two-bone IK (shoulder-elbow-hand, hip-knee-ankle), batched in NumPy.

Positions are relative to the chain's root (the shoulder or hip at the origin) unless ``root=`` gives
the roots' world positions, in which case ``target`` and the returned positions are world positions.
``pole`` is a direction (never a point): the middle joint bends toward its side of the root-target
line. Law of cosines, with the distance clamped to what the bones can span:

- beyond reach (d > upper + lower): the limb stretches straight toward the target;
- too close (d < |upper - lower|): the limb folds flat on the root-target line, its end as near
  the target as it gets;
- target at the root: the root-target direction is undefined; a fixed direction perpendicular to
  the pole stands in for it (so with upper == lower the middle joint sits exactly on the pole side);
- pole parallel to the root-target line (or zero): the bend plane holds the coordinate axis least
  aligned with that line (ties to the lower index: x, then y, then z).

Degenerate inputs never give NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_EPS = 1e-12


@dataclass(frozen=True)
class TwoBone:
    """Result of :func:`two_bone`; arrays have shape (N, ...) or, for unbatched inputs, no N axis.

    mid (N, 3): middle joint (elbow/knee); end (N, 3): end of the lower bone (equal to the target
    when reachable); mid_angle (N,): interior angle at the middle joint in [0, pi] (pi = straight);
    root_angle (N,): angle at the root between the root-target line and the upper bone, in [0, pi];
    bend (N,) = pi - mid_angle: the hinge flexion (0 = straight); reachable (N,) bool.
    """

    mid: np.ndarray
    end: np.ndarray
    mid_angle: np.ndarray
    root_angle: np.ndarray
    bend: np.ndarray
    reachable: np.ndarray


def _lengths(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64) if _numeric(value) else None
    if arr is None or arr.ndim > 1:
        got = f"shape {arr.shape}" if arr is not None else repr(value)
        raise ValueError(f"{name}: expected a positive number or an (N,) array (got {got})")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        bad = arr[~(np.isfinite(arr) & (arr > 0))].flat[0]
        raise ValueError(f"{name}: bone lengths must be finite and positive (got {bad})")
    return arr


def _vectors(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64) if _numeric(value) else None
    if arr is None or arr.ndim not in (1, 2) or arr.shape[-1] != 3:
        got = np.shape(value) if arr is not None else repr(value)
        raise ValueError(f"{name}: expected shape (3,) or (N, 3) (got {got})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite (got {arr[~np.isfinite(arr)].flat[0]})")
    return arr


def _numeric(value) -> bool:
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError):
        return False
    return np.issubdtype(arr.dtype, np.number) and not np.issubdtype(arr.dtype, np.complexfloating)


def _batch_size(named: dict[str, np.ndarray], vec: set[str]) -> int | None:
    """The common N of the batched arguments (None when none is batched); ValueError naming a mismatch."""
    n = None
    first = None
    for name, arr in named.items():
        batched = arr.ndim == (2 if name in vec else 1)
        if batched:
            if n is None:
                n, first = arr.shape[0], name
            elif arr.shape[0] != n:
                raise ValueError(f"{name}: batch size {arr.shape[0]} does not match {first}'s {n}")
    return n


def two_bone_angles(upper, lower, distance):
    """(root_angle, mid_angle, bend) for bones ``upper``, ``lower`` spanning ``distance`` (arrays broadcast).

    The distance is clamped to [|upper - lower|, upper + lower] first. root_angle: between the
    root-end line and the upper bone; mid_angle: interior angle at the middle joint (pi = straight);
    bend = pi - mid_angle, the angle a knee or elbow hinge turns from straight.
    """
    u = _lengths(upper, "upper")
    lw = _lengths(lower, "lower")
    d = np.asarray(distance, dtype=np.float64) if _numeric(distance) else None
    if d is None or not np.all(np.isfinite(d)) or np.any(d < 0):
        bad = repr(distance) if d is None else d[~(np.isfinite(d) & (d >= 0))].flat[0]
        raise ValueError(f"distance: expected finite numbers >= 0 (got {bad})")
    u, lw, d = np.broadcast_arrays(u, lw, d)
    dc = np.clip(d, np.abs(u - lw), u + lw)
    cos_mid = np.clip((u * u + lw * lw - dc * dc) / (2.0 * u * lw), -1.0, 1.0)
    cos_root = np.clip((u * u + dc * dc - lw * lw) / (2.0 * u * np.maximum(dc, _EPS * (u + lw))), -1.0, 1.0)
    mid_angle = np.arccos(cos_mid)
    root_angle = np.arccos(cos_root)
    # the limits exactly (arccos near +-1 would turn rounding into ~1e-8 rad)
    stretched = d >= u + lw
    folded = d <= np.abs(u - lw)
    mid_angle = np.where(stretched, np.pi, np.where(folded, 0.0, mid_angle))
    # folded: the longer bone points along the line (upper toward the target, or lower with upper away);
    # equal bones folded on the root: the upper bone is perpendicular to the stand-in line
    fold_root = np.where(u > lw, 0.0, np.where(u < lw, np.pi, np.pi / 2))
    root_angle = np.where(stretched, 0.0, np.where(folded, fold_root, root_angle))
    return root_angle, mid_angle, np.pi - mid_angle


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors perpendicular to unit d: the coordinate axis least aligned with d, made perpendicular."""
    k = np.argmin(np.abs(d), axis=1)
    e = np.eye(3)[k]
    p = e - np.sum(e * d, axis=1, keepdims=True) * d
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def two_bone(upper, lower, target, pole, solution: int = +1, root=None) -> TwoBone:
    """Place the middle and end joints of two-bone limbs analytically.

    upper, lower: bone lengths (metres), scalars or (N,). target: (3,) or (N, 3), relative to the
    root (or world positions when ``root`` (3,) or (N, 3) is given). pole: (3,) or (N, 3) direction;
    the middle joint bends toward it. solution: +1 (toward the pole) or -1 (the mirror image across
    the root-target line, in the same plane). Returns a :class:`TwoBone`.
    """
    if isinstance(solution, bool) or solution not in (1, -1):
        raise ValueError(f"solution: expected +1 or -1 (got {solution!r})")
    named = dict(upper=_lengths(upper, "upper"), lower=_lengths(lower, "lower"),
                 target=_vectors(target, "target"), pole=_vectors(pole, "pole"))
    if root is not None:
        named["root"] = _vectors(root, "root")
    n = _batch_size(named, {"target", "pole", "root"})
    size = 1 if n is None else n
    u = np.broadcast_to(named["upper"], (size,))
    lw = np.broadcast_to(named["lower"], (size,))
    origin = np.broadcast_to(named.get("root", np.zeros(3)), (size, 3))
    t = np.broadcast_to(named["target"], (size, 3)) - origin
    pole_v = np.broadcast_to(named["pole"], (size, 3))

    dist = np.linalg.norm(t, axis=1)
    pole_len = np.linalg.norm(pole_v, axis=1)
    pole_hat = np.where((pole_len > 0)[:, None], pole_v / np.maximum(pole_len, 1e-300)[:, None], 0.0)
    # stand-in direction when the target sits on the root: perpendicular to the pole (or +x without a pole)
    fallback = np.where((pole_len > 0)[:, None], _perpendicular(np.where((pole_len > 0)[:, None], pole_hat, 1.0)),
                        np.array([1.0, 0.0, 0.0]))
    at_root = dist <= _EPS * (u + lw)
    d_hat = np.where(at_root[:, None], fallback, t / np.maximum(dist, 1e-300)[:, None])
    # bend direction: the pole's component perpendicular to the root-target line
    b = pole_hat - np.sum(pole_hat * d_hat, axis=1, keepdims=True) * d_hat
    b_len = np.linalg.norm(b, axis=1)
    b_hat = np.where((b_len > 1e-9)[:, None], b / np.maximum(b_len, 1e-300)[:, None], _perpendicular(d_hat))

    root_angle, mid_angle, bend = two_bone_angles(u, lw, dist)
    mid = u[:, None] * (np.cos(root_angle)[:, None] * d_hat + solution * np.sin(root_angle)[:, None] * b_hat)
    reach_lo = np.abs(u - lw)
    reach_hi = u + lw
    reachable = (dist >= reach_lo * (1 - 1e-12)) & (dist <= reach_hi * (1 + 1e-12))
    end = np.where(reachable[:, None], t, np.clip(dist, reach_lo, reach_hi)[:, None] * d_hat)
    out = dict(mid=mid + origin, end=end + origin, mid_angle=mid_angle, root_angle=root_angle, bend=bend,
               reachable=reachable)
    if n is None:
        out = {k: v[0] for k, v in out.items()}
        out["reachable"] = bool(out["reachable"])
    return TwoBone(**out)
