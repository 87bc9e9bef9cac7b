"""Rig: constructors, conventions, limits, and the refusal of invalid rigs."""

import math

import numpy as np
import pytest

from crowd_ik.rig import Effector, Joint, Rig


def test_chain_shapes_2d_and_3d():
    r2 = Rig.chain(4, dim=2)
    assert (r2.n_joints, r2.n_dof, r2.effector_names) == (5, 4, ["tip"])
    assert [j.kind for j in r2.joints] == ["hinge"] * 4 + ["fixed"]
    r3 = Rig.chain(16, bone_length=0.1, dim=3)
    assert (r3.n_joints, r3.n_dof) == (17, 48)
    assert r3.reach[0] == pytest.approx(1.6)
    lo, hi = r3.angle_limits()
    assert lo.shape == hi.shape == (48,) and np.all(np.isinf(lo)) and np.all(np.isinf(hi))


def test_chain_limits_broadcast():
    r = Rig.chain(3, 0.5, dim=3, lo=-0.5, hi=0.5)
    lo, hi = r.angle_limits()
    assert np.all(lo == -0.5) and np.all(hi == 0.5)


def test_humanoid_conventions():
    h = Rig.humanoid()
    assert h.effector_names == ["head", "hand_l", "hand_r", "foot_l", "foot_r"]
    assert h.joints[0].name == "pelvis" and h.joints[0].parent == -1
    names = h.joint_names
    for j, joint in enumerate(h.joints[1:], start=1):
        assert joint.parent < j
    assert h.joints[names.index("elbow_l")].kind == "hinge"
    assert h.joints[names.index("knee_r")].kind == "hinge"
    # y up: the head is the highest joint at rest; the left side is +x (faces +z)
    from crowd_ik.geometry.fk import forward_kinematics, angles_to_rotations
    rot = angles_to_rotations(h, np.zeros((1, h.n_dof)))
    pos, _ = forward_kinematics(h, np.zeros((1, 3)), np.zeros(1), rot)
    assert np.argmax(pos[0, :, 1]) == names.index("head")
    assert pos[0, names.index("hand_l"), 0] > 0 > pos[0, names.index("hand_r"), 0]
    assert pos[0, names.index("toe_l"), 2] > pos[0, names.index("ankle_l"), 2]
    assert 0.0 < pos[0, :, 1].min() < 0.1 and pos[0, names.index("head"), 1] == pytest.approx(1.62, abs=0.01)
    lo, hi = h.angle_limits()
    assert np.all(np.isfinite(lo)) and np.all(lo <= hi)
    assert np.all(lo[h.dof_start[names.index("knee_l")]] == 0.0)


def test_humanoid_scales_with_height():
    a, b = Rig.humanoid(1.75), Rig.humanoid(3.5)
    assert b.bone_lengths.sum() == pytest.approx(2 * a.bone_lengths.sum())


@pytest.mark.parametrize("make, match", [
    (lambda: Rig.chain(0), "n_bones"),
    (lambda: Rig.chain(2, bone_length=0.0), "bone_length"),
    (lambda: Rig.chain(2, bone_length=-1.0), "bone_length"),
    (lambda: Rig.chain(2, dim=4), "dim"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)),)), "at least one bone"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (0, 0, 0)))), "bone length must be positive"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 1, (1, 0, 0)))), "parent must come before"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0), "slider"), Joint("a", 0, (1, 0, 0)))), "unknown joint kind 'slider'"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0), "hinge", lo=(1.0,), hi=(0.0,)), Joint("a", 0, (1, 0, 0)))), "lo > hi"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0), "ball", lo=(0.0,), hi=(1.0,)), Joint("a", 0, (1, 0, 0)))), "3 values"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0), "universal", axes=((1, 0, 0), (1, 0, 0))),
                  Joint("a", 0, (1, 0, 0)))), "perpendicular"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1, 0, math.nan)))), "finite"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1, 0, 0))), (Effector("x", 5),)), "out of range"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1, 0, 0))), (Effector("x", 1, -1.0),)), "weight"),
    # values a float32 kernel cannot honour, refused at the edge (a 1e39 offset made a NaN pose look converged)
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1e39, 0, 0)))), r"within \+-10000 m"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0.5, (1, 0, 0)))), "parent: expected an integer"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", True, (1, 0, 0)))), "parent: expected an integer"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1j, 0, 0)))), "real numbers"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1, 0, 0))), (Effector("x", 1.0),)), "integer index"),
    (lambda: Rig((Joint("root", -1, (0, 0, 0)), Joint("a", 0, (1, 0, 0))), (Effector("x", 1, axis=(0, 0, 0)),)),
     "axis must be non-zero"),
    (lambda: Rig.chain(2, bone_length=2e4), "bone_length"),
])
def test_invalid_rigs_raise_clearly(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_arrays_layout():
    h = Rig.humanoid()
    a = h.arrays
    assert a["parent"].dtype == np.int32 and a["offset"].dtype == np.float32
    assert a["lo"].shape == (h.n_dof + 1,)
    kids = [list(a["child_list"][a["child_start"][j]:a["child_start"][j + 1]]) for j in range(h.n_joints)]
    assert kids == [list(c) for c in h.children]
    assert sorted(sum(kids, [])) == list(range(1, h.n_joints))


def test_numpy_scalars_are_numbers():
    """np.float32 bone lengths and np.int64 parents and effector joints are accepted like Python numbers."""
    rig = Rig.chain(np.int64(3), bone_length=np.float32(0.25))
    assert rig.n_joints == 4 and rig.reach[0] == pytest.approx(0.75)
    tree = Rig((Joint("root", np.int64(-1), (0, 0, 0)), Joint("a", np.int32(0), np.float32([1, 0, 0]))),
               (Effector("x", np.int64(1), np.float32(2.0), axis=(0, 2, 0)),))
    assert tree.joints[1].parent == 0 and type(tree.joints[1].parent) is int
    assert tree.effectors[0].axis == (0.0, 1.0, 0.0)  # stored unit length


def test_root_joints_turn_the_first_offset_and_beyond_reach_measures_from_them():
    rig = Rig((Joint("root", -1, (0.5, 1.0, 0.0)), Joint("a", 0, (1.0, 0.0, 0.0)), Joint("b", 1, (0.0, 2.0, 0.0))))
    roots = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, -3.0]])
    base = rig.root_joints(roots, np.array([0.0, np.pi / 2]))
    # a quarter turn about +y takes +x to -z
    assert np.allclose(base, [[0.5, 1.0, 0.0], [10.0, 1.0, -3.5]])
    assert rig.reach == pytest.approx([3.0])
    up = np.array([0.0, 3.0, 0.0])
    assert rig.beyond_reach((base + up)[:, None, :], base).tolist() == [[False], [False]]  # at the reach
    assert rig.beyond_reach((base + 1.001 * up)[:, None, :], base).tolist() == [[True], [True]]
    # measured from the root instead, the first target would be out of reach
    assert rig.beyond_reach((base + up)[:, None, :], roots).all()
