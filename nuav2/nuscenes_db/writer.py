"""One source log -> one shard: its nuScenes records plus the data files they point to.

The writer is shared by native and render mode. It takes the OUTPUT rig (cameras and
LIDAR_TOP in the output ego frame, whose origin is at ground level) and an
:class:`~nuav2.nuscenes_db.images.ImageSource`; everything else is the same:

- ego poses of the output vehicle frame: ``city_T_egoT = city_T_egoS(t) @ egoS_T_egoT``, moved
  into the log's nuScenes global frame (the city frame minus the rigid offset of ``map_frame``:
  whole metres in x, y and the ground height under the first pose in z), one per sample_data
  at its own timestamp;
- the virtual LIDAR_TOP sweep re-expressed in the output rig's LIDAR_TOP frame;
- annotations at the samples, in the global frame.

Data files go straight to the dataroot (names carry the log id, so parallel writers never
collide; each file is written atomically); the records are returned and saved as a shard.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nuav2.geometry import F64, egoS_T_egoT_from_heights
from nuav2.nuscenes_db import annotations as ann_mod
from nuav2.nuscenes_db import records as rec
from nuav2.nuscenes_db.images import CameraShot, ImageSource, images_at_once_of, storing_of
from nuav2.nuscenes_db.keyframes import (
    KEY_IMAGE_TOLERANCE_NS,
    Timeline,
    TimelineFrame,
    build_timeline,
    plan_samples,
)
from nuav2.nuscenes_db.lidar_top import lidar_T_egoS, sweep_to_pcd_rows, write_pcd_bin
from nuav2.nuscenes_db.map_frame import OFFSET_KEY, MapFrame, map_frame_for
from nuav2.nuscenes_db.tables import PER_LOG_TABLES
from nuav2.nuscenes_db.tokens import make_token
from nuav2.nuscenes_db.visibility import (
    VisibilityCamera,
    box_visibility,
    cameras_in_source_ego,
    occluder_points,
)
from nuav2.progress import progress_bar
from nuav2.rig import Rig
from nuav2.scene import SceneLog, VectorMap
from nuav2.threads import ordered_thread_map

log = logging.getLogger(__name__)

# Bump when what a shard holds changes, so old shards are redone instead of merged.
# 2: global frame shifted in z too (city_offset [x, y, z]); 3: 80 m map margin; 4: measured visibility
WRITER_FORMAT = 4


@dataclass(frozen=True)
class WriterOptions:
    keyframe_hz: float | None = None  # None: every sweep with all cameras is a sample
    key_image_tolerance_ns: int = KEY_IMAGE_TOLERANCE_NS
    show_progress: bool = True
    # dataroot-relative files a failed attempt must not remove: the same log's files that another
    # --version's tables use (same names, rewritten with the same bytes)
    keep_on_failure: frozenset[str] = frozenset()


@dataclass
class LogShard:
    """A log's records (per-log tables only) and what the merge step needs to know about it."""

    log_id: str
    tables: dict[str, list[dict]]
    channels: dict[str, str]  # channel -> modality
    meta: dict = field(default_factory=dict)


def map_points_city_xy(scene: SceneLog) -> F64:
    """Every city xy the log's global frame must keep >= the margin: map vertices and poses."""
    pts = [scene.city_T_ego[:, :2, 3]]
    vm = scene.vector_map
    if vm is not None:
        for lane in vm.lane_segments.values():
            pts += [lane.left_boundary[:, :2], lane.right_boundary[:, :2]]
        pts += [pc.polygon[:, :2] for pc in vm.ped_crossings.values()]
        pts += [da.boundary[:, :2] for da in vm.drivable_areas.values()]
    return np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in pts])


def ground_z_city(scene: SceneLog) -> float:
    """Ground height under the ego at the log's first pose: the global frame's z = 0.

    From the ground-height raster where the log has one and it covers that point; otherwise the
    first pose's height minus the source rig's origin height (the output ego origin is on the
    ground, so its first pose then sits at global z = 0 exactly). Rounded to 1 mm.
    """
    city_xyz = np.asarray(scene.city_T_ego[0, :3, 3], dtype=np.float64)
    if scene.ground_height is not None:
        z = float(np.asarray(scene.ground_height.height_at(city_xyz[None, :2])).reshape(-1)[0])
        if np.isfinite(z):
            return round(z, 3)
    return round(float(city_xyz[2] - scene.rig.origin_height_m), 3)


