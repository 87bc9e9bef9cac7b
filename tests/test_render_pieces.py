"""The renderer's loops split for the cores (kernels/raster.py, raster_shade.py): image passes over pieces of
rows and tiles cut by the frame's edge, and splat_shadows over several items per primitive when there are few,
give the same buffers as one item per row / per primitive would, and cover every pixel once."""

import numpy as np

from crowd_ik.kernels import raster as kr
from crowd_ik.kernels import raster_geometry as geo
from crowd_ik.reference import raster as ref
from crowd_ik.view.render import Camera


def _scene(seed, n=12):
    g = np.random.default_rng(seed)
    a = g.uniform([-2.0, 0.0, -2.0], [2.0, 1.8, 2.0], (n, 3))
    b = a + g.normal(0.0, 0.6, (n, 3))
    r = g.uniform(0.05, 0.3, n)
    return tuple(np.ascontiguousarray(x, np.float32) for x in (a, b, r))


def _tiles(h, w, value=1):
    return np.full(((h + geo.TILE - 1) // geo.TILE, (w + geo.TILE - 1) // geo.TILE), value, np.int32)


def _shadow(cam, a, b, r):
    h, w = cam.height, cam.width
    shadow = np.zeros((h // 2, w // 2), np.int32)
    tiles = _tiles(h, w, 0)
    kr.splat_shadows(cam.packed(), a, b, r, len(r), shadow, tiles)
    return shadow, tiles


def test_splat_in_parts_equals_one_item_per_primitive():
    """A dozen primitives are split into several items each (every parts-th texel row); padded with
    PRIMITIVE_ITEMS primitives too high to cast shadows, each primitive is one item: same texels, same tiles."""
    assert geo.PRIMITIVE_ITEMS // 12 >= geo.MAX_PARTS > 1
    cam = Camera((1.0, 6.0, 7.0), (0.0, 0.0, 0.0), 55.0, 96, 64)
    a, b, r = _scene(5)
    split, split_tiles = _shadow(cam, a, b, r)
    pad = geo.PRIMITIVE_ITEMS
    high = np.tile(np.float32([0.0, geo.SHADOW_MAX_HEIGHT + 5.0, 0.0]), (pad, 1))
    radii = np.concatenate([r, np.full(pad, 0.1, np.float32)])
    whole, whole_tiles = _shadow(cam, np.vstack([a, high]), np.vstack([b, high]), radii)
    assert np.count_nonzero(split) > 80
    assert np.count_nonzero(split.any(axis=1)) >= 8  # shadowed rows, each done by another item of its primitive
    np.testing.assert_array_equal(split, whole)
    np.testing.assert_array_equal(split_tiles, whole_tiles)
    expect = ref.splat_shadows(cam.packed(), a, b, r, cam.width, cam.height)
    assert np.abs(split.astype(np.int64) - expect).max() <= 3  # and it is the twin's buffer (float32 rounding)


def test_pieces_and_edge_tiles_shade_every_pixel_once():
    """A frame whose width is no multiple of SPAN or TILE and whose height is no multiple of TILE: the fused
    background pass, the tile pass and the fresh pass (no background stored) write every pixel (sentinels
    gone) and agree bit for bit."""
    w, h = 2 * geo.SPAN + 8 + 2, 3 * geo.TILE + 6
    assert w % geo.SPAN and w % geo.TILE and h % geo.TILE
    cam = Camera((0.5, 3.0, 6.0), (0.0, 0.5, 0.0), 60.0, w, h)
    a, b, r = _scene(6)
    color = np.full((len(r), 3), 0.6, np.float32)
    packed = cam.packed()
    keys = np.zeros((h, w), np.int64)
    shadow = np.zeros((h // 2, w // 2), np.int32)
    tiles = _tiles(h, w)
    kr.clear_buffers(keys, shadow, tiles)
    assert np.all(tiles == 2) and np.all(shadow == 0) and np.all(keys == keys[0, 0])  # every tile cleared
    kr.raster_capsules(packed, a, b, r, len(r), keys, tiles)
    kr.splat_shadows(packed, a, b, r, len(r), shadow, tiles)
    out = {}
    for way in ("fused", "split", "fresh"):
        background = np.full((h, w, 3), -7.0, np.float32)
        frame = np.full((h, w, 3), 3, np.uint8)
        depth = np.full((h, w), -1.0, np.float32)
        if way == "fused":
            kr.shade_frame_background(packed, a, b, color, keys, shadow, background, frame, depth)
        elif way == "split":
            kr.shade_background(packed, background)
            kr.shade_frame(packed, a, b, color, keys, shadow, background, _tiles(h, w, 2), frame, depth)
        else:  # frame and depth only: the background buffer is not written
            kr.shade_frame_fresh(packed, a, b, color, keys, shadow, frame, depth)
            assert np.all(background == -7.0)
        assert not np.any(depth == -1.0) and (way == "fresh" or not np.any(background == -7.0))
        out[way] = (background, frame, depth)
    for x, y in zip(out["fused"], out["split"]):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(out["fused"][1:], out["fresh"][1:]):
        np.testing.assert_array_equal(x, y)
    out[True] = out["fused"]
    assert np.isinf(out[True][2]).any() and np.isfinite(out[True][2]).mean() > 0.3  # sky and ground both seen
    assert len(np.unique(out[True][1].reshape(-1, 3), axis=0)) > 50
