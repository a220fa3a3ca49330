"""Target-view depth proxy: which surface each pixel's ray hits, built only from what the log has.

Three layers meet in a z-buffer (nearest wins): the ground (AV2's ground-height raster refined
from a plane, or the plane alone), LiDAR points aggregated over nearby sweeps (splatted as
disks sized by their footprint, small holes closed), and annotated boxes (ray/box slabs). Each
pixel also records the box it hit, so an actor's points can travel with its box to another
time. Depth is camera z in metres (float64); ``inf`` means "no surface within ``max_depth_m``"
and is treated downstream as a point at infinity (a pure direction).

Rays are z-normalised in the camera (``K^-1 [u, v, 1]``), so a ray parameter *is* camera z.
Pixel centres sit at integer (u, v), as in :meth:`nuav2.rig.CameraSpec.scaled`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec
from nuav2.scene import GroundHeightRaster
from nuav2.warp._kernels import (
    box_depth_kernel,
    fill_closed_kernel,
    ground_depth_kernel,
    ground_heights_kernel,
    ground_intersect_kernel,
    inverse_depth32_kernel,
    ray_box_kernel,
    splat_points_kernel,
)

NO_BOX = -1
GROUND_T_MAX = 1e4  # the ground search along a ray stops here (metres of ray parameter)
GROUND_TOL_M = 0.02  # a raster hit is accepted when the ray is this close to the surface


@dataclass(frozen=True)
class ProxyConfig:
    """Knobs of the depth proxy (metres / pixels)."""

    near_m: float = 0.1
    max_depth_m: float = 300.0
    min_splat_px: float = 0.75  # smallest lidar disk radius
    max_splat_px: float = 6.0  # largest lidar disk radius (near points)
    fill_px: int = 5  # lidar holes up to about this wide are closed
    ground_iterations: int = 3  # raster refinement steps of the ground intersection

    def __post_init__(self) -> None:
        if not 0 < self.near_m < self.max_depth_m:
            raise ValueError(f"ProxyConfig needs 0 < near_m < max_depth_m, got {self.near_m}, "
                             f"{self.max_depth_m}")
        if not 0 < self.min_splat_px <= self.max_splat_px:
            raise ValueError("ProxyConfig needs 0 < min_splat_px <= max_splat_px")
        if self.fill_px < 0 or self.ground_iterations < 0:
            raise ValueError("ProxyConfig fill_px and ground_iterations must be >= 0")


@dataclass(frozen=True)
class GroundSurface:
    """The ground as a plane ``normal . x = offset`` (city frame), optionally refined by a height raster.

    Where the raster has no value (NaN, out of bounds) the plane's height is used instead.
    """

    normal: F64  # (3,) unit, z > 0
    offset: float
    raster: GroundHeightRaster | None = None

    @staticmethod
    def horizontal(z: float, raster: GroundHeightRaster | None = None) -> GroundSurface:
        return GroundSurface(np.array([0.0, 0.0, 1.0]), float(z), raster)

    @staticmethod
    def under_ego(city_T_ego: F64, origin_height_m: float, raster: GroundHeightRaster | None = None
                  ) -> GroundSurface:
        """Plane through the point ``origin_height_m`` below the ego origin, tilted with the ego's z axis."""
        city_T_ego = np.asarray(city_T_ego, dtype=np.float64)
        n = city_T_ego[:3, 2] / np.linalg.norm(city_T_ego[:3, 2])
        if n[2] <= 0.1:
            raise ValueError("ego z axis is not pointing up; cannot place a ground plane under it")
        foot = city_T_ego[:3, 3] - origin_height_m * n
        return GroundSurface(n, float(n @ foot), raster)

    def plane_height(self, xy: F64) -> F64:
        """z of the plane above (N, 2) city xy."""
        n = self.normal
        return (self.offset - xy[:, 0] * n[0] - xy[:, 1] * n[1]) / n[2]

    def height(self, xy: F64) -> F64:
        """Ground z at (N, 2) city xy: the raster (bilinear, as :mod:`nuav2.terrain`) where it has a value,
        else the plane (compiled: every sweep's points are tested against it)."""
        xy = np.ascontiguousarray(np.asarray(xy, np.float64).reshape(-1, 2))
        out = np.empty(len(xy))
        ground_heights_kernel(xy, *self.kernel_args(), out)
        return out

    def intersect(self, origin: F64, dirs: F64, iterations: int = 3, t_max: float = GROUND_T_MAX,
                  tol_m: float = GROUND_TOL_M) -> F64:
        """Ray parameter t >= 0 where ``origin + t dirs`` meets the ground; ``inf`` where it never does.

        Plane first; with a raster, ``iterations`` fixed-point steps onto the raster height under
        the current hit (exact where the raster is locally flat). Rays where that has not settled
        within ``tol_m`` (grazing rays on a slope make the step diverge) are solved by marching to
        the first sign change of "ray height above ground" and bisecting. Rays that do not descend
        (parallel, upward) give ``inf``, never NaN.
        """
        origin = np.ascontiguousarray(origin, dtype=np.float64)
        dirs = np.ascontiguousarray(np.asarray(dirs, dtype=np.float64).reshape(-1, 3))
        out = np.empty(len(dirs))
        ground_intersect_kernel(origin, dirs, *self.ray_kernel_args(), int(iterations), float(t_max),
                                float(tol_m), out)
        return out

    def kernel_args(self) -> tuple:
        """(normal, offset, heights, R, t, s, has_raster) as the compiled kernels take them."""
        r = self.raster
        heights = np.zeros((1, 1), np.float32) if r is None else np.ascontiguousarray(r.heights, np.float32)
        rR = np.eye(2) if r is None else np.ascontiguousarray(r.R, np.float64)
        rt = np.zeros(2) if r is None else np.ascontiguousarray(r.t, np.float64)
        return (np.ascontiguousarray(self.normal, np.float64), float(self.offset), heights, rR, rt,
                1.0 if r is None else float(r.s), r is not None)

    def ray_kernel_args(self) -> tuple:
        """``kernel_args`` and the raster's top height, which lets ray marches skip lookups above it."""
        return (*self.kernel_args(), -np.inf if self.raster is None else self.raster.top)


