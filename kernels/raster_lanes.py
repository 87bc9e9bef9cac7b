"""The sky and ground behind a row's pixels, sixteen at a time: raster_shade.background_pixel for pixels px0 ..
px0 + L - 1 of row py, each value one lane of a ``ti.types.vector(L, ti.f32)``, the same bits as the scalar
function pixel by pixel (its branches become per-lane selects: a lane computes both sides and keeps the one
the scalar code takes).

Why it is here: for a camera that moves every frame (the follow camera) shading computes every pixel's ground
ray, grid and fog, half of the frame's raster CPU in scalar code; in lanes (packed SIMD after LLVM's SLP
vectoriser) it costs half as much.

Bit for bit: Taichi's fast math puts `reassoc` on every float operation, and LLVM's reassociation regroups a
chain of additions by the values its terms have in common across the chains of a block. In scalar code a
pixel's ray d = forward focal + right (px - cx) - up (py - cy) is summed as written; with sixteen lanes in one
block the camera terms forward focal and up (py - cy) are common to all sixteen sums, and LLVM adds them
first, which changes the last bit of some rays of tilted cameras. The SLP vectoriser also turns a three-term
sum (a dot product, a squared norm) into a vector reduction, in another order. `keep` (a max with -1e30:
the identity on every value these sums take) ends a chain where the scalar code's grouping must stay, so each
lane performs the scalar code's operations in its order; tests/test_raster_lanes.py compares the two on random
tilted cameras.
"""

import taichi as ti

from crowd_ik.kernels.raster_geometry import FOG_DISTANCE, GRID_DARK, line_cover

L = 16  # pixels per packet (one AVX-512 register of float32)
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
