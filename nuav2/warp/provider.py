"""Warp mode's image provider: target-rig images from the log's own images, via depth proxies.

:class:`WarpRenderer` is a :data:`nuav2.nuscenes_db.images.RenderFn`: the writer calls it with
each target camera, its city pose and the time; it builds the target depth proxy from the log
at that time, picks the source images near that time whose view can overlap the target's,
renders each source's own proxy (cached, at a capped resolution) for the visibility test, and
blends (:mod:`nuav2.warp.backward_warp`). Uncovered pixels are filled (inpainting by default)
and their share is recorded per image in :attr:`WarpRenderer.coverage`.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import threading
from collections import OrderedDict
from concurrent.futures import Future
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from threadpoolctl import ThreadpoolController

from nuav2.actor_tracks import is_non_rigid
from nuav2.atomic import atomic_write_json
from nuav2.exposure import ExposureConfig, ExposureModel
from nuav2.geometry import F64, T_inverse
from nuav2.image_decode import read_bgr
from nuav2.nuscenes_db.images import ImageSourceError, RenderedImages
from nuav2.rig import EGO_COLOUR_MARGIN_PX, CameraSpec
from nuav2.scene import CameraFrame, SceneLog
from nuav2.warp.actor_points import actor_models, gather_track_points
from nuav2.warp.backward_warp import (
    FILL_MODES,
    BlendConfig,
    SourceView,
    fill_uncovered,
    warp_from_sources,
    warp_to_uint8,
)
from nuav2.warp.depth_proxy import DepthProxy, GroundSurface, ProxyConfig, ProxyGeometry, render_depth_proxy
from nuav2.warp.harmonise import solve_source_exposure, static_points
from nuav2.warp.lidar_cloud import CloudConfig, LidarCloud
from nuav2.warp.tracks import DEFAULT_TOLERANCE_NS, BoxesAt, BoxTracks


@functools.cache
def _threadpools() -> ThreadpoolController:
    return ThreadpoolController()  # scans the loaded libraries once


def one_blas_thread() -> contextlib.AbstractContextManager:
    """Context: BLAS on one thread. The warp's matrix products are small (points x 3x3); OpenBLAS's
    second thread gained no wall time on a 15 s log and spun for 25 CPU s, taken from the other worker.
    Render threads nest theirs inside the writer's (``WarpRenderer.storing``), so each one restores the
    limit it found: one thread."""
    return _threadpools().limit(limits=1, user_api="blas")


@dataclass(frozen=True)
class WarpConfig:
    """Everything that changes a warped image (hashed into the shard fingerprint)."""

    proxy: ProxyConfig = field(default_factory=ProxyConfig)
    blend: BlendConfig = field(default_factory=BlendConfig)
    cloud: CloudConfig = field(default_factory=CloudConfig)
    frames_per_channel: int = 1  # nearest images of each source camera used per target image
    max_source_offset_ns: int = 60_000_000  # source images further from the target time are not used
    overlap_margin_rad: float = 0.1  # a source is used if its view cone can overlap the target's
    visibility_max_pixels: int = 200_000  # source depth proxies are rendered at most this large
    use_ground_raster: bool = True
    fill: str = "inpaint"
    background: tuple[float, float, float] = (0.5, 0.5, 0.5)
    cache_mb: int = 1024  # source views (image + proxy) kept for reuse across target cameras
    # None: sources as taken. 2,000 observations per image (of the 2.5 images per camera-second read) tie the
    # gains to < 1 % (nuav2 bench exposure) at half the solve's cost of 4,000.
    harmonise: ExposureConfig | None = field(
        default_factory=lambda: ExposureConfig(max_observations_per_image=2000))
    smooth_tracks: bool = True  # take per-frame label jitter out of the box tracks (nuav2.actor_tracks)
    static_actors_as_lidar: bool = True  # parked actors are LiDAR geometry (their real shape), not boxes
    actor_check: bool = True  # box pixels only where the actor's own LiDAR points show a surface
    actor_ring: bool = True  # ... also up to actor_points.MARGIN_M past the label, where its points recur

    def __post_init__(self) -> None:
        if self.fill not in FILL_MODES:
            raise ValueError(f"WarpConfig.fill must be one of {FILL_MODES}, got {self.fill!r}")
        if self.frames_per_channel < 1 or self.max_source_offset_ns < 0 or self.visibility_max_pixels < 64:
            raise ValueError("WarpConfig needs frames_per_channel >= 1, max_source_offset_ns >= 0, "
                             "visibility_max_pixels >= 64")

    def fingerprint(self) -> str:
        d = asdict(self)
        d.pop("cache_mb")  # cache sizes change speed and memory, never an image
        d["cloud"].pop("cache_sweeps")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:12]


@dataclass(frozen=True)
class WarpOutput:
    rgb: np.ndarray  # float32 (H, W, 3), filled
    coverage: np.ndarray  # bool (H, W): some source saw the pixel
    n_sources: int  # source images used
    nonrigid: np.ndarray | None = None  # bool (H, W): on a non-rigid actor's box (limbs only approximated)


def half_diagonal_fov(camera: CameraSpec) -> float:
    """Angle from the optical axis to the farthest image corner (a cone containing the view)."""
    K = camera.K
    xs = np.array([-0.5 - K[0, 2], camera.width - 0.5 - K[0, 2]]) / K[0, 0]
    ys = np.array([-0.5 - K[1, 2], camera.height - 0.5 - K[1, 2]]) / K[1, 1]
    return float(np.arctan(np.sqrt(np.max(xs ** 2) + np.max(ys ** 2))))


def read_rgb(path: Path, camera: CameraSpec) -> np.ndarray:
    """uint8 RGB image; raises ImageSourceError naming the file when unreadable or the wrong size."""
    img = read_bgr(path)
    if img.shape[:2] != (camera.height, camera.width):
        raise ImageSourceError(f"{path}: image is {img.shape[1]}x{img.shape[0]} but the calibration of "
                               f"{camera.channel} says {camera.width}x{camera.height}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)  # a 30th of the time of a reversed-channel copy


class WarpRenderer:
    """Renders any target camera at any time of ``scene`` by warping its source images (see module doc)."""

    def __init__(self, scene: SceneLog, config: WarpConfig | None = None, threads: int = 1) -> None:
        self.scene = scene
        self.config = config or WarpConfig()
        # Target images rendered at once by the writer (nuav2.nuscenes_db.writer); the caches below are shared
        # under ``_lock``, the heavy work (depth proxies, decoding, blending) runs outside it.
        self.threads = max(1, int(threads))
        self._lock = threading.RLock()
        self._making: dict[tuple[str, int], Future] = {}  # source views being built by another thread
        self._poses: dict[int, F64] = {}
        self._boxes: OrderedDict[int, BoxesAt] = OrderedDict()
        self.tracks = BoxTracks.from_scene(scene, smooth=self.config.smooth_tracks)
        if self.config.static_actors_as_lidar:  # only what moves needs a box that carries it
            self.tracks = self.tracks.select(self.tracks.moving())
        # Per track, the box layer's cuboid (centre in the box frame, size) and the actor's points around
        # that centre; None without the actor check (label boxes).
        self.layer_points: list[np.ndarray] | None = None
        if self.config.actor_check:
            with one_blas_thread():
                sweep_ns = np.asarray(scene.sweep_timestamps_ns, np.int64)
                period_s = float(np.median(np.diff(sweep_ns))) * 1e-9 if len(sweep_ns) > 1 else 0.1
                models = actor_models(gather_track_points(self.tracks, scene), self.tracks, period_s,
                                      ring=self.config.actor_ring)
            self.layer_centre = np.array([m.centre for m in models]).reshape(-1, 3)
            self.layer_size = np.array([m.size for m in models]).reshape(-1, 3)
            self.layer_points = [m.points_box - m.centre for m in models]
        self.cloud = LidarCloud(scene, self.tracks, self.config.cloud, self.ground_at)
        self.frames: dict[str, list[CameraFrame]] = {}
        self.frame_ns: dict[str, np.ndarray] = {}
        for cam in scene.rig.cameras:
            fr = sorted(scene.camera_frames.get(cam.channel, []), key=lambda f: f.timestamp_ns)
            if fr:
                self.frames[cam.channel] = fr
                self.frame_ns[cam.channel] = np.array([f.timestamp_ns for f in fr], dtype=np.int64)
        if not self.frames:
            raise ImageSourceError(f"log {scene.log_id}: warp mode needs the source camera images, and the "
                                   f"log has none for {scene.rig.camera_channels}")
        self._views: OrderedDict[tuple[str, int], SourceView] = OrderedDict()
        self._view_bytes = 0
        self._valid: dict[str, np.ndarray | None] = {}
        self.coverage: dict[str, dict[int, float]] = {}  # channel -> timestamp_ns -> covered fraction
        self.nonrigid: dict[str, dict[int, float]] = {}  # channel -> timestamp_ns -> non-rigid actor share
        self._exposure: tuple[ExposureModel, dict[tuple[str, int], int]] | None = None

    # -- geometry -------------------------------------------------------------------------------
    def city_T_ego_at(self, timestamp_ns: int) -> F64:
        t = int(timestamp_ns)
        with self._lock:
            if t not in self._poses:
                if len(self._poses) > 4096:
                    self._poses.clear()
                self._poses[t] = self.scene.city_T_ego_at(t)
            return self._poses[t]

    def boxes_at(self, timestamp_ns: int) -> BoxesAt:
        t = int(timestamp_ns)
        with self._lock:
            if t in self._boxes:
                return self._boxes[t]
            self._boxes[t] = self.tracks.at(t, DEFAULT_TOLERANCE_NS)
            while len(self._boxes) > 256:
                self._boxes.popitem(last=False)
            return self._boxes[t]

    def ground_at(self, timestamp_ns: int) -> GroundSurface:
        """The ground plane under the ego at that time, refined by the log's height raster when it has one."""
        raster = self.scene.ground_height if self.config.use_ground_raster else None
        return GroundSurface.under_ego(self.city_T_ego_at(timestamp_ns), self.scene.rig.origin_height_m,
                                       raster)

    def geometry_at(self, timestamp_ns: int) -> tuple[ProxyGeometry, BoxesAt]:
        """Ground, static lidar points and boxes at ``timestamp_ns`` (the boxes also with their tracks)."""
        with self._lock:  # the cloud's window cache
            pts, radius = self.cloud.around(timestamp_ns)
        boxes = self.boxes_at(timestamp_ns)
        city_T_layer, size, actor_pts = boxes.city_T_box, boxes.size_lwh, None
        if self.layer_points is not None and len(boxes):
            city_T_layer = boxes.city_T_box.copy()  # the layer's cuboid: the label box, moved to the actor
            city_T_layer[:, :3, 3] += np.einsum("bij,bj->bi", boxes.city_T_box[:, :3, :3],
                                                self.layer_centre[boxes.track])
            size = self.layer_size[boxes.track]
            actor_pts = tuple(self.layer_points[int(k)] for k in boxes.track)  # layer frame; placed on demand
        geometry = ProxyGeometry(self.ground_at(timestamp_ns), pts, radius, city_T_layer, size, actor_pts)
        return geometry, boxes

    # -- sources --------------------------------------------------------------------------------
    def exposure(self) -> tuple[ExposureModel, dict[tuple[str, int], int]] | None:
        """The log's source exposure model and image index per (channel, frame index), solved on first use
        (:mod:`nuav2.warp.harmonise`); None when harmonising is off."""
        if self.config.harmonise is None:
            return None
        with self._lock:  # solved once; a second thread waits for it
            if self._exposure is None:
                points = static_points(self.scene, lambda i: self.cloud.sweep_points(i)[0])
                self._exposure = solve_source_exposure(self.scene, self.frames, points, self.config.harmonise,
                                                       self.boxes_at)
            return self._exposure

    def _ego_valid(self, camera: CameraSpec) -> np.ndarray | None:
        with self._lock:
            if camera.channel not in self._valid:
                self._valid[camera.channel] = (~camera.ego_mask(EGO_COLOUR_MARGIN_PX)
                                               if camera.ego_mask_polygons else None)
            return self._valid[camera.channel]

    def source_view(self, channel: str, index: int) -> SourceView:
        """Source image ``index`` of ``channel`` with its own depth proxy (cached)."""
        key = (channel, int(self.frames[channel][index].timestamp_ns))
        with self._lock:
            if key in self._views:
                self._views.move_to_end(key)
                return self._views[key]
            making = self._making.get(key)
            if making is None:
                self._making[key] = mine = Future()
        if making is not None:  # another render thread is building it
            return making.result()
        try:
            view = self._make_view(channel, index)
        except BaseException as e:
            with self._lock:
                del self._making[key]
            mine.set_exception(e)
            raise
        with self._lock:
            self._keep_view(key, view)
            del self._making[key]
        mine.set_result(view)
        return view

    def _make_view(self, channel: str, index: int) -> SourceView:
        """A source view, built from scratch (only the shared caches it reads are locked)."""
        frame = self.frames[channel][index]
        cam = self.scene.rig.camera(channel)
        t = int(frame.timestamp_ns)
        city_T_cam = self.city_T_ego_at(t) @ cam.ego_T_cam
        scale = min(1.0, float(np.sqrt(self.config.visibility_max_pixels / (cam.width * cam.height))))
        vis_cam = cam.scaled(scale) if scale < 1.0 else cam
        geom, _ = self.geometry_at(t)
        proxy = render_depth_proxy(vis_cam, city_T_cam, geom, self.config.proxy)
        image = read_rgb(Path(frame.path), cam)
        exposure = self.exposure()
        if exposure is not None:
            image = exposure[0].correct(image, exposure[1][(channel, index)], cam.K)
        return SourceView(image, cam, city_T_cam, t, vis_cam, proxy.inverse_depth(), self._ego_valid(cam))

    def _keep_view(self, key: tuple[str, int], view: SourceView) -> None:
        """Cache ``view`` (least recently used views leave past ``cache_mb``)."""
        nbytes = view.image.nbytes + view.inv_depth.nbytes
        self._views[key] = view
        self._view_bytes += nbytes
        while self._view_bytes > self.config.cache_mb * 2**20 and len(self._views) > 1:
            _, old = self._views.popitem(last=False)
            self._view_bytes -= old.image.nbytes + old.inv_depth.nbytes

    def source_candidates(self, camera: CameraSpec, city_T_cam: F64,
                          timestamp_ns: int) -> list[tuple[str, int]]:
        """(channel, frame index) of the source images near the time whose view cone meets the target's."""
        cfg = self.config
        axis_T = np.asarray(city_T_cam)[:3, 2]
        cone_T = half_diagonal_fov(camera)
        city_R_ego = self.city_T_ego_at(timestamp_ns)[:3, :3]
        out = []
        for ch, ts in self.frame_ns.items():
            cam = self.scene.rig.camera(ch)
            axis_S = city_R_ego @ cam.ego_T_cam[:3, 2]
            cos = axis_T @ axis_S / np.linalg.norm(axis_T) / np.linalg.norm(axis_S)
            ang = float(np.arccos(np.clip(cos, -1.0, 1.0)))
            if ang > cone_T + half_diagonal_fov(cam) + cfg.overlap_margin_rad:
                continue
            dt = np.abs(ts - int(timestamp_ns))
            for j in np.argsort(dt, kind="stable")[:cfg.frames_per_channel]:
                if dt[j] <= cfg.max_source_offset_ns:
                    out.append((ch, int(j)))
        return out

    @staticmethod
    def box_motion(at_target: BoxesAt, at_source: BoxesAt) -> F64:
        """(B, 4, 4) ``city(t_source) <- city(t_target)`` per target box; NaN where the track is absent."""
        motion = np.full((len(at_target), 4, 4), np.nan)
        if len(at_target) == 0 or len(at_source) == 0:
            return motion
        where = {int(k): i for i, k in enumerate(at_source.track)}
        inv_T = T_inverse(at_target.city_T_box)
        for b, k in enumerate(at_target.track):
            i = where.get(int(k))
            if i is not None:
                motion[b] = at_source.city_T_box[i] @ inv_T[b]
        return motion

    # -- rendering ------------------------------------------------------------------------------
    def render(self, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int) -> WarpOutput:
        """Warped float32 image, its coverage, and the number of source images used."""
        target, sources, motions, nonrigid = self.blend_inputs(camera, city_T_cam, timestamp_ns)
        res = warp_from_sources(target, sources, int(timestamp_ns), motions, self.config.blend)
        cov = res.coverage
        rgb = fill_uncovered(res.rgb, cov, self.config.background, self.config.fill)
        return WarpOutput(rgb, cov, len(sources), nonrigid)

    def blend_inputs(self, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int
                     ) -> tuple[DepthProxy, list[SourceView], list[F64], np.ndarray]:
        """The target's depth proxy, its source views with their box motions, and the bool (H, W) mask of
        pixels on non-rigid actors' boxes: what both the float and the uint8 render blend."""
        t = int(timestamp_ns)
        geom, boxes_T = self.geometry_at(t)
        target = render_depth_proxy(camera, city_T_cam, geom, self.config.proxy)
        sources, motions = [], []
        for ch, j in self.source_candidates(camera, city_T_cam, t):
            view = self.source_view(ch, j)
            sources.append(view)
            motions.append(self.box_motion(boxes_T, self.boxes_at(view.timestamp_ns)))
        nonrigid_track = np.array([is_non_rigid(c) for c in self.tracks.category], bool)
        on_box = target.box_index >= 0
        nonrigid = np.zeros(on_box.shape, bool)
        if len(boxes_T) and nonrigid_track.any():
            nonrigid[on_box] = nonrigid_track[boxes_T.track[target.box_index[on_box]]]
        return target, sources, motions, nonrigid

    @property
    def images_at_once(self) -> int:
        """Target images the writer may have this renderer render at once (its ``threads``)."""
        return self.threads

    def storing(self) -> contextlib.AbstractContextManager:
        """Held by the writer around all its images: BLAS stays on one thread from the first image to the
        last (lifted and set again between images, OpenBLAS's idle threads spun for a quarter more CPU)."""
        return one_blas_thread()

    def __call__(self, channel: str, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int) -> np.ndarray:
        """The writer's RenderFn: uint8 (H, W, 3) RGB. Its recorded confidence is the share of pixels a
        source saw, not counting pixels of non-rigid actors (their limbs move inside the warped box)."""
        with one_blas_thread():  # straight to uint8: the same bytes as rounding render()'s float image
            target, sources, motions, nonrigid = self.blend_inputs(camera, city_T_cam, timestamp_ns)
            img, cov = warp_to_uint8(target, sources, int(timestamp_ns), motions, self.config.blend,
                                     self.config.background, self.config.fill)
        self.coverage.setdefault(channel, {})[int(timestamp_ns)] = float((cov & ~nonrigid).mean())
        self.nonrigid.setdefault(channel, {})[int(timestamp_ns)] = float(nonrigid.mean())
        return img

    def save_coverage(self, path: Path) -> None:
        """Per image covered fraction as JSON ``{channel: {timestamp_ns: fraction}}`` (atomic)."""
        atomic_write_json(path, {ch: {str(t): v for t, v in sorted(d.items())}
                                 for ch, d in sorted(self.coverage.items())}, indent=1)


def warp_image_source(scene: SceneLog, config: WarpConfig | None = None, *, at_sweeps: bool = False,
                      jpeg_quality: int = 95, threads: int = 1) -> RenderedImages:
    """The writer's ImageSource for warp mode (one image per target camera at each sample time);
    ``threads`` (1 or 2) changes the time, never an image."""
    renderer = WarpRenderer(scene, config, threads)
    return RenderedImages(render=renderer, name=f"warp:{renderer.config.fingerprint()}", at_sweeps=at_sweeps,
                          jpeg_quality=jpeg_quality)