def pixel_rays_cam(camera: CameraSpec) -> F64:
    """(H, W, 3) z-normalised rays ``K^-1 [u, v, 1]`` through the pixel centres."""
    K = camera.K
    u = (np.arange(camera.width, dtype=np.float64) - K[0, 2]) / K[0, 0]
    v = (np.arange(camera.height, dtype=np.float64) - K[1, 2]) / K[1, 1]
    rays = np.empty((camera.height, camera.width, 3))
    rays[:, :, 0] = u[None, :] - v[:, None] * (K[0, 1] / K[0, 0])
    rays[:, :, 1] = v[:, None]
    rays[:, :, 2] = 1.0
    return rays


def ground_depth(camera: CameraSpec, city_T_cam: F64, ground: GroundSurface, config: ProxyConfig) -> F64:
    """(H, W) camera z of the ground under each pixel; ``inf`` above the horizon or beyond max depth."""
    depth = np.empty((camera.height, camera.width))
    ground_depth_kernel(np.ascontiguousarray(camera.K, dtype=np.float64),
                        np.ascontiguousarray(city_T_cam, dtype=np.float64), *ground.ray_kernel_args(),
                        int(config.ground_iterations), GROUND_T_MAX, GROUND_TOL_M, config.near_m,
                        config.max_depth_m, depth)
    return depth


