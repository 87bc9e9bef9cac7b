"""Checks that several solver test modules share."""

import numpy as np

import crowd_ik as cik


def assert_each_alone_gives_the_same_bits(rig, roots, yaw, targets, method, **kwargs):
    """Solve `targets` for characters standing at roots / yaw as one batch, then each character alone: the same
    rotations, iteration counts and errors, bit for bit. Returns the batch's Crowd and report."""
    n = len(roots)
    batch = cik.Crowd(rig, n=n)
    batch.set_roots(roots, yaw)
    rep = batch.solve(targets, method=method, **kwargs)
    for i in range(n):
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i : i + 1], yaw[i : i + 1])
        r1 = one.solve(targets[i : i + 1], method=method, **kwargs)
        np.testing.assert_array_equal(one.rotations()[0], batch.rotations()[i])
        assert r1.iterations[0] == rep.iterations[i] and r1.error[0] == rep.error[i]
    return batch, rep
