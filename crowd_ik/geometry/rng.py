"""NumPy twin of kernels/rng.py: the same PCG-based counter hash, bit-identical, vectorised.

Arguments broadcast against each other; any integer values are taken modulo 2^32 (two's complement
for negatives), as the kernels' casts to u32 do.
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint32(747796405)
_INC = np.uint32(2891336453)
_M2 = np.uint32(277803737)


def _u32(x) -> np.ndarray:
    return (np.asarray(x, dtype=np.int64) & 0xFFFFFFFF).astype(np.uint32)


def pcg(v) -> np.ndarray:
    """PCG RXS-M-XS output permutation of uint32 words (wrapping arithmetic)."""
    v = _u32(v) if np.asarray(v).dtype != np.uint32 else np.asarray(v)
    with np.errstate(over="ignore"):
        state = v * _M1 + _INC
        word = ((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * _M2
    return (word >> np.uint32(22)) ^ word


def hash_u32(seed, index, counter) -> np.ndarray:
    """uint32 hash pcg(pcg(pcg(seed) + index) + counter), like kernels.rng.hash_u32."""
    with np.errstate(over="ignore"):
        h = pcg(_u32(seed))
        h = pcg(h + _u32(index))
        return pcg(h + _u32(counter))


def uniform(seed, index, counter) -> np.ndarray:
    """float32 in [0, 1): top 24 bits of hash_u32 times 2^-24."""
    return (hash_u32(seed, index, counter) >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / 16777216.0)