def write_map(scene: SceneLog, frame: MapFrame, dataroot: Path) -> str:
    """Write the log's map expansion + mask PNG; returns the mask's dataroot-relative filename."""
    from nuav2.nuscenes_db.map_expansion import write_map_expansion

    vector_map = scene.vector_map or VectorMap(scene.city, {}, {}, {})
    artifacts = write_map_expansion(vector_map, frame, dataroot, cover_xy_city=scene.city_T_ego[:, :2, 3])
    return str(artifacts.mask_filename)


def data_filename(log_id: str, channel: str, timestamp_us: int, is_key_frame: bool, ext: str) -> str:
    """Dataroot-relative path, nuScenes style: ``samples|sweeps/<CH>/<logfile>__<CH>__<ts_us><ext>``."""
    folder = "samples" if is_key_frame else "sweeps"
    return f"{folder}/{channel}/{log_id}__{channel}__{int(timestamp_us)}{ext}"


class _Files:
    """Data files written for one log, removed again if the log fails half-way."""

    def __init__(self, dataroot: Path, keep: frozenset[str] = frozenset()) -> None:
        self.dataroot = dataroot
        self.keep = {dataroot / rel for rel in keep}
        self.written: list[Path] = []

    def path(self, rel: str) -> Path:
        p = self.dataroot / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        self.written.append(p)
        return p

    def remove_all(self) -> None:
        for p in self.written:
            if p not in self.keep and (p.is_file() or p.is_symlink()):
                p.unlink()


def write_log(scene: SceneLog, out_rig: Rig, images: ImageSource, dataroot: Path,
              options: WriterOptions | None = None) -> LogShard:
    """Write one log's data files under ``dataroot`` and return its records (see module doc)."""
    options = options or WriterOptions()
    files = _Files(Path(dataroot), options.keep_on_failure)
    try:
        return _write_log(scene, out_rig, images, files, options)
    except BaseException:
        files.remove_all()
        raise


def _camera_times(shots: dict[str, list[CameraShot]]) -> dict[str, np.ndarray]:
    return {ch: np.array([s.timestamp_ns for s in lst], dtype=np.int64) for ch, lst in shots.items()}


