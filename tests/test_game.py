"""World: stepping and drawing, SUPERHOT time, hits and shattering, dodging with planted feet,
determinism, every shipped scene, and the aiming helpers."""

import math

import numpy as np
import pytest

from crowd_ik.game.shards import SHARD_LIFE, SHARD_PIECES
from crowd_ik.game.world import DT, World, ballistic_direction, cone_sample
from crowd_ik.scene import load_scene, scene_with, shipped_scenes

SMALL = {"characters.count": 6, "shooters.count": 2, "bullets.pool_size": 256}


def small_scene(**overrides):
    return scene_with(load_scene(None), size=(96, 64), **{**SMALL, **overrides})


def lone_character(**overrides):
    """One character standing at the origin (no wandering); time always runs at 1 and the player is far away."""
    return small_scene(**{"characters.count": 1, "characters.walk_speed": 0.0, "time.floor": 1.0,
                          "player.path": [[6.0, 6.0]], **overrides})


def test_world_steps_and_renders():
    world = World(small_scene(frames=8))
    frame = world.render()
    assert frame.shape == (64, 96, 3) and frame.dtype == np.uint8
    for _ in range(5):
        world.step()
    its = world.characters.last_iterations  # the last world step's solve, per character
    assert its.shape == (world.characters.n,) and np.all((its >= 0) & (its <= world.scene.solver.iterations))
    frame = world.render()
    assert frame.shape == (64, 96, 3)
    assert frame.std() > 5  # not a blank image
    s = world.stats
    assert s["frame"] == 5 and s["steps"] >= 1 and s["world_time"] == pytest.approx(s["steps"] * DT)
    for key in ("simulation_ms", "ik_ms", "render_ms"):
        assert s[key] >= 0.0
    assert s["render_ms"] > 0.0 and s["ik_ms"] > 0.0
    lines = world.hud_lines()
    assert lines[0].startswith("TIME x") and "hits" in lines[2] and "dodges" in lines[2]
    assert lines[3].startswith("IK ") and " ms" not in lines[3]  # timings only on request
    timed = World(small_scene(frames=8), hud_timings=True)
    timed.step()
    timed.render()
    assert " ms" in timed.hud_lines()[3]


def test_time_scale_rises_when_the_player_walks_and_falls_when_it_stops():
    scene = small_scene(**{"player.path": [[0.0, 0.0], [1.5, 0.0]], "player.speed": 1.5,
                           "time.floor": 0.05, "time.response": 4.0}, fps=30)
    world = World(scene, autofire=False, autopilot=False)  # the scripted walk: it ends, the player stands
    assert world.time_scale == pytest.approx(0.05)
    world_time = 0.0
    for _ in range(27):  # 0.9 s of walking
        world.step()
        world_time += world.time_scale / 30.0
    assert world.time_scale > 0.9
    peak = world.time_scale
    for _ in range(60):  # the walk ended at 1 s; two seconds standing
        world.step()
        world_time += world.time_scale / 30.0
    assert world.time_scale < peak
    assert world.time_scale == pytest.approx(0.05, abs=0.01)
    # the world advanced by the sum of the frames' time scales, in whole fixed steps
    assert world.world_time == pytest.approx(world.steps * DT)
    assert abs(world.world_time - world_time) <= DT + 1e-9


