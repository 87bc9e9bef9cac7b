"""kernels/bullet_physics.py and the pool's slots (spawn, kill, lifetime, export) against the NumPy twin."""

import numpy as np
import pytest

from bullet_cases import DT, _bullets, _f32, _owner_boxes, _scene
from crowd_ik.game.pool import BulletPool
from crowd_ik.kernels import projectiles as kp
from crowd_ik.reference import projectiles as ref


def test_integrate_matches_twin():
    rng = np.random.default_rng(0)
    pos, vel, age, alive = _bullets(rng, 200)
    pos[:5, 1] = -0.95  # some fall below y = -1 this step
    vel[:5, 1] = -30.0
    pos[5:10] *= 100.0  # some leave the far radius
    alive[:10] = 1
    was_alive = alive.copy()
    args = (0.02, 9.81, 0.05, 0.99, 200.0)
    want = ref.integrate(pos, vel, age, alive, *args)
    prev = np.zeros_like(pos)
    kp.integrate_bullets(pos, vel, age, alive, prev, *args)
    for got, exp in zip((pos, vel, age, alive), want[:4]):
        np.testing.assert_allclose(got, exp, rtol=2e-6, atol=1e-6)
    live = want[3] != 0  # prev only matters for bullets that are still flying
    np.testing.assert_array_equal(prev[live], want[4][live])
    killed = (alive == 0) & (was_alive != 0)
    assert killed[:5].all() and killed.sum() > 10  # y < -1, far and lifetime all kill


def test_drag_slows_but_never_reverses():
    pos = np.zeros((1, 3), np.float32)
    vel = _f32([[500.0, 0.0, 0.0]])
    age, alive, prev = np.zeros(1, np.float32), np.ones(1, np.int32), np.zeros((1, 3), np.float32)
    kp.integrate_bullets(pos, vel, age, alive, prev, 0.1, 0.0, 10.0, 5.0, 1e6)  # drag |v| dt = 500
    assert 0.0 < vel[0, 0] < 1.0 and pos[0, 0] > 0.0


def test_spawn_kernel_matches_twin():
    rng = np.random.default_rng(1)
    pos, vel, age, alive = _bullets(rng, 32)
    prev = pos.copy()
    slots = np.array([3, 7, 0], np.int32)
    origins, velocities = _f32(rng.normal(size=(3, 3))), _f32(rng.normal(size=(3, 3)))
    want = ref.spawn(slots, origins, velocities, pos, vel, age, alive, prev)
    start = [a.copy() for a in (pos, vel, age, alive, prev)]
    kp.spawn_bullets(slots, origins, velocities, pos, vel, age, alive, prev, 3, False)
    for got, exp in zip((pos, vel, age, alive, prev), want):
        np.testing.assert_array_equal(got, exp)
    # serial launch == parallel one; a count below the rows given spawns only the first rows
    again = [a.copy() for a in start]
    kp.spawn_bullets(slots, origins, velocities, *again, 3, True)
    for got, exp in zip(again, want):
        np.testing.assert_array_equal(got, exp)
    part = [a.copy() for a in start]
    want = ref.spawn(slots[:2], origins[:2], velocities[:2], *[a.copy() for a in start])
    kp.spawn_bullets(slots, origins, velocities, *part, 2, True)
    for got, exp in zip(part, want):
        np.testing.assert_array_equal(got, exp)


def test_export_copies_the_pool_state_in_one_launch():
    rng = np.random.default_rng(13)
    pos, vel, _, _ = _bullets(rng, 50)
    pos[:, 1] = 1.0  # none falls below y = -1 on this step
    pool = BulletPool(64)
    pool.spawn(pos, vel)
    pool.step(DT, lifetime=10.0)
    out = np.zeros((64, 3), np.float32), np.zeros((64, 3), np.float32), np.zeros(64, np.int32)
    pool.export(*out)
    np.testing.assert_array_equal(out[0], pool.positions())
    np.testing.assert_array_equal(out[1], pool.velocities())
    np.testing.assert_array_equal(out[2] != 0, pool.alive_mask())
    assert out[2].sum() == 50


