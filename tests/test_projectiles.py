"""kernels/projectiles.py and crowd_ik.game.pool against the brute-force NumPy twin and hand-built scenes."""

import numpy as np
import pytest

from crowd_ik.game.pool import BulletPool, Grid, substep_count
from crowd_ik.kernels import projectiles as kp
from crowd_ik.reference import projectiles as ref

DT = 1.0 / 60.0


def _f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


def _bullets(rng, p):
    pos = _f32(rng.uniform(-3, 3, (p, 3)))
    vel = _f32(rng.normal(0, 20, (p, 3)))
    age = _f32(rng.uniform(0, 1.0, p))
    alive = (rng.random(p) < 0.8).astype(np.int32)
    return pos, vel, age, alive


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
    kp.spawn_bullets(slots, origins, velocities, pos, vel, age, alive, prev)
    for got, exp in zip((pos, vel, age, alive, prev), want):
        np.testing.assert_array_equal(got, exp)


def _capsules(rng, n_chars, per_char, spread=6.0):
    """Random limbs: per character a cluster of short capsules around a root on the ground."""
    roots = np.repeat(rng.uniform(-spread, spread, (n_chars, 3)) * [1, 0, 1], per_char, axis=0) + [0, 1.0, 0]
    a = roots + rng.normal(0, 0.35, roots.shape)
    b = a + rng.normal(0, 0.25, roots.shape)
    radius = rng.uniform(0.04, 0.12, len(a))
    owner = np.repeat(np.arange(n_chars), per_char).astype(np.int32)
    return _f32(a), _f32(b), _f32(radius), owner


def test_grid_matches_twin_including_outside_bounds():
    rng = np.random.default_rng(2)
    a, b, radius, owner = _capsules(rng, 40, 4, spread=7.0)  # bounds below are +-4 m: clamping is exercised
    a1 = _f32(a + rng.normal(0, 0.3, a.shape))
    b1 = _f32(b + rng.normal(0, 0.3, b.shape))
    char_alive = (rng.random(40) < 0.8).astype(np.int32)
    grid = Grid((-4.0, -4.0, 4.0, 4.0), 1.0, capacity=8)  # entries must grow
    total = grid.build(a, b, a1, b1, radius, 0.05, owner, char_alive)
    want = ref.grid_pairs(a, b, a1, b1, radius, 0.05, owner, char_alive, *grid.geometry)
    assert total == len(want) > 8
    np.testing.assert_array_equal(grid.pairs(), want)
    # capsules wholly beyond the bounds are still binned (into the border cells)
    beyond = np.flatnonzero((np.minimum(a[:, 0], a1[:, 0]) > 4.5) & (char_alive[owner] != 0))
    assert len(beyond) > 0 and np.isin(beyond, want[:, 1]).all()
    assert np.all(want[np.isin(want[:, 1], beyond), 0] % 8 == 7)


def _ndarray(x):
    """A ti.ndarray copy of a (P, 3) float32 or (P,) int32 NumPy array."""
    import taichi as ti

    arr = ti.ndarray(ti.math.vec3, shape=x.shape[:1]) if x.ndim == 2 else ti.ndarray(ti.i32, shape=x.shape)
    arr.from_numpy(x)
    return arr