def test_bullet_fired_at_a_character_hits_and_shatters_it():
    world = World(lone_character(), autofire=False)
    world.characters.reflex[:] = 0.0  # a statue: it never reacts
    chest = world.joints()[0, world.body.chest]
    world.fire(chest + [0.0, 0.0, 1.5], [[0.0, 0.0, -25.0]])
    world.simulate(0.2)
    assert world.hits == 1 and world.dodges == 0
    assert not world.characters.alive[0]
    assert world.stats["standing"] == 0 and world.stats["bullets"] == 0
    n_shards = world.stats["shards"]
    assert n_shards == SHARD_PIECES * world.body.n_bones
    start = world.shards.c[world.shards.live].copy()
    world.simulate(1.5)
    now = world.shards.c[world.shards.live]
    assert np.mean(now[:, 1]) < np.mean(start[:, 1]) - 0.3  # they fell ...
    low = now[:, 1] - np.abs(world.shards.h[world.shards.live][:, 1]) - world.shards.r[world.shards.live]
    assert low.min() > -0.05  # ... onto the ground, not through it
    prim = world.primitives()
    assert np.all(prim["capsules"]["body"] != 0)  # the shattered character is no longer drawn whole
    world.simulate(SHARD_LIFE)
    assert world.stats["shards"] == 0  # and the shards faded away
    assert world.render().shape == (64, 96, 3)


def _shoot_at(world, joint_name, origin=(0.3, 1.5, 12.0), speed=25.0):
    j = world.body.rig.joint_names.index(joint_name)
    target = world.joints()[0, j]
    origin = np.array([origin], np.float32)
    world.fire(origin, ballistic_direction(origin, target[None], speed, world.scene.bullets.gravity) * speed)


@pytest.mark.parametrize("prefers_duck", [False, True])
def test_character_dodges_a_bullet_aimed_at_its_head(prefers_duck):
    # control: a statue in the same spot is hit by the same shot, so the bullet was on target
    statue = World(lone_character(), autofire=False)
    statue.characters.reflex[:] = 0.0
    _shoot_at(statue, "head")
    statue.simulate(1.0)
    assert statue.hits == 1

    world = World(lone_character(), autofire=False)
    world.characters.reflex[:] = 0.6
    world.characters.prefers_duck[:] = prefers_duck
    head = world.body.rig.joint_names.index("head")
    head0 = world.joints()[0, head].copy()
    _shoot_at(world, "head")
    moved = 0.0
    for _ in range(int(1.0 / DT)):
        world.step_world()
        moved = max(moved, float(np.linalg.norm(world.joints()[0, head] - head0)))
    assert world.hits == 0 and world.characters.alive[0]
    assert world.dodges == 1
    assert moved > 0.15  # it really moved out of the way
    if prefers_duck:
        assert head0[1] - world.joints()[0, head][1] >= 0.0
    # and it comes back to its stance afterwards
    world.simulate(2.0)
    assert np.linalg.norm(world.joints()[0, head] - head0) < 0.05


def test_feet_stay_planted_while_dodging():
    world = World(lone_character(), autofire=False)
    world.characters.reflex[:] = 0.6
    names = world.body.rig.joint_names
    ankles = [names.index("ankle_l"), names.index("ankle_r")]
    _shoot_at(world, "chest")
    worst, leaned = 0.0, 0.0
    for _ in range(int(1.0 / DT)):
        world.step_world()
        worst = max(worst, float(np.abs(world.joints()[0, ankles] - world.characters.planted[0]).max()))
        leaned = max(leaned, float(np.linalg.norm(world.characters.lean[0])))
    assert leaned > 0.2 and world.dodges == 1 and world.hits == 0
    assert worst < 0.02


def test_shooters_fire_and_the_crowd_counts_hits_and_dodges():
    scene = small_scene(**{"characters.count": 9, "shooters.count": 3, "shooters.fire_rate": 4.0,
                           "time.floor": 1.0})
    world = World(scene)
    world.simulate(3.0)
    s = world.stats
    assert s["shots"] >= 3 * 8
    assert s["hits"] + s["dodges"] > 0
    assert s["hits"] == 9 - s["standing"]


def test_same_scene_gives_identical_frames():
    scene = small_scene(**{"shooters.fire_rate": 6.0, "time.floor": 0.5}, frames=48)
    runs = []
    for _ in range(2):
        world = World(scene, hud_timings=False)
        frames = []
        for k in range(48):
            if k:
                world.step()
            frames.append(world.render())
        runs.append((np.stack(frames), world.hits, world.dodges, world.joints()))
    (a, hits_a, dodges_a, joints_a), (b, hits_b, dodges_b, joints_b) = runs
    assert hits_a + dodges_a > 0  # something happened
    assert (hits_a, dodges_a) == (hits_b, dodges_b)
    np.testing.assert_array_equal(joints_a, joints_b)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("path", shipped_scenes(), ids=lambda p: p.stem)
