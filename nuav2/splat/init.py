"""Seeding a scene from the log: which tracks move, LiDAR aggregation, ground seeds, colours.

Street Gaussians initialises from LiDAR instead of structure-from-motion: every sweep is moved
into the scene frame; points inside a *moving* track's box go to that track (in its box frame),
everything else (static tracks included) is background, voxel-downsampled more coarsely far
from the ego path. Ground seeds on the ground-height surface fill the gaps between LiDAR rings
where lane paint lives. Every seed is coloured from the source image that sees it closest,
behind a coarse z-buffer so a point hidden by a car does not take the car's colour; seeds that
no camera sees are dropped. The same projection marks, per training view, which upward pixels
no seed covers: the sky mask the sky model and the opacity loss train on.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from nuav2.geometry import F64, T_from_quat_trans, T_inverse
from nuav2.progress import progress_bar
from nuav2.rig import CameraSpec
from nuav2.scene import SceneLog
from nuav2.splat.scene_model import TrackPoses

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InitConfig:
    """Knobs of the LiDAR seeding (metres unless named otherwise)."""

    sweep_stride: int = 1  # aggregate every k-th sweep
    voxel_m: float = 0.15  # background voxel near the path; x2 per distance band
    voxel_bands_m: tuple[float, ...] = (20.0, 40.0, 80.0)  # distance-to-path band edges
    object_voxel_m: float = 0.08
    max_background: int = 150_000
    max_object_points: int = 5_000
    min_object_points: int = 300  # fewer LiDAR points: fill with random points on the box surface
    box_margin_m: float = 0.25  # in-box test margin (points on the box skin belong to the object)
    max_range_m: float = 150.0
    ego_box_min: tuple[float, float, float] = (-1.3, -1.2, -0.6)  # ego-frame box of the ego body
    ego_box_max: tuple[float, float, float] = (4.2, 1.2, 1.6)
    ground_spacing_m: float = 0.25  # 0 disables ground seeds
    ground_radius_m: float = 30.0  # ground seeds within this distance of the ego path
    ground_clear_height_m: float = 0.3  # a ground cell with LiDAR higher than this is occupied
    opacity: float = 0.3
    min_scale_m: float = 0.02
    max_scale_m: float = 2.0
    zbuf_cell_px: int = 2  # z-buffer cell at training resolution
    zbuf_rel_tol: float = 0.05
    zbuf_abs_tol_m: float = 0.3
    keep_unseen: bool = False
    sky_height: int = 32
    sky_width: int = 128
    sky_min_elevation_deg: float = 1.0
    sky_dilate_px: int = 3
    sky_colour_tol: float = 0.12  # a sky candidate must be this close (RGB, [0,1]) to the sky's colour
    facade_view_stride: int = 4  # facade seeds from every k-th view (0 disables them)
    facade_max_gap_frac: float = 0.4  # carry LiDAR depth up a column at most this fraction of the height
    motion_min_path_m: float = 1.0  # a track moves if its path is longer than this ...
    motion_min_std_m: float = 0.3  # ... and its position spread (largest axis std) exceeds this
    motion_min_observations: int = 2


# ---- source views ------------------------------------------------------------------------------

@dataclass
class SourceView:
    """One source camera image at training resolution, its pose and (lazily) its pixels."""

    index: int
    channel: str
    timestamp_ns: int
    path: Path
    cam: CameraSpec  # scaled to the training resolution
    city_T_cam: F64
    valid: np.ndarray = field(repr=False)  # (H, W) bool, False under the ego-body mask
    _image: np.ndarray | None = field(default=None, repr=False)

    def image_u8(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB at the training resolution (kept in memory: 4x smaller than float)."""
        if self._image is None:
            self._image = load_image_u8(self.path, self.cam.width, self.cam.height)
        return self._image

    def image(self) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1] at the training resolution."""
        img = self.image_u8()
        return img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)


def load_image_u8(path: Path, width: int, height: int) -> np.ndarray:
    """Read an image file as uint8 RGB, area-resized to width x height."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{path}: camera image missing or unreadable")
    if bgr.shape[:2] != (height, width):
        bgr = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(bgr[:, :, ::-1])


def load_image(path: Path, width: int, height: int) -> np.ndarray:
    """Read an image file as float32 RGB [0,1], area-resized to width x height."""
    return load_image_u8(path, width, height).astype(np.float32) / 255.0


