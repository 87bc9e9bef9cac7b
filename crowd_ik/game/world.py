"""World: the SUPERHOT-style crowd game - player, shooters, bullets, threats -> IK targets, hits, time.

`World(scene)` owns three Crowds (the characters, the shooters, the one player), a BulletPool, the
shards of shattered characters and a Renderer, all allocated once. `step()` advances one video
frame, `render()` draws it.

Time (DESIGN "Game rules"). The player walks its path in *real* (video) time, pausing at every
corner. The time scale s follows the player's speed with a first-order response,
    ds/dt = response * (s_target - s),   s_target = floor + (1 - floor) * min(1, speed / player.speed),
and a video frame covers s / fps seconds of *world* time. The world always advances in fixed steps
of DT seconds: the frame's world time goes into an accumulator and whole steps are taken out of it,
so a frame in slow motion may take no step at all; `render()` then draws the state interpolated
between the last two steps (alpha = accumulator / DT), so slow motion stays smooth.

One world step, in a fixed order:
  1. shooters aim (ballistic aim at a chosen character, IK puts the right hand on the line of fire)
     and fire when due (deterministic spread and timing from the counter-based hash);
  2. each character asks the pool for the first bullet that will pass within THREAT_REACH of its
     chest within THREAT_HORIZON seconds, and - if that is within its own reflex time - turns it
     into a dodge: a lean vector away from the bullet's line, a duck for head-high bullets and a
     hand guard; the dodge is low-passed, moves the pelvis (set_roots) and becomes IK targets for
     head and hands, while the feet are targeted at their planted spots;
  3. IK for characters and shooters (one solve each, dead characters get zero weights);
  4. bullets move and collide (swept, sub-stepped) with the characters' limb capsules;
     hit characters shatter into shards that fall, bounce and fade; then the player's live
     bullets are tested against the standing shooters (see _player_hits_shooters): a shooter hit
     is down - it shatters like a character, stops aiming and firing and is no longer drawn;
  5. bookkeeping: a dodge is a bullet that came within THREAT_REACH of a character's chest and
     went past it (or stopped past it) without hitting it.

No Python loop runs over characters: everything per character is a NumPy array operation or a
kernel. Reproducible: the same scene, seed and frame count give the same frames (the HUD's measured
milliseconds aside, which `hud_timings=False` leaves out).
"""

from __future__ import annotations

import math
import time

import numpy as np

from crowd_ik import runtime
from crowd_ik.reference import rng as hrng
from crowd_ik.rig import Rig
from crowd_ik.scene import Scene

DT = 1.0 / 60.0  # seconds of world time per fixed simulation step
UP = np.array([0.0, 1.0, 0.0], np.float32)

# Threats and dodging; lengths are for a 1.75 m humanoid and scale with characters.scale.
THREAT_HORIZON = 0.7  # s: how far ahead bullets are predicted
THREAT_REACH = 0.7  # m: a bullet passing this close to the chest is a threat (and, if it misses, a dodge)
REFLEX_RANGE = (0.12, 0.65)  # s: each character starts dodging this long before the closest approach
CLEAR_HALF_WIDTH = 0.42  # m: lateral distance from the bullet line that clears the shoulders
MAX_LEAN = 0.42  # m: largest lean of the head away from a bullet line
MAX_DUCK = 0.32  # m: deepest duck
PELVIS_SHARE = 0.35  # fraction of the lean done by moving the pelvis
MAX_PELVIS_SHIFT = 0.16  # m
HEAD_LEVEL = 1.42  # m: bullets above this height are ducked under (by characters that prefer it)
TAU_ATTACK = 0.06  # s: low-pass time constant while a dodge builds up
TAU_RELEASE = 0.35  # s: ... and while it relaxes back to the stance
LEG_SLACK = 0.985  # the pelvis never asks a leg for more than this fraction of its length

# Shooters
ARM_REACH = 0.52  # m: right hand held this far from the shoulder along the line of fire
TAU_AIM = 0.12  # s: the aim follows a new target with this time constant
FIRST_SHOT = (0.3, 1.0)  # first shot after this fraction of 1 / fire_rate (uniform)
INTERVAL_JITTER = (0.8, 1.2)  # later shots every 1 / fire_rate times a factor in this range

# Shards of a hit character: each bone breaks in two short capsules.
SHARD_PIECES = 2
SHARD_LIFE = 3.0  # s of world time
SHARD_FADE = 1.0  # s: shards shrink away over the last second of their life
SHARD_RESTITUTION = 0.35
SHARD_FRICTION = 0.7  # horizontal speed kept at a bounce
SHARD_IMPULSE = 0.1  # fraction of the bullet's velocity given to the pieces next to the impact
SHARD_BURST = 1.6  # m/s: outward speed from the impact point
MAX_SHATTERED = 256  # the shard pool holds this many characters' (and shooters') pieces, oldest reused first

# The player's procedural walk (real time).
CORNER_PAUSE = 0.6  # s: the player stops at every corner of its path (time slows down)
STEP_TRIGGER = 0.17  # m: a foot steps when it is this far from where it should stand
SWING_TIME = 0.22  # s per step
STEP_LIFT = 0.09  # m
ARM_SWING = 0.16  # m
TURN_RATE = 8.0  # 1/s: heading follows the path with this rate

# Look (BGR, 0..1), SUPERHOT-like: white-grey crowd, red shooters, black guns and bullets.
CHARACTER_GREY = (0.80, 0.95)
PLAYER_COLOR = (0.20, 0.16, 0.12)
SHOOTER_COLOR = (0.16, 0.14, 0.82)
GUN_COLOR = (0.08, 0.08, 0.08)
BULLET_COLOR = (0.06, 0.06, 0.10)
SHARD_TINT = np.array([0.55, 0.62, 1.0], np.float32)  # multiplies the character's colour
BULLET_DRAW_RADIUS = 0.05  # m: bullets are drawn at least this big
TRAIL_LENGTH = 2.0  # m
HUD_EMA = 0.1  # smoothing of the HUD's millisecond figures
HUD_TIMINGS = False  # default of World(hud_timings=None): the HUD shows simulation values only, so
# frames are a function of scene, seed and frame count (`play --hud-timings` adds the milliseconds)

# Random streams (the first argument of the counter-based hash is seed + stream).
_STREAM_LAYOUT, _STREAM_CHAR, _STREAM_FIRE, _STREAM_SHARD, _STREAM_SIDE = (1 << 20) * np.arange(1, 6)

_HUMANOID_STANCE = {  # joint -> angles in degrees: knees slightly bent so the legs are never straight
    "hip_l": (-15.0, 0.0, 0.0), "hip_r": (-15.0, 0.0, 0.0), "knee_l": (30.0,), "knee_r": (30.0,),
    "ankle_l": (-15.0, 0.0), "ankle_r": (-15.0, 0.0), "elbow_l": (20.0,), "elbow_r": (20.0,),
}
_CHAIN_BONES = 8


def _rand(seed: int, stream: int, index, counter) -> np.ndarray:
    """float32 in [0, 1) from the counter-based hash: (seed + stream, index, counter) broadcast."""
    return hrng.uniform((int(seed) + int(stream)) & 0xFFFFFFFF, index, counter)


def _yaw_rotate(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) about +y by yaw (...) radians (+z turns toward +x)."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.empty(np.broadcast_shapes(v.shape, np.shape(yaw) + (3,)), np.float32)
    out[..., 0] = c * v[..., 0] + s * v[..., 2]
    out[..., 1] = v[..., 1]
    out[..., 2] = -s * v[..., 0] + c * v[..., 2]
    return out


def _normalize(v: np.ndarray, fallback=(0.0, 0.0, 1.0)) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-9, v / np.maximum(n, 1e-9), np.asarray(fallback, v.dtype)).astype(np.float32)


def _lowpass(current: np.ndarray, desired: np.ndarray, magnitude_now, magnitude_desired) -> np.ndarray:
    """One step of a first-order filter, fast while the magnitude grows and slow while it shrinks."""
    tau = np.where(magnitude_desired > magnitude_now, TAU_ATTACK, TAU_RELEASE)
    k = 1.0 - np.exp(-DT / tau)
    if current.ndim > k.ndim:
        k = k[..., None]
    return (current + (desired - current) * k).astype(np.float32)


