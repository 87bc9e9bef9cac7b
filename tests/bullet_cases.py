"""Bullets, limbs and pools the bullet tests build: random scenes, hand-built posts, owner boxes."""

import numpy as np

from crowd_ik.game.pool import BulletPool

DT = 1.0 / 60.0


def _f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


def _bullets(rng, p):
    pos = _f32(rng.uniform(-3, 3, (p, 3)))
    vel = _f32(rng.normal(0, 20, (p, 3)))
    age = _f32(rng.uniform(0, 1.0, p))
    alive = (rng.random(p) < 0.8).astype(np.int32)
    return pos, vel, age, alive


def _capsules(rng, n_chars, per_char, spread=6.0):
    """Random limbs: per character a cluster of short capsules around a root on the ground."""
    roots = np.repeat(rng.uniform(-spread, spread, (n_chars, 3)) * [1, 0, 1], per_char, axis=0) + [0, 1.0, 0]
    a = roots + rng.normal(0, 0.35, roots.shape)
    b = a + rng.normal(0, 0.25, roots.shape)
    radius = rng.uniform(0.04, 0.12, len(a))
    owner = np.repeat(np.arange(n_chars), per_char).astype(np.int32)
    return _f32(a), _f32(b), _f32(radius), owner


def _ndarray(x):
    """A ti.ndarray copy of a (P, 3) float32 or (P,) int32 NumPy array."""
    import taichi as ti

    arr = ti.ndarray(ti.math.vec3, shape=x.shape[:1]) if x.ndim == 2 else ti.ndarray(ti.i32, shape=x.shape)
    arr.from_numpy(x)
    return arr


def _scene(seed, p=300, n_chars=30, per_char=4):
    rng = np.random.default_rng(seed)
    a, b, radius, owner = _capsules(rng, n_chars, per_char)
    char_alive = (rng.random(n_chars) < 0.85).astype(np.int32)
    # bullets aimed near random limbs from a few metres away, so many hit and many miss
    target = a[rng.integers(0, len(a), p)] + rng.normal(0, 0.15, (p, 3))
    start = target + rng.normal(0, 3.0, (p, 3))
    end = start + (target - start) * rng.uniform(0.5, 2.0, (p, 1))
    start[:, 1], end[:, 1] = np.abs(start[:, 1]), np.abs(end[:, 1])  # above y = -1, where bullets live
    return _f32(start), _f32(end), a, b, radius, owner, char_alive


def _fire(start, end, pool_size=None, radius=0.03, **kw):
    """A pool whose live bullets' last segments are exactly start -> end (one step of dt = 1 s, no forces)."""
    pool = BulletPool(pool_size or len(start), radius=radius, bounds=(-5, -5, 5, 5), cell_size=1.0, **kw)
    pool.spawn(start, _f32(end - start))
    pool.step(1.0, gravity=0.0, drag=0.0, lifetime=10.0)
    return pool


def _post(x=0.0, z=0.0, radius=0.05):
    """One vertical limb (a post from y = 0.5 to 1.5) owned by character 0."""
    return _f32([[x, 0.5, z]]), _f32([[x, 1.5, z]]), _f32([radius]), np.zeros(1, np.int32), np.ones(1, np.int32)


def _owner_boxes(a0, b0, a1, b1, radius, owner, n_chars):
    """(n_chars, 4) x_min, z_min, x_max, z_max of each owner's capsules in both poses, grown by radius."""
    pts = np.stack([a0, b0, a1, b1])[..., [0, 2]]  # (4, C, 2)
    lo = pts.min(axis=0) - radius[:, None]
    hi = pts.max(axis=0) + radius[:, None]
    box = np.zeros((n_chars, 4), np.float32)
    box[:, :2], box[:, 2:] = np.inf, -np.inf
    np.minimum.at(box[:, :2], owner, lo)
    np.maximum.at(box[:, 2:], owner, hi)
    return box
