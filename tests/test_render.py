"""Camera projection, the Taichi rasteriser against its NumPy twin, z-buffer occlusion, shadows,
determinism, overlays and input checks of crowd_ik.view.render."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.kernels import raster as kr
from crowd_ik.reference import raster as ref
from crowd_ik.view.render import Camera, Renderer, decode_keys


def _cam(w=64, h=48, pos=(0.0, 2.0, 6.0), look=(0.0, 0.8, 0.0), fov=50.0):
    return Camera(pos, look, fov, w, h)


def _kernel_buffers(cam, a, b, r, colors=None):
    """Run the five kernels on NumPy arrays: (keys, shadow, frame, seen)."""
    h, w = cam.height, cam.width
    keys = np.zeros((h, w), np.int64)
    shadow = np.zeros((h // 2, w // 2), np.int32)
    frame = np.zeros((h, w, 3), np.uint8)
    seen = np.zeros((h, w), np.float32)
    packed = cam.packed()
    a, b, r = (np.ascontiguousarray(x, np.float32) for x in (a, b, r))
    if colors is None:
        colors = np.full((len(r), 3), 0.7, np.float32)
    tiles = np.ones(((h + kr.TILE - 1) // kr.TILE, (w + kr.TILE - 1) // kr.TILE), np.int32)  # all dirty
    kr.clear_buffers(keys, shadow, tiles)
    kr.raster_capsules(packed, a, b, r, len(r), keys, tiles)
    kr.splat_shadows(packed, a, b, r, len(r), shadow, tiles)
    background = np.zeros((h, w, 3), np.float32)
    kr.shade_background(packed, background)
    kr.shade_frame(packed, a, b, np.ascontiguousarray(colors, np.float32), keys, shadow, background, tiles, frame,
                   seen)
    return keys, shadow, frame, seen


def _scene(seed=0, n=6):
    """A few random capsules around the origin, one sphere, one tiny far sphere, one capsule
    crossing the camera's near plane."""
    g = np.random.default_rng(seed)
    a = g.uniform([-1.5, 0.0, -1.5], [1.5, 1.8, 1.5], (n, 3))
    b = a + g.normal(0.0, 0.5, (n, 3))
    r = g.uniform(0.05, 0.3, n)
    a = np.vstack([a, [0.3, 1.0, 1.0], [2.0, 0.5, -60.0], [0.9, 1.9, 4.0]])
    b = np.vstack([b, [0.3, 1.0, 1.0], [2.0, 0.5, -60.0], [1.0, 2.0, 8.0]])
    r = np.concatenate([r, [0.2, 0.001, 0.1]])
    return a, b, r


def _edge_pixels(ids):
    """Pixels whose 4-neighbourhood holds another id (silhouettes)."""
    e = np.zeros(ids.shape, bool)
    e[1:] |= ids[1:] != ids[:-1]
    e[:-1] |= ids[:-1] != ids[1:]
    e[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    e[:, :-1] |= ids[:, :-1] != ids[:, 1:]
    return e


# --- Camera -----------------------------------------------------------------------------------


def test_look_at_projects_to_image_centre_at_its_distance():
    cam = Camera((3.0, 4.0, 5.0), (0.0, 1.0, -1.0), 60.0, 320, 180)
    pix, depth = cam.project(np.array([[0.0, 1.0, -1.0]]))
    np.testing.assert_allclose(pix[0], [159.5, 89.5], atol=1e-9)
    np.testing.assert_allclose(depth[0], np.linalg.norm([3.0, 3.0, 6.0]))


def test_right_up_and_behind_camera():
    cam = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), 50.0, 64, 48)  # looking down -z: right is +x
    pix, depth = cam.project(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 20.0], [0.0, 0.0, 10.0]]))
    assert pix[0, 0] > cam.cx and pix[0, 1] == pytest.approx(cam.cy)
    assert pix[1, 1] < cam.cy and pix[1, 0] == pytest.approx(cam.cx)  # y down in pixels
    assert depth[2] < 0 and np.all(np.isnan(pix[2]))  # behind: flagged
    assert depth[3] == 0 and np.all(np.isnan(pix[3]))
    # the vertical field of view spans the image height
    top = np.array([[0.0, 10.0 * np.tan(np.radians(25.0)), 0.0]])
    assert cam.project(top)[0][0, 1] == pytest.approx(-0.5)