def test_spawn_fills_lowest_free_slots_first():
    pool = BulletPool(6)
    slots, dropped = pool.spawn([[0, 1, 0], [0, 1, 1], [0, 1, 2]], [[1, 0, 0], [0, -200, 0], [1, 0, 0]])
    assert slots.tolist() == [0, 1, 2] and dropped == 0
    pool.step(DT)  # slot 1 dives below y = -1 and dies
    assert pool.alive_mask().tolist() == [True, False, True, False, False, False]
    slots, dropped = pool.spawn([[5, 1, 0], [6, 1, 0]], [[0, 0, 1], [0, 0, 1]])
    assert slots.tolist() == [1, 3] and dropped == 0
    np.testing.assert_array_equal(pool.positions()[[1, 3]], [[5, 1, 0], [6, 1, 0]])
    assert pool.count_alive() == 4


def test_pool_exhaustion_drops_the_extra_deterministically():
    pool = BulletPool(4)
    origins = np.arange(18, dtype=np.float32).reshape(6, 3)
    slots, dropped = pool.spawn(origins, np.ones((6, 3)))
    assert slots.tolist() == [0, 1, 2, 3] and dropped == 2
    np.testing.assert_array_equal(pool.positions(), origins[:4])  # the first four requests got the slots
    slots, dropped = pool.spawn(origins[:1], np.ones((1, 3)))
    assert slots.tolist() == [] and dropped == 1


def test_kill_frees_the_given_slots():
    pool = BulletPool(4)
    pool.spawn(np.zeros((3, 3)), np.ones((3, 3)))
    pool.kill([2, 0, 2])
    assert pool.alive_mask().tolist() == [False, True, False, False]
    pool.kill([])
    assert pool.count_alive() == 1
    with pytest.raises(ValueError, match="slots"):
        pool.kill([4])
    slots, _ = pool.spawn(np.ones((2, 3)), np.ones((2, 3)))  # freed slots are reused lowest first
    assert slots.tolist() == [0, 2]


def test_lifetime_kills():
    pool = BulletPool(2)
    pool.spawn([[0, 5, 0]], [[1, 0, 0]])
    for _ in range(2):
        pool.step(0.02, gravity=0.0, lifetime=0.05)
    assert pool.count_alive() == 1
    pool.step(0.02, gravity=0.0, lifetime=0.05)
    assert pool.count_alive() == 0 and pool.trails()[0].shape == (0, 3)


def test_a_large_pool_steps_only_its_used_slots_and_gives_the_same_step():
    # the per-step kernels loop over the slots that were ever used (spawn takes the lowest free ones)
    start, end, a, b, radius, owner, char_alive = _scene(17, p=60)
    vel = _f32((end - start) * 60.0)
    P = len(start)
    boxes = _owner_boxes(a, b, a, b, radius, owner, len(char_alive))
    runs = []
    for size in (P, 8 * P):
        pool = BulletPool(size, bounds=(-5, -5, 5, 5))
        pool.spawn(start, vel)
        out = np.zeros((size, 3), np.float32), np.zeros((size, 3), np.float32), np.zeros(size, np.int32)
        hits = pool.advance(DT, 9.81, 0.0, 3.0, a, b, radius, owner, char_alive, len(char_alive),
                            owner_boxes=boxes, export_to=out)
        threats = pool.threats(_f32(a[::7]), np.ones(len(a[::7]), np.int32), 0.5, 0.3)
        runs.append((hits, pool.struck()[:P], pool.positions()[:P], out[0][:P], threats.bullet))
        assert not np.any(out[2][P:]) and not np.any(pool.alive_mask()[P:])
    assert len(runs[0][0].chars) > 3 and np.any(runs[0][4] >= 0)
    for x, y in zip(runs[0][0] + runs[0][1:], runs[1][0] + runs[1][1:]):
        np.testing.assert_array_equal(x, y)
    # bullets spawned later above the old mark move too
    pool.kill(np.arange(P))
    slots, _ = pool.spawn(np.zeros((P + 5, 3)) + [0.0, 1.0, 0.0], np.tile([[1.0, 0.0, 0.0]], (P + 5, 1)))
    assert slots.max() == P + 4
    pool.advance(DT, 0.0, 0.0, 3.0, a, b, radius, owner, np.zeros_like(char_alive), len(char_alive),
                 owner_boxes=boxes)
    np.testing.assert_allclose(pool.positions()[slots, 0], DT, rtol=1e-5)
