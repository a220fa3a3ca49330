"""Numba kernels of the warp: ground ray casting, lidar disk splatting, per-source backward warp.

One loop over rays / points / pixels each, float64 geometry, no temporaries: the numpy
versions of these spent most of their time allocating (N, 3) arrays. They release the GIL, so two
render threads of one log (``WarpRenderer.threads``) run at once. The public wrappers in
``depth_proxy`` and ``backward_warp`` check inputs and document the semantics.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

DIR_EPS = 1e-9
MARCH_SAMPLES = 96
MARCH_T0 = 1e-3
BISECTIONS = 16
GROUND_BLOCK = 4  # ground rays solved in full every this many pixels, the others predicted and checked
GROUND_PREDICT_TOL_M = 0.005  # a predicted hit is kept if the ray passes this close to the ground there
MARCH_SAFE_M = 1e-6  # march samples this far above every possible ground height are stepped over


@njit(cache=True, inline="always")
def _ground_height(x, y, normal, offset, heights, rR, rt, rs, has_raster):
    """Raster height at city (x, y), bilinear between the valid neighbouring cell centres (as
    ``nuav2.terrain.bilinear_height``), else the plane's height."""
    if has_raster:
        px = rs * (rR[0, 0] * x + rR[0, 1] * y + rt[0]) - 0.5
        py = rs * (rR[1, 0] * x + rR[1, 1] * y + rt[1]) - 0.5
        c0 = int(math.floor(px))
        r0 = int(math.floor(py))
        fx = px - c0
        fy = py - r0
        acc = 0.0
        wsum = 0.0
        for dr in range(2):
            r = r0 + dr
            if r < 0 or r >= heights.shape[0]:
                continue
            wy = fy if dr == 1 else 1.0 - fy
            for dc in range(2):
                c = c0 + dc
                if c < 0 or c >= heights.shape[1]:
                    continue
                wgt = wy * (fx if dc == 1 else 1.0 - fx)
                v = float(heights[r, c])
                if wgt > 0.0 and math.isfinite(v):
                    acc += wgt * v
                    wsum += wgt
        if wsum > 1e-12:
            return acc / wsum
    return (offset - normal[0] * x - normal[1] * y) / normal[2]


@njit(cache=True, inline="always")
def _march_safe_t(ox, oy, oz, dx, dy, dz, normal, offset, h_top):  # pragma: no cover - compiled
    """Largest t up to which a descending ray stays ``MARCH_SAFE_M`` above both the raster's top
    ``h_top`` and the plane (the heights ``_ground_height`` can return); -1 where it does not start so."""
    if not oz - h_top >= MARCH_SAFE_M:
        return -1.0
    t = (oz - h_top - MARCH_SAFE_M) / -dz
    g0 = oz - (offset - normal[0] * ox - normal[1] * oy) / normal[2]  # ray height above the plane: g0 + t g1
    if not g0 >= MARCH_SAFE_M:
        return -1.0
    g1 = dz + (normal[0] * dx + normal[1] * dy) / normal[2]
    if g1 < 0.0:
        t = min(t, (g0 - MARCH_SAFE_M) / -g1)
    return t


