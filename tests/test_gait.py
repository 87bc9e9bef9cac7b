"""kernels/gait_kernels.py against its NumPy twin, and the gait's promises: planted feet hold exactly,
swings arc between footprints, the crowd keeps apart, and nobody stands still while walking."""

import numpy as np
import pytest

from crowd_ik.crowd import Crowd
from crowd_ik.game.body import Body
from crowd_ik.game.gait import Gait, leg_joints, plant_legs
from crowd_ik.game.world import DT, World
from crowd_ik.kernels import gait_kernels as gk
from crowd_ik.reference import gait_kernels as ref
from crowd_ik.reference.gait import GaitTwin
from crowd_ik.rig import Rig
from crowd_ik.scene import load_scene, scene_with


def _posed_crowd(n=6, seed=0):
    rig = Rig.humanoid()
    body = Body(rig)
    crowd = Crowd(rig, n=n)
    rng = np.random.default_rng(seed)
    angles = np.tile(body.stance, (n, 1)) + rng.normal(0.0, 0.15, (n, rig.n_dof)).astype(np.float32)
    crowd.set_angles(angles)
    crowd.set_roots(rng.normal(0.0, 2.0, (n, 3)).astype(np.float32) * [1, 0, 1], rng.uniform(-3, 3, n).astype(np.float32))
    return rig, body, crowd, rng


def test_plant_legs_matches_twin_and_puts_ankles_on_their_footprints():
    rig, body, crowd, rng = _posed_crowd()
    n = crowd.n
    legs = leg_joints(rig)
    yaw = crowd.roots()[1]
    hips = crowd.joint_positions()[:, legs[:, 0]]
    down = rng.normal(0.0, 0.25, (n, 2, 3)) + [0.0, -1.0, 0.0]  # below the hips, within the legs' reach
    down /= np.linalg.norm(down, axis=2, keepdims=True)
    feet = (hips + down * rng.uniform(0.4, 0.8, (n, 2, 1))).astype(np.float32)
    active = np.array([1, 1, 0, 1, 1, 1], np.int32)
    before = (crowd.joint_positions(), crowd.world_rotations(), crowd.rotations())
    want = ref.plant_legs(*before, rig.arrays["offset"], legs, feet, yaw, active)
    plant_legs(crowd, legs, feet, yaw, active)
    got = (crowd.joint_positions(), crowd.world_rotations(), crowd.rotations())
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, atol=2e-5)
    ankles = legs[:, 2]
    on = active == 1
    np.testing.assert_allclose(got[0][on][:, ankles], feet[on], atol=1e-5)
    np.testing.assert_array_equal(got[0][~on], before[0][~on])  # inactive characters untouched
    # the world pose written by the kernel is the FK of the rotations it wrote
    crowd.set_rotations(got[2])
    np.testing.assert_allclose(crowd.joint_positions(), got[0], atol=2e-5)
    # soles flat: each ankle frame's local +y is world up
    up = got[1][on][:, ankles]
    from crowd_ik.geometry.quat import qrot
    np.testing.assert_allclose(qrot(up.astype(np.float64), np.broadcast_to([0.0, 1.0, 0.0], up.shape[:-1] + (3,))),
                               np.broadcast_to([0.0, 1.0, 0.0], up.shape[:-1] + (3,)), atol=1e-4)
    # knees bend forward: the knee lies in front of the hip-ankle line
    knees = got[0][on][:, legs[:, 1]]
    hips = got[0][on][:, legs[:, 0]]
    fwd = np.stack([np.sin(yaw[on]), np.zeros(on.sum()), np.cos(yaw[on])], axis=1)[:, None]
    assert np.all(np.sum((knees - 0.5 * (hips + feet[on])) * fwd, axis=2) > 0.0)


