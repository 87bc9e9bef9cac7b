"""The row spans of raster_capsules and splat_shadows (kernels/raster_cover.py) are conservative: no pixel
outside a span is hit by its capsule, no shadow texel outside a span gets a shadow from it, and the
z-buffer has the hits and ids of a loop over each whole screen box, for level, rolled and steep cameras, a
camera inside a capsule's bounding sphere, spheres, standing legs, level arms, thin far capsules and
capsules crossing the near plane.

The depths are compared loosely: under fast math a copy of the same loop in another kernel is compiled with
other groupings of its sums (here up to ~800 ulps of depth apart, in capsule_hit's quadratic), so it cannot
be a bitwise oracle (and raster_capsules tests wide rows in 16-pixel packets, another grouping again). The golden
frames pin raster_capsules' keys for play."""

import numpy as np
import pytest
import taichi as ti

from crowd_ik.kernels import raster as kr
from crowd_ik.kernels.raster_cover import capsule_row, shadow_row_span
from crowd_ik.kernels.raster_geometry import (
    BIG, _CORNER_X, _CORNER_Z, capsule_hit, cam_vec, dir_origin, effective_radius, pixel_range, row3, shadow_soft,
    shadow_value, sphere_bounds,
)
from crowd_ik.view.render import Camera

nd = ti.types.ndarray


@ti.func
def _box(cam: ti.template(), a, b, r, width, height):
    """raster_capsules' screen box of the eye-relative capsule a-b (radius r already effective)."""
    right = cam_vec(cam, 3)
    up = cam_vec(cam, 6)
    fwd = cam_vec(cam, 9)
    focal = cam[12]
    near = cam[15]
    za = a.dot(fwd)
    zb = b.dot(fwd)
    xr = ti.Vector([0, width - 1])
    yr = ti.Vector([0, height - 1])
    if ti.min(za, zb) - r > near:
        bxa = sphere_bounds(a.dot(right), za, r)
        bxb = sphere_bounds(b.dot(right), zb, r)
        bya = sphere_bounds(a.dot(up), za, r)
        byb = sphere_bounds(b.dot(up), zb, r)
        cx = cam[13]
        cy = cam[14]
        xr = pixel_range(cx + focal * ti.min(bxa[0], bxb[0]), cx + focal * ti.max(bxa[1], bxb[1]), width)
        yr = pixel_range(cy - focal * ti.max(bya[1], byb[1]), cy - focal * ti.min(bya[0], byb[0]), height)
    return xr, yr


@ti.kernel
def _box_keys(cam: nd(dtype=ti.f32, ndim=1), pa: nd(dtype=ti.f32, ndim=2), pb: nd(dtype=ti.f32, ndim=2),
              radius: nd(dtype=ti.f32, ndim=1), n: ti.i32, keys: nd(dtype=ti.i64, ndim=2)):
    """raster_capsules as it was before the spans: every pixel of each screen box (the same code)."""
    height = keys.shape[0]
    width = keys.shape[1]
    for i in range(n):
        eye = cam_vec(cam, 0)
        right = cam_vec(cam, 3)
        up = cam_vec(cam, 6)
        fwd = cam_vec(cam, 9)
        focal = cam[12]
        near = cam[15]
        a = row3(pa, i) - eye
        b = row3(pb, i) - eye
        za = a.dot(fwd)
        zb = b.dot(fwd)
        r = effective_radius(za, zb, radius[i], focal)
        if ti.max(za, zb) + r >= near:
            xr, yr = _box(cam, a, b, r, width, height)
            d0 = dir_origin(cam)
            for py in range(yr[0], yr[1] + 1):
                for px in range(xr[0], xr[1] + 1):
                    rd = (d0 + right * ti.cast(px, ti.f32) - up * ti.cast(py, ti.f32)).normalized()
                    t = capsule_hit(rd, a, b, r)
                    if t > 0.0:
                        z = ti.cast(t * rd.dot(fwd), ti.f32)
                        if z >= near:
                            key = (ti.cast(ti.bit_cast(z, ti.i32), ti.i64) << 32) | ti.cast(i, ti.i64)
                            if key < keys[py, px]:
                                ti.atomic_min(keys[py, px], key)


