"""Test-only writer of a tiny but complete nuScenes database that the real devkit loads.

One scene of 3 samples; CAM_FRONT, CAM_BACK (160x90 JPEGs, 4 Hz) and LIDAR_TOP (10 Hz, 5xfloat32
points) with sweeps between key frames; two annotated instances; one map record with a mask PNG;
a map expansion with one lane, one lane connector, dividers, a crossing and a drivable area.
Independent of the product's writer, so the validator is tested against the devkit's own rules.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

VERSION = "v1.0-tiny"
LOCATION = "av2-pit-adcf7d18"
LOGFILE = "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"
IMAGE_WH = (160, 90)
T0_US = 1_600_000_000_000_000
SAMPLE_PERIOD_US = 500_000
N_SAMPLES = 3
CHANNELS = {  # channel -> (modality, translation, rotation wxyz, focal at 1600 px), nuScenes n015 values
    "CAM_FRONT": ("camera", [1.70079118954, 0.0159456324149, 1.51095763913],
                  [0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755],
                  1266.417203046554),
    "CAM_BACK": ("camera", [0.0283260309358, 0.00345136761476, 1.57910346144],
                 [0.5037872666382278, -0.49740249788611096, -0.4941850223835201, 0.5045496097725578],
                 809.2209905677063),
    "LIDAR_TOP": ("lidar", [0.943713, 0.0, 1.84023],
                  [0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817],
                  None),
}


def tok(*key: object) -> str:
    """Deterministic 32-hex token."""
    return hashlib.md5("/".join(map(str, key)).encode()).hexdigest()


def _unit(q: list[float]) -> list[float]:
    n = math.sqrt(sum(v * v for v in q))
    return [v / n for v in q]


def _frame_times(channel: str) -> list[tuple[int, int | None]]:
    """(timestamp_us, index of the sample it is the key frame of, or None for a sweep)."""
    if channel == "LIDAR_TOP":  # 10 Hz, key frames exactly at the sample times
        return [(T0_US + k * 100_000, k // 5 if k % 5 == 0 else None)
                for k in range(5 * (N_SAMPLES - 1) + 1)]
    offset = -12_000 if channel == "CAM_FRONT" else 9_000  # cameras fire near, not at, the sample time
    return [(T0_US + offset + k * 250_000, k // 2 if k % 2 == 0 else None)
            for k in range(2 * (N_SAMPLES - 1) + 1)]


def write_tiny_db(root: Path) -> Path:
    """Write the database under ``root`` (the dataroot) and return it."""
    tables = _tables(root)
    table_dir = root / VERSION
    table_dir.mkdir(parents=True, exist_ok=True)
    for name, recs in tables.items():
        (table_dir / f"{name}.json").write_text(json.dumps(recs, indent=1))
    (table_dir / "splits.json").write_text(json.dumps({"train": ["scene-0001"], "val": []}))
    expansion = root / "maps" / "expansion" / f"{LOCATION}.json"
    expansion.parent.mkdir(parents=True, exist_ok=True)
    expansion.write_text(json.dumps(map_expansion()))
    return root


def _tables(root: Path) -> dict[str, list[dict]]:
    rng = np.random.default_rng(0)
    log_tok, scene_tok = tok("log"), tok("scene")
    category = [{"token": tok("cat", n), "name": n, "description": n}
                for n in ("vehicle.car", "human.pedestrian.adult")]
    attribute = [{"token": tok("attr", n), "name": n, "description": n}
                 for n in ("vehicle.moving", "pedestrian.moving")]
    visibility = [{"token": str(i), "level": lvl, "description": lvl}
                  for i, lvl in enumerate(("v0-40", "v40-60", "v60-80", "v80-100"), start=1)]
    sensor, calibrated = [], []
    for ch, (modality, t, q, f) in CHANNELS.items():
        sensor.append({"token": tok("sensor", ch), "channel": ch, "modality": modality})
        fs = None if f is None else f * IMAGE_WH[0] / 1600  # focal scaled with the image
        K = [] if fs is None else [[fs, 0.0, IMAGE_WH[0] / 2], [0.0, fs, IMAGE_WH[1] / 2], [0.0, 0.0, 1.0]]
        calibrated.append({"token": tok("cs", ch), "sensor_token": tok("sensor", ch), "translation": t,
                           "rotation": _unit(q), "camera_intrinsic": K})
    log = [{"token": log_tok, "logfile": LOGFILE, "vehicle": "av2", "date_captured": "2020-09-13",
            "location": LOCATION}]
    sample_tokens = [tok("sample", i) for i in range(N_SAMPLES)]
    sample = [{"token": sample_tokens[i], "timestamp": T0_US + i * SAMPLE_PERIOD_US, "scene_token": scene_tok,
               "prev": sample_tokens[i - 1] if i else "",
               "next": sample_tokens[i + 1] if i + 1 < N_SAMPLES else ""} for i in range(N_SAMPLES)]
    scene = [{"token": scene_tok, "name": "scene-0001", "description": "tiny", "log_token": log_tok,
              "nbr_samples": N_SAMPLES, "first_sample_token": sample_tokens[0],
              "last_sample_token": sample_tokens[-1]}]
    ego_pose, sample_data = [], []
    for ch, (modality, *_rest) in CHANNELS.items():
        frames = _frame_times(ch)
        tokens = [tok("sd", ch, ts) for ts, _ in frames]
        for k, (ts, key_of) in enumerate(frames):
            follow = next((s for _, s in frames[k:] if s is not None), N_SAMPLES - 1)
            folder = "samples" if key_of is not None else "sweeps"
            ext = "jpg" if modality == "camera" else "pcd.bin"
            filename = f"{folder}/{ch}/{LOGFILE}__{ch}__{ts}.{ext}"
            _write_sensor_file(root / filename, modality, rng)
            yaw = 0.02 * (ts - T0_US) / 1e6
            ego_pose.append({"token": tokens[k], "timestamp": ts,
                             "translation": [60.0 + 5.0 * (ts - T0_US) / 1e6, 50.0, 0.0],
                             "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]})
            w, h = IMAGE_WH if modality == "camera" else (0, 0)
            sample_data.append({"token": tokens[k], "sample_token": sample_tokens[follow],
                                "ego_pose_token": tokens[k], "calibrated_sensor_token": tok("cs", ch),
                                "filename": filename, "fileformat": "jpg" if modality == "camera" else "pcd",
                                "width": w, "height": h, "timestamp": ts, "is_key_frame": key_of is not None,
                                "prev": tokens[k - 1] if k else "",
                                "next": tokens[k + 1] if k + 1 < len(frames) else ""})
    instance, annotation = [], []
    tracks = (("car", "vehicle.car", range(3)), ("ped", "human.pedestrian.adult", range(1, 3)))
    for name, cat, samples in tracks:
        ann_tokens = [tok("ann", name, s) for s in samples]
        for k, s in enumerate(samples):
            annotation.append({"token": ann_tokens[k], "sample_token": sample_tokens[s],
                               "instance_token": tok("inst", name),
                               "attribute_tokens": [tok("attr", "vehicle.moving" if name == "car"
                                                        else "pedestrian.moving")],
                               "visibility_token": "4", "translation": [70.0 + s, 52.0, 0.8],
                               "size": [1.9, 4.5, 1.6] if name == "car" else [0.6, 0.6, 1.7],
                               "rotation": [1.0, 0.0, 0.0, 0.0], "num_lidar_pts": 10, "num_radar_pts": 0,
                               "prev": ann_tokens[k - 1] if k else "",
                               "next": ann_tokens[k + 1] if k + 1 < len(ann_tokens) else ""})
        instance.append({"token": tok("inst", name), "category_token": tok("cat", cat),
                         "nbr_annotations": len(ann_tokens), "first_annotation_token": ann_tokens[0],
                         "last_annotation_token": ann_tokens[-1]})
    mask_name = f"maps/{tok('mask')}.png"
    (root / "maps").mkdir(parents=True, exist_ok=True)
    mask = np.zeros((200, 300), dtype=np.uint8)
    mask[40:160, 20:280] = 255
    Image.fromarray(mask).save(root / mask_name)
    map_table = [{"token": tok("map"), "log_tokens": [log_tok], "category": "semantic_prior",
                  "filename": mask_name}]
    return {"category": category, "attribute": attribute, "visibility": visibility, "instance": instance,
            "sensor": sensor, "calibrated_sensor": calibrated, "ego_pose": ego_pose, "log": log,
            "scene": scene, "sample": sample, "sample_data": sample_data, "sample_annotation": annotation,
            "map": map_table}


def _write_sensor_file(path: Path, modality: str, rng: np.random.Generator) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if modality == "camera":
        img = rng.integers(0, 255, size=(IMAGE_WH[1], IMAGE_WH[0], 3), dtype=np.uint8)
        Image.fromarray(img).save(path, format="JPEG", quality=70)
    else:
        pts = np.zeros((64, 5), dtype=np.float32)
        pts[:, :3] = rng.normal(scale=10.0, size=(64, 3))
        pts[:, 4] = np.arange(64) % 32
        pts.tofile(path)


def map_expansion() -> dict:
    """One lane (x 40..140 at y 48..52) feeding a connector (x 140..150), plus dividers and a crossing."""
    nodes: list[dict] = []
    polygons: list[dict] = []
    lines: list[dict] = []

    def node(x: float, y: float) -> str:
        t = tok("node", len(nodes))
        nodes.append({"token": t, "x": x, "y": y})
        return t

    def polygon(name: str, xy: list[tuple[float, float]]) -> str:
        polygons.append({"token": tok("poly", name), "exterior_node_tokens": [node(x, y) for x, y in xy],
                         "holes": []})
        return tok("poly", name)

    def line(name: str, xy: list[tuple[float, float]]) -> str:
        lines.append({"token": tok("line", name), "node_tokens": [node(x, y) for x, y in xy]})
        return tok("line", name)

    def rect(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float]]:
        return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]

    lane, conn = tok("lane"), tok("connector")
    left = line("left", [(40.0 + 10 * i, 52.0) for i in range(11)])
    right = line("right", [(40.0 + 10 * i, 48.0) for i in range(11)])
    left_nodes = next(r["node_tokens"] for r in lines if r["token"] == left)
    right_nodes = next(r["node_tokens"] for r in lines if r["token"] == right)
    return {
        "version": "1.3", "canvas_edge": [300.0, 200.0],
        "node": nodes, "line": lines, "polygon": polygons,  # filled by the calls below (same list objects)
        "drivable_area": [{"token": tok("da"), "polygon_tokens": [polygon("da", rect(20, 40, 280, 160))]}],
        "road_segment": [{"token": tok("rs"), "polygon_token": polygon("rs", rect(30, 44, 160, 56)),
                          "is_intersection": False, "drivable_area_token": tok("da")}],
        "road_block": [],
        "lane": [{"token": lane, "polygon_token": polygon("lane", rect(40, 48, 140, 52)), "lane_type": "CAR",
                  "from_edge_line_token": "", "to_edge_line_token": "",
                  "left_lane_divider_segments": [{"node_token": t, "segment_type": "DOUBLE_DASHED_WHITE"}
                                                 for t in left_nodes],
                  "right_lane_divider_segments": [{"node_token": t, "segment_type": "NIL"}
                                                  for t in right_nodes]}],
        "lane_connector": [{"token": conn, "polygon_token": polygon("conn", rect(140, 48, 150, 52))}],
        "ped_crossing": [{"token": tok("ped"), "polygon_token": polygon("ped", rect(100, 44, 104, 56)),
                          "road_segment_token": tok("rs")}],
        "walkway": [], "stop_line": [], "carpark_area": [],
        "road_divider": [],
        "lane_divider": [{"token": tok("ld", "left"), "line_token": left, "lane_divider_segments": []},
                         {"token": tok("ld", "right"), "line_token": right, "lane_divider_segments": []}],
        "traffic_light": [],
        "arcline_path_3": {
            lane: [{"start_pose": [40.0, 50.0, 0.0], "end_pose": [140.0, 50.0, 0.0], "shape": "LSL",
                    "radius": 999.0, "segment_length": [0.0, 100.0, 0.0]}],
            conn: [{"start_pose": [140.0, 50.0, 0.0], "end_pose": [150.0, 50.0, 0.0], "shape": "LSL",
                    "radius": 999.0, "segment_length": [0.0, 10.0, 0.0]}]},
        "connectivity": {lane: {"incoming": [], "outgoing": [conn]},
                         conn: {"incoming": [lane], "outgoing": []}},
    }