def source_views(scene: SceneLog, image_scale: float, *, frame_stride: int = 1,
                 channels: list[str] | None = None) -> list[SourceView]:
    """Every ``frame_stride``-th image of every camera, posed at its own timestamp."""
    views: list[SourceView] = []
    for cam in scene.rig.cameras:
        if channels is not None and cam.channel not in channels:
            continue
        small = cam.scaled(image_scale)
        valid = ~small.ego_mask()
        frames = sorted(scene.camera_frames.get(cam.channel, []), key=lambda f: f.timestamp_ns)
        for f in frames[::frame_stride]:
            city_T_cam = scene.city_T_ego_at(int(f.timestamp_ns)) @ cam.ego_T_cam
            views.append(SourceView(len(views), cam.channel, int(f.timestamp_ns), Path(f.path), small,
                                    city_T_cam, valid))
    return views


# ---- tracks ------------------------------------------------------------------------------------

def build_tracks(scene: SceneLog, scene_T_city: F64) -> list[TrackPoses]:
    """Every annotated track's box poses in the scene frame, sorted by track id."""
    ann = scene.annotations
    tracks = []
    for tid in sorted(set(ann.track_id.tolist())):
        rows = np.flatnonzero(ann.track_id == tid)
        rows = rows[np.argsort(ann.timestamp_ns[rows], kind="stable")]
        ts = ann.timestamp_ns[rows].astype(np.int64)
        keep = np.concatenate([[True], np.diff(ts) > 0])  # a repeated timestamp keeps its first box
        rows, ts = rows[keep], ts[keep]
        ego_T_box = T_from_quat_trans(ann.ego_q_box[rows], ann.ego_t_box[rows])
        scene_T_box = scene_T_city[None] @ scene.city_T_ego_at(ts).reshape(-1, 4, 4) @ ego_T_box
        tracks.append(TrackPoses(str(tid), str(ann.category[rows[0]]), np.median(ann.size_lwh[rows], axis=0),
                                 ts, scene_T_box))
    return tracks


def track_motion(track: TrackPoses) -> tuple[float, float]:
    """(path length, largest per-axis std) of the box centre, metres."""
    c = track.scene_T_box[:, :3, 3]
    path = float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0
    return path, float(c.std(axis=0).max())


def is_moving(track: TrackPoses, cfg: InitConfig) -> bool:
    """Model a track as its own object only if it really moves: path AND spread above thresholds
    (path alone grows with annotation jitter on long static tracks)."""
    if len(track.timestamps_ns) < cfg.motion_min_observations:
        return False
    path, std = track_motion(track)
    return path > cfg.motion_min_path_m and std > cfg.motion_min_std_m


# ---- LiDAR aggregation -------------------------------------------------------------------------

def points_in_box(points: F64, box_T_frame: F64, size_lwh: F64, margin: float) -> np.ndarray:
    """Mask of (N,3) points (in some frame) inside a box given the frame->box transform."""
    p = points @ box_T_frame[:3, :3].T + box_T_frame[:3, 3]
    half = np.asarray(size_lwh) / 2 + margin
    return np.all(np.abs(p) <= half, axis=1)


@dataclass
class LidarAggregate:
    """Aggregated LiDAR: background in the scene frame, moving objects in their box frames."""

    background: F64  # (N, 3)
    objects: dict[str, F64]  # track id -> (M, 3)
    n_sweeps: int = 0
    n_points: int = 0