def _write_log(scene: SceneLog, out_rig: Rig, images: ImageSource, files: _Files,
               options: WriterOptions) -> LogShard:
    log_id = scene.log_id
    lidar_ch = out_rig.keyframe_lidar
    egoT_T_lidar = out_rig.lidar(lidar_ch).ego_T_lidar
    egoS_T_egoT = egoS_T_egoT_from_heights(scene.rig.origin_height_m, out_rig.origin_height_m)
    frame = map_frame_for(scene.city, log_id, map_points_city_xy(scene), ground_z_city(scene))
    global_T_city = frame.global_T_city

    # Timeline: which sweeps are samples, which images are key frames, unique µs labels.
    sweep_ns = scene.sweep_timestamps_ns
    probe = _camera_times(images.shots(scene, out_rig, sweep_ns))
    key_idx = plan_samples(sweep_ns, probe, options.keyframe_hz, options.key_image_tolerance_ns)
    shots = images.shots(scene, out_rig, sweep_ns[key_idx])
    timeline = build_timeline(lidar_ch, sweep_ns, key_idx, _camera_times(shots),
                              options.key_image_tolerance_ns)
    log.info("log %s: %d samples from %d sweeps, %d cameras (%s)", log_id, timeline.num_samples,
             len(sweep_ns), len(shots), ", ".join(shots) or "none")

    scene_token = make_token(log_id, "scene", "")
    log_token = make_token(log_id, "log", "")
    sample_tokens = [make_token(log_id, "sample", str(int(t))) for t in timeline.key_ns]
    calib_tokens = {ch: make_token(log_id, "calibrated_sensor", ch) for ch in timeline.frames}
    tables: dict[str, list[dict]] = {t: [] for t in PER_LOG_TABLES}
    tables["calibrated_sensor"].append(rec.calibrated_sensor_record(calib_tokens[lidar_ch], lidar_ch,
                                                                    egoT_T_lidar, None))
    for ch in shots:
        cam = out_rig.camera(ch)
        tables["calibrated_sensor"].append(
            rec.calibrated_sensor_record(calib_tokens[ch], ch, cam.ego_T_cam, cam.K))

    # Output-ego poses of every reading at its own time (one batched interpolation).
    all_frames = [f for ch in timeline.frames for f in timeline.frames[ch]]
    city_T_egoS = scene.city_T_ego_at(np.array([f.timestamp_ns for f in all_frames], dtype=np.int64))
    city_T_egoS = city_T_egoS.reshape(-1, 4, 4)
    city_T_egoT = city_T_egoS @ egoS_T_egoT
    global_T_egoT = global_T_city @ city_T_egoT
    sd_tokens = {(f.channel, f.index): make_token(log_id, "sample_data", f"{f.channel}@{f.timestamp_ns}")
                 for f in all_frames}
    for f, pose in zip(all_frames, global_T_egoT):
        tables["ego_pose"].append(rec.ego_pose_record(sd_tokens[(f.channel, f.index)], pose, f.timestamp_us))
    tables["ego_pose"].sort(key=lambda r: (r["timestamp"], r["token"]))
    city_T_egoT_of = {(f.channel, f.index): T for f, T in zip(all_frames, city_T_egoT)}

    boxes = ann_mod.key_boxes(scene, timeline.key_ns, global_T_city)
    view_cams = cameras_in_source_ego((out_rig.camera(ch) for ch in shots), egoS_T_egoT)
    filenames = _write_lidar_top(scene, timeline, lidar_ch, lidar_T_egoS(egoT_T_lidar, egoS_T_egoT), boxes,
                                 view_cams, files, options)
    filenames.update(_write_cameras(scene, timeline, out_rig, images, shots, city_T_egoT_of, files, options))

    _sample_data_records(tables, timeline, lidar_ch, out_rig, shots, sd_tokens, sample_tokens, calib_tokens,
                         filenames)
    for s, (prev, nxt) in enumerate(rec.linked(sample_tokens)):
        tables["sample"].append(
            rec.sample_record(sample_tokens[s], int(timeline.key_us[s]), scene_token, prev, nxt))

    tables["instance"], tables["sample_annotation"] = ann_mod.annotation_records(log_id, boxes, sample_tokens)

    tables["scene"].append(rec.scene_record(scene_token, log_token, timeline.num_samples, sample_tokens[0],
                                            sample_tokens[-1], name="", description=log_id))
    tables["log"].append(rec.log_record(log_token, log_id, scene.rig.name, int(scene.pose_timestamps_ns[0]),
                                        frame.location))
    mask_filename = write_map(scene, frame, files.dataroot)
    map_token = make_token(log_id, "map", frame.location)
    tables["map"].append(rec.map_record(map_token, [log_token], mask_filename))

    channels = {lidar_ch: "lidar", **{ch: "camera" for ch in shots}}
    n_images = sum(len(timeline.frames[ch]) for ch in shots)
    meta = {
        "log_id": log_id, "source": scene.source, "split": scene.split, "city": scene.city,
        "city_frame": scene.city_frame, "location": frame.location,
        OFFSET_KEY: [float(v) for v in frame.city_offset],
        "source_rig": scene.rig.name, "source_origin_height_m": float(scene.rig.origin_height_m),
        "output_rig": out_rig.name, "output_origin_height_m": float(out_rig.origin_height_m),
        "log_token": log_token, "scene_token": scene_token,
        "num_samples": timeline.num_samples, "num_sweeps": len(timeline.frames[lidar_ch]),
        "num_images": n_images,
        "num_annotations": len(tables["sample_annotation"]),
    }
    return LogShard(log_id=log_id, tables=tables, channels=channels, meta=meta)


