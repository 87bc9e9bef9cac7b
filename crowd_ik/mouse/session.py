"""The planar chain posed with the mouse: ChainSession holds its joint angles, method, limits and
target, and steps it one frame (the live window and the replays both drive it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from crowd_ik import planar
from crowd_ik.mouse.view import (
    View,
    draw_background,
    reachable_mask,
)
from crowd_ik.solvers.registry import (
    CCD,
    DLS,
    FABRIK,
    FOLLOW,
    NEWTON,
    PLANAR_DEFAULT,
    PLANAR_METHODS,
)
from crowd_ik.solvers.registry import (
    METHODS as CROWD_METHODS,
)

METHODS = PLANAR_METHODS
TAICHI_METHODS = (FABRIK, CCD)  # the chain's methods solved by a Crowd of one
HUMANOID_METHODS = CROWD_METHODS
KEYS = {str(k + 1): m for k, m in enumerate(METHODS)}
DEFAULT_BONES, MAX_BONES = 4, 100
LOST_TOL = 0.02  # chain units: a tip farther than this from its target has lost it
# follow's accepted sub-steps each miss by up to its 0.05 threshold, so its tip drifts; more than
# this and the next frame's correction is no longer small: lost as well
FOLLOW_DRIFT = 0.1
TRAIL_LENGTH = 40
MAX_FRAMES = 1_000_000
SCENES = Path(__file__).resolve().parents[1] / "scenes"
NO_DISPLAY = "mouse: no display; replay headless instead: crowd-ik mouse --path scenes/circle.csv -o circle.mp4"
LEGEND = ["1 newton  2 dls  3 fabrik  4 ccd  5 follow   drag: move the target",
          "L limits  R reset  C record path  Esc quit"]


def chain_limits(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) radians of the --limits chain: the coursework's ranges spread over n joints.

    The first joint +-45 deg, the last +-170 deg, the ones between +-90 deg (for 3 bones exactly
    the coursework's [-45, 45], [-90, 90], [-170, 170]).
    """
    deg = np.full(n, 90.0)
    if n > 1:
        deg[-1] = 170.0
    deg[0] = 45.0
    return -np.radians(deg), np.radians(deg)


def rest_pose(n: int) -> np.ndarray:
    """A gentle arc (90 deg of bend in all), so the Jacobian has full rank from the start."""
    return np.full(n, 0.5 * np.pi / n)


def _wrap(t: np.ndarray) -> np.ndarray:
    return (t + np.pi) % (2 * np.pi) - np.pi


def _limited_chain_rig(n: int, limits: bool):
    """Rig.chain(n, dim=2) with the per-joint limits of chain_limits when ``limits``."""
    from dataclasses import replace

    from crowd_ik.rig import Rig

    rig = Rig.chain(n, 1.0, dim=2)
    if not limits:
        return rig
    lo, hi = chain_limits(n)
    joints = tuple(replace(j, lo=(float(lo[i]),), hi=(float(hi[i]),)) if i < n else j for i, j in enumerate(rig.joints))
    return Rig(joints, rig.effectors, dim=2, name=rig.name)