def aggregate_lidar(scene: SceneLog, scene_T_city: F64, moving: dict[str, TrackPoses], cfg: InitConfig,
                    *, progress: bool = False) -> LidarAggregate:
    """Move sweeps into the scene frame, routing points in moving boxes to their tracks."""
    ann = scene.annotations
    bg_parts: list[F64] = []
    obj_parts: dict[str, list[F64]] = {tid: [] for tid in moving}
    sweeps = scene.lidar_sweeps[:: max(1, cfg.sweep_stride)]
    lo, hi = np.asarray(cfg.ego_box_min), np.asarray(cfg.ego_box_max)
    n_points = 0
    for ref in progress_bar(sweeps, desc="lidar", unit="sweep", disable=not progress, leave=False):
        pts = scene.sweep(ref).xyz_ego
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        pts = pts[~np.all((pts >= lo) & (pts <= hi), axis=1)]
        pts = pts[np.linalg.norm(pts, axis=1) <= cfg.max_range_m]
        n_points += len(pts)
        in_any = np.zeros(len(pts), bool)
        for row in ann.at(int(ref.timestamp_ns)):
            tid = str(ann.track_id[row])
            if tid not in moving:
                continue
            box_T_ego = T_inverse(T_from_quat_trans(ann.ego_q_box[row], ann.ego_t_box[row]))
            inside = points_in_box(pts, box_T_ego, ann.size_lwh[row], cfg.box_margin_m) & ~in_any
            if np.any(inside):  # a point in two overlapping boxes goes to the first only
                obj_parts[tid].append(pts[inside] @ box_T_ego[:3, :3].T + box_T_ego[:3, 3])
            in_any |= inside
        scene_T_ego = scene_T_city @ scene.city_T_ego_at(int(ref.timestamp_ns))
        rest = pts[~in_any]
        bg_parts.append(rest @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3])
    bg = np.concatenate(bg_parts) if bg_parts else np.zeros((0, 3))
    objs = {tid: (np.concatenate(p) if p else np.zeros((0, 3))) for tid, p in obj_parts.items()}
    return LidarAggregate(bg, objs, len(sweeps), n_points)


def voxel_downsample(points: F64, voxel_m: float) -> F64:
    """Centroid of the points in each occupied voxel (order: sorted voxel keys, deterministic)."""
    if len(points) == 0:
        return np.zeros((0, 3))
    if not voxel_m > 0:
        raise ValueError(f"voxel size must be > 0, got {voxel_m}")
    key = np.floor(points / voxel_m).astype(np.int64)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out = np.zeros((len(counts), 3))
    for d in range(3):
        out[:, d] = np.bincount(inv, weights=points[:, d], minlength=len(counts)) / counts
    return out


def distance_to_path(points_xy: F64, path_xy: F64) -> F64:
    """Horizontal distance of each point to the nearest ego position."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(path_xy).query(points_xy, k=1)
    return np.asarray(d, np.float64)


def banded_downsample(points: F64, path_xy: F64, voxel_m: float, bands_m: tuple[float, ...]) -> F64:
    """Voxel size doubles per distance band from the ego path (far scenery needs fewer seeds)."""
    if len(points) == 0:
        return points
    d = distance_to_path(points[:, :2], path_xy)
    edges = (0.0, *bands_m, np.inf)
    parts = [voxel_downsample(points[(d >= a) & (d < b)], voxel_m * 2**k)
             for k, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]
    return np.concatenate(parts)


def cap_points(points: F64, cap: int, rng: np.random.Generator) -> F64:
    if len(points) <= cap:
        return points
    return points[np.sort(rng.choice(len(points), cap, replace=False))]


def box_surface_points(size_lwh: F64, n: int, rng: np.random.Generator) -> F64:
    """n random points on a box's surface (faces picked by area), box frame."""
    l, w, h = (float(x) for x in size_lwh)
    areas = np.array([w * h, w * h, l * h, l * h, l * w, l * w])
    face = rng.choice(6, n, p=areas / areas.sum())
    u = rng.uniform(-0.5, 0.5, (n, 3)) * np.array([l, w, h])
    axis, sign = face // 2, np.where(face % 2 == 0, -0.5, 0.5)
    u[np.arange(n), axis] = sign * np.array([l, w, h])[axis]
    return u


class GroundSurface:
    """Ground height in the scene frame: the log's ground-height raster where it has a value,
    else the nearest ego pose's height minus the rig's origin height."""

    def __init__(self, scene: SceneLog, scene_T_city: F64) -> None:
        from scipy.spatial import cKDTree

        self.city_T_scene = T_inverse(scene_T_city)
        self.path = (scene_T_city[None] @ scene.city_T_ego)[:, :3, 3]
        self.tree = cKDTree(self.path[:, :2])
        self.origin_height = scene.rig.origin_height_m
        self.raster = scene.ground_height

    def __call__(self, xy_scene: F64) -> F64:
        xy_scene = np.asarray(xy_scene, np.float64).reshape(-1, 2)
        if len(xy_scene) == 0:
            return np.zeros(0)
        nearest = np.asarray(self.tree.query(xy_scene, k=1)[1], np.int64)
        z = self.path[nearest, 2] - self.origin_height
        if self.raster is not None:
            z_city = self.raster.height_at(xy_scene + self.city_T_scene[:2, 3])
            ok = np.isfinite(z_city)
            z[ok] = z_city[ok] - self.city_T_scene[2, 3]
        return z


