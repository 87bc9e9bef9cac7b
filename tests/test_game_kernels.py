"""kernels/game_kernels.py against its NumPy twin, and the World's use of it."""

import numpy as np
import pytest

from crowd_ik.game import characters
from crowd_ik.game.body import LEG_SLACK, Body
from crowd_ik.game.world import World
from crowd_ik.kernels import game_kernels as gk
from crowd_ik.reference import game_kernels as ref
from crowd_ik.rig import Rig
from crowd_ik.scene import load_scene, scene_with


@pytest.mark.parametrize("serial", [False, True])
def test_limb_capsules_match_twin(serial):
    rig = Rig.humanoid()
    rng = np.random.default_rng(0)
    n, J = 7, rig.n_joints
    parent = rig.arrays["parent"][1:].astype(np.int32)
    radius = rig.arrays["radius"][1:].astype(np.float32)
    world_pos = rng.normal(0.0, 3.0, (n, J, 3)).astype(np.float32)
    prev_box = np.sort(rng.normal(0.0, 3.0, (n, 2, 2)), axis=1).transpose(0, 2, 1).reshape(n, 4)
    prev_box = np.ascontiguousarray(prev_box[:, [0, 2, 1, 3]], np.float32)  # x_min, z_min, x_max, z_max
    a, b = np.zeros((n * (J - 1), 3), np.float32), np.zeros((n * (J - 1), 3), np.float32)
    joints = np.zeros_like(world_pos)
    pose_box, box = np.zeros((n, 4), np.float32), np.zeros((n, 4), np.float32)
    gk.limb_capsules(world_pos, parent, radius, prev_box, a, b, joints, pose_box, box, serial)
    want = ref.limb_capsules(world_pos, parent, radius, prev_box)
    for got, exp in zip((a, b, joints, pose_box, box), want):
        np.testing.assert_array_equal(got, exp)
    # capsule n * B + k joins character n's joints parent[k] and k + 1
    np.testing.assert_array_equal(a[3 * (J - 1) + 4], world_pos[3, parent[4]])
    np.testing.assert_array_equal(b[3 * (J - 1) + 4], world_pos[3, 5])
    # every capsule lies in its character's box, grown by its radius
    owner = np.repeat(np.arange(n), J - 1)
    r = np.tile(radius, n)
    for end in (a, b):
        assert np.all(end[:, 0] - r >= pose_box[owner, 0]) and np.all(end[:, 2] + r <= pose_box[owner, 3])
    assert np.all(box[:, :2] <= np.minimum(pose_box[:, :2], prev_box[:, :2]))


def test_world_keeps_host_joints_and_capsules_in_step():
    scene = scene_with(load_scene(None), size=(96, 64), **{"characters.count": 5, "shooters.count": 1,
                                                           "bullets.pool_size": 64})
    world = World(scene)
    for _ in range(3):
        before = world.joints()
        world.step_world()
        np.testing.assert_array_equal(world.joints(), world.characters.crowd.joint_positions())
        np.testing.assert_array_equal(world.characters.limbs.joints_prev, before)
    a, b = world.characters.limbs.current
    want_a, want_b, _, want_pose, want_box = ref.limb_capsules(
        world.joints(), world.body.bone_parent, world.body.bone_radius, world.characters.limbs.pose_box[1 - world.characters.limbs.now].to_numpy())
    np.testing.assert_array_equal(a.to_numpy(), want_a)
    np.testing.assert_array_equal(b.to_numpy(), want_b)
    np.testing.assert_array_equal(world.characters.limbs.pose_box[world.characters.limbs.now].to_numpy(), want_pose)
    np.testing.assert_array_equal(world.characters.limbs.owner_box.to_numpy(), want_box)


