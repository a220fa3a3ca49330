"""Score camera images against a synthetic world's exact renders, per region, with lane paint.

:class:`RegionScores` collects, per camera, PSNR / SSIM over the whole image and over the ground,
objects and sky regions (the world's own labels of the true image; ego-body pixels count nowhere),
and the lane-paint offset (:mod:`nuav2.bench.paint_alignment`). The benchmarks and the demo all
score with it. For a written database, poses come from the database itself (ego_pose +
calibrated_sensor, read back from the JSON as the devkit would), so that checks the whole chain:
frame alignment, target extrinsics, timestamps and the pixels.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nuav2.evaluate.image_metrics import psnr, region_metrics
from nuav2.geometry import F64, T_from_quat_trans, translation_T
from nuav2.maptr.dataset import load_image_rgb
from nuav2.rig import CameraSpec
from nuav2.scene import VectorMap

REGIONS = ("whole", "ground", "objects", "sky", "nonrigid")
# truth_view's label for a pixel of a non-rigid actor (pedestrian, cyclist: nuav2.actor_tracks.NON_RIGID);
# the synthetic renderer's own labels call it an object.
LABEL_NONRIGID = 255


def world_region_masks(labels: np.ndarray) -> dict[str, np.ndarray]:
    """{region: bool (H, W)} from the labels of :func:`truth_view`; "whole" is every pixel but the ego body,
    "objects" every actor, "nonrigid" the pedestrians and cyclists among them. Static structure
    (buildings, poles) is part of "whole" only."""
    from nuav2.synth import REGION_LABELS

    nonrigid = labels == LABEL_NONRIGID
    return {"whole": labels != REGION_LABELS["ego"], "ground": labels == REGION_LABELS["ground"],
            "objects": (labels == REGION_LABELS["objects"]) | nonrigid, "sky": labels == REGION_LABELS["sky"],
            "nonrigid": nonrigid}


def truth_view(world, camera: CameraSpec, city_T_cam: F64,
               timestamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """(uint8 RGB, region labels) of the world's exact image of ``camera`` at ``city_T_cam`` and time; a
    non-rigid actor's pixels are labelled ``LABEL_NONRIGID``."""
    from nuav2.actor_tracks import is_non_rigid
    from nuav2.synth import render_view

    img, labels, owner = render_view(world, camera, city_T_cam, int(timestamp_ns), with_labels=True,
                                     with_owners=True)
    soft = np.array([is_non_rigid(a.category) for a in world.actors] + [False], bool)
    labels[soft[np.where(owner >= 0, owner, len(soft) - 1)]] = LABEL_NONRIGID
    return img, labels


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 4) if values else None


def _median(parts: list[np.ndarray]) -> tuple[float | None, int]:
    v = np.concatenate(parts) if parts else np.zeros(0)
    return (round(float(np.median(v)), 3) if len(v) else None), int(len(v))


