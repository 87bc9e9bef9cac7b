"""game.cross.cross equals np.cross bit for bit (values, signed zeros, dtype promotion, broadcasting)."""

import numpy as np
import pytest

from crowd_ik.game.cross import cross


@pytest.mark.parametrize("sa, sb, da, db", [
    ((3,), (7, 3), np.float32, np.float32),  # the dodge's UP x directions
    ((5, 3), (5, 3), np.float32, np.float64),
    ((9, 3), (9, 3), np.float64, np.float32),
    ((1, 3), (4, 3), np.float32, np.float32),
    ((2, 6, 3), (6, 3), np.float64, np.float64),
])
def test_cross_equals_np_cross(sa, sb, da, db):
    rng = np.random.default_rng(len(sa) * 10 + sb[0])
    a = rng.normal(size=sa).astype(da)
    b = rng.normal(size=sb).astype(db)
    a.flat[0], b.flat[1], b.flat[2] = -0.0, 0.0, -0.0  # signed zeros come out signed alike
    want, got = np.cross(a, b), cross(a, b)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert got.tobytes() == want.tobytes()
