"""Pixels sixteen at a time, each value one lane of a ``ti.types.vector(L, ti.f32)`` (packed SIMD on the CPU):
- ground_lanes: the sky and ground behind a row's pixels, raster_shade.background_pixel for pixels px0 ..
  px0 + L - 1 of row py, the same bits as the scalar function pixel by pixel (its branches become per-lane
  selects: a lane computes both sides and keeps the one the scalar code takes);
- capsule_hit_lanes: raster_geometry.capsule_hit for a packet of pixel rays (raster_capsules' wide rows) or one
  ray (its narrow rows), so both kinds of row give a pixel the same formula. It is not bit for bit the scalar
  capsule_hit: under fast math each compiled copy of it groups some sums its own way (see below), so the
  golden frames were re-recorded for it (one pixel in 60 arena frames moved one level).

Why: for a camera that moves every frame (the follow camera) shading computes every pixel's ground
ray, grid and fog, half of the frame's raster CPU in scalar code; in lanes (packed SIMD after LLVM's SLP
vectoriser) it costs half as much. An arena frame's capsules (1280x720) cost 5 ms to rasterise in packets, 8
pixel by pixel.

Bit for bit (ground_lanes): Taichi's fast math puts `reassoc` on every float operation, and LLVM's reassociation
regroups a chain of additions by the values its terms have in common across the chains of a block. In scalar code a
pixel's ray d = forward focal + right (px - cx) - up (py - cy) is summed as written; with sixteen lanes in one
block the camera terms forward focal and up (py - cy) are common to all sixteen sums, and LLVM adds them
first, which changes the last bit of some rays of tilted cameras. The SLP vectoriser also turns a three-term
sum (a dot product, a squared norm) into a vector reduction, in another order. `keep` (a max with -1e30:
the identity on every value these sums take) ends a chain where the scalar code's grouping must stay, so each
lane performs the scalar code's operations in its order; tests/test_raster_lanes.py compares the two on random
tilted cameras. The same chase for capsule_hit_lanes failed: keeping the scalar kernel's code but adding the
packet branch beside it already moved some depths, because the number of uses of a shared value decides how
LLVM groups the sums around it.
"""

import taichi as ti

from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels.raster_geometry import (
    BIG, FOG_DISTANCE, GRID_DARK, SHADOW_DARK, SHADOW_FALLOFF, SHADOW_HEIGHT_WEIGHT, line_cover, shadow_axis,
    shadow_soft,
)

L = 16  # pixels per packet (one AVX-512 register of float32)
PACKET_MIN = 8  # a row span narrower than this rasterises pixel by pixel (a packet costs a few scalar pixels)
V = ti.types.vector(L, ti.f32)
_FLOOR = -1.0e30


@ti.func
def keep(x):
    """x itself (every value here is far above -1e30), as a barrier LLVM does not reassociate across."""
    return ti.max(x, _FLOOR)


@ti.func
def ground_lanes(cam: ti.template(), px0, py):
    """background_pixel(cam, px, py) for px = px0 .. px0 + L - 1: lane vectors (ground view depth or inf, brightness
    factor or sky gradient, fog factor or 0)."""
    fy = ti.cast(py, ti.f32)
    fx = V([ti.cast(px0 + k, ti.f32) for k in ti.static(range(L))])
    # pixel_dir: forward focal + right (px - cx) - up (py - cy), summed in that order
    d = [keep(keep(cam[9 + c] * cam[12] + cam[3 + c] * (fx - cam[13])) - cam[6 + c] * (fy - cam[14]))
         for c in ti.static(range(3))]
    inv = 1 / (ti.sqrt(keep(d[0] * d[0] + d[1] * d[1]) + d[2] * d[2] + 0.0) + 0.0)  # Taichi's normalized()
    rd = [inv * d[c] for c in ti.static(range(3))]
    eye = [cam[c] for c in ti.static(range(3))]
    # ground_hit and the ground's view depth (ground_ray)
    tg = ti.select((eye[1] > 0.0) & (rd[1] < -1e-7), -eye[1] / rd[1], -1.0)
    ground = tg > 0.0
    b0 = ti.select(ground, tg * (keep(rd[0] * cam[9] + rd[1] * cam[10]) + rd[2] * cam[11]), ti.math.inf)
    # ground_look: the grid's anti-aliasing footprint from the rays through (px + 1, py) and (px, py + 1), and fog
    g0 = eye[0] + rd[0] * tg
    g2 = eye[2] + rd[2] * tg
    rx = [d[c] + cam[3 + c] for c in ti.static(range(3))]
    ry = [d[c] - cam[6 + c] for c in ti.static(range(3))]
    both = (rx[1] < 0.0) & (ry[1] < 0.0)
    gx0 = eye[0] - rx[0] * (eye[1] / rx[1])
    gx2 = eye[2] - rx[2] * (eye[1] / rx[1])
    gy0 = eye[0] - ry[0] * (eye[1] / ry[1])
    gy2 = eye[2] - ry[2] * (eye[1] / ry[1])
    fwx = ti.select(both, ti.max(ti.max(ti.abs(gx0 - g0), ti.abs(gy0 - g0)), 1e-4), 1.0e3)
    fwz = ti.select(both, ti.max(ti.max(ti.abs(gx2 - g2), ti.abs(gy2 - g2)), 1e-4), 1.0e3)
    grid = ti.max(line_cover(g0, fwx), line_cover(g2, fwz))
    f = 1.0 - ti.exp(-(tg / FOG_DISTANCE) * (tg / FOG_DISTANCE))
    b1 = ti.select(ground, (1.0 - GRID_DARK * grid) * (1.0 - f), ti.sqrt(ti.math.clamp(rd[1], 0.0, 1.0)))
    b2 = ti.select(ground, f, 0.0)
    return b0, b1, b2