def _write_lidar_top(scene: SceneLog, timeline: Timeline, lidar_ch: str, lidar_T_ego: F64,
                     boxes: ann_mod.KeyBoxes, view_cams: list[VisibilityCamera], files: _Files,
                     options: WriterOptions) -> dict[tuple[str, int], str]:
    """Each source sweep moved into the output LIDAR_TOP frame; from the key sweeps, fills unknown box
    point counts (``boxes.num_lidar_pts == -1``) and, with cameras (``view_cams``, in the source ego
    frame), the boxes' visible fractions. Returns {(channel, index): filename}."""
    filenames: dict[tuple[str, int], str] = {}
    for f in progress_bar(timeline.frames[lidar_ch], desc=f"{scene.log_id[:8]} {lidar_ch}", unit="sweep",
                          leave=False, disable=not options.show_progress):
        points = scene.sweep(scene.lidar_sweeps[f.index])
        if not len(points.xyz_ego):
            log.warning("%s: the LiDAR sweep at %d ns has no points; its %s file is empty", scene.log_id,
                        scene.lidar_sweeps[f.index].timestamp_ns, lidar_ch)
        rel = data_filename(scene.log_id, lidar_ch, f.timestamp_us, f.is_key_frame, ".pcd.bin")
        write_pcd_bin(files.path(rel), sweep_to_pcd_rows(points, lidar_T_ego))
        filenames[(lidar_ch, f.index)] = rel
        if f.is_key_frame:
            here = boxes.sample_index == f.sample_index
            todo = np.flatnonzero(here & (boxes.num_lidar_pts < 0))
            if len(todo):
                boxes.num_lidar_pts[todo] = ann_mod.count_points_in_boxes(
                    points.xyz_ego, boxes.ego_T_box[todo], boxes.size_lwh[todo])
            if view_cams and np.any(here):
                occluders = occluder_points(points.xyz_ego, boxes.ego_T_box[here], boxes.size_lwh[here])
                boxes.visible[here] = box_visibility(boxes.ego_T_box[here], boxes.size_lwh[here], view_cams,
                                                     occluders)
    return filenames


def _write_cameras(scene: SceneLog, timeline: Timeline, out_rig: Rig, images: ImageSource,
                   shots: dict[str, list[CameraShot]], city_T_egoT_of: dict, files: _Files,
                   options: WriterOptions) -> dict[tuple[str, int], str]:
    """The image source stores each image, given its camera's pose in the city frame at its time."""
    filenames: dict[tuple[str, int], str] = {}
    # Time-major order: a renderer that caches source views reuses them across target cameras.
    cam_frames = sorted((f for ch in shots for f in timeline.frames[ch]),
                        key=lambda f: (f.timestamp_us, f.channel))

    def store(f: TimelineFrame) -> str:
        shot = shots[f.channel][f.index]
        cam = out_rig.camera(f.channel)
        rel = data_filename(scene.log_id, f.channel, f.timestamp_us, f.is_key_frame, images.extension(shot))
        images.store(shot, cam, city_T_egoT_of[(f.channel, f.index)] @ cam.ego_T_cam, files.path(rel))
        return rel

    # A source that can store several images at once says so (``images_at_once``, warp mode's threads); the
    # files are the same either way.
    # ``storing()``: a context the source holds around the whole loop (warp mode: BLAS on one thread).
    with storing_of(images):
        stored = ordered_thread_map(store, cam_frames, images_at_once_of(images))
        bar = progress_bar(stored, total=len(cam_frames), desc=f"{scene.log_id[:8]} cameras", unit="img",
                           leave=False, disable=not options.show_progress or not cam_frames)
        for f, rel in zip(cam_frames, bar):
            filenames[(f.channel, f.index)] = rel
    return filenames


def _sample_data_records(tables: dict[str, list[dict]], timeline: Timeline, lidar_ch: str, out_rig: Rig,
                         shots: dict[str, list[CameraShot]], sd_tokens: dict, sample_tokens: list[str],
                         calib_tokens: dict[str, str], filenames: dict) -> None:
    """sample_data rows, linked prev/next per channel across key frames and sweeps."""
    for ch, frames in timeline.frames.items():
        is_cam = ch != lidar_ch
        width, height = (out_rig.camera(ch).width, out_rig.camera(ch).height) if is_cam else (0, 0)
        fileformat = "pcd"
        tokens = [sd_tokens[(ch, f.index)] for f in frames]
        for f, tok, (prev, nxt) in zip(frames, tokens, rec.linked(tokens)):
            rel = filenames[(ch, f.index)]
            if is_cam:
                fileformat = Path(rel).suffix.lstrip(".")
            tables["sample_data"].append(rec.sample_data_record(
                tok, sample_tokens[f.sample_index], tok, calib_tokens[ch], f.timestamp_us, fileformat,
                f.is_key_frame, height, width, rel, prev, nxt))


def output_rig_native(scene: SceneLog) -> Rig:
    """Native mode's output rig: the log's own sensors, in a ground-level ego frame."""
    return scene.rig.with_origin_height(0.0)