def ground_seeds(ground: GroundSurface, occupied_xy_scene: F64, cfg: InitConfig) -> F64:
    """Grid points on the ground surface within ``ground_radius_m`` of the ego path, skipping
    cells where LiDAR shows something standing (buildings, parked cars)."""
    if cfg.ground_spacing_m <= 0:
        return np.zeros((0, 3))
    from scipy.spatial import cKDTree

    path = ground.path
    s, r = cfg.ground_spacing_m, cfg.ground_radius_m
    lo, hi = path[:, :2].min(0) - r, path[:, :2].max(0) + r
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], s), np.arange(lo[1], hi[1], s))
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + s / 2
    xy = xy[np.asarray(ground.tree.query(xy, k=1)[0]) <= r]
    if len(occupied_xy_scene) and len(xy):
        d, _ = cKDTree(occupied_xy_scene).query(xy, k=1)
        xy = xy[d > max(s, 0.3)]
    return np.column_stack([xy, ground(xy)])


def occupied_cells(points_scene: F64, ground_z_fn, clear_height: float) -> F64:
    """xy of background LiDAR points standing higher than ``clear_height`` above the ground."""
    if len(points_scene) == 0:
        return np.zeros((0, 2))
    high = points_scene[:, 2] - ground_z_fn(points_scene[:, :2]) > clear_height
    return points_scene[high, :2]


# ---- colouring by projection ----------------------------------------------------------------------

@dataclass
class Projection:
    """Pixels of points in one view: index into the input, pixel coordinates, camera depth."""

    idx: np.ndarray
    u: F64
    v: F64
    z: F64


def project(points_scene: F64, cam: CameraSpec, cam_T_scene: F64, near: float = 0.1) -> Projection:
    """Points in front of the camera that land inside the image (rig pixel convention)."""
    p = points_scene @ cam_T_scene[:3, :3].T + cam_T_scene[:3, 3]
    front = np.flatnonzero(p[:, 2] > near)
    p = p[front]
    u = cam.K[0, 0] * p[:, 0] / p[:, 2] + cam.K[0, 2]
    v = cam.K[1, 1] * p[:, 1] / p[:, 2] + cam.K[1, 2]
    inside = (u > -0.5) & (u < cam.width - 0.5) & (v > -0.5) & (v < cam.height - 0.5)
    return Projection(front[inside], u[inside], v[inside], p[inside, 2])