def test_every_shipped_scene_runs(path):
    scene = load_scene(path)
    small = {"characters.count": min(scene.characters.count, 60), "shooters.count": min(scene.shooters.count, 4)}
    world = World(scene_with(scene, size=(96, 64), frames=4, **small))
    for _ in range(3):
        world.step()
    frame = world.render()
    assert frame.shape == (64, 96, 3) and frame.std() > 1


# ---------------------------------------------------------------------------------------------
# the player's bullets down shooters


def shooter_range(**overrides):
    """One character at the origin, two shooters side by side at x = -1 and +1, z = -6 (facing +z,
    firing at it), the player standing at (0, -3) between them and the character; time runs at 1."""
    return small_scene(**{"characters.count": 1, "shooters.count": 2, "shooters.placement": "line",
                          "shooters.radius": 6.0, "shooters.fire_rate": 4.0, "time.floor": 1.0,
                          "player.path": [[0.0, -3.0]], **overrides})


def _chest(world, k):
    return world.shooters.joints[k, world.hbody.chest].astype(np.float64)


def test_players_bullet_downs_the_shooter_it_hits():
    world = World(shooter_range())
    N = world.n
    hb = world.hbody
    slot = world.set_player_input((0.0, 0.0), _chest(world, 0), fire=True)
    assert len(slot) == 1 and world.bullets.players[slot[0]]
    downed_at = None
    for step in range(int(0.5 / DT)):
        shards = world.stats["shards"]
        world.step_world()
        if world.shooters_down:
            downed_at = step
            # it shattered into as many shards as a humanoid character does, and the bullet is gone
            assert world.stats["shards"] - shards == SHARD_PIECES * hb.n_bones
            assert not world.bullets.pool.alive_mask()[slot[0]] and not world.bullets.alive[slot[0]]
            assert not world.bullets.players.any()
            break
    assert downed_at is not None and downed_at * DT < 0.3  # 3 m at 25 m/s: about 0.12 s
    assert world.shooters.alive.tolist() == [False, True]
    assert world.stats["shooters_down"] == 1
    assert "shooters down 1/2" in world.hud_lines()[2]
    # down for good: it fires no more, the other shooter goes on
    shots = world.shooters.shots_fired.copy()
    world.simulate(2.0)
    assert world.shooters.shots_fired[0] == shots[0] and world.shooters.shots_fired[1] > shots[1]
    assert world.shooters.alive.tolist() == [False, True]
    bodies = world.primitives()["capsules"]["body"]
    assert not np.any(bodies == N + 0) and np.any(bodies == N + 1)  # no longer drawn (shooter 1 still is)
    assert world.render().shape == (64, 96, 3)


@pytest.mark.parametrize("direction", [+1.0, -1.0])
def test_the_first_shooter_along_the_bullets_path_is_hit(direction):
    """A path segment through both shooters in one step: the earlier hit along it counts, once."""
    world = World(shooter_range(), autofire=False)
    world.simulate(DT)
    slot = world.set_player_input((0.0, 0.0), _chest(world, 0), fire=True)[0]
    y, z = _chest(world, 0)[1], _chest(world, 0)[2]
    world.bullets.pos_prev[slot] = [-3.0 * direction, y, z]  # a segment from one side past both chests
    world.bullets.pos[slot] = [3.0 * direction, y, z]
    world._hit_shooters()
    first = 0 if direction > 0 else 1
    assert world.shooters.alive.tolist() == [k != first for k in range(2)]
    assert not world.bullets.alive[slot] and not world.bullets.pool.alive_mask()[slot]


