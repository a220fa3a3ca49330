"""Surface colours of the synthetic world's solids, per material, evaluated at a hit point.

Materials 0-2 are the original box patterns (facade windows, box car with glass and tyres,
pedestrian clothes) and stay exactly as they were, so the ``easy`` world renders unchanged.
The others dress shaped content: car paint and cabins (glass sides, painted roof), tyres with
hubs, bus window bands, cargo boxes, skin, clothes, foliage and bark (world-anchored noise),
metal, sign plates and traffic-light housings (lit lamps are emissive, not sun-shaded), and
facades whose floor height, window pitch and storefronts vary per building (``params``).
"""

from __future__ import annotations

import numba
import numpy as np

from nuav2.synth.boxes import KIND_BUILDING, KIND_PEDESTRIAN, KIND_VEHICLE

MAT_PAINT, MAT_CABIN, MAT_TYRE, MAT_BUS, MAT_CARGO, MAT_SKIN, MAT_CLOTH = 3, 4, 5, 6, 7, 8, 9
MAT_FOLIAGE, MAT_BARK, MAT_METAL, MAT_SIGN, MAT_SIGNAL, MAT_FACADE = 10, 11, 12, 13, 14, 15
GLASS = np.array([52.0, 62.0, 80.0])
CAR_GLASS = np.array([30.0, 36.0, 44.0])
TYRE = np.array([28.0, 28.0, 30.0])
HUB = np.array([150.0, 150.0, 155.0])
ROOF = np.array([118.0, 118.0, 115.0])
TROUSERS = np.array([45.0, 50.0, 75.0])
SKIN = np.array([205.0, 170.0, 140.0])
METAL = np.array([120.0, 124.0, 128.0])
HOUSING = np.array([38.0, 40.0, 36.0])
LAMPS = np.array([[230.0, 40.0, 30.0], [245.0, 170.0, 30.0], [60.0, 230.0, 120.0]])
LAMP_OFF = np.array([55.0, 50.0, 45.0])
FLOOR_M, WINDOW_PITCH_M = 3.2, 3.0
REFLECTIVITY = {
    KIND_BUILDING: 28,
    KIND_VEHICLE: 45,
    KIND_PEDESTRIAN: 30,
    MAT_PAINT: 50,
    MAT_CABIN: 8,
    MAT_TYRE: 6,
    MAT_BUS: 45,
    MAT_CARGO: 60,
    MAT_SKIN: 30,
    MAT_CLOTH: 25,
    MAT_FOLIAGE: 20,
    MAT_BARK: 15,
    MAT_METAL: 70,
    MAT_SIGN: 200,
    MAT_SIGNAL: 20,
    MAT_FACADE: 28,
}


@numba.njit(cache=True, inline="always")
def _hash3(ix, iy, iz):
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF) / 65535.0


@numba.njit(cache=True)
def value_noise3(x, y, z):
    """Smooth value noise in [0, 1] on a unit lattice (trilinear, smoothstep weights)."""
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
    u, v, w = x - fx, y - fy, z - fz
    u, v, w = u * u * (3 - 2 * u), v * v * (3 - 2 * v), w * w * (3 - 2 * w)
    acc = 0.0
    for dz in range(2):
        for dy in range(2):
            for dx in range(2):
                wt = (u if dx else 1 - u) * (v if dy else 1 - v) * (w if dz else 1 - w)
                acc += wt * _hash3(ix + dx, iy + dy, iz + dz)
    return acc


@numba.njit(cache=True, inline="always")
def legacy_color(kind, color, axis, u, half_u, v, height):
    """The original box patterns: facade windows, box car glass and tyres, pedestrian clothes.

    ``u`` is the horizontal coordinate on a side face (|u| <= half_u), ``v`` the height above
    the box bottom; axis 2 is the top face."""
    r, g, b = color[0], color[1], color[2]
    side = axis != 2
    if kind == KIND_BUILDING:
        if not side:
            return ROOF[0], ROOF[1], ROOF[2]
        vf = v % FLOOR_M
        uw = (u + half_u) % WINDOW_PITCH_M
        if 0.9 < uw < 2.1 and 1.0 < vf < 2.4 and abs(u) < half_u - 0.8 and v < height - 0.8:
            return GLASS[0], GLASS[1], GLASS[2]
        if vf < 0.2 and v > 0.5:
            return 0.8 * r, 0.8 * g, 0.8 * b
    elif kind == KIND_VEHICLE:
        if not side:
            return 0.85 * r, 0.85 * g, 0.85 * b
        if v < 0.2 * height:
            return TYRE[0], TYRE[1], TYRE[2]
        if 0.6 * height < v < 0.92 * height and abs(u) < 0.8 * half_u:
            return CAR_GLASS[0], CAR_GLASS[1], CAR_GLASS[2]
    elif kind == KIND_PEDESTRIAN:
        if v < 0.47 * height:
            return TROUSERS[0], TROUSERS[1], TROUSERS[2]
        if v > 0.87 * height:
            return SKIN[0], SKIN[1], SKIN[2]
    return r, g, b