def test_ray_round_trips_through_project_and_view_matrix():
    cam = Camera((1.0, 5.0, 7.0), (-1.0, 0.5, 0.0), 45.0, 128, 96)
    px, py = np.array([0.0, 10.5, 127.0]), np.array([0.0, 50.0, 95.0])
    origin, d = cam.ray(px, py)
    pts = origin + d * np.array([[2.0], [10.0], [33.0]])
    pix, depth = cam.project(pts)
    np.testing.assert_allclose(pix, np.stack([px, py], 1), atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    v = cam.view_matrix
    np.testing.assert_allclose(v @ np.append(cam.position, 1.0), [0, 0, 0, 1], atol=1e-12)
    cam_pts = (v @ np.c_[pts, np.ones(3)].T).T
    np.testing.assert_allclose(-cam_pts[:, 2], depth)  # OpenGL style: looking down -z
    assert cam.pixel_scale(10.0) == pytest.approx(cam.focal / 10.0)
    o, d1 = cam.ray(cam.cx, cam.cy)
    np.testing.assert_allclose(d1, cam.forward)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(width=63),
        dict(height=8),
        dict(width=64.0),
        dict(fov_deg=180.0),
        dict(fov_deg=0),
        dict(look_at=(0.0, 2.0, 6.0)),
        dict(look_at=(0.0, 0.0, 6.0)),  # straight down, parallel to up
        dict(position=(0.0, float("nan"), 1.0)),
    ],
)
def test_camera_rejects_bad_arguments(kwargs):
    args = dict(position=(0.0, 2.0, 6.0), look_at=(0.0, 0.0, 0.0), fov_deg=50.0, width=64, height=48)
    args.update(kwargs)
    with pytest.raises(ValueError):
        Camera(**args)


# --- kernels against the NumPy twin --------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_raster_matches_numpy_twin(seed):
    cam = _cam()
    a, b, r = _scene(seed)
    keys, _, _, _ = _kernel_buffers(cam, a, b, r)
    ids, depth = decode_keys(keys)
    rids, rdepth = ref.raster_capsules(cam.packed(), a, b, r, cam.width, cam.height)
    same = ids == rids
    assert same.mean() >= 0.995
    assert np.all(_edge_pixels(rids)[~same])  # disagreements only on silhouettes
    both = same & (ids >= 0)
    assert both.sum() > 150
    np.testing.assert_allclose(depth[both], rdepth[both], rtol=1e-3)
    present = set(np.unique(rids)) - {-1}
    assert len(r) - 1 in present  # the capsule crossing the near plane is drawn
    assert len(r) - 2 in set(np.unique(ids))  # the sub-pixel far sphere still covers a pixel


def test_shadow_buffer_matches_numpy_twin():
    cam = _cam(pos=(1.0, 5.0, 5.0))
    a, b, r = _scene(3)
    _, shadow, _, _ = _kernel_buffers(cam, a, b, r)
    expect = ref.splat_shadows(cam.packed(), a, b, r, cam.width, cam.height)
    assert expect.max() > 0.3 * kr.SHADOW_SCALE
    assert np.abs(shadow.astype(np.int64) - expect).max() <= 3  # float32 vs float64 rounding only


def test_shading_matches_numpy_twin():
    cam = _cam(pos=(0.5, 3.0, 5.0))
    a, b, r = _scene(4)
    colors = np.random.default_rng(4).uniform(0.1, 1.0, (len(r), 3))
    keys, shadow, frame, seen = _kernel_buffers(cam, a, b, r, colors)
    ids, depth = decode_keys(keys)
    expect, expect_seen = ref.shade_frame(cam.packed(), a, b, colors, ids, depth, shadow, cam.width, cam.height)
    diff = np.abs(frame.astype(int) - expect).max(axis=2)
    assert (diff <= 2).mean() >= 0.995
    assert diff.max() <= 8
    assert np.isinf(seen).sum() >= 64 and np.array_equal(np.isinf(seen), np.isinf(expect_seen))  # sky
    np.testing.assert_allclose(seen[np.isfinite(seen)], expect_seen[np.isfinite(seen)], rtol=1e-4)


# --- Renderer ------------------------------------------------------------------------------------