def lidar_depth(camera: CameraSpec, city_T_cam: F64, points_city: F64, radius_m: F64,
                config: ProxyConfig) -> F64:
    """(H, W) z-buffer of lidar points as disks of ``radius_m`` (pixel radius clipped), holes closed."""
    depth = np.full((camera.height, camera.width), np.inf)
    if len(points_city) == 0:
        return depth
    splat_points_kernel(np.ascontiguousarray(points_city, dtype=np.float64),
                        np.ascontiguousarray(radius_m, dtype=np.float64), T_inverse(city_T_cam),
                        np.ascontiguousarray(camera.K, dtype=np.float64), config.near_m, config.max_depth_m,
                        config.min_splat_px, config.max_splat_px, depth)
    return close_holes(depth, config.fill_px)


def close_holes(depth: F64, fill_px: int) -> F64:
    """Fill empty pixels enclosed within ``fill_px`` by surfaces: a morphological closing of inverse depth.

    Closing (dilate then erode) of 1/z fills gaps narrower than the kernel with the nearer
    neighbours' depth while keeping silhouettes where they were; only empty pixels change.
    """
    if fill_px <= 1:
        return depth
    inv = np.empty(depth.shape, np.float32)
    n_empty = inverse_depth32_kernel(depth, inv)  # one pass, not five numpy temporaries
    if n_empty == 0 or n_empty == depth.size:
        return depth
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (fill_px, fill_px))
    closed = cv2.morphologyEx(inv, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)
    out = np.empty_like(depth)
    fill_closed_kernel(depth, closed, out)
    return out


def box_corners(size_lwh: F64) -> F64:
    """(B, 8, 3) corners in each box frame (centre origin)."""
    half = 0.5 * np.asarray(size_lwh, dtype=np.float64).reshape(-1, 1, 3)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return half * signs[None]


def ray_box_t(origin_box: F64, dirs_box: F64, half: F64, near: float) -> F64:
    """First ray parameter >= near where rays (in the box frame) enter an axis-aligned box; ``inf`` on a miss.

    Slab method with parallel components handled explicitly (inside the slab: no constraint;
    outside: miss), so no 0 * inf NaN. A ray starting inside the box hits at ``near``.
    """
    dirs = np.ascontiguousarray(np.asarray(dirs_box, dtype=np.float64).reshape(-1, 3))
    out = np.empty(len(dirs))
    ray_box_kernel(np.ascontiguousarray(origin_box, dtype=np.float64), dirs,
                   np.ascontiguousarray(half, dtype=np.float64), float(near), out)
    return out


def box_depth(camera: CameraSpec, city_T_cam: F64, city_T_box: F64, size_lwh: F64,
              config: ProxyConfig) -> tuple[F64, np.ndarray]:
    """(H, W) camera z of the nearest box face and (H, W) int32 index of that box (``NO_BOX`` = none).

    Only the pixels inside each box's projected bounding rectangle are tested (the whole image
    when the box reaches behind the near plane).
    """
    h, w = camera.height, camera.width
    depth = np.full((h, w), np.inf)
    index = np.full((h, w), NO_BOX, dtype=np.int32)
    city_T_box = np.asarray(city_T_box, dtype=np.float64).reshape(-1, 4, 4)
    if len(city_T_box) == 0:
        return depth, index
    cam_T_box = T_inverse(city_T_cam) @ city_T_box
    size_lwh = np.asarray(size_lwh, dtype=np.float64).reshape(-1, 3)
    corners = (np.einsum("bij,bkj->bki", cam_T_box[:, :3, :3], box_corners(size_lwh))
               + cam_T_box[:, None, :3, 3])
    rects = np.full((len(cam_T_box), 4), [0, -1, 0, -1], dtype=np.int64)
    K = camera.K
    for b, c in enumerate(corners):
        if np.all(c[:, 2] <= config.near_m) or np.min(c[:, 2]) > config.max_depth_m:
            continue
        if np.all(c[:, 2] > config.near_m):
            uu = K[0, 0] * c[:, 0] / c[:, 2] + K[0, 1] * c[:, 1] / c[:, 2] + K[0, 2]
            vv = K[1, 1] * c[:, 1] / c[:, 2] + K[1, 2]
            rects[b] = (max(int(np.floor(vv.min())), 0), min(int(np.ceil(vv.max())), h - 1),
                        max(int(np.floor(uu.min())), 0), min(int(np.ceil(uu.max())), w - 1))
            if rects[b, 0] > rects[b, 1] or rects[b, 2] > rects[b, 3]:
                rects[b] = (0, -1, 0, -1)
        else:  # reaches behind the camera: its projection is unbounded
            rects[b] = (0, h - 1, 0, w - 1)
    box_depth_kernel(np.ascontiguousarray(K, dtype=np.float64), np.ascontiguousarray(T_inverse(cam_T_box)),
                     np.ascontiguousarray(0.5 * size_lwh), rects, config.near_m, config.max_depth_m, depth,
                     index)
    return depth, index


