"""kernels/bullet_hits.py, bullet_threats.py and the fused kernels of kernels/projectiles.py, through
crowd_ik.game.pool, against the brute-force NumPy twin and hand-built scenes."""

import numpy as np
import pytest

from bullet_cases import DT, _f32, _fire, _owner_boxes, _post, _scene
from crowd_ik.game.pool import BulletPool
from crowd_ik.reference import projectiles as ref


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
    np.testing.assert_allclose(pool.bullet_toi[hit], want_toi[hit], atol=2e-5)

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


@pytest.mark.parametrize("seed", [7, 8])
def test_moving_limbs_sub_step_each_bullet_as_the_brute_force_twin(seed):
    start, end, a, b, radius, owner, char_alive = _scene(seed, p=400)
    rng = np.random.default_rng(seed)
    prev_a, prev_b = _f32(a + rng.normal(0, 0.12, a.shape)), _f32(b + rng.normal(0, 0.12, b.shape))
    n = len(char_alive)
    pool = BulletPool(len(start), bounds=(-8, -8, 8, 8))
    pool.spawn(start, _f32((end - start) / DT))
    hits = pool.advance(DT, 0.0, 0.0, 3.0, a, b, radius, owner, char_alive, n, prev_a=prev_a, prev_b=prev_b,
                        max_substeps=32)
    q0, q1 = pool.prev.to_numpy(), pool.positions()
    alive = np.ones(len(start), np.int32)
    want_char, want_toi, want_k, want_winner = ref.collide_moving(q0, q1, alive, 0.03, prev_a, prev_b, a, b, radius,
                                                                  owner, char_alive, n, max_substeps=32)
    np.testing.assert_array_equal(pool.bullet_substeps, want_k)
    assert (want_k > 1).sum() > 20 and (want_k == 1).sum() > 20 and pool.last_substeps == want_k.max()
    assert pool.last_substepped == (want_k > 1).sum()
    # a graze within 1e-4 m of contact may go either way in float32: set those bullets aside
    lo = ref.collide_moving(q0, q1, alive, 0.03 - 1e-4, prev_a, prev_b, a, b, radius, owner, char_alive, n, 32)[0]
    hi = ref.collide_moving(q0, q1, alive, 0.03 + 1e-4, prev_a, prev_b, a, b, radius, owner, char_alive, n, 32)[0]
    clear = lo == hi
    assert clear.mean() > 0.97 and (want_char[clear & (want_k > 1)] >= 0).sum() > 10
    struck = pool.struck()
    np.testing.assert_array_equal(struck[clear], want_char[clear])
    hit = clear & (want_char >= 0)
    np.testing.assert_allclose(pool.bullet_toi[hit], want_toi[hit], atol=2e-5)
    settled = np.array([clear[(want_char == c) | (lo == c) | (hi == c)].all() for c in range(n)])
    got_winner = np.full(n, -1)
    got_winner[hits.chars] = hits.bullets
    assert settled.sum() >= n - 3 and (want_winner[settled] >= 0).sum() > 10
    np.testing.assert_array_equal(got_winner[settled], want_winner[settled])
    np.testing.assert_array_equal(pool.alive_mask(), struck < 0)  # every bullet that struck a limb died


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


def test_only_the_bullets_near_a_fast_limb_sub_step():
    # one character: an arm swinging 1 m at x = 0, a still leg at x = 3; a bullet passes each, a third flies clear
    prev_a, prev_b = _f32([[-0.5, 1.5, 0], [3, 0.2, 0]]), _f32([[-0.5, 1.9, 0], [3, 0.8, 0]])
    a, b = _f32([[0.5, 1.5, 0], [3, 0.2, 0]]), _f32([[0.5, 1.9, 0], [3, 0.8, 0]])
    radius, owner, alive = _f32([0.05, 0.05]), np.zeros(2, np.int32), np.ones(1, np.int32)
    origins = [[0.0, 1.7, -0.2], [3.0, 0.5, -0.2], [6.0, 1.0, -0.2]]
    pool = BulletPool(4)
    pool.spawn(origins, [[0.0, 0.0, 24.0]] * 3)
    hits = pool.advance(DT, 0.0, 0.0, 3.0, a, b, radius, owner, alive, 1, prev_a=prev_a, prev_b=prev_b)
    assert pool.bullet_substeps[:3].tolist() == [16, 1, 1]  # ceil(1 m / 0.05 m) = 20, capped at max_substeps
    assert pool.last_substeps == 16 and pool.last_substepped == 1
    assert pool.struck()[:3].tolist() == [0, 0, -1] and hits.chars.tolist() == [0]
    # the arm crosses x = 0 half-way through the step, the bullet reaches z = 0 at 0.5: the bullet on the leg wins
    assert hits.bullets.tolist() == [1]


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


def test_a_finer_limb_grid_finds_the_same_hits_and_leaves_the_threat_grid_alone():
    # the grid is only a broad phase: with limbs that do not move (one sub-step) every cell size gives the same
    # hits, bit for bit; limb_cell_size sets the limbs' grid only
    start, end, a, b, radius, owner, char_alive = _scene(17, p=200)
    vel = _f32((end - start) * 60.0)
    boxes = _owner_boxes(a, b, a, b, radius, owner, len(char_alive))
    runs = []
    for limb_cell in (None, 0.25):
        pool = BulletPool(len(start), bounds=(-5, -5, 5, 5), cell_size=1.0, limb_cell_size=limb_cell)
        assert pool.threat_grid.cell == 1.0 and pool.limb_grid.cell == (limb_cell or 1.0)
        pool.spawn(start, vel)
        hits = pool.advance(DT, 9.81, 0.01, 3.0, a, b, radius, owner, char_alive, len(char_alive), owner_boxes=boxes,
                            owner_stride=4)
        runs.append((hits, pool.struck(), pool.alive_mask()))
    assert len(runs[0][0].chars) > 5 and runs[0][0].chars.size == runs[1][0].chars.size
    for x, y in zip(runs[0][0] + runs[0][1:], runs[1][0] + runs[1][1:]):
        np.testing.assert_array_equal(x, y)


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
    with pytest.raises(ValueError, match="limb_cell_size"):
        BulletPool(4, limb_cell_size=-1.0)
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
