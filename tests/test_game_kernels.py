"""kernels/game_kernels.py against its NumPy twin, and the World's use of it."""

import numpy as np

from crowd_ik.game import World
from crowd_ik.kernels import game_kernels as gk
from crowd_ik.reference import game_kernels as ref
from crowd_ik.rig import Rig
from crowd_ik.scene import load_scene, scene_with


def test_limb_capsules_match_twin():
    rig = Rig.humanoid()
    rng = np.random.default_rng(0)
    n, J = 7, rig.n_joints
    parent = rig.arrays["parent"][1:].astype(np.int32)
    radius = rig.arrays["radius"][1:].astype(np.float32)
    world_pos = rng.normal(0.0, 3.0, (n, J, 3)).astype(np.float32)
    prev_a = rng.normal(0.0, 3.0, (n * (J - 1), 3)).astype(np.float32)
    prev_b = rng.normal(0.0, 3.0, (n * (J - 1), 3)).astype(np.float32)
    a, b = np.zeros_like(prev_a), np.zeros_like(prev_b)
    joints = np.zeros_like(world_pos)
    box = np.zeros((n, 4), np.float32)
    gk.limb_capsules(world_pos, parent, radius, prev_a, prev_b, a, b, joints, box)
    want = ref.limb_capsules(world_pos, parent, radius, prev_a, prev_b)
    for got, exp in zip((a, b, joints, box), want):
        np.testing.assert_array_equal(got, exp)
    # capsule n * B + k joins character n's joints parent[k] and k + 1
    np.testing.assert_array_equal(a[3 * (J - 1) + 4], world_pos[3, parent[4]])
    np.testing.assert_array_equal(b[3 * (J - 1) + 4], world_pos[3, 5])


def test_world_keeps_host_joints_and_capsules_in_step():
    scene = scene_with(load_scene(None), size=(96, 64), **{"characters.count": 5, "shooters.count": 1,
                                                           "bullets.pool_size": 64})
    world = World(scene)
    for _ in range(3):
        before = world.joints()
        world.step_world()
        np.testing.assert_array_equal(world.joints(), world.crowd.joint_positions())
        np.testing.assert_array_equal(world._joints_prev, before)
    a, b = world._caps[world._caps_now]
    want_a, want_b, _, _ = ref.limb_capsules(world.joints(), world.body.bone_parent, world.body.bone_radius,
                                             *(c.to_numpy() for c in world._caps[1 - world._caps_now]))
    np.testing.assert_array_equal(a.to_numpy(), want_a)
    np.testing.assert_array_equal(b.to_numpy(), want_b)