def free_of_boxes(camera: CameraSpec, frame_T_cam: F64, frame_T_box: F64, size_lwh: F64,
                  margin_px: int = 2) -> np.ndarray:
    """(H, W) bool: the pixels no box covers, box silhouettes dilated by ``margin_px`` for label error
    (camera and boxes in any one frame). Static-point colour statistics skip the rest: a passing truck
    hides what is behind it."""
    depth, _ = box_depth(camera, frame_T_cam, frame_T_box, size_lwh, ProxyConfig())
    covered = np.isfinite(depth).astype(np.uint8)
    if margin_px > 0 and covered.any():
        covered = cv2.dilate(covered, np.ones((2 * margin_px + 1,) * 2, np.uint8))
    return covered == 0


@dataclass(frozen=True)
class ProxyGeometry:
    """What a depth proxy is built from, all in the city frame at one time."""

    ground: GroundSurface | None
    points_city: F64  # (N, 3) static lidar points (outside boxes)
    point_radius_m: F64  # (N,) disk radius per point
    city_T_box: F64  # (B, 4, 4) box layers at this time (labels, or fitted to the actors: warp.actor_points)
    size_lwh: F64  # (B, 3)
    # Each box's actor's own LiDAR points, in that layer's frame: a box pixel is kept only where these show a
    # surface (boxes with too few points are kept whole). Moved to the city only for the boxes a view shows.
    actor_points_box: tuple[np.ndarray, ...] | None = None  # B x (M_b, 3)

    @staticmethod
    def empty() -> ProxyGeometry:
        return ProxyGeometry(None, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 4, 4)), np.zeros((0, 3)))


@dataclass(frozen=True)
class DepthProxy:
    """Per-pixel camera z (``inf`` = at infinity) and hit box index of one view."""

    camera: CameraSpec
    city_T_cam: F64
    depth: F64  # (H, W)
    box_index: np.ndarray  # (H, W) int32, NO_BOX for static surfaces and infinity

    def inverse_depth(self) -> np.ndarray:
        """float32 (H, W) 1/z, 0 at infinity (linear across a plane, so it interpolates well)."""
        finite = np.isfinite(self.depth)
        return np.where(finite, 1.0 / np.where(finite, self.depth, 1.0), 0.0).astype(np.float32)

    def rays_city(self) -> F64:
        """(H*W, 3) z-normalised pixel rays rotated into the city frame."""
        return pixel_rays_cam(self.camera).reshape(-1, 3) @ np.asarray(self.city_T_cam)[:3, :3].T

    def points_city(self) -> tuple[F64, np.ndarray]:
        """(H*W, 3) city points of the finite pixels (NaN rows elsewhere) and the (H*W,) finite mask."""
        z = self.depth.reshape(-1)
        finite = np.isfinite(z)
        pts = np.full((len(z), 3), np.nan)
        pts[finite] = np.asarray(self.city_T_cam)[:3, 3] + z[finite, None] * self.rays_city()[finite]
        return pts, finite


ACTOR_POINT_RADIUS_M = 0.08
ACTOR_MIN_POINTS = 50