@dataclass
class RegionScores:
    """Quality of one image producer against the world's truth: per camera and region, lists of
    per-image PSNR and SSIM; lane-paint offsets of its images (and of the truth, the measure's floor)."""

    paint_points: tuple[F64, F64] | None = None  # (points, tangents) of the map's solid paint, city frame
    values: dict[str, dict[str, dict[str, list[float]]]] = field(default_factory=dict)
    paint: list[np.ndarray] = field(default_factory=list)
    paint_truth: list[np.ndarray] = field(default_factory=list)
    # per camera and region, per image: (4, 3) sums over the region's pixels of t^2, t*w, w^2, 1 per
    # colour channel (t truth, w written): enough to score the image after any per-channel gain
    gauge_sums: dict[str, dict[str, list[np.ndarray]]] = field(default_factory=dict)
    # (3,) linear gain of the log's mean exposure (nuav2.synth.camera_effects.reference_gain): also score the
    # images brought from that exposure to the truth's unit exposure (``psnr_ref_db``: the log's one offset
    # taken out with its true value, the errors weighed at the truth's brightness as every other row's
    # are); None: the truth is at the images' exposure
    reference_gain: np.ndarray | None = None

    @staticmethod
    def for_map(vector_map: VectorMap | None, reference_gain: np.ndarray | None = None) -> RegionScores:
        from nuav2.bench.paint_alignment import painted_boundary_points

        pts = painted_boundary_points(vector_map) if vector_map is not None else None
        return RegionScores(pts if pts is not None and len(pts[0]) else None, reference_gain=reference_gain)

    def _paint(self, img: np.ndarray, camera: CameraSpec, city_T_cam: F64) -> np.ndarray:
        from nuav2.bench.paint_alignment import paint_offsets_px

        return paint_offsets_px(img, camera, city_T_cam, *self.paint_points)

    def add(self, camera: CameraSpec, city_T_cam: F64, img: np.ndarray, truth: np.ndarray, labels: np.ndarray,
            *, with_paint_floor: bool = False) -> dict:
        """Score one uint8 image against the truth (and its labels); returns the per-region metrics."""
        masks = world_region_masks(labels)
        got = region_metrics(img, truth, masks, data_range=255.0)
        cam = self.values.setdefault(camera.channel, {})
        sums = self.gauge_sums.setdefault(camera.channel, {})
        t, w = truth.astype(np.float64), img.astype(np.float64)
        for region, m in got.items():
            if m is not None:
                sel_t, sel_w = t[masks[region]], w[masks[region]]
                sums.setdefault(region, []).append(np.stack([(sel_t * sel_t).sum(0), (sel_t * sel_w).sum(0),
                                                             (sel_w * sel_w).sum(0),
                                                             np.full(3, float(len(sel_t)))]))
        at_unit = None
        if self.reference_gain is not None:
            from nuav2.synth.camera_effects import expose

            at_unit = expose(img, 1.0 / np.asarray(self.reference_gain, np.float64))
        for region, m in got.items():
            if m is not None:
                r = cam.setdefault(region, {"psnr_db": [], "ssim": [], "psnr_ref_db": []})
                r["psnr_db"].append(m["psnr_db"])
                r["ssim"].append(m["ssim"])
                r["psnr_ref_db"].append(m["psnr_db"] if at_unit is None else
                                        psnr(at_unit, truth, data_range=255.0, mask=masks[region]))
        if self.paint_points is not None:
            self.paint.append(self._paint(img, camera, city_T_cam))
            if with_paint_floor:
                self.paint_truth.append(self._paint(truth, camera, city_T_cam))
        return got

    @property
    def channels(self) -> list[str]:
        return list(self.values)

    def gauge_gain(self) -> np.ndarray:
        """(3,) the per-channel gain on the written images that best fits the truth over every scored
        image's whole region (1 where nothing was scored)."""
        parts = [s for regions in self.gauge_sums.values() for s in regions.get("whole", [])]
        if not parts:
            return np.ones(3)
        tot = np.sum(parts, axis=0)
        return np.where(tot[2] > 0, tot[1] / np.maximum(tot[2], 1e-12), 1.0)

    def _gauge_psnr(self, gain: np.ndarray) -> dict[str, dict[str, float]]:
        """{camera: {region: mean PSNR dB of the images after ``gain``}} from the stored sums."""
        out: dict[str, dict[str, float]] = {}
        for ch, regions in self.gauge_sums.items():
            for region, parts in regions.items():
                psnrs = []
                for tt, tw, ww, n in parts:
                    mse = float(np.sum(tt - 2 * gain * tw + gain**2 * ww) / max(np.sum(n), 1.0))
                    psnrs.append(10.0 * np.log10(255.0**2 / max(mse, 255.0**2 * 1e-10)))
                out.setdefault(ch, {})[region] = _mean(psnrs)
        return out

    def summary(self) -> dict:
        """Means per camera and region, then over cameras (each camera weighs the same); paint medians."""
        per_camera = {ch: {region: {"psnr_db": _mean(v["psnr_db"]), "ssim": _mean(v["ssim"]),
                                    "psnr_ref_db": _mean(v["psnr_ref_db"]), "images": len(v["psnr_db"])}
                           for region, v in regions.items()}
                      for ch, regions in self.values.items()}
        out: dict = {"images": sum(c["whole"]["images"] for c in per_camera.values() if "whole" in c)}
        for metric in ("psnr_db", "ssim", "psnr_ref_db"):
            out[metric] = {region: _mean([c[region][metric] for c in per_camera.values() if region in c])
                           for region in REGIONS}
        gain = self.gauge_gain()
        gauge = self._gauge_psnr(gain)
        out["psnr_gauge_db"] = {r: _mean([c[r] for c in gauge.values() if c.get(r) is not None])
                                for r in REGIONS}
        out["gauge_log_gain"] = [round(float(x), 4) for x in np.log(np.maximum(gain, 1e-12))]
        out["paint_median_px"], out["paint_points"] = _median(self.paint)
        if self.paint_truth:
            out["paint_median_px_truth"], out["paint_points_truth"] = _median(self.paint_truth)
        out["per_camera"] = per_camera
        return out


