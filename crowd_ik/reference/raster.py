"""NumPy twin of kernels/raster.py, written per pixel for clarity (vectorised over pixels, a loop
over the few primitives of a test scene), in float64.

- `raster_capsules`: for every pixel ray, the nearest ray-capsule entry -> primitive id and view
  depth (ties to the lower id), with the kernel's radius inflation and near-plane clipping; every
  pixel is tested against every primitive, so this also checks that the kernel's screen boxes are
  conservative.
- `splat_shadows`: the ground darkness buffer (max over primitives, quantised like the kernel).
- `shade_frame`: the BGR frame from (ids, depth, shadow).
`cam` is the (16,) packed camera of `crowd_ik.view.render.Camera.packed`.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.kernels import raster_geometry as k


def _camera(cam):
    c = np.asarray(cam, dtype=np.float64)
    return c[0:3], c[3:6], c[6:9], c[9:12], c[12], c[13], c[14], c[15]


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pixel_rays(cam, width: int, height: int, dx: float = 0.0, dy: float = 0.0, step: float = 1.0) -> np.ndarray:
    """(H, W, 3) unit ray directions through pixel coordinates (step j + dx, step i + dy)."""
    _, right, up, fwd, focal, cx, cy, _ = _camera(cam)
    px = step * np.arange(width, dtype=np.float64)[None, :, None] + dx
    py = step * np.arange(height, dtype=np.float64)[:, None, None] + dy
    return _normalize(fwd * focal + right * (px - cx) - up * (py - cy))


def effective_radius(za: float, zb: float, r: float, focal: float) -> float:
    return max(r, k.MIN_PIXEL_RADIUS * max(za, zb, 0.0) / focal)


def _sphere_entry(rd: np.ndarray, center: np.ndarray, r: float) -> np.ndarray:
    """Entry distance of unit rays from the origin into a sphere; inf where they miss."""
    b = rd @ center
    h = b * b - (center @ center - r * r)
    with np.errstate(invalid="ignore"):
        return np.where(h >= 0.0, b - np.sqrt(h), np.inf)


def capsule_hit(rd: np.ndarray, pa: np.ndarray, pb: np.ndarray, r: float) -> np.ndarray:
    """Entry distance along unit rays rd (..., 3) from the origin into the capsule pa-pb (origin-
    relative); inf where the ray misses or enters behind the origin. The capsule is the union of a
    cylinder's side (between the end discs) and the two end spheres."""
    ba = pb - pa
    baba = ba @ ba
    best = np.full(rd.shape[:-1], np.inf)
    if baba > 0.0:
        axis = ba / np.sqrt(baba)
        # Cylinder side: |(t rd - pa) x axis| = r, with the foot of t rd on the axis inside [0, 1].
        d_perp = rd - (rd @ axis)[..., None] * axis
        a_perp = -pa + (pa @ axis) * axis
        qa = np.sum(d_perp * d_perp, axis=-1)
        qb = 2.0 * (d_perp @ a_perp)
        qc = a_perp @ a_perp - r * r
        disc = qb * qb - 4.0 * qa * qc
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-qb - np.sqrt(disc)) / (2.0 * qa)
            foot = (t[..., None] * rd - pa) @ ba / baba
            side = (disc >= 0.0) & (qa > 1e-6) & (foot > 0.0) & (foot < 1.0) & (t > 0.0)
        best = np.where(side, t, best)
    for center in (pa, pb):
        t = _sphere_entry(rd, center, r)
        best = np.where((t > 0.0) & (t < best), t, best)
    return best


