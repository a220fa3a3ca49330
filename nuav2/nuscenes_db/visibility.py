"""How much of each annotated box the output cameras see: nuScenes' ``visibility_token``.

nuScenes defines visibility as the fraction of an object visible in all six camera images, in
four bins (0-40, 40-60, 60-80, 80-100 %). AV2 has no such field, so it is measured here, per
sample, in the cameras written for that sample: each box is sampled by rays over its image
rectangle in every camera; a ray that enters the box counts towards the box's area (weighted by
the pixels it stands for), and it is visible unless it meets another box first, passes through
the ego body's mask, or a LiDAR point of the unlabelled scene (a wall, a pole, a tree; not the
ground, not inside any box) lies clearly in front of it in its cell. A box no camera sees scores
0 (bin "1"). The boxes stand in for the objects' shapes, so a ray through a box's empty corner
counts as the object's.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numba import njit

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec

NEAR_M = 0.1  # rays start this far in front of the camera
BOX_MARGIN_M = 0.3  # LiDAR points this close to a box belong to it (label error), not to an occluder
GROUND_CELL_M = 2.0  # ground level is estimated per cell of this size ...
GROUND_QUANTILE = 0.1  # ... as this quantile of its points' heights (robust to LiDAR noise below it)
GROUND_BAND_M = 0.35  # points less than this above their cell's ground level are ground
OCCLUDER_MARGIN_M = 0.5  # a LiDAR point occludes a ray only when this much (+2 % of depth) nearer
BOX_ORDER_M = 0.05  # a box hides another's ray when it is entered this much nearer
# A box hides others with its central part only: bodies do not fill their boxes (rounded roofs and
# bonnets, wheel arches, a cyclist's frame), so what is behind shows past the box's edges.
OCCLUDER_CORE = 0.9
MAX_RAYS_PER_SIDE = 16
# nuScenes bins: token "1" below 40 %, "2" below 60 %, "3" below 80 %, "4" from 80 % on.
BIN_EDGES = (0.4, 0.6, 0.8)


@dataclass(frozen=True)
class VisibilityCamera:
    """One output camera: intrinsics at ``width`` x ``height``, its pose in the boxes' ego frame and
    the ego body's pixel mask (or None)."""

    K: F64
    ego_T_cam: F64
    width: int
    height: int
    body_mask: np.ndarray | None = None


def cameras_in_source_ego(cameras: Iterable[CameraSpec], egoS_T_egoT: F64) -> list[VisibilityCamera]:
    """The output rig's cameras posed in the source ego frame (the frame of the boxes and the sweep),
    with their ego-body masks."""
    return [VisibilityCamera(c.K, egoS_T_egoT @ c.ego_T_cam, c.width, c.height,
                             c.ego_mask() if c.ego_mask_polygons else None) for c in cameras]


def visibility_token(fraction: float) -> str:
    """The nuScenes visibility token ("1".."4") of a visible fraction in [0, 1]."""
    return str(1 + int(np.searchsorted(BIN_EDGES, float(fraction), side="right")))