def test_masked_grid_keeps_only_the_cells_bullets_can_reach():
    rng = np.random.default_rng(12)
    a, b, radius, owner = _capsules(rng, 40, 4, spread=7.0)
    char_alive = (rng.random(40) < 0.8).astype(np.int32)
    pos, vel, _, alive = _bullets(rng, 30)
    pos[:, 0] *= 2.0  # some bullets beyond the bounds: they mark border cells
    pos_t, vel_t, alive_t = (_ndarray(x) for x in (pos, vel, alive))
    grid = Grid((-4.0, -4.0, 4.0, 4.0), 1.0, capacity=8)
    kp.mark_bullet_cells(pos_t, vel_t, alive_t, 0.05, 0.04, *grid.geometry, grid.mask)
    mask = ref.bullet_cells(pos, vel, alive, 0.05, 0.04, *grid.geometry)
    np.testing.assert_array_equal(grid.mask.to_numpy(), mask)
    assert 0 < mask.sum() < len(mask)
    total = grid.build(a, b, a, b, radius, 0.0, owner, char_alive, masked=True)
    want = ref.grid_pairs(a, b, a, b, radius, 0.0, owner, char_alive, *grid.geometry, cell_mask=mask)
    assert total == len(want) > 8
    np.testing.assert_array_equal(grid.pairs(), want)
    # an unmasked build afterwards fills every cell again
    assert grid.build(a, b, a, b, radius, 0.0, owner, char_alive) > total


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


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_collide_matches_brute_force(seed):
    start, end, a, b, radius, owner, char_alive = _scene(seed)
    pool = _fire(start, end)
    np.testing.assert_allclose(pool.trails()[1], end, atol=1e-5)
    hits = pool.collide(a, b, radius, owner, char_alive, len(char_alive))
    struck = pool.struck()

    alive = np.ones(len(start), np.int32)
    want_char, want_toi, want_winner = ref.collide(start, end, alive, 0.03, a, b, radius, owner, char_alive,
                                                   len(char_alive))
    # a bullet grazing a limb within 1e-4 m of contact may go either way in float32: set those aside
    lo = ref.collide(start, end, alive, 0.03 - 1e-4, a, b, radius, owner, char_alive, len(char_alive))[0]
    hi = ref.collide(start, end, alive, 0.03 + 1e-4, a, b, radius, owner, char_alive, len(char_alive))[0]
    clear = lo == hi
    assert clear.mean() > 0.97
    assert (want_char[clear] >= 0).sum() > 50 and (want_char[clear] < 0).sum() > 50
    np.testing.assert_array_equal(struck[clear], want_char[clear])
    hit = clear & (want_char >= 0)
    np.testing.assert_allclose(pool.bullet_toi.to_numpy()[hit], want_toi[hit], atol=2e-5)

    # per character: the winner by (toi, id), where every bullet that struck it is unambiguous
    settled = np.array([clear[(want_char == c) | (lo == c) | (hi == c)].all() for c in range(len(char_alive))])
    got_winner = np.full(len(char_alive), -1)
    got_winner[hits.chars] = hits.bullets
    assert settled.sum() >= len(char_alive) - 3 and (want_winner[settled] >= 0).sum() > 10
    np.testing.assert_array_equal(got_winner[settled], want_winner[settled])
    assert np.all(char_alive[hits.chars] == 1)  # dead characters are never hit
    np.testing.assert_allclose(hits.points, start[hits.bullets] + hits.toi[:, None] * (end - start)[hits.bullets],
                               atol=1e-4)
    # every bullet that struck a limb died, every other one flies on
    np.testing.assert_array_equal(pool.alive_mask(), struck < 0)


def test_collide_is_reproducible():
    start, end, a, b, radius, owner, char_alive = _scene(6)
    runs = []
    for _ in range(2):
        pool = _fire(start, end)
        runs.append((pool.collide(a, b, radius, owner, char_alive, len(char_alive)), pool.struck(),
                     pool.hit_key.to_numpy()))
    for x, y in zip(runs[0][0] + runs[0][1:], runs[1][0] + runs[1][1:]):
        np.testing.assert_array_equal(x, y)


def _post(x=0.0, z=0.0, radius=0.05):
    """One vertical limb (a post from y = 0.5 to 1.5) owned by character 0."""
    return _f32([[x, 0.5, z]]), _f32([[x, 1.5, z]]), _f32([radius]), np.zeros(1, np.int32), np.ones(1, np.int32)


def test_fast_bullet_through_thin_limb_is_caught():
    a, b, radius, owner, alive = _post(radius=0.05)
    pool = BulletPool(4, radius=0.03)
    pool.spawn([[-8.0, 1.0, 0.0]], [[1000.0, 0.0, 0.0]])
    pool.step(DT, gravity=0.0)
    start, end = (t[0] for t in pool.trails())
    assert np.linalg.norm(end - start) > 16.0
    # neither end of the 16 m step is anywhere near the limb: a point-in-capsule test would miss it
    assert ref.point_segment_distance(start, a[0], b[0]) > 1.0 and ref.point_segment_distance(end, a[0], b[0]) > 1.0
    hits = pool.collide(a, b, radius, owner, alive, 1)
    assert hits.chars.tolist() == [0] and hits.bullets.tolist() == [0]
    np.testing.assert_allclose(hits.points[0], [-0.08, 1.0, 0.0], atol=1e-4)  # entry at R = 0.03 + 0.05
    np.testing.assert_allclose(hits.toi[0], (8.0 - 0.08) / (1000.0 * DT), atol=1e-5)
    assert pool.count_alive() == 0