def zbuffer_visible(proj: Projection, width: int, height: int, cfg: InitConfig) -> np.ndarray:
    """Which projected points are the nearest surface in their (dilated) z-buffer cell."""
    c = max(1, cfg.zbuf_cell_px)
    gw, gh = (width + c - 1) // c, (height + c - 1) // c
    cell = (np.clip(np.round(proj.v).astype(np.int64) // c, 0, gh - 1) * gw
            + np.clip(np.round(proj.u).astype(np.int64) // c, 0, gw - 1))
    zmin = np.full(gw * gh, np.inf, np.float32)
    np.minimum.at(zmin, cell, proj.z.astype(np.float32))
    zmin = cv2.erode(zmin.reshape(gh, gw), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).ravel()
    return proj.z <= zmin[cell] * (1 + cfg.zbuf_rel_tol) + cfg.zbuf_abs_tol_m


def bilinear(image: np.ndarray, u: F64, v: F64) -> np.ndarray:
    """Bilinear sample of an (H, W, C) image at rig-convention pixel coordinates (centre of u is u)."""
    h, w = image.shape[:2]
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), w - 2 if w > 1 else 0)
    v0 = np.minimum(np.floor(v).astype(np.int64), h - 2 if h > 1 else 0)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    a, b = (u - u0)[:, None], (v - v0)[:, None]
    return ((1 - a) * (1 - b) * image[v0, u0] + a * (1 - b) * image[v0, u1]
            + (1 - a) * b * image[v1, u0] + a * b * image[v1, u1])


@dataclass
class SeedColours:
    """Per seed: RGB in [0,1] from its closest visible view (NaN if unseen), and the view count."""

    rgb: np.ndarray
    seen: np.ndarray
    sky_masks: dict[int, np.ndarray]  # view index -> (H, W) bool sky pixels


def colour_seeds(background: F64, objects: dict[str, F64], tracks: dict[str, TrackPoses],
                 views: list[SourceView], scene_T_city: F64, cfg: InitConfig, *,
                 progress: bool = False) -> tuple[SeedColours, dict[str, SeedColours]]:
    """Colour background (scene frame) and object (box frame) seeds from the views that see them.

    Objects are placed at each view's own timestamp. Also returns, per view, the sky mask:
    pixels looking above ``sky_min_elevation_deg`` with no seed projected within ``sky_dilate_px``.
    """
    owners = ["background", *objects]
    sizes = [len(background), *(len(objects[t]) for t in objects)]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    n = int(offsets[-1])
    rgb = np.full((n, 3), np.nan, np.float32)
    best_z = np.full(n, np.inf)
    seen = np.zeros(n, np.int32)
    sky_masks: dict[int, np.ndarray] = {}
    min_sin = np.sin(np.radians(cfg.sky_min_elevation_deg))
    for view in progress_bar(views, desc="colour seeds", unit="img", disable=not progress, leave=False):
        parts = [background]
        for tid in objects:
            tr = tracks[tid]
            if tr.present(view.timestamp_ns):
                T = tr.scene_T_box_at(view.timestamp_ns)
                parts.append(objects[tid] @ T[:3, :3].T + T[:3, 3])
            else:
                parts.append(np.full((len(objects[tid]), 3), np.nan))
        pts = np.concatenate(parts) if n else np.zeros((0, 3))
        cam_T_scene = T_inverse(scene_T_city @ view.city_T_cam)
        with np.errstate(invalid="ignore"):
            proj = project(pts, view.cam, cam_T_scene)
        vis = zbuffer_visible(proj, view.cam.width, view.cam.height, cfg)
        pu, pv = np.round(proj.u).astype(np.int64), np.round(proj.v).astype(np.int64)
        vis &= view.valid[np.clip(pv, 0, view.cam.height - 1), np.clip(pu, 0, view.cam.width - 1)]
        idx = proj.idx[vis]
        seen[idx] += 1
        better = proj.z[vis] < best_z[idx]
        if np.any(better):
            take = idx[better]
            rgb[take] = bilinear(view.image(), proj.u[vis][better], proj.v[vis][better])
            best_z[take] = proj.z[vis][better]
        sky_masks[view.index] = _sky_mask(view, scene_T_city, proj, min_sin, cfg.sky_dilate_px)
    splits = [SeedColours(rgb[a:b], seen[a:b], sky_masks) for a, b in zip(offsets[:-1], offsets[1:])]
    return splits[0], dict(zip(owners[1:], splits[1:]))


def _sky_mask(view: SourceView, scene_T_city: F64, proj: Projection, min_sin: float,
              dilate: int) -> np.ndarray:
    h, w = view.cam.height, view.cam.width
    covered = np.zeros((h, w), np.uint8)
    rows = np.clip(np.round(proj.v).astype(np.int64), 0, h - 1)
    covered[rows, np.clip(np.round(proj.u).astype(np.int64), 0, w - 1)] = 1
    if dilate > 0:
        covered = cv2.dilate(covered, np.ones((2 * dilate + 1, 2 * dilate + 1), np.uint8))
    up = _elevation_sin(view, scene_T_city) > min_sin
    return up & (covered == 0) & view.valid


def _elevation_sin(view: SourceView, scene_T_city: F64) -> np.ndarray:
    """(H, W) sine of each pixel ray's elevation in the scene frame (z up)."""
    h, w = view.cam.height, view.cam.width
    R = (scene_T_city @ view.city_T_cam)[:3, :3]
    K = view.cam.K
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ R.T
    return d[..., 2] / np.linalg.norm(d, axis=-1)


def refine_sky_masks(views: list[SourceView], candidates: dict[int, np.ndarray], scene_T_city: F64,
                     tol: float = 0.12, n_bins: int = 18) -> dict[int, np.ndarray]:
    """Keep only candidate sky pixels whose colour matches the sky at their elevation.

    LiDAR does not reach the tops of tall buildings, so "no seed projects here" also marks
    facades above the highest beam. The sky's colour per elevation band is the median over all
    candidates (facades are a minority), and a candidate stays sky only within ``tol`` (RGB
    distance in [0, 1]) of it."""
    elev: dict[int, np.ndarray] = {}
    samples_e, samples_c = [], []
    for view in views:
        m = candidates.get(view.index)
        if m is None or not m.any():
            continue
        e = _elevation_sin(view, scene_T_city)
        elev[view.index] = e
        idx = np.flatnonzero(m.ravel())[::7]  # a subsample is plenty for a median
        samples_e.append(e.ravel()[idx])
        samples_c.append(view.image().reshape(-1, 3)[idx])
    if not samples_e:
        return {k: v.copy() for k, v in candidates.items()}
    se, sc = np.concatenate(samples_e), np.concatenate(samples_c)
    bins = np.clip((np.arcsin(np.clip(se, -1, 1)) / (np.pi / 2) * n_bins).astype(int), 0, n_bins - 1)
    ref = np.full((n_bins, 3), np.nan)
    for b in range(n_bins):
        if np.any(bins == b):
            ref[b] = np.median(sc[bins == b], axis=0)
    ok = np.all(np.isfinite(ref), axis=1)
    if not ok.any():
        return {k: v.copy() for k, v in candidates.items()}
    good = np.flatnonzero(ok)
    ref = ref[good[np.argmin(np.abs(good[None, :] - np.arange(n_bins)[:, None]), axis=1)]]  # fill gaps
    out = {}
    for view in views:
        m = candidates.get(view.index)
        if m is None or view.index not in elev:
            out[view.index] = np.zeros((view.cam.height, view.cam.width), bool) if m is None else m.copy()
            continue
        b = np.clip((np.arcsin(np.clip(elev[view.index], -1, 1)) / (np.pi / 2) * n_bins).astype(int), 0,
                    n_bins - 1)
        dist = np.linalg.norm(view.image() - ref[b], axis=-1)
        out[view.index] = m & (dist < tol)
    return out


def facade_seeds(views: list[SourceView], candidates: dict[int, np.ndarray], sky: dict[int, np.ndarray],
                 lidar_scene: F64, scene_T_city: F64, cfg: InitConfig) -> tuple[F64, np.ndarray]:
    """Seeds for structure above the LiDAR's reach (tall facades), with their pixel colours.

    Pixels that no seed covers but that are not sky either are placed along their ray at the
    camera depth of the nearest LiDAR-covered pixel below them in the same column: on a vertical
    facade seen by a level camera that depth is constant up the column."""
    pts_out, rgb_out = [], []
    max_gap = cfg.facade_max_gap_frac
    for view in views[:: max(1, cfg.facade_view_stride)]:
        cand, sk = candidates.get(view.index), sky.get(view.index)
        if cand is None or sk is None:
            continue
        miss = cand & ~sk
        if not miss.any():
            continue
        h, w = view.cam.height, view.cam.width
        scene_T_cam = scene_T_city @ view.city_T_cam
        proj = project(lidar_scene, view.cam, T_inverse(scene_T_cam))
        zimg = np.full(h * w, np.inf)
        rows = np.clip(np.round(proj.v).astype(np.int64), 0, h - 1)
        np.minimum.at(zimg, rows * w + np.clip(np.round(proj.u).astype(np.int64), 0, w - 1), proj.z)
        zimg = zimg.reshape(h, w)
        carried = zimg.copy()
        age = np.where(np.isfinite(zimg), 0, h)
        for r in range(h - 2, -1, -1):  # carry the depth upwards, remembering how far it came
            take = ~np.isfinite(zimg[r]) & np.isfinite(carried[r + 1])
            carried[r] = np.where(take, carried[r + 1], zimg[r])
            age[r] = np.where(take, age[r + 1] + 1, age[r])
        pick = miss & np.isfinite(carried) & (age <= max_gap * h)
        pick[1::2] = False
        pick[:, 1::2] = False
        vv, uu = np.nonzero(pick)
        if len(vv) == 0:
            continue
        K = view.cam.K
        z = carried[vv, uu]
        p_cam = np.column_stack([(uu - K[0, 2]) / K[0, 0] * z, (vv - K[1, 2]) / K[1, 1] * z, z])
        pts_out.append(p_cam @ scene_T_cam[:3, :3].T + scene_T_cam[:3, 3])
        rgb_out.append(view.image()[vv, uu])
    if not pts_out:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    pts, rgb = np.concatenate(pts_out), np.concatenate(rgb_out)
    # One seed per voxel (the first pixel's colour), so many views of a facade do not pile up.
    key = np.floor(pts / (2 * cfg.voxel_m)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    return pts[first], rgb[first]


def knn_scales(points: F64, k: int = 3, lo: float = 0.02, hi: float = 2.0) -> F64:
    """sqrt(mean squared distance to the k nearest neighbours), clamped: the 3DGS isotropic init."""
    if len(points) == 0:
        return np.zeros(0)
    if len(points) <= k:
        return np.full(len(points), lo)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, k=k + 1)
    return np.clip(np.sqrt(np.mean(d[:, 1:] ** 2, axis=1)), lo, hi)


def sky_texture_from_views(views: list[SourceView], sky_masks: dict[int, np.ndarray], scene_T_city: F64,
                           height: int, width: int) -> np.ndarray | None:
    """(H, W, 3) mean sky colour per lat-long bin from the sky pixels, holes filled by row means
    (then the overall mean); None if no view has a sky pixel."""
    import torch

    from nuav2.splat.scene_model import SkyModel, pixel_rays

    acc = np.zeros((height * width, 3))
    cnt = np.zeros(height * width)
    n_bins = height * width
    for view in views:
        m = sky_masks.get(view.index)
        if m is None or not m.any():
            continue
        m = m.copy()
        m[1::2] = False  # every other row and column is plenty for a 32 x 128 texture
        m[:, 1::2] = False
        dirs = pixel_rays(view.cam, scene_T_city @ view.city_T_cam)[torch.from_numpy(m)]
        g = SkyModel.direction_to_grid(dirs, width).numpy()
        col = np.clip(np.round((g[:, 0] + 1) / 2 * width).astype(np.int64), 0, width) % width
        row = np.clip(np.round((g[:, 1] + 1) / 2 * (height - 1)).astype(np.int64), 0, height - 1)
        bins = row * width + col
        pix = view.image()[m]
        for c in range(3):
            acc[:, c] += np.bincount(bins, weights=pix[:, c], minlength=n_bins)
        cnt += np.bincount(bins, minlength=n_bins)
    if cnt.sum() == 0:
        return None
    overall = acc.sum(0) / cnt.sum()
    tex = np.where(cnt[:, None] > 0, acc / np.maximum(cnt, 1)[:, None], np.nan).reshape(height, width, 3)
    for r in range(height):
        row = tex[r]
        ok = np.all(np.isfinite(row), axis=1)
        row[~ok] = row[ok].mean(0) if ok.any() else np.nan
    rows_ok = np.all(np.isfinite(tex[:, 0]), axis=1)
    for r in range(height):
        if not rows_ok[r]:
            if rows_ok.any():
                nearest = np.flatnonzero(rows_ok)[np.argmin(np.abs(np.flatnonzero(rows_ok) - r))]
                tex[r] = tex[nearest]
            else:
                tex[r] = overall
    return tex


# ---- the initial scene -----------------------------------------------------------------------------

LIDAR, GROUND, FACADE = 0, 1, 2  # kinds of background seeds


@dataclass
class InitResult:
    """The seeded scene plus what training needs from seeding (sky masks) and a summary."""

    scene: object  # SplatScene (typed loosely to keep the import light)
    sky_masks: dict[int, np.ndarray]
    stats: dict


def initial_scene(scene: SceneLog, views: list[SourceView], cfg: InitConfig, *, sh_degree: int = 1,
                  seed: int = 0, progress: bool = False) -> InitResult:
    """Seed background, moving objects and sky from the log's LiDAR, ground surface and images."""
    import torch

    from nuav2.splat.scene_model import GaussianSet, ObjectModel, SkyModel, SplatScene, scene_frame_for

    rng = np.random.default_rng(seed)
    city_T_scene = scene_frame_for(scene.city_T_ego[0])
    scene_T_city = T_inverse(city_T_scene)
    tracks = build_tracks(scene, scene_T_city)
    moving = {t.track_id: t for t in tracks if is_moving(t, cfg)}
    agg = aggregate_lidar(scene, scene_T_city, moving, cfg, progress=progress)
    path_xy = (scene_T_city[None] @ scene.city_T_ego)[:, :2, 3]
    bg_lidar = banded_downsample(agg.background, path_xy, cfg.voxel_m, cfg.voxel_bands_m)

    surface = GroundSurface(scene, scene_T_city)
    occupied = occupied_cells(bg_lidar, surface, cfg.ground_clear_height_m)
    ground = ground_seeds(surface, occupied, cfg)
    bg_pts = np.concatenate([bg_lidar, ground])
    kind = np.concatenate([np.full(len(bg_lidar), LIDAR), np.full(len(ground), GROUND)])
    obj_pts: dict[str, F64] = {}
    for tid, pts in agg.objects.items():
        pts = cap_points(voxel_downsample(pts, cfg.object_voxel_m), cfg.max_object_points, rng)
        if len(pts) < cfg.min_object_points:
            extra = box_surface_points(moving[tid].size_lwh, cfg.min_object_points - len(pts), rng)
            pts = np.concatenate([pts, extra])
        obj_pts[tid] = pts
    bg_col, obj_col = colour_seeds(bg_pts, obj_pts, moving, views, scene_T_city, cfg, progress=progress)

    sky_masks = refine_sky_masks(views, bg_col.sky_masks, scene_T_city, cfg.sky_colour_tol)

    keep = np.isfinite(bg_col.rgb).all(1) if not cfg.keep_unseen else np.ones(len(bg_pts), bool)
    bg_rgb = np.where(np.isfinite(bg_col.rgb), bg_col.rgb, 0.5)
    bg_pts, bg_rgb, kind = bg_pts[keep], bg_rgb[keep], kind[keep]
    facade, facade_rgb = (facade_seeds(views, bg_col.sky_masks, sky_masks, bg_lidar, scene_T_city, cfg)
                          if cfg.facade_view_stride > 0 else (np.zeros((0, 3)), np.zeros((0, 3))))
    bg_pts = np.concatenate([bg_pts, facade])
    bg_rgb = np.concatenate([bg_rgb, facade_rgb])
    kind = np.concatenate([kind, np.full(len(facade), FACADE)])
    if len(bg_pts) > cfg.max_background:
        sel = np.sort(rng.choice(len(bg_pts), cfg.max_background, replace=False))
        bg_pts, bg_rgb, kind = bg_pts[sel], bg_rgb[sel], kind[sel]
    is_ground = kind == GROUND
    scales = np.repeat(knn_scales(bg_pts, 3, cfg.min_scale_m, cfg.max_scale_m)[:, None], 3, axis=1)
    # Ground seeds are flat discs on a regular grid: they tile the road without gaps or bumps.
    scales[is_ground] = [0.6 * cfg.ground_spacing_m, 0.6 * cfg.ground_spacing_m, 0.02]
    background = GaussianSet.create(bg_pts, bg_rgb, scales, opacity=cfg.opacity, sh_degree=sh_degree)

    objects = []
    for tid, pts in obj_pts.items():
        col = obj_col[tid]
        ok = np.isfinite(col.rgb).all(1)
        if not ok.any():
            log.info("track %s: no camera sees it; not modelled", tid)
            continue
        fill = np.nanmean(col.rgb[ok], axis=0)
        rgb = np.where(ok[:, None], col.rgb, fill)
        sc = knn_scales(pts, 3, cfg.min_scale_m, 0.5)
        objects.append(ObjectModel(moving[tid], GaussianSet.create(pts, rgb, sc, opacity=cfg.opacity,
                                                                   sh_degree=sh_degree)))

    sky = SkyModel(cfg.sky_height, cfg.sky_width)
    tex = sky_texture_from_views(views, sky_masks, scene_T_city, cfg.sky_height, cfg.sky_width)
    if tex is not None:
        with torch.no_grad():
            p = torch.from_numpy(np.clip(tex, 0.02, 0.98)).float().permute(2, 0, 1)
            sky.texture.copy_(torch.log(p / (1 - p)))
    splat = SplatScene(city_T_scene, background, objects, sky)
    stats = {"tracks": len(tracks), "moving_tracks": len(moving), "objects": len(objects),
             "lidar_sweeps": agg.n_sweeps, "lidar_points": agg.n_points,
             "background_lidar_seeds": int((kind == LIDAR).sum()),
             "facade_seeds": int((kind == FACADE).sum()),
             "ground_seeds": int(is_ground.sum()),
             "background_gaussians": len(background),
             "object_gaussians": int(sum(len(o.gaussians) for o in objects)),
             "sky_pixels": int(sum(int(m.sum()) for m in sky_masks.values()))}
    return InitResult(splat, sky_masks, stats)
