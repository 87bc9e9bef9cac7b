"""Per-frame pose labels (crowd_ik.io.labels, `play --labels`): the keypoints are the recorded camera's
projection of the recorded 3D joints in COCO order, their visibility agrees with the rendered z-buffer,
the boxes hold what is seen, and the file follows the output rules."""

import json

import numpy as np
import pytest

from crowd_ik.commands.cli import main
from crowd_ik.game.world import World
from crowd_ik.io.labels import COCO_KEYPOINTS, HIDDEN, VISIBLE, coco_joints, frame_labels
from crowd_ik.rig import Rig
from crowd_ik.scene import parse_scene
from crowd_ik.view.render import Camera

# A low camera looking down the rows of a dense grid: the front row hides much of the rows behind it.
CROWDED = """
seed = 5
characters = { count = 16, spacing = 0.9 }
shooters = { count = 2, fire_rate = 4.0 }
bullets = { pool_size = 256 }
time = { floor = 0.5 }
camera = { position = [0.4, 1.3, 7.0], look_at = [0, 1.0, 0], fov_deg = 45 }
video = { width = 192, height = 112, fps = 24, frames = 8 }
"""


@pytest.fixture(scope="module")
def labelled():
    """(world, labels) after rendering frame 7 of the crowded scene."""
    scene = parse_scene(CROWDED, "crowded.toml")
    world = World(scene, hud_timings=False)
    for k in range(8):
        if k:
            world.step()
        world.render()
    return world, frame_labels(world, 7)


def test_coco_map_names_the_rig_joints():
    names = [j.name for j in Rig.humanoid().joints]
    m = coco_joints(names)
    assert len(m) == len(COCO_KEYPOINTS) == 17
    for k, coco in enumerate(COCO_KEYPOINTS):
        side, _, part = coco.partition("_")
        want = f"{part}_{side[0]}" if part else None
        assert (names[m[k]] if m[k] >= 0 else None) == (want if want in names else None)
    assert (m[:5] == -1).all() and (m[5:] >= 0).all()  # no nose, eyes, ears on the humanoid
    assert (coco_joints([j.name for j in Rig.chain(4, dim=3).joints]) == -1).all()


def test_keypoints_are_the_recorded_cameras_projection_of_the_joints(labelled):
    world, rec = labelled
    cam = rec["camera"]
    camera = Camera(cam["position"], cam["look_at"], cam["fov_deg"], *cam["size"])
    assert cam["size"] == [192, 112] and rec["frame"] == 7
    coco = coco_joints([j.name for j in world.hbody.rig.joints])
    groups = {c["group"] for c in rec["characters"]}
    assert groups == {"crowd", "shooter", "player"} or groups >= {"crowd"}
    for c in rec["characters"]:
        joints = np.array(c["joints_3d"])
        assert joints.shape == (world.hbody.rig.n_joints, 3)
        kp = np.array(c["keypoints_2d"])
        assert kp.shape == (17, 3)
        pix, depth = camera.project(joints[coco[coco >= 0]])
        labelled_ = kp[coco >= 0]
        shown = labelled_[:, 2] > 0
        assert np.abs(labelled_[shown, :2] - pix[shown]).max(initial=0.0) < 0.02  # rounded to 0.01 px
        inside = (np.rint(pix[:, 0]) >= 0) & (np.rint(pix[:, 0]) < 192) & (np.rint(pix[:, 1]) >= 0) \
            & (np.rint(pix[:, 1]) < 112) & (depth > 0.05)
        assert (shown == inside).all()  # [0, 0, 0] exactly for joints off the image
        assert (kp[coco < 0] == 0).all()