@dataclass(frozen=True)
class WrittenImage:
    """One key-frame camera image of the database with everything needed to re-render it."""

    channel: str
    path: Path
    camera: CameraSpec
    city_T_cam: F64
    timestamp_ns: int


def key_camera_images(dataroot: Path, version: str, log_offsets: dict[str, np.ndarray]) -> list[WrittenImage]:
    """Key-frame camera images with city poses; ``log_offsets``: {log token: city_offset (x, y, z)}."""
    root = Path(dataroot) / version

    def table(name: str) -> dict[str, dict]:
        return {r["token"]: r for r in json.loads((root / f"{name}.json").read_text())}

    sensors, calibs, poses = table("sensor"), table("calibrated_sensor"), table("ego_pose")
    samples, scenes, logs = table("sample"), table("scene"), table("log")
    out = []
    for sd in json.loads((root / "sample_data.json").read_text()):
        calib = calibs[sd["calibrated_sensor_token"]]
        sensor = sensors[calib["sensor_token"]]
        if sensor["modality"] != "camera" or not sd["is_key_frame"]:
            continue
        log = logs[scenes[samples[sd["sample_token"]]["scene_token"]]["log_token"]]
        offset = log_offsets[log["token"]]
        pose = poses[sd["ego_pose_token"]]
        global_T_ego = T_from_quat_trans(pose["rotation"], pose["translation"])
        ego_T_cam = T_from_quat_trans(calib["rotation"], calib["translation"])
        city_T_cam = translation_T(*offset) @ global_T_ego @ ego_T_cam
        cam = CameraSpec(sensor["channel"], sd["width"], sd["height"], np.asarray(calib["camera_intrinsic"]),
                         ego_T_cam)
        out.append(WrittenImage(sensor["channel"], Path(dataroot) / sd["filename"], cam, city_T_cam,
                                int(sd["timestamp"]) * 1000))
    return out


def score_against_world(images: list[WrittenImage], world, every: int = 1,
                        vector_map: VectorMap | None = None,
                        reference_gain: np.ndarray | None = None) -> RegionScores:
    """Per-channel, per-region PSNR/SSIM of written images vs the world's render at the same pose and
    time; lane-paint offsets (and the truth's floor) when ``vector_map`` is given; PSNR after the log's
    true mean exposure is taken out too when ``reference_gain`` is (``RegionScores.reference_gain``)."""
    scores = RegionScores.for_map(vector_map, reference_gain)
    for im in images[::every]:
        truth, labels = truth_view(world, im.camera, im.city_T_cam, im.timestamp_ns)
        img = load_image_rgb(str(im.path))
        scores.add(im.camera, im.city_T_cam, img, truth, labels, with_paint_floor=True)
    return scores


def log_offsets(dataroot: Path, version: str) -> dict[str, np.ndarray]:
    """{log token: city_offset (x, y, z)} from the converter's ``nuav2_logs.json`` sidecar."""
    from nuav2.nuscenes_db.map_frame import city_offset_of

    path = Path(dataroot) / version / "nuav2_logs.json"
    return {rec["log_token"]: city_offset_of(rec, str(path)) for rec in json.loads(path.read_text())}