def ballistic_direction(origin, target, speed: float, gravity: float, drag: float = 0.0) -> np.ndarray:
    """Unit launch directions (K, 3) from origin (K, 3) that reach target (K, 3) at `speed` m/s under gravity.

    Fixed-point iteration on the flight time t: aim at target + (0, g t^2 / 2, 0), t = |aim| / speed
    (the flat trajectory; drag is compensated to first order by the extra flight time it causes).
    """
    d = np.asarray(target, np.float64) - np.asarray(origin, np.float64)
    t = np.linalg.norm(d, axis=-1) / speed
    aim = d
    for _ in range(4):
        t_eff = t * (1.0 + 0.5 * drag * speed * t)
        aim = d + np.outer(0.5 * gravity * t_eff * t_eff, [0.0, 1.0, 0.0])
        t = np.linalg.norm(aim, axis=-1) / speed
    return _normalize(aim.astype(np.float32))


def cone_sample(direction: np.ndarray, half_angle: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions uniformly distributed (by solid angle) in the cone of `half_angle` radians around
    each unit `direction` (K, 3), from uniforms u1, u2 (K,)."""
    d = _normalize(np.asarray(direction, np.float32))
    helper = np.where(np.abs(d[:, 1:2]) < 0.9, UP, np.array([1.0, 0.0, 0.0], np.float32))
    e1 = _normalize(np.cross(helper, d))
    e2 = np.cross(d, e1)
    cos_t = 1.0 - u1 * (1.0 - math.cos(half_angle))
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * u2
    out = d * cos_t[:, None] + (e1 * np.cos(phi)[:, None] + e2 * np.sin(phi)[:, None]) * sin_t[:, None]
    return _normalize(out.astype(np.float32))


# ------------------------------------------------------------------------------------------------
# bodies: how a rig stands and which effectors follow a dodge


class Body:
    """A rig with its stance and how its effectors take part in a dodge.

    stance: (DOF,) radians; rest_root_y: root height that puts the stance's feet on the ground;
    rest_local: (E, 3) effectors relative to the root at yaw 0; lean/duck gains (E,) say how much
    of the dodge's lean vector and duck each effector follows; planted (E,) marks the feet (and
    orient (E, 3) their local axis target: up, so soles stay flat); pelvis_share: fraction of the
    lean done by the root; hands: effector indices that raise a guard (may be empty).
    """

    def __init__(self, rig: Rig, scale: float = 1.0):
        self.rig = rig
        self.scale = float(scale)
        J, E = rig.n_joints, rig.n_effectors
        names = rig.joint_names
        self.parent = rig.arrays["parent"]
        self.bone_parent = self.parent[1:].astype(np.intp)
        self.bone_radius = rig.arrays["radius"][1:].astype(np.float32)
        self.n_bones = J - 1
        self.eff_joint = rig.arrays["eff_joint"].astype(np.intp)
        stance = np.zeros(rig.n_dof, np.float32)
        self.humanoid = rig.name == "humanoid"
        if self.humanoid:
            for name, angles in _HUMANOID_STANCE.items():
                j = names.index(name)
                s = rig.dof_start[j]
                stance[s : s + len(angles)] = np.radians(angles)
        else:  # a chain stands up: its first joint turns the +x rest pose to +y
            stance[2] = math.pi / 2.0
        self.stance = stance
        # FK of the stance at the origin (one character, yaw 0), host side.
        pos = _stance_fk(rig, stance)
        if self.humanoid:
            ankle = names.index("ankle_l")
            self.rest_root_y = float(0.06 * self.scale - pos[ankle, 1])
            self.chest = names.index("chest")
            self.head = names.index("head")
            self.hand_r = names.index("hand_r")
            self.shoulder_r = names.index("shoulder_r")
            self.hips = np.array([names.index("hip_l"), names.index("hip_r")])
            self.leg_length = float(rig.bone_lengths[names.index("knee_l")] + rig.bone_lengths[ankle])
            self.hip_offset = pos[self.hips]  # (2, 3) hips relative to the root, yaw 0
            self.lean = np.array([1.0, 0.85, 0.85, 0.0, 0.0], np.float32)
            self.duck = np.array([1.0, 1.0, 1.0, 0.0, 0.0], np.float32)
            self.planted = np.array([False, False, False, True, True])
            self.hands = np.array([1, 2])
            self.pelvis_share = PELVIS_SHARE
        else:
            self.rest_root_y = 0.0
            self.chest = J // 2
            self.head = J - 1
            self.hand_r = J - 1
            self.shoulder_r = J - 2
            self.lean = np.ones(E, np.float32)
            self.duck = np.ones(E, np.float32)
            self.planted = np.zeros(E, bool)
            self.hands = np.zeros(0, np.intp)
            self.pelvis_share = 0.0
        self.rest_pos = (pos + [0.0, self.rest_root_y, 0.0]).astype(np.float32)  # (J, 3) at the origin
        self.rest_local = self.rest_pos[self.eff_joint]
        self.orient = np.zeros((E, 3), np.float32)
        self.orient[self.planted] = UP
        self.weights = np.ones(E, np.float32)

    def rest_targets(self, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, E, 3) world effector positions of the stance standing at ground (N, 3) (y = 0), yaw (N,)."""
        return ground[:, None, :] + _yaw_rotate(self.rest_local[None, :, :], yaw[:, None])

    def point(self, joint: int, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 3) world position of `joint` in the stance standing at ground (N, 3), yaw (N,)."""
        return ground + _yaw_rotate(self.rest_pos[joint][None], yaw)


def _stance_fk(rig: Rig, angles: np.ndarray) -> np.ndarray:
    """(J, 3) joint positions of one character in pose `angles`, root at the origin, yaw 0 (host NumPy)."""
    from crowd_ik.reference import fk as ref_fk

    q = ref_fk.angles_to_rotations(rig, angles[None])
    pos, _ = ref_fk.forward_kinematics(rig, np.zeros((1, 3)), np.zeros(1), q)
    return np.asarray(pos[0], np.float64)


def _ndarray(value: np.ndarray):
    """A Taichi ndarray holding a copy of `value`: (n, 3) float32 as n vec3, other arrays element-wise."""
    import taichi as ti

    if value.dtype == np.float32 and value.ndim == 2 and value.shape[1] == 3:
        arr = ti.ndarray(ti.math.vec3, shape=value.shape[:1])
    else:
        arr = ti.ndarray(ti.i32 if value.dtype == np.int32 else ti.f32, shape=value.shape)
    arr.from_numpy(np.ascontiguousarray(value))
    return arr


def _make_rig(kind: str, scale: float) -> Rig:
    if kind == "humanoid":
        return Rig.humanoid(1.75 * scale)
    return Rig.chain(_CHAIN_BONES, bone_length=0.2 * scale, dim=3)


# ------------------------------------------------------------------------------------------------
# the player's walk (one character, real time: scalar code)


class Walker:
    """The player: walks `path` [(x, z), ...] at `speed` m/s with a pause at every corner, stepping
    its feet procedurally (a foot steps when it lags too far behind where it should stand).

    update(dt) advances real time and returns (root (3,), yaw, targets (E, 3), speed m/s).
    """

    def __init__(self, body: Body, path, speed: float):
        self.body = body
        pts = np.asarray(path, np.float64).reshape(-1, 2)
        self.speed = float(speed)
        # schedule: rows of (t0, t1, x0, z0, x1, z1); pauses have equal ends
        rows, t = [], 0.0
        keep = [pts[0]]
        for p in pts[1:]:
            if np.linalg.norm(p - keep[-1]) > 1e-6:
                keep.append(p)
        for i in range(len(keep) - 1):
            if i > 0:
                rows.append((t, t + CORNER_PAUSE, *keep[i], *keep[i]))
                t += CORNER_PAUSE
            dur = float(np.linalg.norm(keep[i + 1] - keep[i])) / self.speed
            rows.append((t, t + dur, *keep[i], *keep[i + 1]))
            t += dur
        self.schedule = np.array(rows, np.float64).reshape(-1, 6)
        self.headings = [math.atan2(r[4] - r[2], r[5] - r[3]) for r in self.schedule if r[1] > r[0] and
                         (r[4], r[5]) != (r[2], r[3])]
        self.end = keep[-1]
        self.t = 0.0
        x, z = self._position(0.0)
        self.yaw = self._heading(0.0)
        self.root = np.array([x, body.rest_root_y, z])
        self.plants = self._homes(self.root, self.yaw).copy()
        self.swing = -1
        self.swing_t = 0.0
        self.swing_from = np.zeros(3)
        self.swing_to = np.zeros(3)
        self.arm = 0.0

    def _position(self, t: float) -> tuple[float, float]:
        if len(self.schedule) == 0 or t >= self.schedule[-1, 1]:
            return float(self.end[0]), float(self.end[1])
        i = int(np.searchsorted(self.schedule[:, 1], t, side="right"))
        t0, t1, x0, z0, x1, z1 = self.schedule[i]
        f = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        return x0 + (x1 - x0) * f, z0 + (z1 - z0) * f

    def _heading(self, t: float) -> float:
        """Heading of the segment walked at time t, or of the next one during a pause."""
        if not self.headings:
            return 0.0
        walks = [r for r in self.schedule if (r[4], r[5]) != (r[2], r[3])]
        for r in walks:
            if t < r[1]:
                return math.atan2(r[4] - r[2], r[5] - r[3])
        return self.headings[-1]

    def _homes(self, root: np.ndarray, yaw: float) -> np.ndarray:
        """(2, 3) where the two feet stand under a standing body at root, yaw."""
        b = self.body
        feet = b.rest_local[b.planted]
        return np.asarray(root, np.float64) * [1.0, 0.0, 1.0] + _yaw_rotate(feet, np.float32(yaw)).astype(np.float64)

    def update(self, dt: float):
        b = self.body
        self.t += dt
        x, z = self._position(self.t)
        moved = math.hypot(x - self.root[0], z - self.root[2])
        speed = moved / dt
        vel = np.array([x - self.root[0], 0.0, z - self.root[2]]) / dt
        want = self._heading(self.t)
        turn = (want - self.yaw + math.pi) % (2.0 * math.pi) - math.pi
        self.yaw += turn * (1.0 - math.exp(-TURN_RATE * dt))
        root = np.array([x, b.rest_root_y, z])
        homes = self._homes(root, self.yaw)
        if self.swing >= 0:
            self.swing_t += dt / SWING_TIME
            if self.swing_t >= 1.0:
                self.plants[self.swing] = self.swing_to
                self.swing = -1
        if self.swing < 0:
            lag = np.linalg.norm(self.plants - homes, axis=1)
            k = int(np.argmax(lag))
            if lag[k] > STEP_TRIGGER * b.scale:
                self.swing, self.swing_t = k, 0.0
                self.swing_from = self.plants[k].copy()
                self.swing_to = homes[k] + vel * SWING_TIME * 1.5
        feet = self.plants.copy()
        lift = 0.0
        if self.swing >= 0:
            f = self.swing_t * self.swing_t * (3.0 - 2.0 * self.swing_t)
            lift = math.sin(math.pi * self.swing_t)
            feet[self.swing] = self.swing_from + (self.swing_to - self.swing_from) * f
            feet[self.swing, 1] += STEP_LIFT * b.scale * lift
        # the pelvis bobs up mid-step and never asks a leg for more than its length
        root[1] += 0.015 * b.scale * lift
        root[1] = min(root[1], _max_root_y(b, root[None], np.array([self.yaw]), feet[None])[0])
        arm_goal = 0.0 if self.swing < 0 else (1.0 if self.swing == 1 else -1.0) * min(1.0, speed / self.speed)
        self.arm += (arm_goal - self.arm) * (1.0 - math.exp(-dt / 0.12))
        ground = (root * [1.0, 0.0, 1.0])[None].astype(np.float32)
        targets = b.rest_targets(ground, np.array([self.yaw], np.float32))[0].astype(np.float64)
        targets[:, 1] += root[1] - b.rest_root_y  # the upper body follows the pelvis bob and drop
        fwd = np.array([math.sin(self.yaw), 0.0, math.cos(self.yaw)])
        targets[0] += fwd * 0.04 * b.scale * min(1.0, speed / max(self.speed, 1e-9))
        if b.humanoid:
            targets[1] += fwd * ARM_SWING * b.scale * self.arm
            targets[2] -= fwd * ARM_SWING * b.scale * self.arm
        targets[b.planted] = feet
        self.root = root
        return root, self.yaw, targets.astype(np.float32), speed


def _max_root_y(body: Body, roots: np.ndarray, yaw: np.ndarray, feet: np.ndarray) -> np.ndarray:
    """(N,) highest root height at which both hips of roots (N, 3), yaw (N,) reach feet (N, 2, 3)."""
    if not body.humanoid:
        return np.full(len(roots), np.inf)
    hips = roots[:, None, :] * [1.0, 0.0, 1.0] + _yaw_rotate(body.hip_offset[None].astype(np.float32), yaw[:, None])
    reach = LEG_SLACK * body.leg_length
    dh = np.linalg.norm((hips - feet)[..., [0, 2]], axis=-1)
    up = np.sqrt(np.maximum(reach * reach - dh * dh, (0.2 * reach) ** 2))
    return np.min(feet[..., 1] + up - body.hip_offset[:, 1][None, :], axis=1)


# ------------------------------------------------------------------------------------------------
# layout


def character_layout(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Roots (N, 3) on the ground and yaw (N,) of the characters: grid facing +z, ring facing the
    centre, random = a jittered grid (seeded) facing +z within +-60 degrees."""
    from crowd_ik.crowd import grid_positions

    c = scene.characters
    n, sp = c.count, c.spacing
    idx = np.arange(n)
    if c.layout == "ring":
        radius = max(sp * n / (2.0 * math.pi), sp)
        theta = 2.0 * math.pi * idx / n
        roots = np.stack([radius * np.sin(theta), np.zeros(n), radius * np.cos(theta)], axis=1)
        yaw = theta + math.pi
    else:
        roots = grid_positions(n, sp, 3).astype(np.float64)
        yaw = np.zeros(n)
        if c.layout == "random":
            jx = _rand(scene.seed, _STREAM_LAYOUT, idx, 0) - 0.5
            jz = _rand(scene.seed, _STREAM_LAYOUT, idx, 1) - 0.5
            roots[:, 0] += 0.5 * sp * jx
            roots[:, 2] += 0.5 * sp * jz
            yaw = (_rand(scene.seed, _STREAM_LAYOUT, idx, 2) - 0.5) * (2.0 * math.pi / 3.0)
    return roots.astype(np.float32), yaw.astype(np.float32)