@njit(cache=True, inline="always")
def _ground_ray(ox, oy, oz, dx, dy, dz, normal, offset, heights, rR, rt, rs, has_raster, h_top, iterations,
                t_max, tol):  # pragma: no cover - compiled
    """Ray parameter of one ray's ground hit (see ``GroundSurface.intersect``); ``h_top``: the raster's
    highest height (``GroundHeightRaster.top``)."""
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    nd = normal[0] * dx + normal[1] * dy + normal[2] * dz
    t = math.inf
    if nd < -DIR_EPS * norm:
        t = (offset - (normal[0] * ox + normal[1] * oy + normal[2] * oz)) / nd
        if t < 0.0:
            t = math.inf
    if not has_raster or iterations == 0:
        return t
    if not dz < -DIR_EPS * norm:
        return math.inf
    for _ in range(iterations):
        if not math.isfinite(t):
            break
        h = _ground_height(ox + t * dx, oy + t * dy, normal, offset, heights, rR, rt, rs, has_raster)
        t = (h - oz) / dz
        if t < 0.0:
            t = math.inf
    if math.isfinite(t):
        h = _ground_height(ox + t * dx, oy + t * dy, normal, offset, heights, rR, rt, rs, has_raster)
        if abs(oz + t * dz - h) <= tol:
            return t
    # March to the first sample below the ground, then bisect the crossing. Samples up to t_safe are
    # above any height the ground can have, so their test is known to fail: no height lookup there.
    ratio = (t_max / MARCH_T0) ** (1.0 / (MARCH_SAMPLES - 1))
    t_safe = _march_safe_t(ox, oy, oz, dx, dy, dz, normal, offset, h_top)
    t_prev = MARCH_T0
    if t_prev > t_safe:
        h0 = _ground_height(ox + t_prev * dx, oy + t_prev * dy, normal, offset, heights, rR, rt, rs,
                            has_raster)
        if oz + t_prev * dz < h0:
            return math.inf
    tk = t_prev
    for _ in range(1, MARCH_SAMPLES):
        tk = tk * ratio
        if tk <= t_safe:
            t_prev = tk
            continue
        hk = _ground_height(ox + tk * dx, oy + tk * dy, normal, offset, heights, rR, rt, rs, has_raster)
        if oz + tk * dz < hk:
            lo, hi = t_prev, tk
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                hm = _ground_height(ox + mid * dx, oy + mid * dy, normal, offset, heights, rR, rt, rs,
                                    has_raster)
                if oz + mid * dz >= hm:
                    lo = mid
                else:
                    hi = mid
            return 0.5 * (lo + hi)
        t_prev = tk
    return math.inf


@njit(cache=True, nogil=True)
def ground_intersect_kernel(origin, dirs, normal, offset, heights, rR, rt, rs, has_raster, h_top, iterations,
                            t_max, tol, out):  # pragma: no cover - compiled
    for i in range(dirs.shape[0]):
        out[i] = _ground_ray(origin[0], origin[1], origin[2], dirs[i, 0], dirs[i, 1], dirs[i, 2], normal,
                             offset, heights, rR, rt, rs, has_raster, h_top, iterations, t_max, tol)