def actor_surface(camera: CameraSpec, city_T_cam: F64, geometry: ProxyGeometry, box_index: np.ndarray,
                  behind: F64, config: ProxyConfig) -> np.ndarray:
    """(H, W) bool: where a box pixel really shows its actor. A box is a cuboid, an actor is not (rounded
    bodies, the road under a car, a box a few centimetres off): the actor's own points, splatted as
    ``ACTOR_POINT_RADIUS_M`` disks with small holes closed, must show a surface there in front of what
    lies behind. Boxes with fewer than ``ACTOR_MIN_POINTS`` points (far, occluded) are kept whole.
    The points are splatted only into the rectangle around the checked boxes' pixels (plus the hole
    closing's reach): actors cover a small part of most views."""
    counts = np.array([len(p) for p in geometry.actor_points_box], np.int64)
    has_points = counts >= ACTOR_MIN_POINTS
    valid = box_index >= 0
    checked = np.zeros(box_index.shape, bool)
    checked[valid] = has_points[box_index[valid]]
    out = valid & ~checked  # boxes without enough points are trusted whole
    if not checked.any():
        return out
    use = np.unique(box_index[checked])  # only the boxes this view shows
    parts = [geometry.actor_points_box[b] @ geometry.city_T_box[b, :3, :3].T + geometry.city_T_box[b, :3, 3]
             for b in use]
    rows, cols = np.flatnonzero(checked.any(axis=1)), np.flatnonzero(checked.any(axis=0))
    reach = 2 * max(int(config.fill_px), 1)  # closing reads this far; beyond it the crop edge cannot matter
    r0, r1 = max(int(rows[0]) - reach, 0), min(int(rows[-1]) + reach + 1, camera.height)
    c0, c1 = max(int(cols[0]) - reach, 0), min(int(cols[-1]) + reach + 1, camera.width)
    K = np.array(camera.K, dtype=np.float64)
    K[0, 2] -= c0
    K[1, 2] -= r0
    crop = replace(camera, width=c1 - c0, height=r1 - r0, K=K, ego_mask_polygons=())
    pts = np.concatenate(parts)
    d = lidar_depth(crop, city_T_cam, pts, np.full(len(pts), ACTOR_POINT_RADIUS_M), config)
    out[r0:r1, c0:c1] |= checked[r0:r1, c0:c1] & np.isfinite(d) & (d < behind[r0:r1, c0:c1])
    return out


def render_depth_proxy(camera: CameraSpec, city_T_cam: F64, geometry: ProxyGeometry,
                       config: ProxyConfig | None = None) -> DepthProxy:
    """Depth proxy of one view: nearest of ground, lidar disks and boxes (see module doc)."""
    config = config or ProxyConfig()
    city_T_cam = np.asarray(city_T_cam, dtype=np.float64)
    if city_T_cam.shape != (4, 4) or not np.all(np.isfinite(city_T_cam)):
        raise ValueError("city_T_cam must be a finite 4x4 transform")
    depth = np.full((camera.height, camera.width), np.inf)
    if geometry.ground is not None:
        depth = ground_depth(camera, city_T_cam, geometry.ground, config)
    if len(geometry.points_city):
        depth = np.minimum(depth, lidar_depth(camera, city_T_cam, geometry.points_city,
                                              geometry.point_radius_m, config))
    bd, bi = box_depth(camera, city_T_cam, geometry.city_T_box, geometry.size_lwh, config)
    on_box = bd < depth
    if geometry.actor_points_box is not None and len(geometry.actor_points_box) and on_box.any():
        on_box &= actor_surface(camera, city_T_cam, geometry, np.where(on_box, bi, NO_BOX), depth, config)
    depth = np.where(on_box, bd, depth)
    index = np.where(on_box, bi, NO_BOX).astype(np.int32)
    return DepthProxy(camera, city_T_cam, depth, index)
