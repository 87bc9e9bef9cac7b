"""The sixteen-pixel background (kernels/raster_lanes.py) is the scalar one bit for bit: shade_background and
shade_frame_fresh (lanes) against shade_frame_background (scalar background_span), on random tilted cameras and
widths that leave a row's last pixels short of a packet."""

import numpy as np
import pytest

from crowd_ik.kernels import raster as kr
from crowd_ik.kernels.raster_lanes import L as LANES
from crowd_ik.kernels.raster_lanes import PACKET_MIN
from crowd_ik.reference import raster as ref
from crowd_ik.view.render import Camera


def _camera(g, width, height):
    eye = g.uniform([-20.0, 0.5, -20.0], [20.0, 12.0, 20.0])
    return Camera(eye, g.uniform(-5.0, 5.0, 3), g.uniform(30.0, 80.0), width, height,
                  up=(g.normal(0.0, 0.3), 1.0, g.normal(0.0, 0.3)))


@pytest.mark.parametrize("seed,width,height", [(0, 320, 180), (1, 200, 120), (2, 96, 64), (3, 328, 200)])
def test_lane_background_and_fresh_frames_equal_the_scalar_path(seed, width, height):
    g = np.random.default_rng(seed)
    cam = _camera(g, width, height)
    n = 40
    a = g.uniform([-3.0, 0.0, -3.0], [3.0, 1.8, 3.0], (n, 3)).astype(np.float32)
    b = (a + g.normal(0.0, 0.6, (n, 3))).astype(np.float32)
    r = g.uniform(0.05, 0.3, n).astype(np.float32)
    c = g.uniform(0.0, 1.0, (n, 3)).astype(np.float32)
    p = cam.packed()
    keys = np.zeros((height, width), np.int64)
    shadow = np.zeros((height // 2, width // 2), np.int32)
    tiles = np.ones(((height + kr.TILE - 1) // kr.TILE, (width + kr.TILE - 1) // kr.TILE), np.int32)
    kr.clear_buffers(keys, shadow, tiles)
    kr.raster_capsules(p, a, b, r, n, keys, tiles)
    kr.splat_shadows(p, a, b, r, n, shadow, tiles)
    ref_bg = np.zeros((height, width, 3), np.float32)
    ref_frame = np.zeros((height, width, 3), np.uint8)
    ref_depth = np.zeros((height, width), np.float32)
    kr.shade_frame_background(p, a, b, c, keys, shadow, ref_bg, ref_frame, ref_depth)
    bg = np.zeros_like(ref_bg)
    kr.shade_background(p, bg)
    frame = np.zeros_like(ref_frame)
    depth = np.zeros_like(ref_depth)
    kr.shade_frame_fresh(p, a, b, c, keys, shadow, frame, depth)
    assert np.array_equal(bg.view(np.int32), ref_bg.view(np.int32))
    assert np.array_equal(frame, ref_frame)
    assert np.array_equal(depth.view(np.int32), ref_depth.view(np.int32))


@pytest.mark.parametrize("seed,width,height", [(4, 320, 180), (5, 202, 122), (6, 96, 64)])
def test_packet_raster_hits_the_pixels_of_the_pixel_loop(seed, width, height):
    # raster_capsules tests rows of PACKET_MIN or more pixels LANES at a time (capsule_hit_lanes): the same
    # pixels hit by the same ids as test_raster_cover's whole-box loop of capsule_hit, depths to float32 rounding
    from test_raster_cover import _box_keys

    g = np.random.default_rng(seed)
    cam = _camera(g, width, height)
    n = 30
    centre = cam.position + 4.0 * cam.forward  # near the camera: boxes dozens of pixels wide
    a = (centre + g.normal(0.0, 1.0, (n, 3))).astype(np.float32)
    b = (a + g.normal(0.0, 0.8, (n, 3))).astype(np.float32)
    b[::4] = a[::4]  # spheres
    r = g.uniform(0.05, 0.4, n).astype(np.float32)
    p = cam.packed()
    keys = np.zeros((height, width), np.int64)
    shadow = np.zeros((height // 2, width // 2), np.int32)
    tiles = np.ones(((height + kr.TILE - 1) // kr.TILE, (width + kr.TILE - 1) // kr.TILE), np.int32)
    kr.clear_buffers(keys, shadow, tiles)
    full = keys.copy()
    kr.raster_capsules(p, a, b, r, n, keys, tiles)
    _box_keys(p, a, b, r, n, full)
    ids = keys & 0xFFFFFFFF
    np.testing.assert_array_equal(ids, full & 0xFFFFFFFF)
    hit = keys != full.max()
    assert hit.mean() > 0.2
    widest = max(_longest_run(row) for row in np.where(hit, ids, -1))
    assert widest > LANES + PACKET_MIN  # rows wider than a packet: packets and their masked tails are used
    depth, depth_full = ((k >> 32).astype(np.int32).view(np.float32) for k in (keys, full))
    np.testing.assert_allclose(depth[hit], depth_full[hit], rtol=2e-4)  # grazing rays: the quadratic cancels



@pytest.mark.parametrize("seed", [7, 8])
def test_packet_shadows_match_the_numpy_twin(seed):
    # splat_shadows tests texel rows of PACKET_MIN or more LANES at a time (shadow_lanes): the twin's levels to
    # float32 rounding, on footprints far wider than a packet
    g = np.random.default_rng(seed)
    cam = Camera((0.0, 4.0, 5.0), (0.0, 0.0, 0.0), 50.0, 320, 180, up=(g.normal(0.0, 0.2), 1.0, 0.0))
    n = 12
    a = g.uniform([-2.0, 0.0, -2.0], [2.0, 1.0, 2.0], (n, 3)).astype(np.float32)
    b = (a + g.normal(0.0, 0.7, (n, 3))).astype(np.float32)
    r = g.uniform(0.1, 0.4, n).astype(np.float32)
    keys = np.zeros((180, 320), np.int64)
    shadow = np.zeros((90, 160), np.int32)
    tiles = np.ones(((180 + kr.TILE - 1) // kr.TILE, (320 + kr.TILE - 1) // kr.TILE), np.int32)
    kr.clear_buffers(keys, shadow, tiles)
    kr.splat_shadows(cam.packed(), a, b, r, n, shadow, tiles)
    expect = ref.splat_shadows(cam.packed(), a, b, r, 320, 180)
    assert max(_longest_run(np.where(row > 0, 0, -1)) for row in expect) > LANES + PACKET_MIN
    assert np.abs(shadow.astype(np.int64) - expect).max() <= 3  # float32 vs float64 rounding only
    assert (shadow > 0).sum() > 1000

def _longest_run(row):
    """Length of the longest run of one id (not -1) in a row of ids."""
    starts = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
    lengths = np.diff(np.r_[starts, len(row)])
    return int(lengths[row[starts] >= 0].max(initial=0))