def occluder_points(xyz_ego: F64, ego_T_box: F64, size_lwh: F64) -> F64:
    """The sweep's points that can hide a box: finite, off the ground, outside every box (+margin)."""
    xyz = np.asarray(xyz_ego, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    if not len(xyz):
        return xyz
    xyz = xyz[~_near_ground(xyz)]
    if len(ego_T_box) and len(xyz):
        inside = _inside_any_box(np.ascontiguousarray(xyz), np.ascontiguousarray(T_inverse(ego_T_box)),
                                 np.ascontiguousarray(0.5 * np.asarray(size_lwh, np.float64) + BOX_MARGIN_M))
        xyz = xyz[~inside]
    return xyz


def _near_ground(xyz: F64) -> np.ndarray:
    """Points within GROUND_BAND_M of their cell's low height quantile (slopes: per 2 m cell)."""
    cells = np.floor(xyz[:, :2] / GROUND_CELL_M).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    return _near_ground_kernel(key, np.ascontiguousarray(xyz[:, 2]), int(key.max()) + 1)


@njit(cache=True, nogil=True)
def _near_ground_kernel(key, z, n_cells):  # pragma: no cover
    """Counting sort by cell, then each cell's heights sorted for its GROUND_QUANTILE."""
    start = np.zeros(n_cells + 1, np.int64)
    for i in range(key.shape[0]):
        start[key[i] + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    zs = np.empty(key.shape[0])
    for i in range(key.shape[0]):
        zs[fill[key[i]]] = z[i]
        fill[key[i]] += 1
    low = np.empty(n_cells)
    for c in range(n_cells):
        n = start[c + 1] - start[c]
        if n:
            cell_z = np.sort(zs[start[c]:start[c + 1]])
            low[c] = cell_z[int(n * GROUND_QUANTILE)]
    out = np.empty(key.shape[0], np.bool_)
    for i in range(key.shape[0]):
        out[i] = z[i] < low[key[i]] + GROUND_BAND_M
    return out


@njit(cache=True, nogil=True)
def _inside_any_box(xyz, box_T_ego, half):  # pragma: no cover
    """Per point: inside at least one box grown to ``half`` (bounding-sphere test first)."""
    n, nb = xyz.shape[0], box_T_ego.shape[0]
    out = np.zeros(n, np.bool_)
    centre = np.empty((nb, 3))
    radius2 = np.empty(nb)
    for b in range(nb):
        R = box_T_ego[b, :3, :3]
        for k in range(3):  # the box centre in the ego frame: -R^T t
            centre[b, k] = -(R[0, k] * box_T_ego[b, 0, 3] + R[1, k] * box_T_ego[b, 1, 3]
                             + R[2, k] * box_T_ego[b, 2, 3])
        radius2[b] = half[b, 0] ** 2 + half[b, 1] ** 2 + half[b, 2] ** 2
    for i in range(n):
        for b in range(nb):
            dx, dy, dz = xyz[i, 0] - centre[b, 0], xyz[i, 1] - centre[b, 1], xyz[i, 2] - centre[b, 2]
            if dx * dx + dy * dy + dz * dz > radius2[b]:
                continue
            inside = True
            for k in range(3):
                local = (box_T_ego[b, k, 0] * xyz[i, 0] + box_T_ego[b, k, 1] * xyz[i, 1]
                         + box_T_ego[b, k, 2] * xyz[i, 2] + box_T_ego[b, k, 3])
                if abs(local) > half[b, k]:
                    inside = False
                    break
            if inside:
                out[i] = True
                break
    return out


def box_visibility(ego_T_box: F64, size_lwh: F64, cameras: list[VisibilityCamera], occluders_ego: F64,
                   occluder_core: float = OCCLUDER_CORE) -> F64:
    """(B,) visible fraction of each box over all ``cameras`` (0 where no camera sees it).

    Boxes, cameras and occluder points (``occluder_points``) share one ego frame. A box hides others
    with its central ``occluder_core`` part; boxes that intersect (a rider's box and its bicycle's)
    never hide each other, nor does a box holding the camera (a label error: the ego is in none)."""
    ego_T_box = np.asarray(ego_T_box, np.float64).reshape(-1, 4, 4)
    half = np.ascontiguousarray(0.5 * np.asarray(size_lwh, np.float64).reshape(-1, 3))
    core = np.ascontiguousarray(half * float(occluder_core))
    box_T_ego = np.ascontiguousarray(T_inverse(ego_T_box))
    overlap = _boxes_overlap(np.ascontiguousarray(ego_T_box), half)
    visible = np.zeros(len(ego_T_box))
    total = np.zeros(len(ego_T_box))
    if not len(ego_T_box):
        return visible
    occ = np.ascontiguousarray(np.asarray(occluders_ego, np.float64).reshape(-1, 3))
    for cam in cameras:
        cam_T_ego = T_inverse(np.asarray(cam.ego_T_cam, np.float64))
        cam_T_box = np.ascontiguousarray(cam_T_ego @ ego_T_box)
        # The camera centre in each box's frame: where every ray into that box starts.
        cam_in_box = box_T_ego[:, :3, :3] @ np.asarray(cam.ego_T_cam, np.float64)[:3, 3] + box_T_ego[:, :3, 3]
        skip = overlap | np.all(np.abs(cam_in_box) <= half, axis=1)[None, :]
        K = np.asarray(cam.K, np.float64)
        w, h = int(cam.width), int(cam.height)
        cell = max(2, w // 80)
        zbuf = _occluder_depth(occ, np.ascontiguousarray(cam_T_ego), np.ascontiguousarray(K), w, h, cell)
        has_mask = cam.body_mask is not None
        mask = np.ascontiguousarray(cam.body_mask, np.bool_) if has_mask else np.zeros((1, 1), np.bool_)
        _camera_pass(cam_T_box, np.ascontiguousarray(cam_in_box), half, core, skip, np.ascontiguousarray(K),
                     w, h, zbuf, cell, mask, has_mask, visible, total)
    return np.where(total > 0, visible / np.where(total > 0, total, 1.0), 0.0).clip(0.0, 1.0)


@njit(cache=True, nogil=True)
def _occluder_depth(occ_ego, cam_T_ego, K, width, height, cell):  # pragma: no cover
    """(cells,) nearest occluder z-depth per ``cell`` x ``cell`` pixel block (inf where none)."""
    gw, gh = (width + cell - 1) // cell, (height + cell - 1) // cell
    zbuf = np.full(gw * gh, np.inf)
    for i in range(occ_ego.shape[0]):
        # scalars, not a per-point np.empty(3): the heap allocation was 5/6 of the kernel's time
        x, y, z = occ_ego[i, 0], occ_ego[i, 1], occ_ego[i, 2]
        pz = cam_T_ego[2, 0] * x + cam_T_ego[2, 1] * y + cam_T_ego[2, 2] * z + cam_T_ego[2, 3]
        if pz <= NEAR_M:
            continue
        px = cam_T_ego[0, 0] * x + cam_T_ego[0, 1] * y + cam_T_ego[0, 2] * z + cam_T_ego[0, 3]
        py = cam_T_ego[1, 0] * x + cam_T_ego[1, 1] * y + cam_T_ego[1, 2] * z + cam_T_ego[1, 3]
        u = K[0, 0] * px / pz + K[0, 1] * py / pz + K[0, 2]
        v = K[1, 1] * py / pz + K[1, 2]
        if u < 0.0 or u >= width or v < 0.0 or v >= height:
            continue
        c = int(v // cell) * gw + int(u // cell)
        if pz < zbuf[c]:
            zbuf[c] = pz
    return zbuf


@njit(cache=True, nogil=True)
def _entry(cam_T_box, cam_in_box, half, b, dx, dy, dz):  # pragma: no cover
    """Ray parameter (= camera z-depth, the ray's z is 1) where the camera ray (dx, dy, dz) enters box
    ``b``, NEAR_M if the camera is inside it, -1 if it misses."""
    t_lo, t_hi = NEAR_M, np.inf
    for k in range(3):
        # Box frame: the ray starts at the camera centre there and runs along R^T ray (R = cam_T_box's).
        o = cam_in_box[b, k]
        d = cam_T_box[b, 0, k] * dx + cam_T_box[b, 1, k] * dy + cam_T_box[b, 2, k] * dz
        if abs(d) < 1e-12:
            if abs(o) > half[b, k]:
                return -1.0
            continue
        t1, t2 = (-half[b, k] - o) / d, (half[b, k] - o) / d
        if t1 > t2:
            t1, t2 = t2, t1
        t_lo, t_hi = max(t_lo, t1), min(t_hi, t2)
        if t_lo > t_hi:
            return -1.0
    return t_lo


@njit(cache=True, nogil=True)
def _camera_pass(cam_T_box, cam_in_box, half, core, skip, K, width, height, zbuf, cell, mask, check_mask,
                 visible, total):  # pragma: no cover
    """Adds each box's sampled area in this camera to ``total`` and its unhidden part to ``visible``."""
    nb = cam_T_box.shape[0]
    gw = (width + cell - 1) // cell
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    rect = np.empty((nb, 4))  # u0, u1, v0, v1; u0 >= u1: not in this camera
    for b in range(nb):
        u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
        behind, ahead = 0, 0
        for c in range(8):
            sx = half[b, 0] if c & 1 else -half[b, 0]
            sy = half[b, 1] if c & 2 else -half[b, 1]
            sz = half[b, 2] if c & 4 else -half[b, 2]
            p = np.empty(3)
            for k in range(3):
                p[k] = (cam_T_box[b, k, 0] * sx + cam_T_box[b, k, 1] * sy + cam_T_box[b, k, 2] * sz
                        + cam_T_box[b, k, 3])
            if p[2] <= NEAR_M:
                behind += 1
                continue
            ahead += 1
            u = fx * p[0] / p[2] + skew * p[1] / p[2] + cx
            v = fy * p[1] / p[2] + cy
            u0, u1, v0, v1 = min(u0, u), max(u1, u), min(v0, v), max(v1, v)
        if ahead == 0:
            u0, u1, v0, v1 = 0.0, 0.0, 0.0, 0.0
        elif behind > 0:  # straddles the camera plane: its image may reach any border
            u0, u1, v0, v1 = 0.0, float(width), 0.0, float(height)
        rect[b, 0], rect[b, 1] = max(u0, 0.0), min(u1, float(width))
        rect[b, 2], rect[b, 3] = max(v0, 0.0), min(v1, float(height))
    for b in range(nb):
        rw, rh = rect[b, 1] - rect[b, 0], rect[b, 3] - rect[b, 2]
        if rw <= 0.0 or rh <= 0.0:
            continue
        n = min(MAX_RAYS_PER_SIDE, max(3, int(np.ceil(max(rw, rh) / cell))))
        weight = rw * rh / (n * n)
        for i in range(n):
            u = rect[b, 0] + (i + 0.5) * rw / n
            for j in range(n):
                v = rect[b, 2] + (j + 0.5) * rh / n
                dy = (v - cy) / fy
                dx = (u - cx - skew * dy) / fx
                t = _entry(cam_T_box, cam_in_box, half, b, dx, dy, 1.0)
                if t < 0.0:
                    continue
                total[b] += weight
                if check_mask and mask[min(int(v), height - 1), min(int(u), width - 1)]:
                    continue
                if zbuf[min(int(v) // cell, (height - 1) // cell) * gw + min(int(u) // cell, gw - 1)] \
                        < t - OCCLUDER_MARGIN_M - 0.02 * t:
                    continue
                hidden = False
                for o in range(nb):
                    if o == b or skip[b, o] or u < rect[o, 0] or u > rect[o, 1] or v < rect[o, 2] \
                            or v > rect[o, 3]:
                        continue
                    to = _entry(cam_T_box, cam_in_box, core, o, dx, dy, 1.0)
                    if to >= 0.0 and to < t - BOX_ORDER_M:
                        hidden = True
                        break
                if not hidden:
                    visible[b] += weight


@njit(cache=True, nogil=True)
def _boxes_overlap(ego_T_box, half):  # pragma: no cover
    """(B, B) whether two oriented boxes intersect (separating-axis test over the 15 axes)."""
    nb = ego_T_box.shape[0]
    out = np.zeros((nb, nb), np.bool_)
    axes = np.empty((15, 3))
    for a in range(nb):
        for b in range(a + 1, nb):
            d = ego_T_box[b, :3, 3] - ego_T_box[a, :3, 3]
            if np.sqrt(np.sum(d * d)) > np.sqrt(np.sum(half[a] ** 2)) + np.sqrt(np.sum(half[b] ** 2)):
                continue
            for i in range(3):
                axes[i] = ego_T_box[a, :3, i]
                axes[3 + i] = ego_T_box[b, :3, i]
                for j in range(3):
                    axes[6 + 3 * i + j] = np.cross(ego_T_box[a, :3, i], ego_T_box[b, :3, j])
            separated = False
            for k in range(15):
                n = axes[k]
                norm = np.sqrt(np.sum(n * n))
                if norm < 1e-9:
                    continue
                ra, rb = 0.0, 0.0
                for i in range(3):
                    ra += half[a, i] * abs(np.sum(ego_T_box[a, :3, i] * n))
                    rb += half[b, i] * abs(np.sum(ego_T_box[b, :3, i] * n))
                if abs(np.sum(d * n)) > ra + rb:
                    separated = True
                    break
            out[a, b] = out[b, a] = not separated
    return out