@ti.func
def capsule_hit_lanes(d0, right, up, fwd, fx, fy, a, b, r):
    """raster_geometry.capsule_hit for the rays d0 + right fx - up fy (3-vectors as component lists, lane_math's
    helpers on them), and each ray's rd . fwd (rd the unit ray):
    (t, -1 on a miss; rd . fwd). fx is a lane vector of pixel columns (a packet of L pixels) or one column. The
    scalar function's branches become selects; a masked square root or division sees a harmless operand."""
    rd = lm.normalized(*[d0[c] + right[c] * fx - up[c] * fy for c in ti.static(range(3))])
    ba = b - a
    s = a + b
    t0 = 0.5 * lm.dot3(*s, *rd)
    oa = [rd[c] * t0 - a[c] for c in ti.static(range(3))]
    ob = [rd[c] * t0 - b[c] for c in ti.static(range(3))]
    rr = r * r
    baba = ba.dot(ba)
    bard = lm.dot3(*ba, *rd)
    baoa = lm.dot3(*ba, *oa)
    k2 = baba - bard * bard
    rdoa = lm.dot3(*rd, *oa)
    oaoa = lm.dot3(*oa, *oa)
    k1 = baba * rdoa - baoa * bard
    k0 = baba * oaoa - baoa * baoa - rr * baba
    h = k1 * k1 - k2 * k0
    side = (k2 > 1e-6 * baba) & (h >= 0.0)
    t = (-k1 - ti.sqrt(ti.max(h, 0.0))) / ti.select(side, k2, 1.0)
    y = baoa + t * bard
    best = ti.select(side & (y > 0.0) & (y < baba) & (t0 + t > 0.0), t, BIG)
    ha = rdoa * rdoa - (oaoa - rr)
    ta = ti.select(ha >= 0.0, -rdoa - ti.sqrt(ti.max(ha, 0.0)), BIG)
    best = ti.select((ta < best) & (t0 + ta > 0.0), ta, best)
    rdob = lm.dot3(*rd, *ob)
    hb = rdob * rdob - (lm.dot3(*ob, *ob) - rr)
    tb = ti.select(hb >= 0.0, -rdob - ti.sqrt(ti.max(hb, 0.0)), BIG)
    best = ti.select((tb < best) & (t0 + tb > 0.0), tb, best)
    return ti.select(best < BIG, t0 + best, -1.0), lm.dot3(*rd, *fwd)


@ti.func
def shadow_lanes(d0, right, up, eye, fx, fy, a, b, r):
    """raster_geometry.shadow_value at the ground points seen along d0 + right fx - up fy (fx a lane vector of
    texel-row sample columns or one column), 0 where the ray does not point down: the darkness of each."""
    d = [d0[c] + right[c] * fx - up[c] * fy for c in ti.static(range(3))]
    down = d[1] < 0.0
    k = -eye[1] / ti.select(down, d[1], -1.0)
    gx = eye[0] + d[0] * k
    gz = eye[2] + d[2] * k
    ha, hb, ex, ey, ez, ee = shadow_axis(a, b)
    w = SHADOW_HEIGHT_WEIGHT
    u = ti.math.clamp(((gx - a[0]) * ex + (-w * ha) * ey + (gz - a[2]) * ez) / ti.max(ee, 1e-12), 0.0, 1.0)
    if ee <= 1e-12:
        u = u * 0.0
    dx = gx - (a[0] + u * ex)
    dz = gz - (a[2] + u * ez)
    dd = dx * dx + dz * dz
    h = ha + u * (hb - ha)
    s = shadow_soft(h)
    cover = 1.0 - ti.math.smoothstep(r - s, r + s, ti.sqrt(dd))
    return ti.select(down & (dd < (r + s) * (r + s)), SHADOW_DARK * ti.exp(-h / SHADOW_FALLOFF) * cover, 0.0)