def test_near_capsule_hides_far_one_whatever_the_order():
    cam = _cam(w=96, h=64, pos=(0.0, 1.0, 6.0), look=(0.0, 1.0, 0.0))
    near = ([-1.0, 1.0, 2.0], [1.0, 1.0, 2.0], 0.3, [0.0, 0.0, 1.0])  # red (BGR)
    far = ([-1.0, 1.0, -2.0], [1.0, 1.0, -2.0], 0.9, [0.0, 1.0, 0.0])  # green
    rend = Renderer(cam, 4, 0)
    for order in ((near, far), (far, near)):
        a, b, r, c = (np.array([cap[k] for cap in order]) for k in range(4))
        frame = rend.render(a, b, r, c)
        ids, depth = rend.id_buffer()
        near_id = order.index(near)
        centre = (cam.height // 2, cam.width // 2)
        assert ids[centre] == near_id
        assert depth[centre] == pytest.approx(4.0 - 0.3, rel=1e-3)
        # the far one still shows above and below the near one
        pix, _ = cam.project(np.array([[0.0, 1.8, -2.0]]))
        assert ids[int(round(pix[0, 1])), int(round(pix[0, 0]))] == 1 - near_id
        assert frame[centre][2] > 100 and frame[centre][1] < 60  # the near capsule's red


def test_two_renders_are_bit_identical():
    cam = _cam(w=160, h=96)
    g = np.random.default_rng(5)
    a = g.uniform([-3, 0, -3], [3, 2, 3], (3000, 3))
    b = a + g.normal(0, 0.3, (3000, 3))
    r = g.uniform(0.02, 0.2, 3000)
    c = g.uniform(0, 1, (3000, 3))
    s = g.uniform([-3, 0, -3], [3, 2, 3], (50, 3))
    rend = Renderer(cam, 3000, 50)
    f1 = rend.render(a, b, r, c, s, np.full(50, 0.05), (0.2, 0.8, 1.0))
    ids1, d1 = rend.id_buffer()
    f2 = rend.render(a, b, r, c, s, np.full(50, 0.05), (0.2, 0.8, 1.0))
    ids2, d2 = rend.id_buffer()
    np.testing.assert_array_equal(f1, f2)
    np.testing.assert_array_equal(ids1, ids2)
    np.testing.assert_array_equal(d1.view(np.uint32), d2.view(np.uint32))
    assert len(np.unique(ids1)) > 200  # a crowded frame, with many overlaps resolved by the z-buffer


def test_a_new_camera_gets_its_own_sky_and_ground():
    g = np.random.default_rng(6)
    a = g.uniform([-2, 0, -2], [2, 2, 2], (40, 3))
    b = a + g.normal(0, 0.3, (40, 3))
    r = g.uniform(0.05, 0.2, 40)
    near, far = _cam(w=96, h=64), _cam(w=96, h=64, pos=(4.0, 1.0, 9.0), look=(0.0, 1.5, 0.0))
    rend = Renderer(near, 40)
    first = rend.render(a, b, r, (0.5, 0.5, 0.5))
    rend.camera = far  # same image size: the cached background must follow the camera
    moved = rend.render(a, b, r, (0.5, 0.5, 0.5))
    np.testing.assert_array_equal(moved, Renderer(far, 40).render(a, b, r, (0.5, 0.5, 0.5)))
    rend.camera = near
    np.testing.assert_array_equal(rend.render(a, b, r, (0.5, 0.5, 0.5)), first)
    assert not np.array_equal(first, moved)


def test_frames_drawn_over_earlier_ones_equal_fresh_renders():
    # the renderer repaints only the tiles drawn on this frame or the last; a sequence of frames
    # with limbs and shadows moving away (and one frame crossing the near plane) must equal fresh renders
    cam = _cam(w=160, h=96, pos=(0.0, 3.0, 7.0), look=(0.0, 0.5, 0.0))
    g = np.random.default_rng(8)
    a0 = g.uniform([-3, 0, -3], [3, 2, 3], (60, 3))
    b0 = a0 + g.normal(0, 0.3, (60, 3))
    r = g.uniform(0.03, 0.2, 60)
    c = g.uniform(0, 1, (60, 3))
    rend = Renderer(cam, 61, 0)
    for k, shift in enumerate([0.0, 0.4, 3.0, -2.5, 6.0, 0.0]):
        a, b = a0 + [shift, 0.0, 0.0], b0 + [shift, 0.0, 0.0]
        if k == 3:  # a capsule through the near plane: every tile
            a, b = np.vstack([a, [0.0, 3.0, 6.99]]), np.vstack([b, [0.0, 3.0, 4.0]])
            rr, cc = np.append(r, 0.2), np.vstack([c, c[:1]])
        else:
            rr, cc = r, c
        got = rend.render(a, b, rr, cc)
        fresh = Renderer(cam, 61, 0)
        np.testing.assert_array_equal(got, fresh.render(a, b, rr, cc))
        np.testing.assert_array_equal(rend.id_buffer()[0], fresh.id_buffer()[0])
        np.testing.assert_array_equal(rend.depth_buffer(), fresh.depth_buffer())
        np.testing.assert_array_equal(rend.shadow_buffer(), fresh.shadow_buffer())


def test_only_drawn_tiles_are_flagged():
    cam = _cam(w=160, h=96)
    rend = Renderer(cam, 1, 0)
    rend.render([[0.0, 1.0, 0.0]], [[0.0, 1.2, 0.0]], [0.05], (0.5, 0.5, 0.5))
    tiles = rend._tiles.to_numpy()
    drawn = (tiles & 1) != 0
    assert 0 < drawn.sum() < drawn.size // 4  # one small capsule and its shadow
    ids, _ = rend.id_buffer()
    ys, xs = np.nonzero(ids >= 0)
    assert drawn[ys // kr.TILE, xs // kr.TILE].all()
    # every pixel whose bilinear shadow sample is non-zero (it reads texels up to a row and a column
    # beyond its own 2x2 block) lies in a flagged tile
    sy, sx = np.nonzero(ref.sample_shadow(rend._shadow.to_numpy(), cam.width, cam.height) > 0)
    assert len(sy) > 50 and drawn[sy // kr.TILE, sx // kr.TILE].all()


def _threads_scene(near=False):
    """A crowded 96x64 frame, or (near) a 256x160 frame of 60 capsules close to the camera, whose rows are
    rasterised and shadowed in 16-pixel packets: (frame, ids, shadow) rendered in this process."""
    g = np.random.default_rng(11)
    n, size, spread, r = (60, (256, 160), 0.6, (0.1, 0.4)) if near else (2000, (96, 64), 0.3, (0.02, 0.2))
    a = g.uniform([-3, 0, -3], [3, 2, 3], (n, 3))
    b = a + g.normal(0, spread, (n, 3))
    rend = Renderer(Camera((0.0, 3.0, 7.0), (0.0, 0.5, 0.0), 50.0, *size), n, 0)
    frame = rend.render(a, b, g.uniform(*r, n), g.uniform(0, 1, (n, 3)))
    return frame, rend.id_buffer()[0], rend.shadow_buffer()


_OTHER_THREADS = """
import sys, numpy as np, crowd_ik
crowd_ik.init(arch="cpu", threads=int(sys.argv[3]))
sys.path.insert(0, sys.argv[2])
from test_render import _threads_scene
frame, ids, shadow = _threads_scene(sys.argv[4] == "near")
np.savez(sys.argv[1], frame=frame, ids=ids, shadow=shadow)
"""


@pytest.mark.parametrize("near", [False, True])
def test_frame_is_the_same_with_another_thread_count(tmp_path, near):
    import crowd_ik.runtime

    other = 2 if crowd_ik.runtime.current().get("threads") == 1 else 1  # this process: all cores
    path = tmp_path / "other.npz"
    cmd = [sys.executable, "-c", _OTHER_THREADS, str(path), str(Path(__file__).parent), str(other),
           "near" if near else "crowd"]
    subprocess.run(cmd, check=True, capture_output=True)
    theirs = np.load(path)
    for key, value in zip(("frame", "ids", "shadow"), _threads_scene(near)):
        np.testing.assert_array_equal(theirs[key], value)
    assert len(np.unique(theirs["ids"])) > (50 if near else 200)


def test_load_primitives_copies_the_first_n_rows():
    g = np.random.default_rng(9)
    shapes = [(10, 3), (10, 3), (10,), (10, 3)]
    src = [g.normal(size=s).astype(np.float32) for s in shapes]
    dst = [np.full(s, -7, np.float32) for s in shapes]
    kr.load_primitives(*src, 6, *dst)
    for s_, d_ in zip(src, dst):
        np.testing.assert_array_equal(d_[:6], s_[:6])
        assert np.all(d_[6:] == -7)


def test_primitives_behind_the_camera_are_culled():
    cam = _cam(w=64, h=48, pos=(0.0, 1.0, 5.0), look=(0.0, 1.0, 0.0))
    rend = Renderer(cam, 2, 0)
    rend.render([[-1.0, 1.0, 7.0], [0.0, 1.0, 5.3]], [[1.0, 1.0, 7.0], [0.0, 1.2, 5.3]], [0.5, 0.2], [1.0, 1.0, 1.0])
    ids, _ = rend.id_buffer()
    assert np.all(ids == -1)


def test_empty_scene_is_sky_over_ground():
    cam = _cam(w=64, h=48, pos=(0.0, 1.5, 5.0), look=(0.0, 1.5, 0.0))  # level: horizon mid-image
    rend = Renderer(cam, 8, 8)
    frame = rend.render(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8 and frame.flags.c_contiguous
    ids, depth = rend.id_buffer()
    assert np.all(ids == -1) and np.all(np.isinf(depth))
    assert np.all(rend.shadow_buffer() == 0)
    top, bottom = frame[0].astype(int), frame[-1].astype(int)
    assert np.all(top[:, 0] > top[:, 2] + 40)  # blue sky (B >> R)
    assert np.all(np.abs(bottom - np.array(kr.GROUND) * 255).max(axis=1) < 50)  # ground colour
    none = np.zeros((0, 3))
    expect, _ = ref.shade_frame(cam.packed(), none, none, none, ids, depth, np.zeros((24, 32), np.int32), 64, 48)
    assert np.abs(frame.astype(int) - expect).max() <= 2


def test_shadow_darkens_ground_under_capsule_and_softens_with_height():
    cam = _cam(w=128, h=96, pos=(0.0, 4.0, 5.0), look=(0.0, 0.0, 0.0))
    rend = Renderer(cam, 2, 0)
    empty = rend.render(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    ground_pix, _ = cam.project(np.array([[0.0, 0.0, 0.15], [2.5, 0.0, 0.0]]))
    (u, v), (u_far, v_far) = np.round(ground_pix).astype(int)
    cores, widths = [], []
    for height in (0.3, 1.5):
        frame = rend.render([[-0.5, height, 0.0]], [[0.5, height, 0.0]], [0.1], [0.9, 0.9, 0.9])
        ids, _ = rend.id_buffer()
        assert ids[v, u] == -1  # the ground point is visible beside the capsule
        assert int(empty[v, u].sum()) - int(frame[v, u].sum()) > 30  # darker
        np.testing.assert_array_equal(frame[v_far, u_far], empty[v_far, u_far])  # far away: untouched
        shadow = rend.shadow_buffer()
        cores.append(shadow.max())
        widths.append((shadow > 0.02).sum())
    assert cores[0] > cores[1]  # a higher capsule casts a lighter shadow ...
    assert widths[1] > widths[0]  # ... that spreads wider


def test_ten_thousand_random_capsules_render():
    cam = Camera((0.0, 12.0, 30.0), (0.0, 0.0, 0.0), 50.0, 320, 180)
    g = np.random.default_rng(7)
    a = g.uniform([-20, 0, -20], [20, 2, 20], (10_000, 3))
    b = a + g.normal(0, 0.3, (10_000, 3))
    rend = Renderer(cam, 10_000, 0)
    frame = rend.render(a, b, g.uniform(0.03, 0.15, 10_000), g.integers(0, 256, (10_000, 3), dtype=np.uint8))
    assert frame.shape == (180, 320, 3) and frame.dtype == np.uint8
    ids, _ = rend.id_buffer()
    assert len(np.unique(ids)) > 2000


def test_uint8_colours_equal_float_colours():
    cam = _cam()
    a, b, r = _scene(2)
    c8 = np.random.default_rng(2).integers(0, 256, (len(r), 3), dtype=np.uint8)
    rend = Renderer(cam, 16, 0)
    f8 = rend.render(a, b, r, c8)
    ff = rend.render(a, b, r, c8.astype(np.float32) / 255.0)
    np.testing.assert_array_equal(f8, ff)


def test_spheres_draw_with_ids_after_capsules():
    cam = _cam(w=96, h=64, pos=(0.0, 1.0, 5.0), look=(0.0, 1.0, 0.0))
    rend = Renderer(cam, 3, 2)
    capsule = ([[-1.5, 1.0, 0.0]], [[-1.5, 1.5, 0.0]], [0.1], [1.0, 1.0, 1.0])
    spheres = ([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0]], [0.2, 0.3], [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    frame = rend.render(*capsule, *spheres)
    ids, depth = rend.id_buffer()
    pix, z = cam.project(np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]))
    for k, (x, y) in enumerate(np.round(pix).astype(int)):
        assert ids[y, x] == 1 + k
    assert depth[int(pix[1, 1]), int(pix[1, 0])] == pytest.approx(z[1] - 0.3, rel=1e-3)
    assert frame[int(pix[1, 1]), int(pix[1, 0]), 0] > 150  # blue (BGR) sphere


def test_trails_fade_from_head_to_tail_and_hud_draws_a_box():
    cam = _cam(w=160, h=96, pos=(0.0, 1.0, 6.0), look=(0.0, 1.0, 0.0))
    rend = Renderer(cam, 1, 0)
    empty = np.zeros((0, 3))
    base = rend.render(empty, empty, np.zeros(0), empty)
    trail = np.array([[[-2.0, 1.5, 0.0], [2.0, 1.5, 0.0]]])
    behind = np.array([[[0.0, 1.0, 8.0], [0.0, 1.0, 9.0]]])  # entirely behind the camera: skipped
    frame = rend.render(empty, empty, np.zeros(0), empty, trails=np.concatenate([trail, behind]))
    pix, _ = cam.project(np.array([[-1.7, 1.5, 0.0], [1.7, 1.5, 0.0]]))
    (hx, hy), (tx, ty) = np.round(pix).astype(int)
    head_change = np.abs(frame[hy, hx].astype(int) - base[hy, hx]).sum()
    tail_change = np.abs(frame[ty, tx].astype(int) - base[ty, tx]).sum()
    assert head_change > 60 and head_change > 3 * tail_change
    assert np.array_equal(frame[90], base[90])  # away from the line: untouched
    hud = rend.render(empty, empty, np.zeros(0), empty, hud_lines=["frame 12", "hits 3"])
    box = hud[10:30, 10:40].astype(int)
    assert box.min() < 0.5 * base[10:30, 10:40].min()  # darkened backing box
    assert box.max() > 200  # white text
    assert np.array_equal(hud[60:], base[60:])


def test_trails_hide_behind_nearer_limbs():
    cam = _cam(w=160, h=96, pos=(0.0, 1.0, 6.0), look=(0.0, 1.0, 0.0))
    rend = Renderer(cam, 1, 0)
    post = ([[0.0, 0.0, 2.0]], [[0.0, 2.0, 2.0]], [0.3], [0.9, 0.9, 0.9])  # a vertical limb in front
    base = rend.render(*post)
    depth = rend.depth_buffer()
    frame = rend.render(*post, trails=[[[-2.0, 1.0, -1.0], [2.0, 1.0, -1.0]]])  # a trail behind it
    pix, z = cam.project(np.array([[-1.8, 1.0, -1.0], [-0.2, 1.0, -1.0], [0.0, 1.0, 2.0]]))
    (lx, ly), (bx, by), (cx, cy) = np.round(pix).astype(int)
    assert depth[cy, cx] == pytest.approx(z[2] - 0.3, rel=1e-3) and depth[by, bx] < z[1]
    assert np.abs(frame[ly, lx].astype(int) - base[ly, lx]).sum() > 60  # beside the limb: drawn
    np.testing.assert_array_equal(frame[:, bx - 2 : bx + 3], base[:, bx - 2 : bx + 3])  # behind it: hidden
    assert np.isinf(depth[0]).all() and np.isfinite(depth[-1]).all()  # sky above, ground below


def test_renderer_rejects_bad_input():
    cam = _cam()
    rend = Renderer(cam, 2, 1)
    one = np.zeros((1, 3))
    with pytest.raises(ValueError, match="max_capsules"):
        rend.render(np.zeros((3, 3)), np.zeros((3, 3)), np.ones(3), np.ones((3, 3)))
    with pytest.raises(ValueError, match="capsules_a"):
        rend.render([[np.nan, 0, 0]], one, [0.1], [1, 1, 1])
    with pytest.raises(ValueError, match="radii"):
        rend.render(one, one, [-0.1], [1, 1, 1])
    with pytest.raises(ValueError, match="colors"):
        rend.render(one, one, [0.1], [2.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="max_spheres"):
        rend.render(one, one, [0.1], [1, 1, 1], np.zeros((2, 3)), [0.1, 0.1], [1, 1, 1])
    with pytest.raises(ValueError, match="trails"):
        rend.render(one, one, [0.1], [1, 1, 1], trails=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="hud_lines"):
        rend.render(one, one, [0.1], [1, 1, 1], hud_lines="frame 1")
    with pytest.raises(ValueError, match="image size"):
        rend.camera = _cam(w=32, h=32)
    with pytest.raises(ValueError, match="max_capsules"):
        Renderer(cam, -1, 0)
    rend.camera = _cam(pos=(1.0, 2.0, 6.0))  # same size: accepted


def _draw_buffers(cam, p):
    h, w = cam.height, cam.width
    tiles = np.ones(((h + kr.TILE - 1) // kr.TILE, (w + kr.TILE - 1) // kr.TILE), np.int32)
    return dict(pa=np.zeros((p, 3), np.float32), pb=np.zeros((p, 3), np.float32), radius=np.zeros(p, np.float32),
                color=np.zeros((p, 3), np.float32), keys=np.zeros((h, w), np.int64),
                shadow=np.zeros((h // 2, w // 2), np.int32), tiles=tiles, background=np.zeros((h, w, 3), np.float32),
                frame=np.zeros((h, w, 3), np.uint8), depth=np.zeros((h, w), np.float32))


def test_draw_frame_is_the_five_kernels_in_turn():
    """The one-launch frame (kernels/raster.draw_frame) against load, clear, raster, shadows and shade
    launched one by one on a copy of the same persistent buffers, in the renderer's order: a new camera's
    frame (all pixels, SHADE_FRESH), then frames of moved primitives that shade only the dirty tiles, the
    first of them storing the camera's background (SHADE_FILL), the next using it (SHADE_TILES)."""
    cam = _cam(w=96, h=64)
    a, b, r = (np.ascontiguousarray(x, np.float32) for x in _scene(seed=3))
    colors = np.random.default_rng(3).uniform(0.0, 1.0, (len(r), 3)).astype(np.float32)
    p = len(r) + 2
    fused, split = _draw_buffers(cam, p), _draw_buffers(cam, p)
    packed = cam.packed()
    for frame_no, (shift, shading) in enumerate(((0.0, kr.SHADE_FRESH), (0.4, kr.SHADE_FILL),
                                                 (0.4, kr.SHADE_TILES))):
        src = (a[:-1] + shift, b[:-1] + shift, r[:-1], colors[:-1])  # n < P: rows past n are not drawn
        n = len(r) - 1
        hosts = [np.zeros_like(fused[k]) for k in ("pa", "pb", "radius", "color")]
        for host, s in zip(hosts, src):
            host[:n] = s
        kr.draw_frame(packed, *hosts, n, *fused.values(), shading)
        s = split
        kr.load_primitives(*hosts, n, s["pa"], s["pb"], s["radius"], s["color"])
        kr.clear_buffers(s["keys"], s["shadow"], s["tiles"])
        kr.raster_capsules(packed, s["pa"], s["pb"], s["radius"], n, s["keys"], s["tiles"])
        kr.splat_shadows(packed, s["pa"], s["pb"], s["radius"], n, s["shadow"], s["tiles"])
        common = (packed, s["pa"], s["pb"], s["color"], s["keys"], s["shadow"])
        if shading == kr.SHADE_FRESH:
            kr.shade_frame_fresh(*common, s["frame"], s["depth"])
        else:
            if shading == kr.SHADE_FILL:
                kr.shade_background(packed, s["background"])
            kr.shade_frame(*common, s["background"], s["tiles"], s["frame"], s["depth"])
        for key, value in fused.items():
            np.testing.assert_array_equal(value, split[key], err_msg=f"frame {frame_no}: {key}")
        assert len(np.unique(decode_keys(fused["keys"])[0])) > 4  # primitives drawn
    assert np.any(fused["tiles"] == 3) and np.any(fused["tiles"] == 0)  # the last frame skipped clean tiles
