"""Rigs that several solver test modules share (tests/test_fabrik.py, tests/test_fabrik_free_lanes.py,
tests/test_ccd_lanes.py)."""

import crowd_ik as cik


def free_tree():
    """A constraint-free tree of 7 joints (a sub-base with two branches), two effectors."""
    return cik.Rig(
        tuple(cik.Joint(n, p, o) for n, p, o in [("root", -1, (0, 0, 0)), ("a", 0, (0, 0.3, 0)), ("b", 1, (0, 0.3, 0)),
                                              ("l", 2, (0.2, 0.1, 0)), ("r", 2, (-0.2, 0.1, 0)), ("lt", 3, (0.2, 0, 0)),
                                              ("rt", 4, (-0.2, 0, 0))]),
        (cik.Effector("left", 5), cik.Effector("right", 6)))