def test_a_shooters_own_bullets_never_down_a_shooter():
    # a bullet that is not the player's, fired from 1.5 m in front of shooter 0 straight at its chest
    world = World(shooter_range(), autofire=False)
    chest = _chest(world, 0)
    world.fire((chest + [0.0, 0.0, 1.5])[None], [[0.0, 0.0, -25.0]])
    world.simulate(0.5)
    assert world.shooters_down == 0 and world.shooters.alive.all() and world.stats["shards"] == 0
    # two shooters facing each other across a dodging character: their misses fly on to each other
    ring = small_scene(**{"characters.count": 1, "characters.walk_speed": 0.0, "shooters.count": 2, "shooters.radius": 6.0,
                          "shooters.fire_rate": 6.0, "shooters.spread_deg": 4.0, "time.floor": 1.0,
                          "player.path": [[6.0, 6.0]]})
    world = World(ring)
    world.simulate(2.0)
    assert world.stats["shots"] >= 6 and world.stats["dodges"] >= 3
    assert world.shooters_down == 0 and world.shooters.alive.all()


def test_a_players_bullet_that_misses_downs_nobody():
    world = World(shooter_range(), autofire=False)
    world.set_player_input((0.0, 0.0), _chest(world, 0) + [0.0, 3.0, 0.0], fire=True)
    world.simulate(1.0)
    assert world.shooters_down == 0 and world.shooters.alive.all()
    assert world.stats["shards"] == 0 and "shooters down 0/2" in world.hud_lines()[2]