def _dodge_inputs(body, n, seed):
    """Random dodge states for n characters of `body` standing on a jittered grid."""
    rng = np.random.default_rng(seed)
    ground = np.zeros((n, 3), np.float32)
    ground[:, [0, 2]] = rng.uniform(-5, 5, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    rest = body.rest_targets(ground, yaw).astype(np.float32)
    planted = np.ascontiguousarray(rest[:, body.planted] + rng.normal(0, 0.05, (n, int(body.planted.sum()), 3)),
                                   np.float32)
    lean = rng.normal(0, 0.2, (n, 3)).astype(np.float32)
    duck = rng.uniform(0, 0.3, n).astype(np.float32)
    guard = rng.uniform(0, 1, n).astype(np.float32)
    guard[::3] = 0.0
    roots = (ground + [0.0, body.rest_root_y, 0.0]).astype(np.float32)
    chest = np.ascontiguousarray(body.point(body.chest, ground, yaw), np.float32)
    return rest, lean, duck, guard, roots, yaw, planted, chest


@pytest.mark.parametrize("serial", [False, True])
def test_dodge_targets_match_twin_and_keep_feet_planted(serial):
    body = Body(Rig.humanoid())
    n, E = 50, body.rig.n_effectors
    rest, lean, duck, guard, roots, yaw, planted, chest = _dodge_inputs(body, n, 1)
    lean[:5] *= 10.0  # leans beyond the pelvis limit
    duck[5:10] = 0.6  # deep ducks
    slot = np.full(E, -1, np.int32)
    slot[body.planted] = np.arange(int(body.planted.sum()), dtype=np.int32)
    consts = (body.lean, body.duck, slot, body.hands.astype(np.int32), body.hip_offset.astype(np.float32), 1,
              body.pelvis_share, characters.MAX_PELVIS_SHIFT, LEG_SLACK * body.leg_length, body.scale)
    targets, out_roots = np.zeros((n, E, 3), np.float32), np.zeros((n, 3), np.float32)
    gk.dodge_targets(rest, lean, duck, guard, roots, yaw, planted, chest, *consts, targets, out_roots, serial)
    want_t, want_r = ref.dodge_targets(rest, lean, duck, guard, roots, yaw, planted, chest, *consts)
    np.testing.assert_allclose(targets, want_t, atol=2e-5)
    np.testing.assert_allclose(out_roots, want_r, atol=2e-5)
    np.testing.assert_array_equal(targets[:, body.planted], planted)
    # the pelvis follows the lean by pelvis_share, at most MAX_PELVIS_SHIFT
    shift = lean * body.pelvis_share
    limit = np.minimum(1.0, characters.MAX_PELVIS_SHIFT / np.linalg.norm(shift, axis=1))
    np.testing.assert_allclose((out_roots - roots)[:, [0, 2]], (shift * limit[:, None])[:, [0, 2]], atol=1e-5)
    assert np.all(limit[:5] < 1.0)
    # ... and never stands higher than the legs reach (as Body.max_root_y, which the Walker uses): long leans are held there
    highest = body.max_root_y(out_roots, yaw, planted)
    assert np.all(out_roots[:, 1] <= highest + 1e-5)
    wanted = roots[:, 1] + (shift * limit[:, None])[:, 1] - 0.85 * duck
    held = out_roots[:, 1] < wanted - 1e-4
    assert held.any() and np.allclose(out_roots[held, 1], highest[held], atol=1e-5)


def test_dodge_targets_of_a_chain_follow_lean_and_duck_only():
    body = Body(Rig.chain(8, bone_length=0.2, dim=3))
    n, E = 20, body.rig.n_effectors
    rest, lean, duck, guard, roots, yaw, _, chest = _dodge_inputs(body, n, 2)
    consts = (body.lean, body.duck, np.full(E, -1, np.int32), np.full(1, -1, np.int32), np.zeros((1, 3), np.float32),
              0, 0.0, characters.MAX_PELVIS_SHIFT, 1.0, 1.0)
    placeholder = np.zeros((n, 1, 3), np.float32)
    targets, out_roots = np.zeros((n, E, 3), np.float32), np.zeros((n, 3), np.float32)
    gk.dodge_targets(rest, lean, duck, guard, roots, yaw, placeholder, chest, *consts, targets, out_roots, False)
    want_t, want_r = ref.dodge_targets(rest, lean, duck, guard, roots, yaw, placeholder, chest, *consts)
    np.testing.assert_allclose(targets, want_t, atol=2e-5)
    np.testing.assert_array_equal(out_roots, roots)
    np.testing.assert_allclose(targets[:, :, 1], rest[:, :, 1] + lean[:, None, 1] - duck[:, None], atol=2e-5)