@ti.kernel
def _span_counts(cam: nd(dtype=ti.f32, ndim=1), pa: nd(dtype=ti.f32, ndim=2), pb: nd(dtype=ti.f32, ndim=2),
                 radius: nd(dtype=ti.f32, ndim=1), n: ti.i32, width: ti.i32, height: ti.i32,
                 counts: nd(dtype=ti.i64, ndim=1)):
    """Over every box pixel: [0] hits outside the row span, [1] hits inside it, [2] pixels outside it."""
    for i in range(n):
        eye = cam_vec(cam, 0)
        fwd = cam_vec(cam, 9)
        a = row3(pa, i) - eye
        b = row3(pb, i) - eye
        r = effective_radius(a.dot(fwd), b.dot(fwd), radius[i], cam[12])
        if ti.max(a.dot(fwd), b.dot(fwd)) + r >= cam[15]:
            xr, yr = _box(cam, a, b, r, width, height)
            for py in range(yr[0], yr[1] + 1):
                x0, x1 = capsule_row(a, b, r, cam, py, xr[0], xr[1])
                for px in range(xr[0], xr[1] + 1):
                    inside = px >= x0 and px <= x1
                    if not inside:
                        counts[2] += 1
                    rd = (dir_origin(cam) + cam_vec(cam, 3) * ti.cast(px, ti.f32)
                          - cam_vec(cam, 6) * ti.cast(py, ti.f32)).normalized()
                    if capsule_hit(rd, a, b, r) > 0.0:
                        counts[ti.select(inside, 1, 0)] += 1


@ti.kernel
def _shadow_counts(cam: nd(dtype=ti.f32, ndim=1), pa: nd(dtype=ti.f32, ndim=2), pb: nd(dtype=ti.f32, ndim=2),
                   radius: nd(dtype=ti.f32, ndim=1), n: ti.i32, width: ti.i32, height: ti.i32,
                   counts: nd(dtype=ti.i64, ndim=1)):
    """Over every texel of splat_shadows' texel boxes (width x height texels), spans taken whatever the box
    width: [0] shadowed texels outside the row span, [1] inside it, [2] texels outside it."""
    for i in range(n):
        eye = cam_vec(cam, 0)
        right = cam_vec(cam, 3)
        up = cam_vec(cam, 6)
        fwd = cam_vec(cam, 9)
        a = row3(pa, i)
        b = row3(pb, i)
        r = radius[i]
        reach = r + shadow_soft(ti.max(ti.max(a[1], b[1]), 0.0))
        x_lo = ti.min(a[0], b[0]) - reach
        x_hi = ti.max(a[0], b[0]) + reach
        z_lo = ti.min(a[2], b[2]) - reach
        z_hi = ti.max(a[2], b[2]) + reach
        s_lo = ti.Vector([BIG, BIG])
        s_hi = ti.Vector([-BIG, -BIG])
        for k in ti.static(range(4)):  # the footprint rectangle's corners (all in front of these cameras)
            p = ti.Vector([x_lo + (x_hi - x_lo) * _CORNER_X[k], 0.0, z_lo + (z_hi - z_lo) * _CORNER_Z[k]]) - eye
            s = ti.Vector([cam[13] + cam[12] * p.dot(right) / p.dot(fwd), cam[14] - cam[12] * p.dot(up) / p.dot(fwd)])
            s_lo = ti.min(s_lo, s)
            s_hi = ti.max(s_hi, s)
        xr = pixel_range((s_lo[0] - 0.5) * 0.5, (s_hi[0] - 0.5) * 0.5, width)
        yr = pixel_range((s_lo[1] - 0.5) * 0.5, (s_hi[1] - 0.5) * 0.5, height)
        for py in range(yr[0], yr[1] + 1):
            x0, x1 = shadow_row_span(a, b, r, cam, py, xr[0], xr[1])
            for px in range(xr[0], xr[1] + 1):
                inside = px >= x0 and px <= x1
                if not inside:
                    counts[2] += 1
                d = dir_origin(cam) + right * (2.0 * px + 0.5) - up * (2.0 * py + 0.5)
                if d[1] < 0.0:
                    g = eye + d * (-eye[1] / d[1])
                    if shadow_value(g[0], g[2], a, b, r) > 0.0:
                        counts[ti.select(inside, 1, 0)] += 1