def test_shooting_shooters_is_deterministic():
    def run():
        world = World(shooter_range(frames=20), hud_timings=False)
        frames = []
        for k in range(20):
            aim = _chest(world, k // 10)  # shooter 0 first, then shooter 1
            world.set_player_input((0.3, 0.0) if k < 8 else (0.0, 0.0), aim, fire=k in (1, 11))
            world.step()
            frames.append(world.render())
        stats = {key: v for key, v in world.stats.items() if not key.endswith("_ms")}
        return (stats, world.joints(), world.shooters.joints, world.shards.c[world.shards.live],
                np.stack(frames))

    (stats_a, *arrays_a), (stats_b, *arrays_b) = run(), run()
    assert stats_a["shooters_down"] == 2  # both shots hit: something happened
    assert stats_a == stats_b
    for a, b in zip(arrays_a, arrays_b):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("layout,rig", [("ring", "humanoid"), ("random", "humanoid"), ("grid", "chain")])
def test_layouts_and_rigs(layout, rig):
    scene = small_scene(**{"characters.layout": layout, "characters.rig": rig, "time.floor": 1.0,
                           "shooters.fire_rate": 5.0, "characters.scale": 1.2})
    world = World(scene)
    roots = world.characters.ground
    gaps = np.linalg.norm(roots[:, None] - roots[None], axis=-1) + np.eye(len(roots)) * 99
    assert gaps.min() > 0.4 * scene.characters.spacing  # nobody stands inside anybody
    assert np.all(world.joints()[..., 1] > -0.1)  # everyone stands on the ground
    top = world.joints()[..., 1].max(axis=1)
    assert np.all(top > 1.2 * 1.2)  # and stands up (a chain too)
    world.simulate(1.0)
    assert world.stats["shots"] > 0
    assert world.render().shape == (64, 96, 3)


def test_ballistic_direction_reaches_the_target():
    origin = np.array([[0.0, 1.4, 0.0], [3.0, 1.0, -2.0]])
    target = np.array([[0.0, 1.6, -12.0], [-10.0, 0.5, 20.0]])
    speed, g = 25.0, 9.81
    d = ballistic_direction(origin, target, speed, g)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    for o, t, u in zip(origin, target, d):
        horizontal = np.linalg.norm((t - o)[[0, 2]])
        time_of_flight = horizontal / (speed * np.linalg.norm(u[[0, 2]]))
        landing = o + u * speed * time_of_flight + np.array([0.0, -0.5 * g * time_of_flight**2, 0.0])
        assert np.linalg.norm(landing - t) < 0.01


def test_cone_sample_stays_within_the_spread():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    half = math.radians(3.0)
    out = cone_sample(d, half, rng.random(2000).astype(np.float32), rng.random(2000).astype(np.float32))
    angle = np.arccos(np.clip(np.sum(out * d, axis=1), -1, 1))
    assert angle.max() <= half * 1.001
    assert angle.mean() > 0.5 * half  # uniform in solid angle: mean 2/3 of the half-angle
    np.testing.assert_array_equal(cone_sample(d, 0.0, np.zeros(2000, np.float32), np.zeros(2000, np.float32)),
                                  cone_sample(d, 0.0, np.ones(2000, np.float32) * 0.5, np.zeros(2000, np.float32)))


def test_world_refuses_a_non_scene():
    with pytest.raises(ValueError, match="scene"):
        World({"characters": 3})


def test_the_bullets_host_flags_are_the_pools_and_spawning_never_reads_the_device(monkeypatch):
    """game.bullets.Bullets owns every slot: its alive flags equal the device pool's after every step, and
    spawning takes the free slots from them (the pool's alive ndarray is never read back for a spawn)."""
    world = World(small_scene(frames=60, **{"shooters.fire_rate": 8.0}))
    pool = world.bullets.pool
    reads = []
    real = pool.alive.to_numpy
    monkeypatch.setattr(pool.alive, "to_numpy", lambda: (reads.append(1), real())[1])
    spawned = 0
    for _ in range(90):
        before = int(world.bullets.alive.sum())
        world.step_world()
        spawned += max(0, int(world.bullets.alive.sum()) - before)
        assert np.array_equal(world.bullets.alive, real() != 0)
    assert spawned > 0 and world.stats["shots"] > 0 and not reads


def elbow_directions(joints: np.ndarray, yaw: np.ndarray, names: list) -> tuple[np.ndarray, np.ndarray]:
    """(out, forward) of both elbows of bodies joints (K, J, 3) heading yaw (K,): the unit direction from the
    shoulder-hand line to the elbow, along the side away from the body and along the facing direction
    (NaN where the arm is straight)."""
    fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=1)
    left = np.stack([np.cos(yaw), np.zeros_like(yaw), -np.sin(yaw)], axis=1)
    out, forward = [], []
    for side, sx in (("l", 1.0), ("r", -1.0)):
        s, e, h = (joints[:, names.index(f"{j}_{side}")] for j in ("shoulder", "elbow", "hand"))
        a = (h - s) / np.linalg.norm(h - s, axis=1, keepdims=True)
        u = (e - s) - np.sum((e - s) * a, axis=1, keepdims=True) * a
        n = np.linalg.norm(u, axis=1, keepdims=True)
        u = np.where(n > 0.02, u / np.maximum(n, 1e-9), np.nan)
        out.append(sx * np.sum(u * left, axis=1))
        forward.append(np.sum(u * fwd, axis=1))
    return np.concatenate(out), np.concatenate(forward)


def test_arm_poles_follow_the_root_and_heading_and_skip_the_fallen():
    from crowd_ik.game.arm_poles import ArmPoles
    from crowd_ik.geometry.vectors import yaw_rotate

    world = World(small_scene())
    body = world.body
    poles = ArmPoles(body, 3)
    roots = np.float32([[0.0, 0.9, 0.0], [2.0, 0.8, -1.0], [-3.0, 0.95, 4.0]])
    yaw = np.float32([0.0, 1.2, -2.5])
    p = poles.update(roots, yaw, np.array([True, False, True]))
    assert p is poles.poles and p.shape == (3, body.rig.n_effectors, 3)  # one array, refilled
    hands = [body.rig.effector_names.index(h) for h in ("hand_l", "hand_r")]
    others = [e for e in range(body.rig.n_effectors) if e not in hands]
    assert np.isnan(p[:, others]).all() and np.isnan(p[1]).all()  # no knee/head poles; the fallen get none
    for n in (0, 2):
        want = roots[n] + yaw_rotate(poles.local, np.full(2, yaw[n], np.float32))
        np.testing.assert_allclose(p[n, hands], want, atol=1e-5)
    # at yaw 0 the left hand's pole lies left (+x) of the left elbow, behind it (-z) and below it
    elbow = body.rest_pos[body.rig.joint_names.index("elbow_l")] - [0.0, body.rest_root_y, 0.0]
    d = poles.local[0] - elbow
    assert d[0] > 0.0 and d[1] < 0.0 and d[2] < 0.0
    assert not np.isnan(poles.update(roots, yaw)).any(axis=-1)[:, hands].any()  # everyone standing again


