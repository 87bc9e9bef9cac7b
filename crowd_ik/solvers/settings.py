"""Solver constants and the SIMD lane width: the one module kernels/ may import besides kernels.*.

The kernels, their NumPy twins in crowd_ik/reference/ and the product all read the constants here, so
the oracle and the product cannot drift apart and neither depends on the other. Importing this module
creates no Taichi state.

Lane width L: the lane-packed kernels (kernels/fabrik_lanes.py, kernels/dls_lanes.py) solve a packet of
L characters per CPU thread, each scalar of a character's state one lane of a ``ti.types.vector(L,
ti.f32)``, which Taichi's CPU backend compiles to packed SIMD code. L is chosen once, when
:func:`crowd_ik.init` starts Taichi: 16 float32 lanes where the CPU has AVX-512, 8 with AVX2, 4
otherwise, and 1 on CUDA (one character per GPU thread is already vectorised across the warp). The
environment variable ``CROWD_IK_LANES`` or ``crowd_ik.init(lanes=...)`` overrides it (tests use small
widths). Kernels are built per L by cached factories, so a process only compiles the widths it uses.
"""

from __future__ import annotations

import math
import os

# ---------------------------------------------------------------------------------------------- FABRIK
# Sine of the bend FABRIK proposes for a hinge limb: below TWIST_MIN_BEND the ball joint above keeps its
# twist, above TWIST_FULL_BEND it turns the hinge axis fully onto the proposed plane (linear in between).
TWIST_MIN_BEND, TWIST_FULL_BEND = 0.01, 0.1
# A character has stalled after FABRIK_STALL_AFTER updates in a row that improve its errors by less than
# FABRIK_FLAT.
FABRIK_STALL_AFTER, FABRIK_FLAT = 4, 1e-6
# A joint with several active children (a sub-base) turns by the weighted mean of their swings, refined
# this many times (4 rounds fit no better than 2 on the humanoid and cost 15 % more per iteration).
SWING_ROUNDS = 2
# CCD has stalled after CCD_STALL_AFTER sweeps in a row that improve neither error by CCD_FLAT of itself
CCD_STALL_AFTER, CCD_FLAT = 4, 1e-4
CCD_MULTI_ROUNDS = 4  # rounds of swing averaging at a CCD joint with several effectors below it
# FABRIK's windowed solve (solvers/fabrik_restart.py) runs in windows of FABRIK_WINDOW iterations (a solve of at
# most this many is one launch, as without windows); a window that leaves more than FABRIK_SLOW of the error it
# started with is slow: its angles are tracked for jumps.
FABRIK_WINDOW, FABRIK_SLOW = 8, 0.5

# ---------------------------------------------------------------------------------------------- poles
# kernels/poles.py: a limb whose bend joint lies within POLE_MIN_BEND x its distance of the line from the pivot to
# the effector is straight (no bend plane to turn); a swivel is undone if it makes any effector's error worse
# than max(before, tolerance) by more than POLE_SLACK (metres, or radians for rotation targets).
POLE_MIN_BEND, POLE_SLACK = 1e-3, 1e-6

# ---------------------------------------------------------------------------------------------- DLS
DLS_ERROR_CLAMP = 1.0  # d_max = 1.0 * mean bone length * sqrt(bones from the root), Buss & Kim 2005; the LM
# acceptance test already rejects steps that overshoot, so a looser clamp than their 0.4 costs no stability
# and saves iterations: chain16 from straight 13.8 -> 9.4 mean, the same 100 % humanoid and 99.99 % chain16
# success (benchmark workloads)
DLS_DAMPING = 0.05  # default damping = 0.05 * L
DLS_DAMPING_MIN = 1e-3  # damping below 1e-3 * L is raised to it (keeps the float32 Cholesky positive definite)
DLS_ORI_CLAMP = 0.5  # radians: the largest orientation error one step aims to remove
DLS_STALL_AFTER = 5  # rejected or flat attempts in a row that make a stall
DLS_FLAT = 1e-4  # an accepted step is flat if it removes less than this fraction of F
DLS_WINDOW = 6  # accepted steps over which F must fall by DLS_PROGRESS, or the solve counts as stalled
DLS_PROGRESS = 0.05
DLS_LAM_CAP = 1e3  # lam beyond DLS_LAM_CAP * L is a stall
DLS_LIMIT_EPS = 1e-6  # radians: a DOF this close to a limit counts as on it
DLS_EULER_B_MAX = 0.5 * math.pi - 0.01  # an Euler-angle ball joint's middle angle stays this far from gimbal lock
DLS_KICK = 0.5  # radians: an escape moves DOFs stuck on a limit this far inward (at most half their range)
DLS_MAX_ESCAPES = 3  # escapes per solve
DLS_ESCAPE_ATTEMPTS = 12  # attempts an escape gets to beat the pose before its kick
# Secondary terms (rest, velocity, balance) in the null space of the targets (kernels/dls_system.py): their step z
# is scaled to at most DLS_NULL_STEP (radians, or metres for a free root) times damping / lam per column, and a
# step that does not lower the targets' part of F is still taken if it lowers the secondary part while every
# target error stays within DLS_NULL_BAND x tolerance.
DLS_NULL_STEP = 0.1
DLS_NULL_BAND = 0.5
# A free root under FABRIK and CCD (kernels/root_shift.py): before the solve the root moves, ROOT_SHIFT_ROUNDS
# times, by min(root_weight, 1) x the weighted mean of how far the effectors' targets lie beyond
# (1 - ROOT_SHIFT_SLACK) x their reach from the chain's base, over the effectors whose targets do.
ROOT_SHIFT_ROUNDS, ROOT_SHIFT_SLACK = 8, 0.1