@pytest.mark.parametrize("offset,caught", [(0.0815, False), (0.0785, True), (0.5, False)])
def test_near_miss_is_not_a_hit(offset, caught):
    a, b, radius, owner, alive = _post(radius=0.05)
    pool = BulletPool(4, radius=0.03)
    pool.spawn([[-8.0, 1.0, offset]], [[1000.0, 0.0, 0.0]])
    pool.step(DT, gravity=0.0)
    hits = pool.collide(a, b, radius, owner, alive, 1)
    assert (len(hits.chars) == 1) == caught
    assert pool.count_alive() == (0 if caught else 1)


def test_bullet_over_the_end_cap_and_along_the_axis():
    a, b, radius, owner, alive = _post(radius=0.05)
    pool = BulletPool(4, radius=0.03)
    # straight down the limb's axis from above: enters through the top cap at y = 1.5 + 0.08
    # and just over the top cap: misses
    pool.spawn([[0.0, 3.0, 0.0], [-2.0, 1.5 + 0.0801, 0.0]], [[0.0, -120.0, 0.0], [240.0, 0.0, 0.0]])
    pool.step(DT, gravity=0.0)
    hits = pool.collide(a, b, radius, owner, alive, 1)
    assert hits.bullets.tolist() == [0]
    np.testing.assert_allclose(hits.points[0], [0.0, 1.58, 0.0], atol=1e-4)
    assert pool.struck().tolist() == [0, -1, -1, -1]


def test_earlier_toi_wins_then_lower_id():
    a, b, radius, owner, alive = _post()
    # slots 0 and 1 fly the same path (an exact tie); slot 2 starts nearer and hits first
    origins = [[-8.0, 1.0, 0.0], [-8.0, 1.0, 0.0], [-4.0, 1.2, 0.0]]
    velocities = [[600.0, 0.0, 0.0]] * 3
    pool = BulletPool(8)
    pool.spawn(origins, velocities)
    pool.step(DT, gravity=0.0)
    hits = pool.collide(a, b, radius, owner, alive, 1)
    assert hits.bullets.tolist() == [2]
    assert pool.struck()[:3].tolist() == [0, 0, 0] and pool.count_alive() == 0  # losers die in the body too

    pool = BulletPool(8)
    pool.spawn(origins[:2], velocities[:2])  # only the tied pair
    pool.step(DT, gravity=0.0)
    first = pool.collide(a, b, radius, owner, alive, 1)
    assert first.bullets.tolist() == [0]
    # the same scene with the bullets in the other slots: the earlier one still wins, wherever it sits
    pool = BulletPool(8)
    pool.spawn(origins[::-1], velocities[::-1])
    pool.step(DT, gravity=0.0)
    assert pool.collide(a, b, radius, owner, alive, 1).bullets.tolist() == [0]  # slot 0 now holds the near one


def test_two_characters_two_winners_and_dead_characters_are_skipped():
    a = _f32([[0, 0.5, 0], [0, 0.5, 2]])
    b = _f32([[0, 1.5, 0], [0, 1.5, 2]])
    radius, owner = _f32([0.05, 0.05]), np.array([0, 1], np.int32)
    origins = [[-5, 1, 0], [-5, 1, 2]]
    velocities = [[600, 0, 0]] * 2
    for char_alive, want in (([1, 1], [0, 1]), ([1, 0], [0])):
        pool = BulletPool(4)
        pool.spawn(origins, velocities)
        pool.step(DT, gravity=0.0)
        hits = pool.collide(a, b, radius, owner, char_alive, 2)
        assert hits.chars.tolist() == want and hits.bullets.tolist() == want
        assert pool.count_alive() == 2 - len(want)


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


