"""view.frame.primitives: the capsules written block by block into their outputs equal the parts concatenated
(the straightforward assembly, written out here as the reference), with characters hit, shooters downed,
shards in flight and any interpolation weight."""

import numpy as np

from crowd_ik.game.shooters import COLOR as SHOOTER_COLOR
from crowd_ik.game.world import DT, World
from crowd_ik.reference.gait import GaitTwin
from crowd_ik.scene import load_scene, scene_with
from crowd_ik.view.frame import GUN_COLOR, PLAYER_COLOR, primitives


def reference_capsules(world, alpha: float) -> dict:
    """The capsules as separate parts per kind, concatenated (what primitives() must equal bit for bit)."""
    chars, shooters = world.characters, world.shooters
    b, hb = world.body, world.hbody
    N, S = chars.n, shooters.n
    alpha = np.float32(alpha)
    alive, up = np.flatnonzero(chars.alive), np.flatnonzero(shooters.alive)
    J = chars.limbs.joints_prev[alive] + (chars.limbs.joints[alive] - chars.limbs.joints_prev[alive]) * alpha
    SJ = shooters.joints_prev[up] + (shooters.joints[up] - shooters.joints_prev[up]) * alpha
    hand = SJ[:, hb.hand_r]
    PJ = world.player.joints
    a = [J[:, b.bone_parent].reshape(-1, 3), SJ[:, hb.bone_parent].reshape(-1, 3),
         hand - shooters.aim[up] * 0.04 * hb.scale, PJ[hb.bone_parent]]
    e = [J[:, 1:].reshape(-1, 3), SJ[:, 1:].reshape(-1, 3), hand + shooters.aim[up] * 0.16 * hb.scale, PJ[1:]]
    r = [np.tile(b.bone_radius, len(alive)), np.tile(hb.bone_radius, len(up)),
         np.full(len(up), 0.03 * hb.scale, np.float32), hb.bone_radius]
    c = [np.repeat(chars.colors[alive], b.n_bones, axis=0), np.tile(np.float32(SHOOTER_COLOR), (len(up) * hb.n_bones, 1)),
         np.tile(np.float32(GUN_COLOR), (len(up), 1)), np.tile(np.float32(PLAYER_COLOR), (hb.n_bones, 1))]
    o = [np.repeat(alive, b.n_bones), np.repeat(N + up, hb.n_bones), N + up, np.full(hb.n_bones, N + S)]
    shards = world.shards.capsules(alpha)
    if shards is not None:
        for parts, value in zip((a, e, r, c), shards):
            parts.append(value)
        o.append(np.full(len(shards[0]), N + S + 1))
    return {"a": np.concatenate(a).astype(np.float32), "b": np.concatenate(e).astype(np.float32),
            "radius": np.concatenate(r).astype(np.float32), "color": np.concatenate(c).astype(np.float32),
            "body": np.concatenate(o).astype(np.int32)}


def test_primitives_equal_the_concatenated_parts():
    scene = scene_with(load_scene(None), size=(96, 64), **{"characters.count": 6, "shooters.count": 2,
                                                           "bullets.pool_size": 256})
    world = World(scene)
    seen = set()
    for k in range(43):
        world.step()
        if k == 20:  # a shooter down and a character hit: both kinds of gaps in the blocks
            world.shooters.struck(np.array([0]))
            world.characters.struck(np.array([2]))
            world.shards.shatter(world.body, world.characters.joints[[2]], world.characters.colors[[2]],
                                 np.float32([[0.0, 0.0, 20.0]]), world.characters.joints[2, :1])
        if k % 7:
            continue
        for alpha in (0.0, 0.4, 1.0):
            got = primitives(world, alpha)["capsules"]
            want = reference_capsules(world, alpha)
            for key, value in want.items():
                assert got[key].dtype == value.dtype and got[key].flags.c_contiguous
                np.testing.assert_array_equal(got[key], value, err_msg=f"step {k} alpha {alpha} {key}")
            seen.add((bool(world.characters.alive.all()), bool(world.shooters.alive.all()),
                      world.shards.capsules(alpha) is not None))
    assert (True, True, False) in seen and (False, False, True) in seen  # both before and after the hits
    world.simulate(10 * DT)
    assert primitives(world, 0.5)["capsules"]["a"].shape[1] == 3


def test_shared_step_values_equal_the_ones_computed_apart():
    """The walk pose the gait kernel leaves is its twin's, and dodge filters with one gain: the same values as
    computed inside."""
    from crowd_ik.game.characters import lowpass, lowpass_gain

    scene = scene_with(load_scene(None), size=(96, 64), **{"characters.count": 12, "shooters.count": 2,
                                                           "bullets.pool_size": 256})
    world = World(scene)
    for _ in range(30):
        world.step()
    chars = world.characters
    gait = chars.gait
    assert (gait.swing >= 0).any()  # some feet in the air
    # the pose gait_step left is the twin's pose of the state it left, at the walkers' speeds
    twin = GaitTwin(gait.foot_local, gait.scale, {k: getattr(gait, k) for k in
                                                  ("feet", "swing", "progress", "period", "start", "goal", "last")})
    speed = np.linalg.norm(chars.velocity, axis=1)
    for got, want in zip(gait.pose(), twin.pose(chars.yaw, speed, twin.targets())):
        np.testing.assert_allclose(got, want, atol=2e-6)
    rng = np.random.default_rng(4)
    now, goal = rng.uniform(0, 1, 50), rng.uniform(0, 1, 50)
    gain = lowpass_gain(now, goal, DT)
    for shape in ((50,), (50, 3)):
        cur, des = rng.normal(size=shape).astype(np.float32), rng.normal(size=shape).astype(np.float32)
        np.testing.assert_array_equal(lowpass(cur, des, now, goal, DT, gain), lowpass(cur, des, now, goal, DT))
    assert np.any(gain != gain[0])  # both time constants used
