"""FABRIK's quality on the limited humanoid (issue 15): the cases the tests check, also runnable as a script that
prints the figures (python tests/fabrik_quality.py [n] [method]).

- in_limit_poses: from rest to the effectors of in-limit poses (angles ~ N(0, 0.25) clipped to the limits), all
  five effectors, tolerance 5 mm, 100 iterations: the converged fraction;
- cross_body: hand_l to 0.25 m in front of the right hip, the other effectors held: the hand's error;
- head_forward: the head dragged 0.3 m forward, the rest held: the neck's bend over spine's + chest's + neck's;
- rotation_poses: as in_limit_poses with the poses' effector world rotations as full rotation targets.
"""

from __future__ import annotations

import sys

import numpy as np

import crowd_ik as cik


def in_limit_angles(rig, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = rig.angle_limits()
    return np.clip(rng.normal(0.0, 0.25, (n, rig.n_dof)), lo, hi).astype(np.float32)


def pose_goals(rig, n, seed):
    """Effector positions (N, E, 3) and world rotations (N, E, 4) of n in-limit poses."""
    posed = cik.Crowd(rig, n=n, spacing=2.0)
    posed.set_angles(in_limit_angles(rig, n, seed))
    return posed.effector_positions().copy(), posed.world_rotations()[:, rig.arrays["eff_joint"]].copy()


def in_limit_poses(n=1000, seed=0, method="fabrik", max_iterations=100):
    rig = cik.Rig.humanoid()
    eff, _ = pose_goals(rig, n, seed)
    rep = cik.Crowd(rig, n=n, spacing=2.0).solve(eff, method=method, max_iterations=max_iterations, tolerance=5e-3)
    return rep


def rotation_poses(n=200, seed=0, method="fabrik", max_iterations=100):
    rig = cik.Rig.humanoid()
    eff, rot = pose_goals(rig, n, seed)
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    rep = crowd.solve(eff, method=method, max_iterations=max_iterations, tolerance=5e-3, rotations=rot)
    return rep, crowd


def cross_body(method="fabrik", max_iterations=500):
    """The hand_l's final distance from a point 0.25 m in front of the right hip, the other effectors held."""
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=1)
    t = crowd.effector_positions().copy()
    hip = crowd.joint_positions()[0, rig.joint_names.index("hip_r")]
    t[0, 1] = hip + np.array([0.0, 0.0, 0.25], np.float32)
    rep = crowd.solve(t, method=method, max_iterations=max_iterations, tolerance=5e-3)
    return float(np.linalg.norm(crowd.effector_positions()[0, 1] - t[0, 1])), rep


def bend(rig, rot, joint, child):
    """Angle (N,) between the child's rest bone direction and its direction after joint's local rotation."""
    from crowd_ik.geometry.quat import qrot

    off = rig.arrays["offset"][rig.joint_names.index(child)].astype(np.float64)
    q = rot[:, rig.joint_names.index(joint)].astype(np.float64)
    d = qrot(q, np.broadcast_to(off, q.shape[:-1] + (3,)))
    c = np.sum(d * off, -1) / (np.linalg.norm(d, axis=-1) * np.linalg.norm(off))
    return np.arccos(np.clip(c, -1.0, 1.0))


def head_forward(method="fabrik", max_iterations=100, forward=0.3):
    """(neck bend / (spine + chest + neck bends), head error, report) for the head moved `forward` m along +z."""
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=1)
    t = crowd.effector_positions().copy()
    t[0, 0, 2] += forward
    rep = crowd.solve(t, method=method, max_iterations=max_iterations, tolerance=5e-3)
    rot = crowd.rotations()
    b = [bend(rig, rot, j, c)[0] for j, c in (("spine", "chest"), ("chest", "neck"), ("neck", "head"))]
    return b[2] / max(sum(b), 1e-12), float(rep.error[0]), b


def failure_profile(rep, crowd, eff, seed, top=6):
    """Lines describing the unconverged characters of in_limit_poses: the effector farthest off, the iterations they
    stopped at, and the DOFs that sit at a limit far more often in them than in the converged ones."""
    rig = crowd.rig
    bad = ~rep.converged
    if not bad.any():
        return ["no failures"]
    pe = np.linalg.norm(crowd.effector_positions() - eff, axis=-1)[bad]
    worst = np.bincount(pe.argmax(1), minlength=rig.n_effectors)
    lines = ["worst effector: " + ", ".join(f"{e.name} {c}" for e, c in zip(rig.effectors, worst)) +
             f"; iterations p10/50/90 {np.percentile(rep.iterations[bad], [10, 50, 90])}"]
    lo, hi = rig.angle_limits()
    at = (np.abs(crowd.angles() - lo) < 1e-3) | (np.abs(crowd.angles() - hi) < 1e-3)
    goal = in_limit_angles(rig, len(bad), seed)
    goal_at = ((np.abs(goal - lo) < 1e-3) | (np.abs(goal - hi) < 1e-3))[bad].mean(0)
    names = [f"{j.name}[{d}]" for j in rig.joints for d in range(j.dof)]
    gap = at[bad].mean(0) - at[~bad].mean(0)
    for k in np.argsort(-gap)[:top]:
        lines.append(f"  {names[k]} at a limit: {at[bad, k].mean():.2f} of failures, {at[~bad, k].mean():.2f} of "
                     f"converged; in the failures' goal poses {goal_at[k]:.2f}")
    return lines


def main(argv):
    cik.init(arch="cpu")
    n = int(argv[1]) if len(argv) > 1 else 1000
    method = argv[2] if len(argv) > 2 else "fabrik"
    for seed in (0, 1, 2):
        rig = cik.Rig.humanoid()
        eff, _ = pose_goals(rig, n, seed)
        crowd = cik.Crowd(rig, n=n, spacing=2.0)
        rep = crowd.solve(eff, method=method, max_iterations=100, tolerance=5e-3)
        print(f"in-limit poses seed {seed}: {np.mean(rep.converged) * 100:.1f} % converged of {n}, "
              f"median error {np.median(rep.error) * 1e3:.2f} mm, mean iterations {rep.iterations.mean():.1f}")
        print("\n".join(failure_profile(rep, crowd, eff, seed)))
    err, _ = cross_body(method)
    print(f"cross-body hand_l: {err * 100:.2f} cm off")
    ratio, herr, b = head_forward(method)
    print(f"head 0.3 m forward: neck / (spine + chest + neck) = {ratio:.3f}, bends {np.round(b, 3)}, "
          f"head error {herr * 1e3:.2f} mm")
    for seed in (0, 1):
        rep, _ = rotation_poses(200, seed, method)
        print(f"rotation targets seed {seed}: {int(np.sum(rep.converged))}/200 converged, "
              f"median rotation error {np.median(rep.rotation_error) * 1e3:.2f} mrad, "
              f"max position error {rep.error.max() * 1e3:.2f} mm")


if __name__ == "__main__":
    main(sys.argv)