class ChainSession:
    """The planar demo's state: angles, method, limits, target; :meth:`step` solves one frame."""

    def __init__(self, n_bones: int = DEFAULT_BONES, method: str = PLANAR_DEFAULT, limits: bool = False):
        if method not in METHODS:
            raise ValueError(f"--method: expected one of {', '.join(METHODS)} (got {method!r})")
        self.n, self.method, self.limits = n_bones, method, bool(limits)
        self._crowds: dict[bool, object] = {}
        self._backgrounds: dict[tuple, np.ndarray] = {}
        self.reset()

    def reset(self) -> None:
        """Back to the rest pose, the target on the tip."""
        self.thetas = rest_pose(self.n)
        self.target = planar.chain(self.thetas)
        self.error, self.lost = 0.0, False

    @property
    def reach(self) -> float:
        return float(self.n)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return chain_limits(self.n) if self.limits else (np.full(self.n, -np.inf), np.full(self.n, np.inf))

    def toggle_limits(self) -> None:
        self.limits = not self.limits
        self.thetas = np.clip(self.thetas, *self.bounds)

    def set_method(self, method: str) -> None:
        if method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)} (got {method!r})")
        self.method = method

    def background(self, view: View) -> np.ndarray:
        """The static layer (grid, reachable area, reach circle) for this view and limits setting;
        the area is sampled once per setting, then cached."""
        key = (view, self.limits)
        if key not in self._backgrounds:
            self._backgrounds[key] = draw_background(view, reachable_mask(view, *self.bounds))
        return self._backgrounds[key]

    def _aim(self) -> np.ndarray:
        """The target, or for one beyond the reach its projection just inside the reach circle."""
        dist = float(np.linalg.norm(self.target))
        edge = self.reach * (1.0 - 1e-3)
        return self.target * (edge / dist) if dist > edge else self.target.copy()

    def _crowd(self):
        if self.limits not in self._crowds:
            from crowd_ik.crowd import Crowd

            self._crowds[self.limits] = Crowd(_limited_chain_rig(self.n, self.limits), n=1)
        return self._crowds[self.limits]

    def step(self) -> None:
        """Solve one frame toward ``self.target``; update ``error`` and ``lost``."""
        lo, hi = self.bounds
        reached = True
        if self.method == NEWTON:
            # the homework's 8 pseudoinverse steps; with limits, clamped after each (coursework 4.3)
            aim = self._aim()
            t = self.thetas
            for _ in range(8 if self.limits else 1):
                t = np.clip(planar.newton(t, aim, iterations=1 if self.limits else 8), lo, hi)
            self.thetas = t
        elif self.method == DLS:
            self.thetas = planar.dls(self.thetas, self.target, damping=0.1, iterations=100, tolerance=1e-4,
                                     limits=(lo, hi) if self.limits else None)
        elif self.method == FOLLOW:
            aim = self._aim()
            t, reached = planar.follow(self.thetas, aim - planar.chain(self.thetas), threshold=0.05, max_depth=10)
            self.thetas = np.clip(t, lo, hi)
        else:
            crowd = self._crowd()
            crowd.set_angles(self.thetas.astype(np.float32))
            crowd.solve(self.target.reshape(1, 1, 2).astype(np.float32), method=self.method,
                        max_iterations=100, tolerance=1e-3)
            self.thetas = crowd.angles()[0].astype(np.float64)
        if not self.limits:
            self.thetas = _wrap(self.thetas)
        self.error = float(np.linalg.norm(planar.chain(self.thetas) - self.target))
        if self.method == FOLLOW:  # the lab's rule: lost when move() gives up
            beyond = np.linalg.norm(self.target) > self.reach
            self.lost = bool(not reached or beyond or self.error > FOLLOW_DRIFT)
        else:
            self.lost = self.error > LOST_TOL

    def settle(self, target) -> None:
        """Start on ``target``: pose the chain from rest by DLS run to convergence (replays begin so)."""
        self.target = np.asarray(target, dtype=np.float64).copy()
        self.thetas = planar.dls(rest_pose(self.n), self.target, damping=0.1, iterations=1000, tolerance=1e-6,
                                 limits=self.bounds if self.limits else None)

    def joints(self) -> np.ndarray:
        return planar.chain_all(self.thetas)

    def hud(self) -> list[str]:
        engine = "Taichi, N=1" if self.method in TAICHI_METHODS else "NumPy"
        x, y = self.target
        return [f"{self.method} ({engine})   {self.n} bones   limits {'on' if self.limits else 'off'}",
                f"target ({x:+.2f}, {y:+.2f})   error {self.error:.3f}",
                "target LOST" if self.lost else "target reached"]