def test_substep_count_matches_twin():
    rng = np.random.default_rng(7)
    a, b, radius, owner = _capsules(rng, 20, 3)
    a1, b1 = _f32(a + rng.normal(0, 0.2, a.shape)), _f32(b + rng.normal(0, 0.2, b.shape))
    char_alive = (rng.random(20) < 0.7).astype(np.int32)
    want = ref.substeps(a, b, a1, b1, radius, owner, char_alive)
    assert 1 < want < 64
    assert substep_count(a, b, a1, b1, radius, owner, char_alive, max_substeps=64) == want
    assert substep_count(a, b, a, b, radius, owner, char_alive) == 1
    assert substep_count(a, b, a1, b1, radius, owner, char_alive, max_substeps=2) == 2


def test_substeps_catch_a_limb_sweeping_through_a_slow_bullet():
    # a limb swings from x = -2 to x = +2 in one step; the bullet creeps across z = 0 at x = 0.01
    prev_a, prev_b = _f32([[-2, 0.5, 0]]), _f32([[-2, 1.5, 0]])
    a, b = _f32([[2, 0.5, 0]]), _f32([[2, 1.5, 0]])
    radius, owner, alive = _f32([0.05]), np.zeros(1, np.int32), np.ones(1, np.int32)
    origin, velocity = [[0.01, 1.0, -0.01]], [[0.0, 0.0, 1.2]]

    pool = BulletPool(2)
    pool.spawn(origin, velocity)
    pool.step(DT, gravity=0.0)
    assert len(pool.collide(a, b, radius, owner, alive, 1).chars) == 0  # end-of-step pose only: missed

    pool = BulletPool(2)
    pool.spawn(origin, velocity)
    hits = pool.advance(DT, 0.0, 0.0, 3.0, a, b, radius, owner, alive, 1, prev_a=prev_a, prev_b=prev_b,
                        max_substeps=64)
    assert pool.last_substeps == 64  # ceil(4 m / 0.05 m) = 80, capped
    assert hits.chars.tolist() == [0]
    # the sub-step whose pose first reaches within R: limb at x = -2 + 4 s >= 0.01 - 0.08, s = (j + 1) / 64
    j = int(np.ceil((0.01 - 0.08 + 2.0) / 4.0 * 64)) - 1
    assert j / 64 <= hits.toi[0] <= (j + 1) / 64


def test_advance_without_previous_pose_equals_step_then_collide():
    start, end, a, b, radius, owner, char_alive = _scene(8, p=120)
    vel = _f32((end - start) * 60.0)
    results = []
    for mode in ("advance", "step"):
        pool = BulletPool(len(start), bounds=(-5, -5, 5, 5))
        pool.spawn(start, vel)
        if mode == "advance":
            hits = pool.advance(DT, 9.81, 0.01, 3.0, a, b, radius, owner, char_alive, len(char_alive))
            assert pool.last_substeps == 1
        else:
            pool.step(DT, 9.81, 0.01, 3.0)
            hits = pool.collide(a, b, radius, owner, char_alive, len(char_alive))
        results.append((hits, pool.struck(), pool.positions()))
    assert len(results[0][0].chars) > 5
    for x, y in zip(results[0][0] + results[0][1:], results[1][0] + results[1][1:]):
        np.testing.assert_array_equal(x, y)


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


def test_reachable_owners_match_twin():
    rng = np.random.default_rng(14)
    n = 60
    centre = rng.uniform(-6, 6, (n, 2))
    half = rng.uniform(0.1, 1.5, (n, 2))
    box = _f32(np.hstack([centre - half, centre + half]))
    owner_alive = (rng.random(n) < 0.8).astype(np.int32)
    grid = Grid((-5.0, -5.0, 5.0, 5.0), 1.0, capacity=8)
    mask = (rng.random(grid.nx * grid.nz) < 0.1).astype(np.int32)
    grid.mask.from_numpy(mask)
    got = np.zeros(n, np.int32)
    kp.reachable_owners(box, owner_alive, *grid.geometry, grid.mask, got)
    want = ref.reachable_owners(box, owner_alive, mask, *grid.geometry)
    np.testing.assert_array_equal(got, want)
    assert 5 < want.sum() < owner_alive.sum()