RING_PHASES = (0.5, 0.0, 0.25, 0.75, 0.125, 0.375, 0.625, 0.875)  # in units of the shooters' spacing


def shooter_layout(scene: Scene, camera=None) -> tuple[np.ndarray, np.ndarray]:
    """Roots (S, 3) on the ground and yaw (S,) of the shooters, facing the centre (a ring) or +z (a line).

    ring: S places on a circle of shooters.radius, turned by the first of RING_PHASES that puts the
    most shooters wholly in the camera's view (feet and head inside the frame), so that as many
    as possible are seen shooting; line: 2 m apart at z = -radius.
    """
    s = scene.shooters
    k = np.arange(s.count)
    if s.placement == "line":
        roots = np.stack([(k - (s.count - 1) / 2.0) * 2.0, np.zeros(s.count), np.full(s.count, -s.radius)], axis=1)
        return roots.astype(np.float32), np.zeros(s.count, np.float32)
    best, best_seen = RING_PHASES[0], -1
    for phase in RING_PHASES if camera is not None else RING_PHASES[:1]:
        theta = 2.0 * math.pi * (k + phase) / s.count
        feet = np.stack([s.radius * np.sin(theta), np.zeros(s.count), s.radius * np.cos(theta)], axis=1)
        if camera is None:
            break
        head = feet + [0.0, 1.8 * scene.characters.scale, 0.0]
        inside = np.ones(s.count, bool)
        for points in (feet, head):
            pix, _ = camera.project(points)
            inside &= ((pix[:, 0] >= 0) & (pix[:, 0] <= camera.width - 1)
                       & (pix[:, 1] >= 0) & (pix[:, 1] <= camera.height - 1))
        if int(inside.sum()) > best_seen:
            best, best_seen = phase, int(inside.sum())
    theta = 2.0 * math.pi * (k + best) / s.count
    roots = np.stack([s.radius * np.sin(theta), np.zeros(s.count), s.radius * np.cos(theta)], axis=1)
    return roots.astype(np.float32), (theta + math.pi).astype(np.float32)


# ------------------------------------------------------------------------------------------------
# the world


