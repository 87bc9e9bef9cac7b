"""NumPy twin of kernels/root_shift.py: the sub-base rule that moves a free root before FABRIK or CCD."""

from __future__ import annotations

import numpy as np

from crowd_ik.solvers.settings import ROOT_SHIFT_ROUNDS, ROOT_SHIFT_SLACK


def shift_roots(reach, root_pos, base, targets, weights, root_weight: float, dim: int = 3) -> np.ndarray:
    """(N, 3) float64 moved roots: root_pos (N, 3) plus the shift of the rule in kernels/root_shift.py.

    reach (E,) metres; base (N, 3) the root joints' world positions; targets (N, E, 3); weights (N, E).
    """
    reach = np.asarray(reach, np.float64)
    base = np.asarray(base, np.float64)
    targets = np.asarray(targets, np.float64)
    weights = np.asarray(weights, np.float64)
    frac = min(float(root_weight), 1.0)
    shift = np.zeros_like(base)
    for _ in range(ROOT_SHIFT_ROUNDS):
        r = targets - (base + shift)[:, None]
        dist = np.linalg.norm(r, axis=-1)
        beyond = dist - (1.0 - ROOT_SHIFT_SLACK) * reach[None]
        ask = (weights > 0) & (beyond > 0)
        w = np.where(ask, weights, 0.0)
        acc = np.einsum("ne,ne,nek->nk", w, np.where(ask, beyond / np.maximum(dist, 1e-30), 0.0), r)
        wsum = w.sum(1)
        shift += np.where(wsum[:, None] > 0, frac * acc / np.maximum(wsum, 1e-30)[:, None], 0.0)
    if dim == 2:
        shift[:, 2] = 0.0
    return np.asarray(root_pos, np.float64) + shift