@numba.njit(cache=True)
def material_color(kind, color, params, axis, u, half_u, v, height, bx, by, bz, half, nz_box, wx, wy, wz):
    """(r, g, b, emissive) of a solid's surface point.

    ``bx, by, bz``: the point in the solid's frame (``half``: its half size); ``nz_box``: the z of its
    normal there; ``wx, wy, wz``: the point in the local frame (for world-anchored noise)."""
    if kind <= KIND_PEDESTRIAN:
        r, g, b = legacy_color(kind, color, axis, u, half_u, v, height)
        return r, g, b, False
    r, g, b = color[0], color[1], color[2]
    if kind == MAT_PAINT:
        return r, g, b, False
    if kind == MAT_CABIN:
        if nz_box > 0.75:
            return r, g, b, False
        return CAR_GLASS[0], CAR_GLASS[1], CAR_GLASS[2], False
    if kind == MAT_TYRE:
        if abs(by) > 0.8 * half[1] and bx * bx + bz * bz < (0.55 * half[0]) ** 2:
            return HUB[0], HUB[1], HUB[2], False
        return TYRE[0], TYRE[1], TYRE[2], False
    if kind == MAT_BUS:
        if nz_box < 0.75 and 0.45 * height < v < 0.85 * height:
            front = bx > half[0] - 0.3
            if front or abs(bx) < half[0] - 0.5:
                return CAR_GLASS[0], CAR_GLASS[1], CAR_GLASS[2], False
        return r, g, b, False
    if kind == MAT_CARGO:
        if nz_box < 0.75 and (bx + half[0]) % 1.2 < 0.05:
            return 0.82 * r, 0.82 * g, 0.82 * b, False
        return r, g, b, False
    if kind == MAT_SKIN:
        return SKIN[0], SKIN[1], SKIN[2], False
    if kind == MAT_CLOTH:
        return r, g, b, False
    if kind == MAT_FOLIAGE or kind == MAT_BARK:
        n = value_noise3(wx * 2.5, wy * 2.5, wz * 2.5)
        n = 0.6 * n + 0.4 * value_noise3(wx * 7.0, wy * 7.0, wz * 7.0)
        k = 0.65 + 0.7 * n
        return r * k, g * k, b * k, False
    if kind == MAT_METAL:
        return r, g, b, False
    if kind == MAT_SIGN:
        if axis == 0 and bx > 0.0:  # the face toward +x carries the sign
            return r, g, b, False
        return METAL[0], METAL[1], METAL[2], False
    if kind == MAT_SIGNAL:
        if axis == 0 and bx > 0.0:
            for k in range(3):
                cz = (1 - k) * 0.62 * half[2]
                if by * by + (bz - cz) ** 2 < (0.62 * half[1]) ** 2:
                    if k == int(params[0]):
                        return LAMPS[k, 0], LAMPS[k, 1], LAMPS[k, 2], True
                    return LAMP_OFF[0], LAMP_OFF[1], LAMP_OFF[2], False
        return HOUSING[0], HOUSING[1], HOUSING[2], False
    if kind == MAT_FACADE:
        if axis == 2:
            return ROOF[0] * params[3], ROOF[1] * params[3], ROOF[2] * params[3], False
        floor_h, pitch, win = params[0], params[1], params[2]
        ground = v < floor_h
        vf = v % floor_h
        uw = (u + half_u) % pitch
        shop = ground and abs(u) < half_u - 1.0 and 0.3 < vf < floor_h - 0.5 and uw > 0.25 * pitch
        inside = abs(u) < half_u - 0.6 and v < height - 0.8
        if shop or (not ground and inside and uw > (1 - win) * pitch and 0.28 * floor_h < vf < 0.8 * floor_h):
            shade = 0.85 + 0.3 * _hash3(np.int64((u + half_u) // pitch), np.int64(v // floor_h), 7)
            return GLASS[0] * shade, GLASS[1] * shade, GLASS[2] * shade, False
        if vf < 0.15:
            return 0.8 * r, 0.8 * g, 0.8 * b, False
        n = 0.92 + 0.16 * value_noise3(wx * 0.7, wy * 0.7, wz * 0.7)
        return r * n, g * n, b * n, False
    return r, g, b, False