def test_owner_boxes_give_the_same_hits_and_ignore_unreachable_flailing_limbs():
    start, end, a, b, radius, owner, char_alive = _scene(15, p=120)
    n = len(char_alive)
    vel = _f32((end - start) * 60.0)
    # one more character 40 m away swings a limb 3 m in the step: nothing can reach it
    a = _f32(np.vstack([a, [[40.0, 1.0, 40.0]]]))
    b = _f32(np.vstack([b, [[40.0, 1.5, 40.0]]]))
    prev_a, prev_b = a.copy(), b.copy()
    prev_a[-1, 0] -= 3.0
    prev_b[-1, 0] -= 3.0
    radius = _f32(np.append(radius, 0.05))
    owner = np.append(owner, n).astype(np.int32)
    char_alive = np.append(char_alive, 1).astype(np.int32)
    boxes = _owner_boxes(prev_a, prev_b, a, b, radius, owner, n + 1)
    results = []
    for use_boxes in (False, True):
        pool = BulletPool(len(start), bounds=(-50, -50, 50, 50))
        pool.spawn(start, vel)
        P = len(start)
        out = np.zeros((P, 3), np.float32), np.zeros((P, 3), np.float32), np.zeros(P, np.int32)
        hits = pool.advance(DT, 9.81, 0.0, 3.0, a, b, radius, owner, char_alive, n + 1, prev_a=prev_a,
                            prev_b=prev_b, max_substeps=64, owner_boxes=boxes if use_boxes else None, export_to=out)
        results.append((pool.last_substeps, hits, pool.struck()))
        np.testing.assert_array_equal(out[0], pool.positions())  # exported at the end of the step
        np.testing.assert_array_equal(out[2] != 0, pool.alive_mask())
    assert results[0][0] == 60  # ceil(3 m / 0.05 m): the far limb sub-steps every bullet
    assert results[1][0] == 1  # ... unless the pool knows no bullet can reach it
    # the near limbs did not move: the same winners either way (toi up to the gravity integration of
    # 60 sub-steps; losers differ: on later sub-steps a character already hit no longer stops bullets)
    (_, h0, s0), (_, h1, s1) = results
    assert len(h1.chars) > 5
    np.testing.assert_array_equal(h0.chars, h1.chars)
    np.testing.assert_array_equal(h0.bullets, h1.bullets)
    np.testing.assert_array_equal(s0[h0.bullets], s1[h1.bullets])
    np.testing.assert_allclose(h0.toi, h1.toi, atol=1e-3)


def test_fused_advance_equals_the_phase_kernels():
    # with owner boxes advance prepares in one launch (prepare_limbs); without, with the separate phase kernels
    start, end, a, b, radius, owner, char_alive = _scene(16, p=150)
    vel = _f32((end - start) * 60.0)
    boxes = _owner_boxes(a, b, a, b, radius, owner, len(char_alive))
    runs = []
    for use_boxes in (False, True):
        pool = BulletPool(len(start), bounds=(-5, -5, 5, 5), capsule_capacity=4)  # the limb grid must grow
        pool.spawn(start, vel)
        hits = pool.advance(DT, 9.81, 0.01, 3.0, a, b, radius, owner, char_alive, len(char_alive),
                            owner_boxes=boxes if use_boxes else None)
        runs.append((hits, pool.struck(), pool.positions(), pool.alive_mask()))
    assert len(runs[0][0].chars) > 5
    for x, y in zip(runs[0][0] + runs[0][1:], runs[1][0] + runs[1][1:]):
        np.testing.assert_array_equal(x, y)


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