# ---------------------------------------------------------------------------------------------- rotations
GIMBAL = 0.9999995  # |R02| from which an XYZ decomposition is taken as gimbal-locked
# A ball joint with a cone and box limits: when the box clamp puts the bone back outside its cone, the angles
# are pulled toward the box's point nearest rest along a straight line, by this many bisection steps (the
# cone then holds to ~range / 2^24, the box exactly).
CONE_BOX_STEPS = 24

# ---------------------------------------------------------------------------------------------- lanes
LANE_CHOICES = (1, 2, 4, 8, 16, 32)
_LANES: dict = {}


def cpu_vector_lanes(cpuinfo: str = "/proc/cpuinfo") -> int:
    """float32 lanes of the widest vector unit the CPU reports: 16 (AVX-512F), 8 (AVX2), else 4."""
    try:
        with open(cpuinfo, encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return 16 if "avx512f" in flags else 8 if "avx2" in flags else 4
    except OSError:
        pass
    return 4


def parse_lanes(value, source: str) -> int:
    """A lane width from a user (flag, argument or environment variable) or ValueError naming the source."""
    try:
        lanes = int(str(value).strip()) if not isinstance(value, int) or isinstance(value, bool) else value
    except ValueError:
        lanes = -1
    if isinstance(value, bool) or lanes not in LANE_CHOICES:
        raise ValueError(f"{source}: expected one of {', '.join(map(str, LANE_CHOICES))} (got {value!r})")
    return lanes


def choose_lanes(arch: str, requested: int | None = None) -> int:
    """The lane width for `arch` ("cpu" or "cuda"): `requested`, else CROWD_IK_LANES, else the hardware's."""
    if requested is not None:
        return parse_lanes(requested, "lanes")
    env = os.environ.get("CROWD_IK_LANES")
    if env:
        return parse_lanes(env, "CROWD_IK_LANES")
    return 1 if arch == "cuda" else cpu_vector_lanes()


def set_lanes(lanes: int, arch: str = "cpu") -> None:
    """Record the lane width and the backend (called once by crowd_ik.runtime.init)."""
    _LANES["L"] = parse_lanes(lanes, "lanes")
    _LANES["arch"] = arch


def on_gpu() -> bool:
    """Whether Taichi runs on CUDA (the free FABRIK lanes then size their streams for a GPU: kernels/lane_plan.py)."""
    return _LANES.get("arch") == "cuda"


def lanes() -> int:
    """The lane width of this process (chosen by crowd_ik.init; the CPU's before it runs)."""
    return _LANES.get("L") or choose_lanes("cpu")


LIMITED_LANES_MAX = 8  # kernels/fabrik_limited_lanes.py's width at most: its IR, and compile time, grow with the width
# (Taichi scalarises lane vectors; humanoid, cold, 2-core machine: 4 lanes 26-37 s of CPU, 8 lanes 40 s, 16 lanes
# 140 s). With the limb trigonometry element-wise (kernels/lane_trig.py) 8 lanes pay: warm 10,000-humanoid game
# solve 66.0 -> 37.5 ms against libm's calls at 8 lanes (which ran no faster than 4). Without Taichi's CFG passes
# (docs/ARCHITECTURE.md "Compile time"): 8 lanes 14.7 s, 16 lanes 35.8 s for a warm solve 10 % faster


def limited_lanes() -> int:
    """The lane width of the joint-limited FABRIK lanes: lanes(), at most LIMITED_LANES_MAX; 0 (the general
    kernel everywhere) with CROWD_IK_LIMITED_LANES=0. Against the one-character kernel, per solve from the same
    start (the game's warm 4-iteration frames on 10,000 humanoids, with and without the soles' orientation
    targets): statuses the same for >= 99.93 %, iteration counts for >= 99.96 %, poses within 1e-4 m for
    >= 99.2 % (p99 < 1e-4 m; float32 rounding in another order, which limits and nearly straight limbs amplify).
    Batch == one at a time holds bit for bit (the limb trigonometry is element-wise, kernels/lane_trig.py). Its
    cold compile at 8 lanes is less than the one-character kernel's, which the game then no longer needs
    (crowd-ik play cold, 2 cores: 76 s of CPU instead of 119 s)."""
    if os.environ.get("CROWD_IK_LIMITED_LANES", "1") == "0":
        return 0
    return min(lanes(), LIMITED_LANES_MAX)


def free_lanes() -> bool:
    """Whether constraint-free FABRIK runs the lane kernels (kernels/fabrik_lanes.py): at L lanes on the CPU, and at
    one lane on CUDA, a stream per GPU thread with its scratch joint-major (coalesced); CROWD_IK_FREE_LANES=0 sends
    it to the one-character kernel (kernels/fabrik.py) instead, on either backend (for comparison)."""
    return os.environ.get("CROWD_IK_FREE_LANES", "1") != "0"


def general_lanes() -> int:
    """The lane width of the general DLS lanes (kernels/dls_general_lanes.py): limited_lanes()' (its IR grows with
    the width as theirs does); 0 or 1, the one-character kernel (kernels/dls.py), with CROWD_IK_GENERAL_LANES=0 or
    on CUDA."""
    if os.environ.get("CROWD_IK_GENERAL_LANES", "1") == "0":
        return 0
    return limited_lanes()
