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
    if len(rows) == total:
        return prev + (now - prev) * alpha
    return prev[rows] + (now[rows] - prev[rows]) * alpha


def primitives(world, alpha: float) -> dict:
    """capsules: a, b (M, 3) metres, radius (M,), color (M, 3) BGR 0..1, body (M,) int32 owner ids
    (characters 0..N-1, shooters N..N+S-1, the player N+S, shards N+S+1); spheres: centre (K, 3),
    radius (K,), color (K, 3) (the bullets); trails (K, 2, 3)."""
    chars, shooters, bullets = world.characters, world.shooters, world.bullets
    b, hb = world.body, world.hbody
    N, S = chars.n, shooters.n
    alpha = np.float32(alpha)
    alive = np.flatnonzero(chars.alive)
    up = np.flatnonzero(shooters.alive)
    J = _lerp(chars.limbs.joints_prev, chars.limbs.joints, alive, N, alpha)
    SJ = _lerp(shooters.joints_prev, shooters.joints, up, S, alpha)
    parts_a = [J[:, b.bone_parent].reshape(-1, 3), SJ[:, hb.bone_parent].reshape(-1, 3)]
    parts_b = [J[:, 1:].reshape(-1, 3), SJ[:, 1:].reshape(-1, 3)]
    parts_r = [np.tile(b.bone_radius, len(alive)), np.tile(hb.bone_radius, len(up))]
    parts_c = [np.repeat(chars.colors[alive], b.n_bones, axis=0),
               np.broadcast_to(np.float32(SHOOTER_COLOR), (len(up) * hb.n_bones, 3))]
    parts_o = [np.repeat(alive, b.n_bones), np.repeat(N + up, hb.n_bones)]
    # guns: short black capsules in the shooters' right hands along the aim
    hand = SJ[:, hb.hand_r]
    parts_a.append(hand - shooters.aim[up] * 0.04 * hb.scale)
    parts_b.append(hand + shooters.aim[up] * 0.16 * hb.scale)
    parts_r.append(np.full(len(up), 0.03 * hb.scale, np.float32))
    parts_c.append(np.broadcast_to(np.float32(GUN_COLOR), (len(up), 3)))
    parts_o.append(N + up)
    PJ = world.player.joints
    parts_a.append(PJ[hb.bone_parent])
    parts_b.append(PJ[1:])
    parts_r.append(hb.bone_radius)
    parts_c.append(np.broadcast_to(np.float32(PLAYER_COLOR), (hb.n_bones, 3)))
    parts_o.append(np.full(hb.n_bones, N + S))
    shards = world.shards.capsules(alpha)
    if shards is not None:
        for parts, value in zip((parts_a, parts_b, parts_r, parts_c), shards):
            parts.append(value)
        parts_o.append(np.full(len(shards[0]), N + S + 1))
    caps = {  # concatenate makes the new arrays; astype only converts what is not already its type
        "a": np.concatenate(parts_a).astype(np.float32, copy=False),
        "b": np.concatenate(parts_b).astype(np.float32, copy=False),
        "radius": np.concatenate(parts_r).astype(np.float32, copy=False),
        "color": np.concatenate(parts_c).astype(np.float32, copy=False),
        "body": np.concatenate(parts_o).astype(np.int32, copy=False),
    }
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