class World:
    """The game: characters, shooters, the player, bullets and shards, stepped and drawn.

    autofire=False keeps the shooters aiming but not firing (bullets then come only from `fire`).
    hud_timings=False leaves the measured milliseconds out of the HUD, so frames are bit-identical
    between runs (None: the module default HUD_TIMINGS).
    """

    def __init__(self, scene: Scene, autofire: bool = True, hud_timings: bool | None = None):
        if not isinstance(scene, Scene):
            raise ValueError(f"World: scene: expected a crowd_ik.Scene (got {type(scene).__name__})")
        runtime.ensure_init()
        from crowd_ik.game.bullets import BulletPool
        from crowd_ik.crowd import Crowd
        from crowd_ik.view.render import Camera

        self.scene = scene
        self.seed = scene.seed
        self.autofire = bool(autofire)
        self.hud_timings = HUD_TIMINGS if hud_timings is None else bool(hud_timings)
        self.n = N = scene.characters.count
        self.n_shooters = S = scene.shooters.count
        scale = scene.characters.scale
        self.body = Body(_make_rig(scene.characters.rig, scale), scale)
        self.hbody = self.body if self.body.humanoid else Body(Rig.humanoid(1.75 * scale), scale)
        b, hb = self.body, self.hbody
        E, B = b.rig.n_effectors, b.n_bones

        # characters
        self.ground, self.yaw = character_layout(scene)  # (N, 3) y = 0, (N,)
        self.roots = self.ground + np.float32([0.0, b.rest_root_y, 0.0])
        self.crowd = Crowd(b.rig, n=N, seed=scene.seed)
        self.crowd.set_angles(b.stance)
        self.crowd.set_roots(self.roots, self.yaw)
        self.rest_targets = b.rest_targets(self.ground, self.yaw)  # (N, E, 3)
        self.planted = self.rest_targets[:, b.planted].copy()  # (N, 2, 3) ankles, world
        # the point threats are measured from: the chest (a chain's middle joint)
        self.ref_points = np.ascontiguousarray(b.point(b.chest, self.ground, self.yaw), np.float32)
        self.alive = np.ones(N, bool)
        self.reflex = (REFLEX_RANGE[0] + (REFLEX_RANGE[1] - REFLEX_RANGE[0])
                       * _rand(self.seed, _STREAM_CHAR, np.arange(N), 0)).astype(np.float32)
        self.prefers_duck = _rand(self.seed, _STREAM_CHAR, np.arange(N), 1) < 0.5
        lo, hi = CHARACTER_GREY
        grey = lo + (hi - lo) * _rand(self.seed, _STREAM_CHAR, np.arange(N), 2)
        self.colors = np.repeat(grey[:, None], 3, axis=1).astype(np.float32)  # (N, 3) BGR
        self.lean = np.zeros((N, 3), np.float32)  # low-passed dodge state
        self.duck = np.zeros(N, np.float32)
        self.guard = np.zeros(N, np.float32)
        self.threat = None  # the last step's Threats, for inspection
        self._tracked = np.full(N, -1, np.int32)  # bullet slot that threatens each character
        self._tracked_serial = np.full(N, -1, np.int64)
        self._char_orient = np.ascontiguousarray(np.broadcast_to(b.orient, (N, E, 3)), np.float32)
        self._char_weights = np.ascontiguousarray(np.broadcast_to(b.weights, (N, E)), np.float32)
        # dodge_targets' per-rig arguments (placeholders where a chain has no hips or hands) and outputs
        slot = np.full(E, -1, np.int32)
        slot[b.planted] = np.arange(int(b.planted.sum()), dtype=np.int32)
        self._dodge_consts = (
            b.lean.astype(np.float32), b.duck.astype(np.float32), slot,
            (b.hands if len(b.hands) else np.full(1, -1)).astype(np.int32),
            (b.hip_offset if b.humanoid else np.zeros((1, 3))).astype(np.float32),
            int(b.humanoid), b.pelvis_share, MAX_PELVIS_SHIFT, LEG_SLACK * b.leg_length if b.humanoid else 1.0, b.scale,
        )
        self._planted_arg = self.planted if b.humanoid else np.zeros((N, 1, 3), np.float32)
        self._targets_buf = np.zeros((N, E, 3), np.float32)
        self._roots_buf = np.zeros((N, 3), np.float32)
        # limbs for the bullet pool, kept in Taichi ndarrays: capsule n * B + k is character n's bone k
        self._owner = _ndarray(np.repeat(np.arange(N, dtype=np.int32), B))  # capsule c is character c // B
        self._cap_radius = _ndarray(np.tile(b.bone_radius, N))
        self._bone_parent = _ndarray(b.bone_parent.astype(np.int32))
        self._bone_radius = _ndarray(b.bone_radius)
        self._caps = [(_ndarray(np.zeros((N * B, 3), np.float32)), _ndarray(np.zeros((N * B, 3), np.float32)))
                      for _ in range(2)]  # this step's and the previous step's capsule ends, alternating
        self._pose_box = [_ndarray(np.zeros((N, 4), np.float32)) for _ in range(2)]  # (x, z) box of each set
        self._caps_now = 0
        self._owner_box = _ndarray(np.zeros((N, 4), np.float32))
        self._joint_bufs = (np.zeros((N, b.rig.n_joints, 3), np.float32), np.zeros((N, b.rig.n_joints, 3), np.float32))
        self._joints = self._joint_bufs[0]
        for _ in range(2):  # both capsule sets hold the starting pose
            self._update_limbs()
        self._joints_prev = self._joints  # (N, J, 3) now and at the previous step (host)

        # shooters: humanoids at the characters' scale, aiming with the right hand
        cam = scene.camera
        self.camera = Camera(cam.position, cam.look_at, cam.fov_deg, scene.video.width, scene.video.height)
        self.shooter_ground, self.shooter_yaw = shooter_layout(scene, self.camera)
        self.shooter_roots = self.shooter_ground + np.float32([0.0, hb.rest_root_y, 0.0])
        self.shooters = Crowd(hb.rig, n=S, seed=scene.seed)
        self.shooters.set_angles(hb.stance)
        self.shooters.set_roots(self.shooter_roots, self.shooter_yaw)
        self._shooter_joints = self.shooters.joint_positions().astype(np.float32)
        self._shooter_joints_prev = self._shooter_joints.copy()
        self._shooter_orient = np.ascontiguousarray(np.broadcast_to(hb.orient, (S, hb.rig.n_effectors, 3)), np.float32)
        self.shots_fired = np.zeros(S, np.int64)
        self.shooter_alive = np.ones(S, bool)  # False once a player's bullet has downed the shooter
        self._shooter_weights = np.ones((S, hb.rig.n_effectors), np.float32)  # zero rows for downed shooters
        k = np.arange(S)
        period = 1.0 / scene.shooters.fire_rate
        self.next_fire = (period * (FIRST_SHOT[0] + (FIRST_SHOT[1] - FIRST_SHOT[0])
                                    * _rand(self.seed, _STREAM_FIRE, k, 0))).astype(np.float64)
        self.shooter_target = np.zeros(S, np.int32)
        self.shooter_aim_joint = np.zeros(S, np.intp)
        self._pick_targets(k)
        hand = self._shooter_joints[:, hb.hand_r]
        self.aim = self._aim_directions(k, hand)

        # the player
        self.walker = Walker(hb, scene.player.path, scene.player.speed)
        self.player = Crowd(hb.rig, n=1, seed=scene.seed)
        self.player.set_angles(hb.stance)
        self.player_speed = 0.0
        self._player_orient = hb.orient[None].copy()

        # bullets: a pool over the arena's extent
        extent = max(float(np.abs(self.roots[:, [0, 2]]).max()) + 2.0 * scene.characters.spacing,
                     float(np.abs(self.shooter_roots[:, [0, 2]]).max()) + 2.0,
                     float(np.abs(np.asarray(scene.player.path)).max()) + 2.0)
        bounds = (-extent, -extent, extent, extent)
        cell = max(1.0, 1.2 * scene.characters.spacing)
        self.pool = BulletPool(scene.bullets.pool_size, scene.bullets.radius, bounds=bounds, cell_size=cell,
                               far=4.0 * extent + 50.0, capsule_capacity=N * B)
        P = scene.bullets.pool_size
        self._slot_serial = np.full(P, -1, np.int64)
        self._slot_origin = np.zeros((P, 3), np.float32)
        self._bpos = np.zeros((P, 3), np.float32)
        self._bpos_prev = np.zeros((P, 3), np.float32)
        self._bvel = np.zeros((P, 3), np.float32)
        self._balive = np.zeros(P, bool)
        self._balive_i32 = np.zeros(P, np.int32)  # the pool's alive flags, exported each step
        # slots holding the player's live bullets: only these hit shooters (a shooter's own bullets
        # start in its hand, inside its own limbs); cleared when the bullet dies or the slot is reused
        self._player_slot = np.zeros(P, bool)
        self._serial = 0

        # shards: a ring of pieces, SHARD_PIECES per bone of MAX_SHATTERED characters and as many shooters
        M = SHARD_PIECES * (B * min(N, MAX_SHATTERED) + hb.n_bones * min(S, MAX_SHATTERED))
        self._sh_c = np.zeros((M, 3), np.float32)
        self._sh_c_prev = np.zeros((M, 3), np.float32)
        self._sh_h = np.zeros((M, 3), np.float32)
        self._sh_v = np.zeros((M, 3), np.float32)
        self._sh_w = np.zeros((M, 3), np.float32)
        self._sh_r = np.zeros(M, np.float32)
        self._sh_age = np.zeros(M, np.float32)
        self._sh_live = np.zeros(M, bool)
        self._sh_color = np.zeros((M, 3), np.float32)
        self._sh_next = 0
        self._sh_serial = 0

        # clocks and counters
        self.frame = 0
        self.world_time = 0.0
        self.time_scale = scene.time.floor
        self.steps = 0
        self.hits = 0
        self.dodges = 0
        self._acc = 0.0
        self._phase_ms = {"simulation": 0.0, "ik": 0.0, "render": 0.0}
        self.last_step_ms = {"ik": 0.0, "bullets": 0.0, "total": 0.0}  # see step_world
        self.last_report = None  # the characters' SolveReport of the last world step
        self.totals = {"simulation_ms": 0.0, "ik_ms": 0.0, "render_ms": 0.0, "frames": 0, "rendered": 0}
        self._hud_ms = {"ik": None, "simulation": None}  # smoothed for the HUD

        # drawing
        self.max_capsules = N * B + S * (hb.n_bones + 1) + hb.n_bones + M
        self._renderer = None  # made on the first render(): export and timing runs never draw
        self._body_names = None  # primitives()' body names, made on first use
        self._update_player(0.0)

    # ------------------------------------------------------------------ public API
    @property
    def stats(self) -> dict:
        """Counters and the last frame's per-phase milliseconds (simulation, IK, render).

        hits and standing count the characters; shooters_down the shooters downed by the player's bullets.
        """
        return {
            "frame": self.frame,
            "world_time": self.world_time,
            "time_scale": self.time_scale,
            "steps": self.steps,
            "hits": self.hits,
            "dodges": self.dodges,
            "shots": int(self.shots_fired.sum()),
            "standing": int(self.alive.sum()),
            "shooters_down": self.shooters_down,
            "bullets": int(self._balive.sum()),
            "shards": int(self._sh_live.sum()),
            "simulation_ms": self._phase_ms["simulation"],
            "ik_ms": self._phase_ms["ik"],
            "render_ms": self._phase_ms["render"],
        }

    @property
    def shooters_down(self) -> int:
        """How many shooters the player's bullets have downed."""
        return int(self.n_shooters - np.count_nonzero(self.shooter_alive))

    def joints(self) -> np.ndarray:
        """(N, J, 3) float32 world joint positions of the characters after the last world step."""
        return self._joints.copy()

    def bullets(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (K, 3), velocities (K, 3)) of the live bullets after the last world step."""
        return self._bpos[self._balive].copy(), self._bvel[self._balive].copy()

    def fire(self, origins, velocities) -> np.ndarray:
        """Spawn bullets now at origins (K, 3) m with velocities (K, 3) m/s; returns their slots.

        They are nobody's in particular: like the shooters' bullets they hit characters, not shooters
        (only the player's bullets, fired by set_player_input, hit shooters).
        """
        origins = np.asarray(origins, np.float32).reshape(-1, 3)
        velocities = np.asarray(velocities, np.float32).reshape(-1, 3)
        if origins.shape != velocities.shape or not (np.all(np.isfinite(origins)) and np.all(np.isfinite(velocities))):
            raise ValueError(f"fire: origins and velocities must be finite (K, 3) arrays "
                             f"(got {origins.shape} and {velocities.shape})")
        return self._spawn(origins, velocities)

    def set_player_input(self, move, aim=None, fire: bool = False) -> np.ndarray:
        """Steer the player by hand instead of along its path (live play, recorded inputs).

        move: (x, z) in [-1, 1] world axes (a longer vector is cut to length 1): the player walks
        at move * player.speed in the following step() calls, until the next call (the scripted
        path is not resumed); the time scale follows its speed as before. aim: (3,) world point
        or None: the player turns toward it and IK holds its right hand on the line from the
        shoulder to it. fire: spawn one bullet now from the right hand toward aim (needs aim),
        through the pool like the shooters' bullets; the player's bullets also hit the shooters
        (a shooter hit is down). Returns the pool slots spawned (0 or 1).
        """
        from crowd_ik.game.live import SteeredWalker

        if not isinstance(self.walker, SteeredWalker):
            self.walker = SteeredWalker(self.walker)
        self.walker.steer(move, aim)
        if not fire:
            return np.zeros(0, np.int64)
        if aim is None:
            raise ValueError("set_player_input: fire needs an aim point (got aim=None)")
        bl, hb = self.scene.bullets, self.hbody
        hand = self._player_joints[hb.hand_r][None].astype(np.float32)
        d = ballistic_direction(hand, self.walker.aim[None], bl.speed, bl.gravity, bl.drag)
        return self._spawn(hand + d * np.float32(0.08 * hb.scale), d * np.float32(bl.speed), player=True)

    def step(self) -> None:
        """Advance one video frame: the player walks 1/fps s of real time, the time scale follows it,
        and the world takes as many fixed DT steps as the frame's world time allows."""
        t0 = time.perf_counter()
        self._phase_ms["ik"] = 0.0
        dt_video = 1.0 / self.scene.video.fps
        self._update_player(dt_video)
        t = self.scene.time
        goal = t.floor + (1.0 - t.floor) * min(1.0, self.player_speed / self.scene.player.speed)
        self.time_scale += (goal - self.time_scale) * (1.0 - math.exp(-t.response * dt_video))
        self._acc += self.time_scale * dt_video
        while self._acc >= DT:
            self._acc -= DT
            self.step_world()
        self.frame += 1
        total = 1e3 * (time.perf_counter() - t0)
        self._phase_ms["simulation"] = total - self._phase_ms["ik"]
        self.totals["simulation_ms"] += self._phase_ms["simulation"]
        self.totals["ik_ms"] += self._phase_ms["ik"]
        self.totals["frames"] += 1
        for key in ("ik", "simulation"):
            old = self._hud_ms[key]
            self._hud_ms[key] = self._phase_ms[key] if old is None else old + HUD_EMA * (self._phase_ms[key] - old)

    def step_world(self) -> None:
        """One fixed world step of DT seconds (shooters, threats and dodges, IK, bullets and hits, shards)."""
        self._joints_prev, self._shooter_joints_prev = self._joints, self._shooter_joints
        np.copyto(self._bpos_prev, self._bpos)
        np.copyto(self._sh_c_prev, self._sh_c)
        t0 = time.perf_counter()
        self._shooters_aim_and_fire()
        self._dodge()
        t1 = time.perf_counter()
        self._solve_characters()
        t2 = time.perf_counter()
        self._solve_shooters()
        t3 = time.perf_counter()
        self._bullets_and_hits()
        t4 = time.perf_counter()
        self._shards_step()
        self.world_time += DT
        self.steps += 1
        # milliseconds of this step: the characters' IK (targets, solve, limb capsules), the bullets' step with
        # its hits, and the whole step
        self.last_step_ms = dict(ik=1e3 * (t2 - t1), bullets=1e3 * (t4 - t3),
                                 total=1e3 * (time.perf_counter() - t0))

    def simulate(self, seconds: float) -> None:
        """Advance the world alone by `seconds` of world time (whole DT steps; the player and the
        time scale stay put): for scripted tests and for timing the simulation without rendering."""
        for _ in range(int(round(seconds / DT))):
            self.step_world()

    # ------------------------------------------------------------------ player and time
    def _update_player(self, dt: float) -> None:
        t0 = time.perf_counter()
        hb = self.hbody
        if dt > 0.0:
            root, yaw, targets, speed = self.walker.update(dt)
        else:
            w = self.walker
            root, yaw = w.root.astype(np.float32), w.yaw
            targets = hb.rest_targets((root * [1.0, 0.0, 1.0])[None].astype(np.float32), np.array([yaw], np.float32))[0]
            speed = 0.0
        self.player_speed = speed
        self.player.set_roots(np.asarray(root, np.float32)[None], np.array([yaw], np.float32))
        sv = self.scene.solver
        iterations = sv.iterations if dt > 0.0 else max(sv.iterations, 50)
        self.player.solve(targets[None], method=sv.method, max_iterations=iterations, tolerance=sv.tolerance,
                          orientations=self._player_orient)
        self._player_joints = self.player.joint_positions()[0].astype(np.float32)
        self._phase_ms["ik"] += 1e3 * (time.perf_counter() - t0)

    # ------------------------------------------------------------------ shooters
    def _pick_targets(self, k: np.ndarray) -> None:
        """New targets for shooters k: a standing character (hash pick) and head or chest."""
        living = np.flatnonzero(self.alive)
        if living.size == 0 or k.size == 0:
            return
        shot = self.shots_fired[k]
        u = _rand(self.seed, _STREAM_FIRE, k, 8 * shot + 1)
        self.shooter_target[k] = living[np.minimum((u * living.size).astype(np.int64), living.size - 1)]
        head = _rand(self.seed, _STREAM_FIRE, k, 8 * shot + 2) < 0.5
        self.shooter_aim_joint[k] = np.where(head, self.body.head, self.body.chest)

    def _aim_directions(self, k: np.ndarray, muzzle: np.ndarray) -> np.ndarray:
        """Ballistic unit directions (K, 3) from muzzle (K, 3) to shooters k's aim points."""
        b = self.scene.bullets
        point = self._joints[self.shooter_target[k], self.shooter_aim_joint[k]]
        return ballistic_direction(muzzle, point, b.speed, b.gravity, b.drag)

    def _shooters_aim_and_fire(self) -> None:
        hb = self.hbody
        S = self.n_shooters
        k = np.arange(S)
        up = self.shooter_alive  # downed shooters neither aim nor fire
        dead_target = ~self.alive[self.shooter_target] & up
        if dead_target.any():
            self._pick_targets(k[dead_target])
        muzzle = self._shooter_joints[:, hb.hand_r]
        want = self._aim_directions(k, muzzle)
        aim = _normalize(self.aim + (want - self.aim) * (1.0 - math.exp(-DT / TAU_AIM)))
        self.aim = aim if up.all() else np.where(up[:, None], aim, self.aim)
        if not (self.autofire and self.alive.any()):
            return
        due = np.flatnonzero((self.world_time >= self.next_fire) & up)
        if due.size == 0:
            return
        shot = self.shots_fired[due]
        sc = self.scene.shooters
        u1 = _rand(self.seed, _STREAM_FIRE, due, 8 * shot + 3)
        u2 = _rand(self.seed, _STREAM_FIRE, due, 8 * shot + 4)
        dirs = cone_sample(want[due], math.radians(sc.spread_deg), u1, u2)
        origins = muzzle[due] + dirs * 0.08 * hb.scale
        self._spawn(origins, dirs * self.scene.bullets.speed)
        jitter = INTERVAL_JITTER[0] + (INTERVAL_JITTER[1] - INTERVAL_JITTER[0]) * _rand(
            self.seed, _STREAM_FIRE, due, 8 * shot + 5)
        self.next_fire[due] = self.world_time + jitter / sc.fire_rate
        self.shots_fired[due] += 1
        self._pick_targets(due)

    def _spawn(self, origins: np.ndarray, velocities: np.ndarray, player: bool = False) -> np.ndarray:
        """Bullets into the pool's lowest free slots; player=True marks them as the player's."""
        slots, _dropped = self.pool.spawn(origins, velocities)
        n = len(slots)
        self._player_slot[slots] = bool(player)
        self._slot_serial[slots] = self._serial + np.arange(n)
        self._serial += n
        self._slot_origin[slots] = origins[:n]
        self._bpos[slots] = origins[:n]
        self._bpos_prev[slots] = origins[:n]
        self._bvel[slots] = velocities[:n]
        self._balive[slots] = True
        return slots

    def _solve_shooters(self) -> None:
        """Turn toward the aim and put the right hand on the line of fire (downed shooters keep their
        last pose: zero weights; none standing, no solve)."""
        hb = self.hbody
        up = self.shooter_alive
        if not up.any():
            return
        fwd = self.aim * [1.0, 0.0, 1.0]
        want_yaw = np.arctan2(fwd[:, 0], fwd[:, 2])
        turn = (want_yaw - self.shooter_yaw + math.pi) % (2.0 * math.pi) - math.pi
        turn = np.where(up, turn, 0.0)
        self.shooter_yaw = (self.shooter_yaw + turn * (1.0 - math.exp(-DT / 0.25))).astype(np.float32)
        targets = hb.rest_targets(self.shooter_ground, self.shooter_yaw)
        shoulder = hb.point(hb.shoulder_r, self.shooter_ground, self.shooter_yaw)
        targets[:, 2] = shoulder + self.aim * ARM_REACH * hb.scale
        t0 = time.perf_counter()
        self.shooters.set_roots(self.shooter_roots, self.shooter_yaw)
        sv = self.scene.solver
        self.shooters.solve(targets, method=sv.method, max_iterations=sv.iterations, tolerance=sv.tolerance,
                            weights=self._shooter_weights, orientations=self._shooter_orient)
        self._shooter_joints = self.shooters.joint_positions().astype(np.float32)
        self._phase_ms["ik"] += 1e3 * (time.perf_counter() - t0)

    # ------------------------------------------------------------------ threats and dodges
    def _dodge(self) -> None:
        """Threats -> dodge bookkeeping -> the low-passed dodge state (lean, duck, guard)."""
        b = self.body
        scale = b.scale
        alive_i = self.alive.astype(np.int32)
        thr = self.pool.threats(self.ref_points, alive_i, THREAT_HORIZON, THREAT_REACH * scale)
        self.threat = thr
        # 1. tracked bullets that went past their character are dodges; ones that stopped short are dropped
        tr = self._tracked
        idx = np.flatnonzero((tr >= 0) & self.alive)
        if idx.size:
            p = tr[idx]
            same = self._slot_serial[p] == self._tracked_serial[idx]
            rel = self.ref_points[idx] - self._bpos[p]
            past = np.einsum("ij,ij->i", rel, self._bvel[p]) <= 0.0
            dodged = same & past
            self.dodges += int(dodged.sum())
            done = dodged | ~same | (~self._balive[p] & ~past)
            tr[idx[done]] = -1
        # 2. new close passes are tracked
        close = (tr < 0) & self.alive & (thr.bullet >= 0) & (thr.time < THREAT_HORIZON)
        tr[close] = thr.bullet[close]
        self._tracked_serial[close] = self._slot_serial[thr.bullet[close]]
        # 3. the dodge each character wants now
        react = self.alive & (thr.bullet >= 0) & (thr.time <= self.reflex)
        lean_goal = np.zeros_like(self.lean)
        duck_goal = np.zeros_like(self.duck)
        guard_goal = np.zeros_like(self.guard)
        i = np.flatnonzero(react)
        if i.size:
            d = thr.direction[i]
            m = self.ref_points[i] - thr.point[i]  # from the bullet's closest point to the chest
            side = _normalize(np.cross(UP, d) * [1.0, 0.0, 1.0], fallback=(1.0, 0.0, 0.0))
            along = np.einsum("ij,ij->i", m, side)
            coin = _rand(self.seed, _STREAM_SIDE, i, self._slot_serial[thr.bullet[i]]) < 0.5
            sign = np.where(np.abs(along) > 0.02 * scale, np.sign(along), np.where(coin, 1.0, -1.0))
            height = thr.point[i, 1] - self.ground[i, 1]
            head_high = height > HEAD_LEVEL * scale
            ducks = head_high & self.prefers_duck[i] & b.humanoid
            clear = (CLEAR_HALF_WIDTH * scale + self.scene.bullets.radius) - np.abs(along)
            lean = np.clip(clear, 0.0, MAX_LEAN * scale) * np.where(ducks, 0.4, 1.0)
            head_top = (b.rest_pos[b.head, 1] + 0.12 * scale) if b.humanoid else b.rest_pos[:, 1].max() + 0.05
            duck = np.where(ducks, np.clip(head_top + 0.05 * scale - height, 0.0, MAX_DUCK * scale), 0.0)
            if not b.humanoid:  # a chain dodges by bending: duck for anything above its middle
                duck = np.where(height > 0.5 * head_top, np.clip(head_top - height + 0.3, 0.0, MAX_DUCK * scale), 0.0)
            lean_goal[i] = side * (sign * lean)[:, None]
            duck_goal[i] = duck
            guard_goal[i] = np.where(head_high, 1.0, 0.0)
        mag_now = np.linalg.norm(self.lean, axis=1) + self.duck
        mag_goal = np.linalg.norm(lean_goal, axis=1) + duck_goal
        self.lean = _lowpass(self.lean, lean_goal, mag_now, mag_goal)
        self.duck = _lowpass(self.duck, duck_goal, mag_now, mag_goal)
        self.guard = _lowpass(self.guard, guard_goal, mag_now, mag_goal)

    def _solve_characters(self) -> None:
        if not self.alive.any():
            return
        # the dodge -> root and IK targets (lean, duck with planted feet, hand guard): one kernel
        from crowd_ik.kernels import game_kernels as gk

        f32 = np.float32
        targets, roots = self._targets_buf, self._roots_buf
        gk.dodge_targets(self.rest_targets, np.ascontiguousarray(self.lean, f32), np.ascontiguousarray(self.duck, f32),
                         np.ascontiguousarray(self.guard, f32), self.roots, self.yaw, self._planted_arg,
                         self.ref_points, *self._dodge_consts, targets, roots)
        weights = self._char_weights * self.alive[:, None]
        t0 = time.perf_counter()
        self.crowd.set_roots(roots, self.yaw)
        sv = self.scene.solver
        self.last_report = self.crowd.solve(targets, method=sv.method, max_iterations=sv.iterations,
                                            tolerance=sv.tolerance, weights=weights, orientations=self._char_orient)
        self._phase_ms["ik"] += 1e3 * (time.perf_counter() - t0)
        self._update_limbs()

    # ------------------------------------------------------------------ bullets, hits, shards
    def _update_limbs(self) -> None:
        """From the crowd's solved pose, in one launch: the limb capsules (N * B of them, dead
        characters included; the pool masks them by owner) into the next capsule set, the host
        joints (N, J, 3) into the buffer that `_joints` does not hold, and each character's box
        over this and the previous step's capsules."""
        from crowd_ik.kernels import game_kernels as gk

        prev_box = self._pose_box[self._caps_now]
        self._caps_now = 1 - self._caps_now
        a, b = self._caps[self._caps_now]
        joints = self._joint_bufs[1] if self._joints is self._joint_bufs[0] else self._joint_bufs[0]
        gk.limb_capsules(self.crowd.world_pos, self._bone_parent, self._bone_radius, prev_box, a, b, joints,
                         self._pose_box[self._caps_now], self._owner_box)
        self._joints = joints

    def _bullets_and_hits(self) -> None:
        bl = self.scene.bullets
        a, b = self._caps[self._caps_now]
        prev_a, prev_b = self._caps[1 - self._caps_now]
        hits = self.pool.advance(DT, bl.gravity, bl.drag, bl.lifetime, a, b, self._cap_radius, self._owner,
                                 self.alive.astype(np.int32), self.n, prev_a=prev_a, prev_b=prev_b,
                                 owner_boxes=self._owner_box, export_to=(self._bpos, self._bvel, self._balive_i32),
                                 owner_stride=self.body.n_bones)
        np.not_equal(self._balive_i32, 0, out=self._balive)
        if len(hits.chars):
            chars = hits.chars.astype(np.intp)
            self.alive[chars] = False
            self._tracked[chars] = -1
            self.hits += len(chars)
            self._shatter(self.body, self._joints[chars], self.colors[chars], self._bvel[hits.bullets], hits.points)
        self._player_hits_shooters()

    def _player_hits_shooters(self) -> None:
        """The player's live bullets against the standing shooters, after the pool's advance.

        Each bullet's path segment of this step (_bpos_prev -> _bpos, a straight chord of its
        arc) is swept against the shooters' limb capsules in their end-of-step pose: a hit is the
        first point within bullet radius + limb radius (analytic, crowd_ik.reference.projectiles.
        sweep_toi; no sub-steps: shooters only turn and move an arm). Each bullet's earliest hit
        counts (ties to the lower capsule id); the bullet dies there and its shooter is down. A
        shooter hit by several bullets in one step is downed once, by the earliest (toi, slot).
        Only the player's bullets are tested: shooters do not down each other, and a shooter's own
        bullets start in its hand, among its own limbs. A bullet the pool stopped on a character
        this step is gone before this test (a character hit counts first, even when a shooter
        stood earlier on the same step's segment). Free when the player has no live bullet (one
        `any` over the pool's flags).
        """
        mine = self._player_slot
        if not mine.any():
            return
        mine &= self._balive  # flags of bullets that died (a character hit, lifetime, far) are dropped
        if not mine.any() or not self.shooter_alive.any():
            return
        from crowd_ik.reference.projectiles import sweep_toi

        hb = self.hbody
        slots = np.flatnonzero(mine)  # (K,) ascending
        standing = np.flatnonzero(self.shooter_alive)  # (S',)
        SJ = self._shooter_joints[standing]  # (S', J, 3) end-of-step pose
        a = SJ[:, hb.bone_parent].reshape(-1, 3)  # (C, 3), C = S' * B, capsule c is bone c % B of standing[c // B]
        b = SJ[:, 1:].reshape(-1, 3)
        r = np.tile(hb.bone_radius, len(standing)) + np.float32(self.scene.bullets.radius)
        p0, p1 = self._bpos_prev[slots], self._bpos[slots]
        toi = sweep_toi(p0[:, None], p1[:, None], a[None], b[None], r[None])  # (K, C), -1: no hit
        toi = np.where(toi >= 0.0, toi, np.inf)
        first = np.argmin(toi, axis=1)  # the lowest capsule id among equal times
        t = toi[np.arange(len(slots)), first]
        hit = np.isfinite(t)
        if not hit.any():
            return
        slots, first, t = slots[hit], first[hit], t[hit]
        shooter = standing[first // hb.n_bones]
        self.pool.kill(slots)
        self._balive[slots] = False
        self._balive_i32[slots] = 0
        mine[slots] = False
        order = np.lexsort((slots, t))  # per shooter the earliest (toi, slot) bullet shatters it
        down, firsts = np.unique(shooter[order], return_index=True)
        win = order[firsts]
        impact = (p0[hit][win] + (p1[hit][win] - p0[hit][win]) * t[win, None]).astype(np.float32)
        self.shooter_alive[down] = False
        self._shatter(hb, self._shooter_joints[down], np.broadcast_to(np.float32(SHOOTER_COLOR), (len(down), 3)),
                      self._bvel[slots[win]], impact)
        self._shooter_weights[down] = 0.0

    def _shatter(self, body: Body, joints: np.ndarray, colors: np.ndarray, bullet_vel: np.ndarray,
                 impact: np.ndarray) -> None:
        """Break H bodies of `body`'s rig, posed at joints (H, J, 3) and coloured colors (H, 3) BGR,
        into shards, pushed by their bullets' velocities (H, 3) and bursting from the impacts (H, 3)."""
        b = body
        P = joints  # (H, J, 3)
        a, e = P[:, b.bone_parent], P[:, 1:]  # (H, B, 3)
        f = np.linspace(0.0, 1.0, SHARD_PIECES + 1, dtype=np.float32)
        starts = a[:, :, None] + (e - a)[:, :, None] * f[None, None, :-1, None]
        ends = a[:, :, None] + (e - a)[:, :, None] * f[None, None, 1:, None]
        H, K = len(P), SHARD_PIECES * b.n_bones
        c = ((starts + ends) * 0.5).reshape(H, K, 3)
        h = ((ends - starts) * 0.5).reshape(H, K, 3)
        r = np.repeat(b.bone_radius * 0.9, SHARD_PIECES)[None].repeat(H, 0)
        serial = self._sh_serial + np.arange(H * K).reshape(H, K)
        self._sh_serial += H * K
        u = [_rand(self.seed, _STREAM_SHARD, serial, j) for j in range(6)]
        off = c - impact[:, None, :]
        dist = np.linalg.norm(off, axis=-1)
        radial = _normalize(off + 0.05 * (np.stack(u[3:6], -1) - 0.5))
        push = bullet_vel[:, None, :] * (SHARD_IMPULSE * np.exp(-dist / (0.4 * b.scale)))[..., None]
        v = push + radial * (SHARD_BURST * (0.4 + u[0]))[..., None] + UP * (0.8 + 1.5 * u[1])[..., None]
        w = (np.stack(u[2:5], -1) - 0.5) * 18.0
        M = len(self._sh_c)
        slots = (self._sh_next + np.arange(H * K)) % M
        self._sh_next = int((self._sh_next + H * K) % M)
        self._sh_c[slots] = c.reshape(-1, 3)
        self._sh_c_prev[slots] = c.reshape(-1, 3)
        self._sh_h[slots] = h.reshape(-1, 3)
        self._sh_v[slots] = v.reshape(-1, 3)
        self._sh_w[slots] = w.reshape(-1, 3)
        self._sh_r[slots] = r.reshape(-1)
        self._sh_age[slots] = 0.0
        self._sh_live[slots] = True
        self._sh_color[slots] = np.repeat(colors * SHARD_TINT, K, axis=0)

    def _shards_step(self) -> None:
        live = self._sh_live
        if not live.any():
            return
        i = np.flatnonzero(live)
        g = self.scene.bullets.gravity
        v, c, h, w = self._sh_v[i], self._sh_c[i], self._sh_h[i], self._sh_w[i]
        v[:, 1] -= g * DT
        c += v * DT
        # rotate the half-axis by w dt (Rodrigues)
        ang = np.linalg.norm(w, axis=1) * DT
        k = _normalize(w)
        cos, sin = np.cos(ang)[:, None], np.sin(ang)[:, None]
        h = h * cos + np.cross(k, h) * sin + k * np.einsum("ij,ij->i", k, h)[:, None] * (1.0 - cos)
        low = c[:, 1] - np.abs(h[:, 1]) - self._sh_r[i]
        ground = low < 0.0
        c[ground, 1] -= low[ground]
        bounce = ground & (v[:, 1] < 0.0)
        v[bounce, 1] *= -SHARD_RESTITUTION
        v[bounce, 0] *= SHARD_FRICTION
        v[bounce, 2] *= SHARD_FRICTION
        w[bounce] *= 0.6
        self._sh_v[i], self._sh_c[i], self._sh_h[i], self._sh_w[i] = v, c, h.astype(np.float32), w
        self._sh_age[i] += DT
        self._sh_live[i] = self._sh_age[i] < SHARD_LIFE

    # ------------------------------------------------------------------ drawing
    def primitives(self) -> dict:
        """What a frame shows, interpolated between the last two world steps.

        capsules: a, b (M, 3) metres, radius (M,), color (M, 3) BGR 0..1, body (M,) int32 owner ids
        (characters 0..N-1, shooters N..N+S-1, the player N+S, shards N+S+1); body_names (N+S+2,);
        spheres: centre (K, 3), radius (K,), color (K, 3) (the bullets); trails (K, 2, 3).
        Hit characters and downed shooters are not drawn (their shards are).
        """
        b, hb = self.body, self.hbody
        N, S = self.n, self.n_shooters
        alpha = np.float32(min(max(self._acc / DT, 0.0), 1.0))
        alive = np.flatnonzero(self.alive)
        up = np.flatnonzero(self.shooter_alive)
        J = self._joints_prev[alive] + (self._joints[alive] - self._joints_prev[alive]) * alpha
        SJ = self._shooter_joints_prev[up] + (self._shooter_joints[up] - self._shooter_joints_prev[up]) * alpha
        parts_a = [J[:, b.bone_parent].reshape(-1, 3), SJ[:, hb.bone_parent].reshape(-1, 3)]
        parts_b = [J[:, 1:].reshape(-1, 3), SJ[:, 1:].reshape(-1, 3)]
        parts_r = [np.tile(b.bone_radius, len(alive)), np.tile(hb.bone_radius, len(up))]
        parts_c = [np.repeat(self.colors[alive], b.n_bones, axis=0),
                   np.broadcast_to(np.float32(SHOOTER_COLOR), (len(up) * hb.n_bones, 3))]
        parts_o = [np.repeat(alive, b.n_bones), np.repeat(N + up, hb.n_bones)]
        # guns: short black capsules in the shooters' right hands along the aim
        hand = SJ[:, hb.hand_r]
        parts_a.append(hand - self.aim[up] * 0.04 * hb.scale)
        parts_b.append(hand + self.aim[up] * 0.16 * hb.scale)
        parts_r.append(np.full(len(up), 0.03 * hb.scale, np.float32))
        parts_c.append(np.broadcast_to(np.float32(GUN_COLOR), (len(up), 3)))
        parts_o.append(N + up)
        PJ = self._player_joints
        parts_a.append(PJ[hb.bone_parent])
        parts_b.append(PJ[1:])
        parts_r.append(hb.bone_radius)
        parts_c.append(np.broadcast_to(np.float32(PLAYER_COLOR), (hb.n_bones, 3)))
        parts_o.append(np.full(hb.n_bones, N + S))
        sh = np.flatnonzero(self._sh_live)
        if sh.size:
            c = self._sh_c_prev[sh] + (self._sh_c[sh] - self._sh_c_prev[sh]) * alpha
            h = self._sh_h[sh]
            fade = np.clip((SHARD_LIFE - self._sh_age[sh]) / SHARD_FADE, 0.0, 1.0)
            parts_a.append(c - h)
            parts_b.append(c + h)
            parts_r.append(self._sh_r[sh] * fade)
            parts_c.append(self._sh_color[sh])
            parts_o.append(np.full(sh.size, N + S + 1))
        caps = {
            "a": np.concatenate(parts_a).astype(np.float32),
            "b": np.concatenate(parts_b).astype(np.float32),
            "radius": np.concatenate(parts_r).astype(np.float32),
            "color": np.concatenate(parts_c).astype(np.float32),
            "body": np.concatenate(parts_o).astype(np.int32),
        }
        live = np.flatnonzero(self._balive)
        pos = self._bpos_prev[live] + (self._bpos[live] - self._bpos_prev[live]) * alpha
        direction = _normalize(self._bvel[live])
        travelled = np.linalg.norm(pos - self._slot_origin[live], axis=1)
        tail = pos - direction * np.minimum(TRAIL_LENGTH, travelled)[:, None]
        if self._body_names is None:  # built once: 10,000 f-strings cost ~3 ms a frame
            self._body_names = ([f"character_{i}" for i in range(N)] + [f"shooter_{k}" for k in range(S)]
                                + ["player", "shards"])
        names = list(self._body_names)
        return {
            "capsules": caps,
            "body_names": names,
            "spheres": {
                "center": pos.astype(np.float32),
                "radius": np.full(live.size, max(self.scene.bullets.radius, BULLET_DRAW_RADIUS), np.float32),
                "color": np.broadcast_to(np.float32(BULLET_COLOR), (live.size, 3)),
            },
            "trails": np.stack([pos, tail], axis=1).astype(np.float32),
        }

    def hud_lines(self) -> list[str]:
        """The HUD text: time scale, frame, hits, dodges, standing characters, shooters down, IK milliseconds."""
        counts = f"hits {self.hits}   dodges {self.dodges}   standing {int(self.alive.sum())}/{self.n}"
        if self.n_shooters:
            counts += f"   shooters down {self.shooters_down}/{self.n_shooters}"
        lines = [
            f"TIME x{self.time_scale:.2f}",
            f"frame {self.frame}/{self.scene.n_frames}   world {self.world_time:.2f} s",
            counts,
        ]
        if self.hud_timings and self._hud_ms["ik"] is not None:
            lines.append(f"IK {self._hud_ms['ik']:.1f} ms   sim {self._hud_ms['simulation']:.1f} ms"
                         f"   ({self.n + self.n_shooters + 1} bodies)")
        else:
            lines.append(f"IK {self.scene.solver.method} x{self.scene.solver.iterations}"
                         f"   ({self.n + self.n_shooters + 1} bodies)")
        return lines

    @property
    def renderer(self):
        """The Renderer (its buffers are allocated on first use, sized for the scene's maxima)."""
        if self._renderer is None:
            from crowd_ik.view.render import Renderer

            self._renderer = Renderer(self.camera, self.max_capsules, self.scene.bullets.pool_size)
        return self._renderer

    def render(self) -> np.ndarray:
        """The current frame: (H, W, 3) uint8 BGR."""
        t0 = time.perf_counter()
        prim = self.primitives()
        caps, sph = prim["capsules"], prim["spheres"]
        frame = self.renderer.render(caps["a"], caps["b"], caps["radius"], caps["color"],
                                     sph["center"], sph["radius"], sph["color"],
                                     trails=prim["trails"] if len(prim["trails"]) else None,
                                     hud_lines=self.hud_lines())
        ms = 1e3 * (time.perf_counter() - t0)
        self._phase_ms["render"] = ms
        self.totals["render_ms"] += ms
        self.totals["rendered"] += 1
        return frame


__all__ = ["World", "Body", "Walker", "DT", "ballistic_direction", "cone_sample", "character_layout",
           "shooter_layout"]