@pytest.mark.parametrize("serial", [False, True])
def test_separate_matches_brute_force_twin(serial):
    rng = np.random.default_rng(3)
    m = 300
    pts = rng.uniform(-6.0, 6.0, (m, 2)).astype(np.float32)
    pts[5] = pts[4]  # coincident bodies are pushed apart along a fixed direction
    radius = rng.uniform(0.2, 0.4, m).astype(np.float32)
    kind = rng.choice([0, 1, 1, 1, 2], m).astype(np.int32)
    kind[4:6] = 1
    reach, cell = 1.1, 1.1
    lo = pts.min(axis=0)
    cells = (np.floor((pts.max(axis=0) - lo) / cell) + 1).astype(np.int64)
    c = np.floor((pts - lo) / cell).astype(np.int64)
    key = c[:, 0] * cells[1] + c[:, 1]
    order = np.argsort(key, kind="stable").astype(np.int32)
    start = np.zeros(int(cells.prod()) + 1, np.int32)
    np.cumsum(np.bincount(key, minlength=int(cells.prod())), out=start[1:])
    steer, push = np.zeros_like(pts), np.zeros_like(pts)
    gk.separate(pts, radius, kind, order, start, float(lo[0]), float(lo[1]), cell, int(cells[0]), int(cells[1]),
                reach, steer, push, serial)
    want_steer, want_push = ref.separate(pts, radius, kind, reach)
    np.testing.assert_allclose(steer, want_steer, atol=1e-5)
    np.testing.assert_allclose(push, want_push, atol=1e-5)
    assert np.linalg.norm(push[4]) > 0.1 and np.linalg.norm(push[5]) > 0.1
    assert np.all(steer[kind != 1] == 0.0) and np.any(push[kind == 1] != 0.0)


STATE = ("feet", "swing", "progress", "period", "start", "goal", "last")


@pytest.mark.parametrize("scale", [1.0, 0.6])
def test_gait_step_matches_the_twin_step_after_step(scale):
    """gait_step against reference/gait.py from the same state, every step of a crowd that starts, stops, turns and
    changes speed (some bodies inactive): the same swings and landings, feet, targets and pose within float32
    rounding (the twin's NumPy sin / cos against the kernel's). Each step starts from the twin's state, so a
    decision that a last-ulp difference flipped would stay one step's (none did when this was written)."""
    body = Body(Rig.humanoid(1.75 * scale), scale=scale)
    n = 48
    rng = np.random.default_rng(7)
    ground = rng.uniform(-3.0, 3.0, (n, 3)).astype(np.float32) * np.float32([1, 0, 1])
    yaw = rng.uniform(-3.0, 3.0, n).astype(np.float32)
    gait = Gait(body, ground, yaw)
    twin = GaitTwin(gait.foot_local, scale, {k: getattr(gait, k) for k in STATE} | {"steps": 0})
    speed = rng.uniform(0.0, 2.2, n) * scale
    agree = []
    for k in range(150):
        if k % 30 == 0:  # new speeds (some standing) and headings now and then
            speed = np.where(rng.random(n) < 0.3, 0.0, rng.uniform(0.2, 2.2, n) * scale)
            yaw = (yaw + rng.normal(0.0, 0.6, n)).astype(np.float32)
        vel = (np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], 1) * speed[:, None]).astype(np.float32)
        ground = (ground + vel * DT).astype(np.float32)
        active = rng.random(n) > 0.1
        for name in STATE:  # both from the twin's state
            np.copyto(getattr(gait, name), getattr(twin, name))
        started, twin_started = gait.steps, twin.steps
        gait.step(ground, yaw, vel, DT, active)
        want_targets, want_bob, want_hands, want_head = twin.step(ground, yaw, vel, DT, active)
        same = (gait.swing == twin.swing) & (gait.last == twin.last)
        agree.append(same.mean())
        if same.all():
            assert gait.steps - started == twin.steps - twin_started
        for name in ("feet", "start", "goal"):
            np.testing.assert_allclose(getattr(gait, name)[same], getattr(twin, name)[same], atol=2e-5 * scale)
        np.testing.assert_allclose(gait.progress[same], twin.progress[same], atol=1e-6)
        np.testing.assert_allclose(gait.period[same], twin.period[same], rtol=1e-6)
        np.testing.assert_allclose(gait.targets()[same], want_targets[same], atol=2e-5 * scale)
        bob, hands, head = gait.pose()
        np.testing.assert_allclose(bob[same], want_bob[same], atol=1e-6)
        np.testing.assert_allclose(hands[same], want_hands[same], atol=2e-6)
        np.testing.assert_allclose(head[same], want_head[same], atol=2e-6)
    assert np.mean(agree) >= 0.999 and twin.steps > n  # the bodies stepped, the same way
    assert np.any(twin.swing >= 0) and np.any(twin.swing < 0)


