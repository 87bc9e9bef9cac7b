"""When a small launch's top-level loops run on the launching thread instead of Taichi's thread pool.

On the CPU backend each parallel top-level loop of a kernel is handed to the thread pool while the launching
thread waits: about 30-100 us per loop on an idle 2-core machine, and milliseconds when another process holds
a core (the video encoder, the render process), since the hand-off waits for a descheduled worker. A loop under
`ti.loop_config(serialize=True)` runs on the launching thread and skips that. The game's kernels (bullets,
limbs, dodges, gait, poles, FK) take `serial` as a `ti.template()` argument, so each is compiled once per
value, and their callers pass `serial_for(items, weight)`: serial when items x weight is at most SERIAL_WORK.
Results do not depend on it: none of these kernels uses float atomics, and their integer atomics feed only
order-free results (counts, prefix sums, minima under a total order); tests check serial == parallel.
"""

from crowd_ik.solvers.settings import on_gpu

# Units of work a serial launch may hold: one unit is about 0.1 us of one thread's time, so SERIAL_WORK is the
# ~0.4 ms of work below which the thread pool's hand-offs cost more than the second core saves.
SERIAL_WORK = 4096

# What one item costs in those units (timed at 40, 1,000 and 10,000 humanoids; the launch's fixed cost aside).
CELL = 1.0 / 64.0  # a grid cell cleared
CHEAP = 0.25  # a character's threat look-up or reach test
LIGHT = 1.0  # a bullet's step and collisions; a body's separation from its neighbours
BOX = 2.0  # a character's dodge targets, or its limb capsules and boxes
JOINT = 0.1  # a joint's forward kinematics
POSE = 5.0  # a humanoid's two planted legs, or its pole swivels
# a joint of a constraint-free chain solved by the FABRIK or closed-form DLS lanes (a solve of ~8 iterations;
# serial up to 1,003 chain16s). Chain16 from straight, median of 60 Crowd.solve calls, pool -> launching thread:
# stop 49 FABRIK 100 / 500 chains 505 -> 329 / 819 -> 650 us, DLS 444 -> 352 / 989 -> 890 us. Since a serial
# launch runs one stream (kernels/lane_plan.py streams), stop 50, interleaved: 600 / 1,000 / 2,000 chains FABRIK
# 866 -> 640 / 1,672 -> 1,095 / 2,152 -> 1,882 us, DLS 1,345 -> 1,042 / 1,670 -> 1,534 / 3,075 -> 2,966 us; from
# 3,000 (DLS: 3,893 / 4,304) or 5,000 (FABRIK: 3,014 / 4,151) the pool is faster. The pool's hand-offs on this VM
# vary from day to day, so the bound stays below both crossovers
CHAIN_JOINT = 0.24


def serial_for(items: float, weight: float = LIGHT) -> bool:
    """True when a launch over `items` items of `weight` units each is small enough to run on one thread; never on
    CUDA, where a serialised loop runs on one GPU thread and a launch costs the same either way."""
    return not on_gpu() and float(items) * float(weight) <= SERIAL_WORK