def _scene(seed, n=60):
    g = np.random.default_rng(seed)
    a = g.uniform([-3.0, 0.0, -3.0], [3.0, 2.0, 3.0], (n, 3))
    b = a + g.normal(0.0, 0.7, (n, 3))
    b[: n // 6] = a[: n // 6]  # spheres
    b[n // 6: n // 3] = a[n // 6: n // 3] + [0.0, 0.9, 0.0]  # standing legs
    b[n // 3: n // 2, 1] = a[n // 3: n // 2, 1]  # level arms
    r = g.uniform(0.02, 0.3, n)
    a = np.vstack([a, [[0.5, 1.0, -80.0], [0.2, 1.5, 5.0]]])  # a thin far capsule; one through the near plane
    b = np.vstack([b, [[2.5, 1.2, -90.0], [0.4, 1.9, 9.0]]])
    r = np.concatenate([r, [0.005, 0.1]])
    return tuple(np.ascontiguousarray(x, np.float32) for x in (a, b, r))


CAMERAS = {
    "level": ((0.0, 1.7, 7.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0)),
    "rolled": ((1.5, 3.0, 6.0), (0.0, 0.5, 0.0), (0.45, 1.0, 0.2)),
    "steep": ((-2.0, 9.0, 2.5), (0.3, 0.0, -0.5), (0.2, 1.0, -0.3)),
    "inside": ((0.3, 1.2, 0.4), (2.0, 0.8, -3.0), (-0.3, 1.0, 0.0)),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_spans_hold_every_hit_and_keep_the_keys(name):
    pos, look, up = CAMERAS[name]
    cam = Camera(pos, look, 55.0, 120, 80, up=up)
    packed = cam.packed()
    a, b, r = _scene(len(name))
    h, w = cam.height, cam.width
    keys = np.zeros((h, w), np.int64)
    shadow = np.zeros((h // 2, w // 2), np.int32)
    tiles = np.ones(((h + kr.TILE - 1) // kr.TILE, (w + kr.TILE - 1) // kr.TILE), np.int32)
    kr.clear_buffers(keys, shadow, tiles)
    full = keys.copy()
    kr.raster_capsules(packed, a, b, r, len(r), keys, tiles)
    counts = np.zeros(3, np.int64)
    _box_keys(packed, a, b, r, len(r), full)
    _span_counts(packed, a, b, r, len(r), w, h, counts)
    assert counts[0] == 0, f"{counts[0]} hits outside the spans"
    assert counts[1] > 500 and counts[2] > 500  # pixels hit, and box pixels the spans skip
    np.testing.assert_array_equal(keys & 0xFFFFFFFF, full & 0xFFFFFFFF)  # the same pixels hit, by the same ids
    depth, depth_full = ((k >> 32).astype(np.int32).view(np.float32) for k in (keys, full))
    np.testing.assert_allclose(depth, depth_full, rtol=1e-3)


@pytest.mark.parametrize("name", ["level", "rolled", "steep"])
def test_shadow_spans_hold_every_shadowed_texel(name):
    pos, look, up = CAMERAS[name]
    cam = Camera(pos, look, 55.0, 320, 200, up=up)
    a, b, r = _scene(len(name) + 7)
    keep = (a[:, 2] > -20.0) & (b[:, 2] > -20.0) & (np.maximum(a[:, 2], b[:, 2]) < 4.0)  # footprints in view
    a, b, r = (np.ascontiguousarray(x[keep]) for x in (a, b, r))
    counts = np.zeros(3, np.int64)
    _shadow_counts(cam.packed(), a, b, r, len(r), cam.width // 2, cam.height // 2, counts)
    assert counts[0] == 0, f"{counts[0]} shadowed texels outside the spans"
    assert counts[1] > 1000 and counts[2] > 1000
