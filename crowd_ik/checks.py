"""The Crowd's edge checks: arguments turned into the arrays and numbers the kernels can honour, or a
ValueError naming the argument and the value (real dtypes only, finite, within bounds, numpy scalars
accepted wherever numbers are)."""

from __future__ import annotations

import math

import numpy as np

def is_integer(value) -> bool:
    """A Python or numpy integer, not a bool."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer))


def is_number(value) -> bool:
    """A real Python or numpy number, not a bool (finiteness is the caller's to check)."""
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


MAX_ITERATIONS = 10_000  # the most iterations one solve may ask for (the kernels count in int32 and float32)


def as_array(value, name: str, shape: tuple, dtype=np.float32, limit: float | None = None) -> np.ndarray:
    """Broadcast ``value`` to ``shape`` as a C-contiguous array; refuse complex, NaN/inf, |x| > limit and bad
    shapes."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":  # bool, signed, unsigned, float: not object, complex, text, dates
        raise ValueError(f"{name}: expected real numbers (got dtype {arr.dtype})")
    if arr.shape != shape:
        try:
            arr = np.broadcast_to(arr, shape)
        except ValueError:
            raise ValueError(f"{name}: expected shape {shape} (got {np.shape(value)})") from None
    arr = np.ascontiguousarray(arr, dtype=dtype)
    if not arr.size:
        return arr
    floating = arr.dtype.kind == "f"
    if floating or limit is not None:
        peak = float(np.abs(arr).max())  # NaN when any is NaN, inf when any is inf: one pass for both checks
        if floating and not math.isfinite(peak):
            bad = arr[~np.isfinite(arr)].flat[0]
            raise ValueError(f"{name}: must be finite (got {bad})")
        if limit is not None and peak > limit:
            raise ValueError(f"{name}: must be within +-{limit:g} (got {float(arr.flat[np.argmax(np.abs(arr))])})")
    return arr


def positive_int(value, name: str, most: int | None = None) -> int:
    if not is_integer(value) or value < 1 \
            or (most is not None and value > most):
        bound = "a positive integer" if most is None else f"an integer in [1, {most:,}]"
        raise ValueError(f"{name}: expected {bound} (got {value!r})")
    return int(value)


def non_negative(value, name: str) -> float:
    if not is_number(value):
        raise ValueError(f"{name}: expected a number (got {value!r})")
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name}: expected a finite number >= 0 (got {value!r})")
    return float(value)
