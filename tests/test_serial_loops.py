"""kernels/serial_loops.py: the game's kernels give the same bits with their loops serial or parallel, and the
policy picks serial for small launches only."""

import numpy as np
import pytest
from crowd_ik.kernels import fk
from crowd_ik.kernels import serial_loops as sl

from crowd_ik.game.world import World
from crowd_ik.scene import load_scene, scene_with


def test_small_launches_are_serial_and_large_ones_parallel():
    assert sl.serial_for(40, sl.POSE) and sl.serial_for(1000, sl.BOX) and sl.serial_for(0)
    assert not sl.serial_for(10_000, sl.BOX) and not sl.serial_for(1000, sl.POSE)
    assert sl.serial_for(sl.SERIAL_WORK) and not sl.serial_for(sl.SERIAL_WORK + 1)


def test_nothing_is_serial_on_cuda(monkeypatch):
    """On CUDA a serialised loop would run on one GPU thread."""
    from crowd_ik.solvers import settings

    monkeypatch.setitem(settings._LANES, "arch", "cuda")
    assert settings.on_gpu() and not sl.serial_for(0) and not sl.serial_for(40, sl.POSE)


def _state(world):
    c, b = world.characters, world.bullets
    return [c.joints.copy(), c.alive.copy(), c.lean.copy(), c.crowd.local_rot.to_numpy(), world.shooters.joints.copy(),
            world.player.joints.copy(), b.pos.copy(), b.vel.copy(), b.alive.copy(), world.shards.c.copy(),
            c.limbs.owner_box.to_numpy(), np.array([world.hits, world.dodges, world.shooters.down])]


def _run(monkeypatch, work, steps):
    monkeypatch.setattr(sl, "SERIAL_WORK", work)
    scene = scene_with(load_scene(None), size=(96, 64), **{"characters.count": 9, "shooters.count": 3,
                                                           "shooters.fire_rate": 6.0, "bullets.pool_size": 128,
                                                           "time.floor": 1.0})
    world = World(scene)
    states = []
    for _ in range(steps):
        world.step()
        states.append(_state(world))
    return world, states


def test_world_is_the_same_with_every_loop_serial_or_parallel(monkeypatch):
    serial_world, serial = _run(monkeypatch, float("inf"), 40)
    _, parallel = _run(monkeypatch, -1.0, 40)
    assert serial_world.bullets.pool.last_substeps >= 1
    assert serial_world.hits + serial_world.dodges > 0  # bullets flew, hit or were dodged
    for k, (a, b) in enumerate(zip(serial, parallel)):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y, err_msg=f"frame {k}")


@pytest.mark.parametrize("n", [3, 5000])
def test_forward_kinematics_picks_by_size_and_matches_either_way(n):
    from crowd_ik.crowd import Crowd
    from crowd_ik.rig import Rig

    rig = Rig.humanoid()
    crowd = Crowd(rig, n=n, seed=1)
    rng = np.random.default_rng(n)
    crowd.set_angles(rng.normal(0.0, 0.4, (n, rig.n_dof)).astype(np.float32))
    ra = crowd.rig_arrays
    got = []
    for serial in (False, True):
        crowd.world_pos.fill(0.0)
        fk.fk_kernel(ra["parent"], ra["offset"], crowd.root_pos, crowd.root_yaw, crowd.local_rot, crowd.world_pos,
                     crowd.world_rot, crowd._every, rig.n_joints, serial)
        got.append((crowd.world_pos.to_numpy(), crowd.world_rot.to_numpy()))
    for x, y in zip(*got):
        np.testing.assert_array_equal(x, y)
    crowd.world_pos.fill(0.0)
    fk.forward_kinematics(ra["parent"], ra["offset"], crowd.root_pos, crowd.root_yaw, crowd.local_rot, crowd.world_pos,
                          crowd.world_rot, crowd._every, rig.n_joints)
    np.testing.assert_array_equal(crowd.world_pos.to_numpy(), got[0][0])
    assert sl.serial_for(n * rig.n_joints, sl.JOINT) == (n < 1000)
    # set_angles' and angles()' conversions (a launch over every joint too): the same bits either way
    angles = rng.normal(0.0, 0.4, (n, rig.n_dof)).astype(np.float32)
    out = []
    for serial in (False, True):
        q = np.zeros((n, rig.n_joints, 4), np.float32)
        back = np.zeros((n, rig.n_dof), np.float32)
        fk.angles_to_rotations(ra["kind"], ra["axes"], ra["dof_start"], angles, q, serial)
        fk.rotations_to_angles(ra["kind"], ra["axes"], ra["dof_start"], q, back, serial)
        out.append((q, back))
    for x, y in zip(*out):
        np.testing.assert_array_equal(x, y)
    crowd.set_angles(angles)
    np.testing.assert_array_equal(crowd.rotations(), out[0][0])
    np.testing.assert_array_equal(crowd.angles(), out[0][1])


@pytest.mark.parametrize("method", ["fabrik", "dls"])
def test_chain_solves_are_the_same_on_the_launching_thread(monkeypatch, method):
    """The constraint-free FABRIK and closed-form DLS lanes run a small crowd's streams on the launching thread
    (serial_for with CHAIN_JOINT: 100 and 1,000 chain16s serial, 2,000 not) and get the same bits as on the pool."""
    import crowd_ik as cik
    from crowd_ik.bench import workloads as w

    assert sl.serial_for(1000 * 17, sl.CHAIN_JOINT) and not sl.serial_for(2000 * 17, sl.CHAIN_JOINT)
    wl = w.make_workload("chain16", 300)
    out = []
    for work in (float("inf"), -1.0):
        monkeypatch.setattr(sl, "SERIAL_WORK", work)
        crowd = cik.Crowd(wl.rig, wl.n, spacing=w.SPACING)
        crowd.set_angles(wl.angles)
        rep = crowd.solve(wl.targets, method=method, max_iterations=wl.max_iterations, tolerance=wl.tolerance)
        out.append((rep.iterations, rep.error, crowd.joint_positions(), crowd.rotations()))
    assert out[0][0].mean() > 3
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