def test_gait_steps_ahead_and_holds_stance_feet():
    body = Body(Rig.humanoid())
    n = 3
    ground = np.zeros((n, 3), np.float32)
    yaw = np.zeros(n, np.float32)
    gait = Gait(body, ground, yaw)
    vel = np.array([[0.0, 0.0, 1.2], [0.0, 0.0, 0.0], [0.6, 0.0, 0.0]], np.float32)
    last_feet, held = gait.targets(), []
    for _ in range(int(2.0 / DT)):
        ground = ground + vel * DT
        stance = gait.swing.copy()
        gait.step(ground, yaw, vel, DT, np.ones(n, bool))
        feet = gait.targets()
        for i in range(n):  # a foot that was on the ground and still is did not move at all
            for f in range(2):
                if stance[i] != f and gait.swing[i] != f:
                    held.append(float(np.abs(feet[i, f] - last_feet[i, f]).max()))
        last_feet = feet
    assert max(held) == 0.0
    # the walker's feet are near its body (footprints chosen ahead), the still one never stepped
    assert abs(float(gait.feet[0, :, 2].mean() - ground[0, 2])) < 0.5
    assert gait.feet[1, :, 2].max() == gait.homes(np.zeros((1, 3)), np.zeros(1))[0, :, 2].max()
    assert gait.steps >= 2 * 4  # walking at 1.2 m/s for 2 s: several steps each


def test_bystanders_walk_on_planted_feet_and_keep_apart():
    scene = scene_with(load_scene("arena"), **{"characters.count": 30, "characters.spacing": 0.7,
                                              "shooters.count": 1}, frames=4, width=64, height=36)
    world = World(scene, autofire=False)
    names = world.body.rig.joint_names
    ankles = [names.index("ankle_l"), names.index("ankle_r")]
    start = world.characters.motion.pos.copy()
    for _ in range(int(3.0 / DT)):
        world.step_world()
        np.testing.assert_allclose(world.joints()[:, ankles], world.characters.planted, atol=2e-3)
        p = world.characters.motion.pos
        d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p)) * 9
        assert d.min() > 0.3
    assert np.median(np.linalg.norm(world.characters.motion.pos - start, axis=1)) > 0.5
    assert world.characters.gait.steps > 30


def test_standing_scene_keeps_its_grid():
    scene = scene_with(load_scene("arena"), **{"characters.walk_speed": 0.0}, frames=4, width=64, height=36)
    world = World(scene, autofire=False)
    start = world.characters.ground.copy()
    world.simulate(1.0)
    np.testing.assert_array_equal(world.characters.ground, start)
    assert world.characters.gait.steps == 0


def test_autopilot_never_stands_still_for_long_and_loops_the_path():
    scene = scene_with(load_scene("arena"), frames=300, width=64, height=36)
    world = World(scene, autofire=False)
    still, longest, xs = 0, 0, []
    for _ in range(300):
        world.step()
        still = still + 1 if world.player.speed < 0.05 else 0
        longest = max(longest, still)
        xs.append(world.player.position()[[0, 2]])
    assert longest / scene.video.fps <= 0.5
    xs = np.asarray(xs)
    assert np.linalg.norm(xs[-1] - xs[0]) < 4.0 and np.abs(xs).max() <= 2.0 + 1e-6  # stays on its square
    path_len = np.linalg.norm(np.diff(xs, axis=0), axis=1).sum()
    assert path_len > 8.0 + 2.0  # more than one lap of the 8 m square in 10 s
