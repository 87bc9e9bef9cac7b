"""Joint limits the limit-projection tests share (tests/test_quat.py, tests/test_lane_limits.py): (kind, axes, lo,
hi) of hinges, universal joints and ball joints, with limits that bite, never bite and are partly unlimited."""

LIMIT_CASES = [
    (1, [(0.0, 0.0, 1.0)], [0.0], [2.62]),  # a knee
    (1, [(0.6, 0.0, 0.8)], [-1.0], [0.5]),
    (1, [(1.0, 0.0, 0.0)], [-4.0], [4.0]),  # limits beyond +-pi never bite
    (2, [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)], [-1.22, -0.52], [1.22, 0.52]),  # a wrist
    (2, [(0.0, 1.0, 0.0), (1.0, 0.0, 0.0)], [-0.7, -2.8], [0.52, 2.9]),
    (3, [], [-0.44, -0.7, -0.35], [0.44, 0.7, 0.35]),  # a pelvis
    (3, [], [-2.97, -1.4, -0.35], [0.87, 1.4, 2.97]),  # a shoulder
    (3, [], [-1e30, -0.3, -1e30], [1e30, 1e30, 0.2]),  # partly unlimited
]