def raster_capsules(cam, pa, pb, radius, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(ids (H, W) int32, -1 where no hit; depth (H, W) float64 view depth, inf where none)."""
    eye, _, _, fwd, focal, _, _, near = _camera(cam)
    rd = pixel_rays(cam, width, height)
    cos = rd @ fwd
    ids = np.full((height, width), -1, np.int32)
    depth = np.full((height, width), np.inf)
    for i in range(len(radius)):
        a = np.asarray(pa[i], np.float64) - eye
        b = np.asarray(pb[i], np.float64) - eye
        r = effective_radius(a @ fwd, b @ fwd, float(radius[i]), focal)
        z = capsule_hit(rd, a, b, r) * cos
        nearer = (z >= near) & (z < depth)
        ids[nearer] = i
        depth[nearer] = z[nearer]
    return ids, depth


def shadow_value(g: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Darkness cast by capsule a-b (world) on ground points g (..., 3), as kernels.raster.shadow_value."""
    w = k.SHADOW_HEIGHT_WEIGHT
    ha, hb = max(a[1], 0.0), max(b[1], 0.0)
    a_s = np.array([a[0], w * ha, a[2]])
    e = np.array([b[0] - a[0], w * (hb - ha), b[2] - a[2]])
    ee = e @ e
    rel = np.stack([g[..., 0], np.zeros(g.shape[:-1]), g[..., 2]], axis=-1) - a_s
    u = np.clip(rel @ e / ee, 0.0, 1.0) if ee > 1e-12 else np.zeros(g.shape[:-1])
    d = np.hypot(g[..., 0] - (a[0] + u * e[0]), g[..., 2] - (a[2] + u * e[2]))
    h = ha + u * (hb - ha)
    s = k.SHADOW_SOFT0 + k.SHADOW_SOFT_K * h
    x = np.clip((d - (r - s)) / (2.0 * s), 0.0, 1.0)
    cover = 1.0 - x * x * (3.0 - 2.0 * x)
    return k.SHADOW_DARK * np.exp(-h / k.SHADOW_FALLOFF) * cover


def ground_hit(eye: np.ndarray, rd: np.ndarray) -> np.ndarray:
    """Ray parameter of the ground y = 0 seen from above; -1 where the ray does not reach it."""
    if eye[1] <= 0.0:
        return np.full(rd.shape[:-1], -1.0)
    with np.errstate(divide="ignore"):
        return np.where(rd[..., 1] < -1e-7, -eye[1] / rd[..., 1], -1.0)


def splat_shadows(cam, pa, pb, radius, width: int, height: int) -> np.ndarray:
    """(H/2, W/2) int32: max over primitives of round(SHADOW_SCALE * darkness) at the ground point
    seen through pixel coordinates (2j + 0.5, 2i + 0.5) (the centre of each 2x2 block)."""
    eye = _camera(cam)[0]
    rd = pixel_rays(cam, width // 2, height // 2, dx=0.5, dy=0.5, step=2.0)
    tg = ground_hit(eye, rd)
    g = eye + rd * tg[..., None]
    out = np.zeros((height // 2, width // 2), np.int32)
    for i in range(len(radius)):
        a, b = np.asarray(pa[i], np.float64), np.asarray(pb[i], np.float64)
        if min(max(a[1], 0.0), max(b[1], 0.0)) >= k.SHADOW_MAX_HEIGHT:
            continue
        level = np.floor(shadow_value(g, a, b, float(radius[i])) * k.SHADOW_SCALE + 0.5).astype(np.int32)
        out = np.maximum(out, np.where(tg > 0.0, level, 0))
    return out


def sample_shadow(shadow: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) darkness 0..1: the (H/2, W/2) shadow levels sampled bilinearly at every pixel."""
    h, w = shadow.shape
    u = np.maximum((np.arange(width) - 0.5) * 0.5, 0.0)
    v = np.maximum((np.arange(height) - 0.5) * 0.5, 0.0)
    j0 = np.minimum(u.astype(int), w - 1)
    i0 = np.minimum(v.astype(int), h - 1)
    j1, i1 = np.minimum(j0 + 1, w - 1), np.minimum(i0 + 1, h - 1)
    fu, fv = np.minimum(u - j0, 1.0)[None, :], np.minimum(v - i0, 1.0)[:, None]
    s = shadow.astype(np.float64)
    top = s[i0][:, j0] * (1 - fu) + s[i0][:, j1] * fu
    bottom = s[i1][:, j0] * (1 - fu) + s[i1][:, j1] * fu
    return (top * (1 - fv) + bottom * fv) / k.SHADOW_SCALE


def _line_cover(u: np.ndarray, fw: np.ndarray) -> np.ndarray:
    d = np.abs(u - np.floor(u + 0.5))
    lo = np.maximum(d - 0.5 * fw, -0.5 * k.GRID_WIDTH)
    hi = np.minimum(d + 0.5 * fw, 0.5 * k.GRID_WIDTH)
    return np.maximum(hi - lo, 0.0) / fw


def _fog(col: np.ndarray, dist: np.ndarray) -> np.ndarray:
    f = 1.0 - np.exp(-((dist / k.FOG_DISTANCE) ** 2))
    return col + (np.array(k.SKY_HORIZON) - col) * f[..., None]


def shade_frame(cam, pa, pb, color, ids, depth, shadow, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame (H, W, 3) uint8 BGR, seen (H, W) view depth of what each pixel shows, inf for sky)
    from ids/depth (as `raster_capsules` returns) and the (H/2, W/2) shadow levels (as
    `splat_shadows` returns)."""
    eye, _, _, fwd, _, _, _, _ = _camera(cam)
    rd = pixel_rays(cam, width, height)
    y = np.clip(rd[..., 1], 0.0, 1.0)
    horizon, zenith = np.array(k.SKY_HORIZON), np.array(k.SKY_ZENITH)
    col = horizon + (zenith - horizon) * np.sqrt(y)[..., None]
    tg = ground_hit(eye, rd)
    seen = np.full((height, width), np.inf)

    hit = ids >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(hit, depth / (rd @ fwd), np.inf)
    capsule = hit & ((tg < 0.0) | (t < tg))
    if np.any(capsule):
        i = ids[capsule]
        r = rd[capsule]
        tc = t[capsule][:, None]
        a = np.asarray(pa, np.float64)[i] - eye
        b = np.asarray(pb, np.float64)[i] - eye
        p = r * tc
        ba = b - a
        baba = np.sum(ba * ba, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            h = np.where(baba > 1e-20, np.clip(np.sum((p - a) * ba, axis=1) / baba, 0.0, 1.0), 0.0)
        n = _normalize(p - a - ba * h[:, None])
        light = np.array([k.LIGHT_X, k.LIGHT_Y, k.LIGHT_Z])
        diffuse = np.maximum(n @ light, 0.0)
        ambient = k.AMBIENT + k.AMBIENT_SKY * n[:, 1]
        rim = k.RIM * (1.0 - np.maximum(-np.sum(n * r, axis=1), 0.0)) ** k.RIM_POWER
        half = _normalize(light - r)
        spec = k.SPECULAR * np.maximum(np.sum(n * half, axis=1), 0.0) ** k.SHININESS
        height_y = eye[1] + r[:, 1] * tc[:, 0]
        ao = k.AO_MIN + (1.0 - k.AO_MIN) * np.clip(height_y / k.AO_HEIGHT, 0.0, 1.0)
        base = np.asarray(color, np.float64)[i]
        shaded = base * ((ambient + k.DIFFUSE * diffuse) * ao)[:, None] + (rim + spec)[:, None]
        col[capsule] = _fog(shaded, tc[:, 0])
        seen[capsule] = depth[capsule]

    ground = ~capsule & (tg > 0.0)
    if np.any(ground):
        g = eye + rd * tg[..., None]
        rx = pixel_rays(cam, width, height, dx=1.0)  # rays through the next pixel right / down
        ry = pixel_rays(cam, width, height, dy=1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            gx = eye - rx * (eye[1] / rx[..., 1])[..., None]
            gy = eye - ry * (eye[1] / ry[..., 1])[..., None]
        both = (rx[..., 1] < 0.0) & (ry[..., 1] < 0.0)
        step_x, step_y = np.abs(gx - g), np.abs(gy - g)  # ground moved by one pixel right / down
        fwx = np.where(both, np.maximum(np.maximum(step_x[..., 0], step_y[..., 0]), 1e-4), 1e3)
        fwz = np.where(both, np.maximum(np.maximum(step_x[..., 2], step_y[..., 2]), 1e-4), 1e3)
        grid = np.maximum(_line_cover(g[..., 0], fwx), _line_cover(g[..., 2], fwz))
        dark = sample_shadow(shadow, width, height)
        shade = (1.0 - k.GRID_DARK * grid) * (1.0 - dark)
        ground_col = _fog(np.array(k.GROUND) * shade[..., None], tg)
        col[ground] = ground_col[ground]
        seen[ground] = (tg * (rd @ fwd))[ground]
    return np.floor(np.clip(col, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), seen