def test_owner_stride_visits_the_same_limbs_by_owner_block():
    # capsule c of _scene belongs to character c // 4: with owner_stride=4 the preparation walks the reachable
    # characters' blocks instead of every capsule, and the step is the same
    start, end, a, b, radius, owner, char_alive = _scene(18, p=200)
    n = len(char_alive)
    vel = _f32((end - start) * 60.0)
    prev_a, prev_b = a.copy(), b.copy()
    prev_a[::5, 0] -= 0.3  # some limbs moved: several sub-steps
    boxes = _owner_boxes(prev_a, prev_b, a, b, radius, owner, n)
    runs = []
    for stride in (0, 4):
        pool = BulletPool(len(start), bounds=(-5, -5, 5, 5), capsule_capacity=4)  # the limb grid must grow
        pool.spawn(start, vel)
        hits = pool.advance(DT, 9.81, 0.0, 3.0, a, b, radius, owner, char_alive, n, prev_a=prev_a, prev_b=prev_b,
                            owner_boxes=boxes, owner_stride=stride)
        runs.append((pool.last_substeps, hits, pool.struck(), pool.positions(), pool.alive_mask()))
    assert runs[0][0] > 1 and len(runs[0][1].chars) > 3
    assert runs[0][0] == runs[1][0]
    for x, y in zip(runs[0][1] + runs[0][2:], runs[1][1] + runs[1][2:]):
        np.testing.assert_array_equal(x, y)
    for stride, bad_owner, match in ((3, owner, "30 characters x 3"), (4, owner[::-1].copy(), "is not c // 4"),
                                     (-1, owner, "integer >= 0")):
        with pytest.raises(ValueError, match=match):
            pool.advance(DT, 9.81, 0.0, 3.0, a, b, radius, bad_owner, char_alive, n, owner_boxes=boxes,
                         owner_stride=stride)


def test_threats_match_twin():
    rng = np.random.default_rng(9)
    n, p = 40, 100
    chest = _f32(np.c_[rng.uniform(-5, 5, n), np.full(n, 1.3), rng.uniform(-5, 5, n)])
    char_alive = (rng.random(n) < 0.9).astype(np.int32)
    aim = chest[rng.integers(0, n, p)] + rng.normal(0, 0.5, (p, 3))
    origin = _f32(aim + rng.normal(0, 6.0, (p, 3)) * [1, 0.1, 1])
    vel = _f32((aim - origin) / np.linalg.norm(aim - origin, axis=1, keepdims=True) * rng.uniform(5, 30, (p, 1)))
    pool = BulletPool(p, bounds=(-5, -5, 5, 5))
    pool.spawn(origin, vel)
    got = pool.threats(chest, char_alive, horizon=0.3, reach=0.4)
    want = ref.threats(chest, char_alive, origin, vel, np.ones(p, np.int32), 0.3, 0.4)
    np.testing.assert_array_equal(got.bullet, want[0])
    assert (got.bullet >= 0).sum() > 5 and (got.bullet < 0).sum() > 5
    for g, w in zip(got[1:], want[1:]):
        np.testing.assert_allclose(g, w, atol=1e-4)
    assert np.all(got.bullet[char_alive == 0] == -1)


def test_threats_ignore_receding_and_far_bullets():
    pool = BulletPool(4)
    chest = _f32([[0, 1.3, 0]])
    # 0: coming straight at the chest; 1: already past it, flying away; 2: passing 2 m wide
    pool.spawn([[-5, 1.3, 0], [1, 1.3, 0], [-5, 1.3, 2]], [[10, 0, 0], [10, 0, 0], [10, 0, 0]])
    got = pool.threats(chest, [1], horizon=1.0, reach=0.5)
    assert got.bullet.tolist() == [0]
    np.testing.assert_allclose([got.time[0], got.miss[0]], [0.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(got.direction[0], [1, 0, 0])
    got = pool.threats(chest, [1], horizon=0.2, reach=0.5)  # out of reach within the horizon
    assert got.bullet.tolist() == [-1] and got.time[0] == -1.0


def test_bad_input_is_refused_with_the_argument_name():
    with pytest.raises(ValueError, match="pool_size"):
        BulletPool(0)
    pool = BulletPool(4)
    with pytest.raises(ValueError, match="origins"):
        pool.spawn(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="velocities"):
        pool.spawn(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="dt"):
        pool.step(0.0)
    a, b, radius, owner, alive = _post()
    with pytest.raises(ValueError, match="owner"):
        pool.collide(a, b, radius, np.array([3], np.int32), alive, 1)
    with pytest.raises(ValueError, match="radii"):
        pool.collide(a, b, -radius, owner, alive, 1)
