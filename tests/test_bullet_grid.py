"""kernels/bullet_grid.py (the broad phase) and owner boxes against the NumPy twin and hand-built scenes."""

import numpy as np
import pytest

from bullet_cases import DT, _bullets, _capsules, _f32, _ndarray, _owner_boxes, _scene
from crowd_ik.game.pool import BulletPool, Grid
from crowd_ik.kernels import projectiles as kp
from crowd_ik.reference import projectiles as ref


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


def test_owner_boxes_give_the_same_hits_and_a_far_flailing_limb_sub_steps_nobody():
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
    # the far limb sub-steps no bullet (none comes near it), and the hits are the same either way
    assert results[0][0] == results[1][0] == 1
    (_, h0, s0), (_, h1, s1) = results
    assert len(h1.chars) > 5
    for x, y in zip(h0 + (s0,), h1 + (s1,)):
        np.testing.assert_array_equal(x, y)


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
