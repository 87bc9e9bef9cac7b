"""What a frame of the game shows: the World's bodies, guns, shards and bullets as drawable primitives.

Everything is interpolated between the last two world steps (alpha = the World's accumulator / DT),
so slow motion stays smooth. Hit characters and downed shooters are not drawn (their shards are).
"""

from __future__ import annotations

import numpy as np

from crowd_ik.game.shooters import COLOR as SHOOTER_COLOR
from crowd_ik.geometry.vectors import normalize

PLAYER_COLOR = (0.20, 0.16, 0.12)
GUN_COLOR = (0.08, 0.08, 0.08)
BULLET_COLOR = (0.06, 0.06, 0.10)
BULLET_DRAW_RADIUS = 0.05  # m: bullets are drawn at least this big
TRAIL_LENGTH = 2.0  # m


def _lerp(prev: np.ndarray, now: np.ndarray, rows: np.ndarray, total: int, alpha) -> np.ndarray:
    """prev + (now - prev) * alpha of the given rows; when every row is given the arrays are used as
    they are (the same values as the gathered rows: no three copies of 10,000 skeletons)."""
    if len(rows) != total:
        prev, now = prev[rows], now[rows]
    out = np.subtract(now, prev)  # in place from here: (now - prev) * alpha + prev, the same sums (a + b == b + a)
    np.multiply(out, alpha, out=out)
    return np.add(out, prev, out=out)


def _bones(joints: np.ndarray, bone_parent: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """a, b (K * B, 3) <- the bones' ends of skeletons joints (K, J, 3): joint bone_parent[k] and joint k + 1."""
    K, B = len(joints), len(bone_parent)
    np.take(joints, bone_parent, axis=1, out=a.reshape(K, B, 3))
    b.reshape(K, B, 3)[:] = joints[:, 1:]


def primitives(world, alpha: float) -> dict:
    """capsules: a, b (M, 3) metres, radius (M,), color (M, 3) BGR 0..1, body (M,) int32 owner ids
    (characters 0..N-1, shooters N..N+S-1, the player N+S, shards N+S+1); spheres: centre (K, 3),
    radius (K,), color (K, 3) (the bullets); trails (K, 2, 3).

    The capsules are written straight into their output arrays, block by block (characters' bones, shooters'
    bones, guns, the player's bones, shards): no per-part arrays and no concatenation (200,000 capsules at
    10,000 characters)."""
    chars, shooters, bullets = world.characters, world.shooters, world.bullets
    b, hb = world.body, world.hbody
    N, S = chars.n, shooters.n
    alpha = np.float32(alpha)
    alive = np.flatnonzero(chars.alive)
    up = np.flatnonzero(shooters.alive)
    J = _lerp(chars.limbs.joints_prev, chars.limbs.joints, alive, N, alpha)
    SJ = _lerp(shooters.joints_prev, shooters.joints, up, S, alpha)
    shards = world.shards.capsules(alpha)
    B, HB = b.n_bones, hb.n_bones
    sizes = [len(alive) * B, len(up) * HB, len(up), HB, 0 if shards is None else len(shards[0])]
    ends = np.cumsum([0] + sizes)
    M = int(ends[-1])
    cap_a, cap_b = np.empty((M, 3), np.float32), np.empty((M, 3), np.float32)
    radius, color = np.empty(M, np.float32), np.empty((M, 3), np.float32)
    body = np.empty(M, np.int32)
    blocks = [slice(int(ends[k]), int(ends[k + 1])) for k in range(5)]
    c, s, g, p, h = blocks
    _bones(J, b.bone_parent, cap_a[c], cap_b[c])
    radius[c].reshape(len(alive), B)[:] = b.bone_radius
    color[c].reshape(len(alive), B, 3)[:] = chars.colors[alive][:, None, :]
    body[c].reshape(len(alive), B)[:] = alive[:, None]
    _bones(SJ, hb.bone_parent, cap_a[s], cap_b[s])
    radius[s].reshape(len(up), HB)[:] = hb.bone_radius
    color[s] = np.float32(SHOOTER_COLOR)
    body[s].reshape(len(up), HB)[:] = (N + up)[:, None]
    # guns: short black capsules in the shooters' right hands along the aim
    hand = SJ[:, hb.hand_r]
    cap_a[g] = hand - shooters.aim[up] * 0.04 * hb.scale
    cap_b[g] = hand + shooters.aim[up] * 0.16 * hb.scale
    radius[g] = np.float32(0.03 * hb.scale)
    color[g] = np.float32(GUN_COLOR)
    body[g] = N + up
    PJ = world.player.joints
    _bones(PJ[None], hb.bone_parent, cap_a[p], cap_b[p])
    radius[p] = hb.bone_radius
    color[p] = np.float32(PLAYER_COLOR)
    body[p] = N + S
    if shards is not None:
        for out, value in zip((cap_a, cap_b, radius, color), shards):
            out[h] = value
        body[h] = N + S + 1
    caps = {"a": cap_a, "b": cap_b, "radius": radius, "color": color, "body": body}
    live = np.flatnonzero(bullets.alive)
    pos = bullets.pos_prev[live] + (bullets.pos[live] - bullets.pos_prev[live]) * alpha
    direction = normalize(bullets.vel[live])
    travelled = np.linalg.norm(pos - bullets.origin[live], axis=1)
    tail = pos - direction * np.minimum(TRAIL_LENGTH, travelled)[:, None]
    return {
        "capsules": caps,
        "spheres": {
            "center": pos.astype(np.float32),
            "radius": np.full(live.size, max(world.scene.bullets.radius, BULLET_DRAW_RADIUS), np.float32),
            "color": np.broadcast_to(np.float32(BULLET_COLOR), (live.size, 3)),
        },
        "trails": np.stack([pos, tail], axis=1).astype(np.float32),
    }