@njit(cache=True, nogil=True)
def splat_points_kernel(points, radius_m, cam_T_city, K, near, far, min_px, max_px,
                        depth):  # pragma: no cover - compiled
    """Project city points and z-buffer them as disks of ``f * radius / z`` pixels (clipped)."""
    h, w = depth.shape
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    f = 0.5 * (fx + fy)
    for i in range(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        z = cam_T_city[2, 0] * px + cam_T_city[2, 1] * py + cam_T_city[2, 2] * pz + cam_T_city[2, 3]
        if not (z > near and z < far):  # most points are behind or beside the camera: reject before x, y
            continue
        x = cam_T_city[0, 0] * px + cam_T_city[0, 1] * py + cam_T_city[0, 2] * pz + cam_T_city[0, 3]
        y = cam_T_city[1, 0] * px + cam_T_city[1, 1] * py + cam_T_city[1, 2] * pz + cam_T_city[1, 3]
        u = fx * x / z + skew * y / z + cx
        v = fy * y / z + cy
        r = min(max(f * radius_m[i] / z, min_px), max_px)
        if u + r < 0.0 or v + r < 0.0 or u - r > w - 1 or v - r > h - 1:
            continue
        r2 = r * r
        for yy in range(max(int(math.floor(v - r)), 0), min(int(math.ceil(v + r)), h - 1) + 1):
            ddy = yy - v
            for xx in range(max(int(math.floor(u - r)), 0), min(int(math.ceil(u + r)), w - 1) + 1):
                ddx = xx - u
                if ddx * ddx + ddy * ddy <= r2 and z < depth[yy, xx]:
                    depth[yy, xx] = z


@njit(cache=True, nogil=True)
def inverse_depth32_kernel(depth, inv):  # pragma: no cover - compiled
    """float32 ``1 / z`` of a depth map (0 where empty: not finite) in one pass; returns the empty count."""
    n_empty = 0
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            if math.isfinite(z):
                inv[r, c] = np.float32(1.0 / z)
            else:
                inv[r, c] = np.float32(0.0)
                n_empty += 1
    return n_empty


@njit(cache=True, nogil=True)
def fill_closed_kernel(depth, closed, out):  # pragma: no cover - compiled
    """``out`` = ``depth``, except empty pixels where the closed inverse depth is > 0 get ``1 / closed``."""
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            if not math.isfinite(z) and closed[r, c] > 0:
                out[r, c] = 1.0 / np.float64(closed[r, c])
            else:
                out[r, c] = z


@njit(cache=True, inline="always")
def _corners(h, w, u, v):
    """Bilinear taps at (u, v) (pixel centres at integers), edge-clamped: x0, x1, y0, y1, ax, ay."""
    x = min(max(u, 0.0), w - 1.0)
    y = min(max(v, 0.0), h - 1.0)
    x0 = int(math.floor(x))
    y0 = int(math.floor(y))
    return x0, min(x0 + 1, w - 1), y0, min(y0 + 1, h - 1), x - x0, y - y0


@njit(cache=True, inline="always")
def _bilinear2(img, u, v):
    x0, x1, y0, y1, ax, ay = _corners(img.shape[0], img.shape[1], u, v)
    a = float(img[y0, x0]) * (1 - ax) + float(img[y0, x1]) * ax
    b = float(img[y1, x0]) * (1 - ax) + float(img[y1, x1]) * ax
    return a * (1 - ay) + b * ay


@njit(cache=True, inline="always")
def _bilinear3(img, u, v, c):
    x0, x1, y0, y1, ax, ay = _corners(img.shape[0], img.shape[1], u, v)
    a = float(img[y0, x0, c]) * (1 - ax) + float(img[y0, x1, c]) * ax
    b = float(img[y1, x0, c]) * (1 - ax) + float(img[y1, x1, c]) * ax
    return a * (1 - ay) + b * ay


@njit(cache=True, nogil=True)
def warp_source_kernel(depth_T, K_T, city_T_camT, box_index, motion, image, image_scale, K_S, cam_T_city_S,
                       centre_S, inv_depth, K_vis, valid, has_valid, time_w, near, rel_tol, inf_inv,
                       angle_sigma, border_px, min_w, acc, wsum, count):  # pragma: no cover - compiled
    """Add one source's weighted colours into ``acc`` / ``wsum`` / ``count`` (flat per target pixel)."""
    hT, wT = depth_T.shape
    hS, wS = image.shape[0], image.shape[1]
    hV, wV = inv_depth.shape
    sx = wV / wS
    sy = hV / hS
    cT = city_T_camT[:3, 3]
    for row in range(hT):
        for col in range(wT):
            i = row * wT + col
            # Target ray (z-normalised in the camera) in the city frame.
            ry = (row - K_T[1, 2]) / K_T[1, 1]
            rx = (col - K_T[0, 2] - K_T[0, 1] * ry) / K_T[0, 0]
            dx = city_T_camT[0, 0] * rx + city_T_camT[0, 1] * ry + city_T_camT[0, 2]
            dy = city_T_camT[1, 0] * rx + city_T_camT[1, 1] * ry + city_T_camT[1, 2]
            dz = city_T_camT[2, 0] * rx + city_T_camT[2, 1] * ry + city_T_camT[2, 2]
            z_T = depth_T[row, col]
            finite = math.isfinite(z_T)
            if finite:
                px = cT[0] + z_T * dx
                py = cT[1] + z_T * dy
                pz = cT[2] + z_T * dz
                tx, ty, tz = px - cT[0], py - cT[1], pz - cT[2]
                b = box_index[row, col]
                if b >= 0:
                    if b >= motion.shape[0] or not math.isfinite(motion[b, 0, 0]):
                        continue
                    qx = motion[b, 0, 0] * px + motion[b, 0, 1] * py + motion[b, 0, 2] * pz + motion[b, 0, 3]
                    qy = motion[b, 1, 0] * px + motion[b, 1, 1] * py + motion[b, 1, 2] * pz + motion[b, 1, 3]
                    qz = motion[b, 2, 0] * px + motion[b, 2, 1] * py + motion[b, 2, 2] * pz + motion[b, 2, 3]
                    px, py, pz = qx, qy, qz
                M = cam_T_city_S
                x = M[0, 0] * px + M[0, 1] * py + M[0, 2] * pz + M[0, 3]
                y = M[1, 0] * px + M[1, 1] * py + M[1, 2] * pz + M[1, 3]
                z = M[2, 0] * px + M[2, 1] * py + M[2, 2] * pz + M[2, 3]
                sx_, sy_, sz_ = px - centre_S[0], py - centre_S[1], pz - centre_S[2]
            else:
                x = cam_T_city_S[0, 0] * dx + cam_T_city_S[0, 1] * dy + cam_T_city_S[0, 2] * dz
                y = cam_T_city_S[1, 0] * dx + cam_T_city_S[1, 1] * dy + cam_T_city_S[1, 2] * dz
                z = cam_T_city_S[2, 0] * dx + cam_T_city_S[2, 1] * dy + cam_T_city_S[2, 2] * dz
                tx, ty, tz = dx, dy, dz
                sx_, sy_, sz_ = dx, dy, dz
            if not z > near:
                continue
            u = K_S[0, 0] * x / z + K_S[0, 1] * y / z + K_S[0, 2]
            v = K_S[1, 1] * y / z + K_S[1, 2]
            if not (u >= -0.5 and u <= wS - 0.5 and v >= -0.5 and v <= hS - 0.5):
                continue
            inv_s = _bilinear2(inv_depth, (u + 0.5) * sx - 0.5, (v + 0.5) * sy - 0.5)
            if finite:
                if 1.0 / z < (1.0 - rel_tol) * inv_s:
                    continue
            elif inv_s > inf_inv:
                continue
            if has_valid:
                vr = min(max(int(math.floor(v + 0.5)), 0), hS - 1)
                vc = min(max(int(math.floor(u + 0.5)), 0), wS - 1)
                if not valid[vr, vc]:
                    continue
            # Weights: ray angle, border distance, time offset (each floored at min_w).
            nt = math.sqrt(tx * tx + ty * ty + tz * tz)
            ns = math.sqrt(sx_ * sx_ + sy_ * sy_ + sz_ * sz_)
            c = (tx * sx_ + ty * sy_ + tz * sz_) / max(nt * ns, 1e-12)
            ang = math.acos(min(max(c, -1.0), 1.0))
            w_ang = max(math.exp(-0.5 * (ang / angle_sigma) ** 2), min_w)
            dist = min(min(u + 0.5, wS - 0.5 - u), min(v + 0.5, hS - 0.5 - v))
            w_border = max(min(dist / border_px, 1.0), min_w)
            wgt = w_ang * w_border * time_w
            for ch in range(3):
                acc[i, ch] += wgt * _bilinear3(image, u, v, ch) * image_scale
            wsum[i] += wgt
            count[i] += 1


@njit(cache=True, inline="always")
def _slab_t(ox, oy, oz, dx, dy, dz, hx, hy, hz, near):
    """First t >= near where the ray enters the centred box of half sizes (hx, hy, hz); inf on a miss.

    Axis-parallel components are handled explicitly (inside that slab: no constraint; outside:
    miss), so there is no 0 * inf NaN; a ray starting inside hits at ``near``.
    """
    t_enter = -math.inf
    t_exit = math.inf
    for a in range(3):
        if a == 0:
            o, d, h = ox, dx, hx
        elif a == 1:
            o, d, h = oy, dy, hy
        else:
            o, d, h = oz, dz, hz
        if abs(d) < DIR_EPS:
            if abs(o) > h:
                return math.inf
            continue
        t1 = (-h - o) / d
        t2 = (h - o) / d
        if t1 > t2:
            t1, t2 = t2, t1
        t_enter = max(t_enter, t1)
        t_exit = min(t_exit, t2)
    if t_enter <= t_exit and t_exit >= near:
        return max(t_enter, near)
    return math.inf


@njit(cache=True, nogil=True)
def ray_box_kernel(origin, dirs, half, near, out):  # pragma: no cover - compiled
    for i in range(dirs.shape[0]):
        out[i] = _slab_t(origin[0], origin[1], origin[2], dirs[i, 0], dirs[i, 1], dirs[i, 2],
                         half[0], half[1], half[2], near)


@njit(cache=True, nogil=True)
def box_depth_kernel(K, box_T_cam, half, rects, near, max_depth, depth, index):  # pragma: no cover - compiled
    """Nearest box face per pixel inside each box's rectangle (r0, r1, c0, c1 inclusive; r1 < r0: skip)."""
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    for b in range(box_T_cam.shape[0]):
        R = box_T_cam[b]
        ox, oy, oz = R[0, 3], R[1, 3], R[2, 3]
        for row in range(rects[b, 0], rects[b, 1] + 1):
            ry = (row - cy) / fy
            for col in range(rects[b, 2], rects[b, 3] + 1):
                rx = (col - cx - skew * ry) / fx
                dx = R[0, 0] * rx + R[0, 1] * ry + R[0, 2]
                dy = R[1, 0] * rx + R[1, 1] * ry + R[1, 2]
                dz = R[2, 0] * rx + R[2, 1] * ry + R[2, 2]
                t = _slab_t(ox, oy, oz, dx, dy, dz, half[b, 0], half[b, 1], half[b, 2], near)
                if t < depth[row, col] and t <= max_depth:
                    depth[row, col] = t
                    index[row, col] = b


@njit(cache=True, nogil=True)
def ground_depth_kernel(K, city_T_cam, normal, offset, heights, rR, rt, rs, has_raster, h_top, iterations,
                        t_max, tol, near, max_depth, depth):  # pragma: no cover - compiled
    """Camera z of the ground for every pixel (rays generated here; ``inf`` outside [near, max_depth]).

    With a raster, rays are solved in full only on a grid every ``GROUND_BLOCK`` pixels (and where a
    block's corners do not all hit the ground); a pixel inside a block takes the bilinear interpolation of
    its corners' inverse depth (exact on a plane) and, if the ray passes within ``GROUND_PREDICT_TOL_M``
    of the ground there, one fixed-point step from it (the residual already computed gives it): one
    height lookup instead of four or more. Otherwise the pixel is solved in full.
    """
    h, w = depth.shape
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    ox, oy, oz = city_T_cam[0, 3], city_T_cam[1, 3], city_T_cam[2, 3]
    S = GROUND_BLOCK if (has_raster and iterations > 0) else 1
    n_r = (h - 1 + S - 1) // S + 1  # grid rows min(k S, h - 1)
    n_c = (w - 1 + S - 1) // S + 1
    grid = np.empty((n_r, n_c))
    for kr in range(n_r):
        row = min(kr * S, h - 1)
        ry = (row - cy) / fy
        for kc in range(n_c):
            col = min(kc * S, w - 1)
            rx = (col - cx - skew * ry) / fx
            dx = city_T_cam[0, 0] * rx + city_T_cam[0, 1] * ry + city_T_cam[0, 2]
            dy = city_T_cam[1, 0] * rx + city_T_cam[1, 1] * ry + city_T_cam[1, 2]
            dz = city_T_cam[2, 0] * rx + city_T_cam[2, 1] * ry + city_T_cam[2, 2]
            grid[kr, kc] = _ground_ray(ox, oy, oz, dx, dy, dz, normal, offset, heights, rR, rt, rs,
                                       has_raster, h_top, iterations, t_max, tol)
    for row in range(h):
        ry = (row - cy) / fy
        kr = min(row // S, n_r - 2) if n_r > 1 else 0
        r_a = min(kr * S, h - 1)
        r_b = min((kr + 1) * S, h - 1) if n_r > 1 else r_a
        wy = (row - r_a) / (r_b - r_a) if r_b > r_a else 0.0
        for col in range(w):
            rx = (col - cx - skew * ry) / fx
            kc = min(col // S, n_c - 2) if n_c > 1 else 0
            c_a = min(kc * S, w - 1)
            c_b = min((kc + 1) * S, w - 1) if n_c > 1 else c_a
            wx = (col - c_a) / (c_b - c_a) if c_b > c_a else 0.0
            if (row == r_a or row == r_b) and (col == c_a or col == c_b):
                t = grid[kr + (1 if row == r_b and r_b != r_a else 0),
                         kc + (1 if col == c_b and c_b != c_a else 0)]
            else:
                dx = city_T_cam[0, 0] * rx + city_T_cam[0, 1] * ry + city_T_cam[0, 2]
                dy = city_T_cam[1, 0] * rx + city_T_cam[1, 1] * ry + city_T_cam[1, 2]
                dz = city_T_cam[2, 0] * rx + city_T_cam[2, 1] * ry + city_T_cam[2, 2]
                t00, t01 = grid[kr, kc], grid[kr, min(kc + 1, n_c - 1)]
                t10, t11 = grid[min(kr + 1, n_r - 1), kc], grid[min(kr + 1, n_r - 1), min(kc + 1, n_c - 1)]
                t = math.inf
                solved = False
                if (math.isfinite(t00) and math.isfinite(t01) and math.isfinite(t10) and math.isfinite(t11)
                        and dz < 0.0):
                    inv = ((1.0 - wy) * ((1.0 - wx) / t00 + wx / t01) + wy * ((1.0 - wx) / t10 + wx / t11))
                    if inv > 0.0:
                        tp = 1.0 / inv
                        hp = _ground_height(ox + tp * dx, oy + tp * dy, normal, offset, heights, rR, rt, rs,
                                            has_raster)
                        res = oz + tp * dz - hp
                        if abs(res) <= GROUND_PREDICT_TOL_M:  # then one fixed-point step (for free)
                            t = tp - res / dz
                            solved = t >= 0.0
                if not solved:
                    t = _ground_ray(ox, oy, oz, dx, dy, dz, normal, offset, heights, rR, rt, rs, has_raster,
                                    h_top, iterations, t_max, tol)
            depth[row, col] = t if (t >= near and t <= max_depth) else math.inf


@njit(cache=True, nogil=True)
def inside_boxes_kernel(points, box_T_frame, lo, hi, out):  # pragma: no cover - compiled
    """``out[b, i]``: point i (frame coordinates) lies in box b's frame within ``lo[b] <= p <= hi[b]``."""
    for b in range(box_T_frame.shape[0]):
        R = box_T_frame[b]
        for i in range(points.shape[0]):
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            px = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + R[0, 3]
            if px < lo[b, 0] or px > hi[b, 0]:
                continue
            py = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + R[1, 3]
            if py < lo[b, 1] or py > hi[b, 1]:
                continue
            pz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + R[2, 3]
            out[b, i] = pz >= lo[b, 2] and pz <= hi[b, 2]


@njit(cache=True, nogil=True)
def ground_heights_kernel(xy, normal, offset, heights, rR, rt, rs, has_raster, out):  # pragma: no cover
    """Ground z at each city (x, y): the raster's bilinear height where it has one, else the plane's."""
    for i in range(xy.shape[0]):
        out[i] = _ground_height(xy[i, 0], xy[i, 1], normal, offset, heights, rR, rt, rs, has_raster)


@njit(cache=True, nogil=True)
def blend_to_uint8_kernel(acc, wsum, img8, hole):  # pragma: no cover - compiled
    """Blended colours straight to uint8: ``clip(rint(float32(acc / wsum) * 255))``, the same float64
    division, float32 rounding and float32 product as the numpy steps it replaces; 0 where ``wsum`` is 0.
    ``hole`` is 1 where ``float32(wsum)`` is 0 (``WarpResult.coverage``); returns the hole count."""
    h, w = hole.shape
    k = np.float32(255.0)
    zero = np.float32(0.0)
    n_holes = 0
    for r in range(h):
        for c in range(w):
            i = r * w + c
            ws = wsum[i]
            covered = np.float32(ws) > zero
            hole[r, c] = 0 if covered else 1
            n_holes += 0 if covered else 1
            d = max(ws, 1e-300)
            for ch in range(3):
                v = np.rint(np.float32(acc[i, ch] / d) * k) if ws > 0.0 else zero
                img8[r, c, ch] = np.uint8(min(max(v, zero), k))
    return n_holes