def test_game_elbows_point_out_and_back_never_into_the_body():
    world = World(small_scene())
    names = world.body.rig.joint_names
    out, forward = [], []
    for _ in range(30):
        world.step()
        for joints, yaw, alive in ((world.characters.joints, world.characters.yaw, world.characters.alive),
                                   (world.shooters.joints, world.shooters.yaw, world.shooters.alive),
                                   (world.player.joints[None], np.float32([world.player.walker.yaw]), [True])):
            o, f = elbow_directions(joints[np.asarray(alive)], np.asarray(yaw)[np.asarray(alive)], names)
            out.append(o)
            forward.append(f)
    out, forward = np.concatenate(out), np.concatenate(forward)
    bent = ~np.isnan(out)
    assert bent.sum() > 300
    # without poles the same run has elbows turned 0.39 into the body and a mean 'out' of 0.03
    assert out[bent].min() > -0.2 and out[bent].mean() > 0.2
    assert forward[bent].max() < 0.4 and forward[bent].mean() < -0.4  # elbows behind the arm's line


def test_autopilot_line_of_fire_matches_every_pair_brute_force():
    from types import SimpleNamespace

    from crowd_ik.game.autopilot import CLEAR_WIDTH, Autopilot

    rng = np.random.default_rng(5)
    pilot = Autopilot.__new__(Autopilot)  # _pick reads only the body's scale
    pilot.body = SimpleNamespace(scale=1.0)
    blocked = 0
    for _ in range(40):
        n, s = int(rng.integers(1, 400)), int(rng.integers(1, 12))
        here = rng.uniform(-5.0, 5.0, 2)
        shooters = SimpleNamespace(alive=rng.random(s) < 0.8, ground=np.zeros((s, 3), np.float32))
        shooters.alive[0] = True
        shooters.ground[:, [0, 2]] = rng.uniform(-30.0, 30.0, (s, 2))
        chars = SimpleNamespace(alive=rng.random(n) < 0.9, ground=np.zeros((n, 3), np.float32))
        chars.ground[:, [0, 2]] = rng.uniform(-30.0, 30.0, (n, 2))
        d = shooters.ground[0, [0, 2]] - here  # a few bystanders right at the clearance from the first line
        side = np.array([-d[1], d[0]]) / np.hypot(*d)
        m = min(n, 10)
        chars.ground[:m, [0, 2]] = here + d * rng.random((m, 1)) + side * (CLEAR_WIDTH + rng.normal(0.0, 1e-6, (m, 1)))
        up = np.flatnonzero(shooters.alive)
        seg = shooters.ground[up][:, [0, 2]].astype(np.float64) - here
        length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-12)
        p = chars.ground[chars.alive][:, [0, 2]].astype(np.float64) - here
        t = (p @ seg.T) / length2
        near = (np.linalg.norm(t[..., None] * seg[None] - p[:, None, :], axis=2) < CLEAR_WIDTH) & (t > 0.0) & (t < 1.0)
        clear = ~near.any(axis=0)
        order = np.argsort(length2, kind="stable")
        best = order[clear[order]]
        k = best[0] if best.size else order[0]
        assert pilot._pick(here, shooters, chars) == (int(up[k]), bool(clear[k]))
        blocked += int((~clear).sum())
    assert blocked > 0