def test_visibility_agrees_with_the_rendered_depth(labelled):
    world, rec = labelled
    ids, zbuf = world.renderer.id_buffer()
    body = world.primitives()["capsules"]["body"]
    cam = world.camera
    radius = np.zeros(world.hbody.rig.n_joints)
    np.maximum.at(radius, np.arange(1, len(radius)), world.hbody.bone_radius)
    np.maximum.at(radius, world.hbody.bone_parent, world.hbody.bone_radius)
    coco = coco_joints([j.name for j in world.hbody.rig.joints])
    same_body, counts = 0, {VISIBLE: 0, HIDDEN: 0}
    for c in rec["characters"]:
        joints = np.array(c["joints_3d"])
        for k, (x, y, v) in enumerate(c["keypoints_2d"]):
            if v == 0:
                continue
            j = coco[k]
            px, py = int(round(x)), int(round(y))
            depth = float((joints[j] - cam.position) @ cam.forward)
            front = float(zbuf[py, px])
            counts[v] += 1
            if v == VISIBLE:  # nothing in front of the joint beyond the limb around it
                assert front >= depth - radius[j] - depth / cam.focal - 2e-3
                same_body += ids[py, px] >= 0 and ids[py, px] < len(body) and body[ids[py, px]] == c["id"]
            else:  # something is drawn nearer than the joint's own limb surface
                assert front < depth - radius[j]
    assert counts[VISIBLE] >= 20 and counts[HIDDEN] >= 20, counts  # the scene has both
    assert same_body >= 0.9 * counts[VISIBLE]  # a visible keypoint's pixel mostly shows its own character


def test_every_character_seen_is_listed_with_the_box_of_its_pixels(labelled):
    world, rec = labelled
    ids, _ = world.renderer.id_buffer()
    body = np.concatenate([world.primitives()["capsules"]["body"], np.full(4096, -1)])
    pixel_body = np.where(ids >= 0, body[np.maximum(ids, 0)], -1)
    seen = set(np.unique(pixel_body[(pixel_body >= 0) & (pixel_body <= world.n + world.n_shooters)]).tolist())
    listed = [c["id"] for c in rec["characters"]]
    assert listed == sorted(seen) and len(listed) >= 10
    for c in rec["characters"]:
        ys, xs = np.nonzero(pixel_body == c["id"])
        assert c["bbox"] == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
        group = "crowd" if c["id"] < world.n else "shooter" if c["id"] < world.n + world.n_shooters else "player"
        assert c["group"] == group
        for x, y, v in c["keypoints_2d"]:
            if v == VISIBLE:
                assert c["bbox"][0] - 1 <= x <= c["bbox"][2] and c["bbox"][1] - 1 <= y <= c["bbox"][3]


def test_labels_do_not_change_the_frames(tmp_path):
    scene = tmp_path / "crowded.toml"
    scene.write_text(CROWDED)
    a, b, labels = tmp_path / "a/", tmp_path / "b/", tmp_path / "l.jsonl"
    assert main(["play", str(scene), "-o", str(a) + "/", "--frames", "4"]) == 0
    assert main(["play", str(scene), "-o", str(b) + "/", "--frames", "4", "--labels", str(labels)]) == 0
    for name in sorted(p.name for p in a.iterdir()):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    lines = labels.read_text().splitlines()
    assert [json.loads(line)["frame"] for line in lines] == [0, 1, 2, 3]


def test_labels_file_follows_the_output_rules(tmp_path, capsys):
    scene = tmp_path / "crowded.toml"
    scene.write_text(CROWDED)
    labels = tmp_path / "l.jsonl"
    labels.write_text("precious")
    assert main(["play", str(scene), "-o", str(tmp_path / "v.mp4"), "--frames", "2", "--labels", str(labels)]) == 2
    assert labels.read_text() == "precious" and not (tmp_path / "v.mp4").exists()
    assert "l.jsonl exists" in capsys.readouterr().err
    assert main(["play", str(scene), "-o", str(tmp_path / "v.mp4"), "--labels", str(tmp_path / "l.json")]) == 2
    assert ".jsonl" in capsys.readouterr().err
    assert main(["play", "--live", "--labels", str(tmp_path / "x.jsonl")]) == 2
    assert main(["play", str(scene), "--still", "1", "-o", str(tmp_path / "s.png"), "--labels", str(labels),
                 "--force"]) == 0
    assert [json.loads(line)["frame"] for line in labels.read_text().splitlines()] == [1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crowded.toml", "l.jsonl", "s.png"]
