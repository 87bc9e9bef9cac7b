"""`crowd-ik export SCENE --frame K -o F.glb`: capsule meshes of a posed world."""

import numpy as np
import pytest
import trimesh

from crowd_ik.commands.cli import main
from crowd_ik.io.gltf import capsule_vertices
from crowd_ik.game.world import World
from crowd_ik.scene import load_scene

TINY = """
seed = 4
characters = { count = 5 }
shooters = { count = 2, fire_rate = 6.0 }
bullets = { pool_size = 128 }
time = { floor = 1.0 }
video = { width = 96, height = 64, frames = 20 }
"""


@pytest.fixture
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def expected_meshes(scene_path, frame):
    world = World(load_scene(scene_path))
    for _ in range(frame):
        world.step()
    s = world.stats
    return s["standing"] + 2 + 1 + (s["bullets"] > 0) + (s["shards"] > 0), s


@pytest.mark.parametrize("frame", [0, 15])
def test_glb_loads_back_with_one_mesh_per_body(tiny, tmp_path, frame):
    out = tmp_path / "pose.glb"
    assert main(["export", str(tiny), "--frame", str(frame), "-o", str(out)]) == 0
    loaded = trimesh.load(out)
    want, stats = expected_meshes(tiny, frame)
    assert len(loaded.geometry) == want
    names = set(loaded.geometry)
    assert {"player", "shooter_0", "shooter_1"} <= names
    assert sum(n.startswith("character_") for n in names) == stats["standing"]
    if frame:
        assert stats["bullets"] > 0 and "bullets" in names
    player = loaded.geometry["player"]
    assert 1.5 < np.ptp(player.vertices[:, 1]) < 2.0  # a standing humanoid, y up, metres
    colors = loaded.geometry["shooter_0"].visual.vertex_colors
    assert colors[:, 0].mean() > 150 and colors[:, 2].mean() < 100  # red shooters (RGB in the file)


def test_a_downed_shooter_has_no_mesh():
    from crowd_ik.io.glb import world_meshes
    from crowd_ik.scene import scene_with

    scene = scene_with(load_scene(None), size=(96, 64), **{
        "characters.count": 1, "shooters.count": 2, "shooters.placement": "line", "shooters.radius": 6.0,
        "bullets.pool_size": 64, "time.floor": 1.0, "player.path": [[0.0, -3.0]]})
    world = World(scene, autofire=False)
    chest = world.shooters.joints[0, world.hbody.chest]
    world.set_player_input((0.0, 0.0), chest, fire=True)
    world.simulate(0.3)
    assert world.shooters.alive.tolist() == [False, True]
    names = set(world_meshes(world))
    assert "shooter_0" not in names and {"shooter_1", "player", "shards"} <= names


def test_export_does_not_clobber(tiny, tmp_path):
    out = tmp_path / "pose.glb"
    out.write_bytes(b"keep")
    assert main(["export", str(tiny), "-o", str(out)]) == 2
    assert out.read_bytes() == b"keep"
    assert main(["export", str(tiny), "-o", str(out), "--force"]) == 0
    assert len(trimesh.load(out).geometry) == 5 + 2 + 1


@pytest.mark.parametrize("argv,message", [
    (["-o", "pose.obj"], ".glb"),
    (["--frame", "-1"], "--frame"),
    (["--frame", "20"], "has 20 frames, so 0 to 19"),  # the scene's length (100000000 ran until killed)
    (["--frame", "100000000"], "--frame"),
    (["--bvh", "walk.txt"], "--bvh"),
])
def test_bad_export_arguments_exit_2(tiny, tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(tiny), *argv]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


def test_capsule_vertices_lie_on_the_capsule_surface():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 3))
    b = a + rng.normal(size=(50, 3)) * 0.5
    b[0] = a[0]  # a sphere
    b[1] = a[1] + [0.0, 0.3, 0.0]  # along y, the helper-axis special case
    r = rng.uniform(0.02, 0.2, size=50)
    verts, faces = capsule_vertices(a, b, r)
    e = b - a
    t = np.clip(np.einsum("mvd,md->mv", verts - a[:, None], e) / np.maximum((e * e).sum(1), 1e-12)[:, None], 0, 1)
    closest = a[:, None] + t[..., None] * e[:, None]
    dist = np.linalg.norm(verts - closest, axis=-1)
    np.testing.assert_allclose(dist, np.broadcast_to(r[:, None], dist.shape), rtol=1e-6, atol=1e-9)
    mesh = trimesh.Trimesh(verts[3], faces, process=True)
    assert mesh.is_watertight and mesh.volume > 0
    # the volume approaches a capsule's: pi r^2 L + 4/3 pi r^3
    length = np.linalg.norm(e[3])
    exact = np.pi * r[3] ** 2 * length + 4.0 / 3.0 * np.pi * r[3] ** 3
    assert 0.85 * exact < mesh.volume <= exact
