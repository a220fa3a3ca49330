"""How right are the written ``visibility_token`` values? Against a synthetic world's exact render.

    python -m nuav2.bench.visibility_check DATAROOT LOG_DIR [--version v1.0-nuav2] [--json OUT]

DATAROOT is ``nuav2 convert``'s output for the synthetic log LOG_DIR (``nuav2 synth``). For every
key-frame camera image, the world's ground-truth renderer (which shares no code with the
converter) draws the depth and the actor owning each pixel at the sample's LiDAR time and pose
(the time the boxes are for). A pixel inside an annotation's box (an exact ray-box test written
here) counts as seen when the truth there is the box's own actor or lies no nearer than where
the ray enters the box. The seen share over all cameras, binned as nuScenes bins it, is the
oracle token. Also times the converter's own measure (``nuav2/nuscenes_db/visibility.py``) on
every sample of the source log, in CPU seconds.
"""

from __future__ import annotations

import argparse
import collections
import json
import time
from pathlib import Path

import numpy as np

from nuav2.cli_types import path
from nuav2.geometry import T_inverse, make_T, quat_to_rot
from nuav2.nuscenes_db.tokens import make_token
from nuav2.rig import CameraSpec
from nuav2.synth.render import render_view
from nuav2.synth.world import load_world

NUSCENES_BIN_EDGES = (0.4, 0.6, 0.8)  # nuScenes: v0-40, v40-60, v60-80, v80-100


def oracle_bin(fraction: float) -> int:
    return 1 + int(np.searchsorted(NUSCENES_BIN_EDGES, fraction, side="right"))


def oracle_fractions(dataroot: Path, log_dir: Path,
                     version: str = "v1.0-nuav2") -> dict[str, tuple[float, str]]:
    """{annotation token: (seen fraction in the exact render, token the converter wrote)}."""
    v = Path(dataroot) / version
    tab = {n: json.loads((v / f"{n}.json").read_text()) for n in (
        "sample", "sample_data", "calibrated_sensor", "ego_pose", "sample_annotation", "sensor")}
    world = load_world(log_dir)
    meta = next(m for m in json.loads((v / "nuav2_logs.json").read_text()) if m["log_id"] == world.log_id)
    city_T_global = make_T(np.eye(3), meta["city_offset"])
    actor_of = {make_token(meta["log_id"], "instance", a.track_uuid): i for i, a in enumerate(world.actors)}
    calib = {c["token"]: c for c in tab["calibrated_sensor"]}
    channel = {s["token"]: s["channel"] for s in tab["sensor"]}
    pose = {p["token"]: p for p in tab["ego_pose"]}
    scene_samples = {s["token"] for s in tab["sample"]}
    lidar_pose = {d["sample_token"]: pose[d["ego_pose_token"]] for d in tab["sample_data"]
                  if d["is_key_frame"] and d["fileformat"] == "pcd"}
    time_us = {s["token"]: s["timestamp"] for s in tab["sample"]}
    anns = collections.defaultdict(list)
    for a in tab["sample_annotation"]:
        if a["instance_token"] in actor_of:
            anns[a["sample_token"]].append(a)
    seen, total = collections.Counter(), collections.Counter()
    for sd in tab["sample_data"]:
        if not sd["is_key_frame"] or sd["fileformat"] == "pcd" or sd["sample_token"] not in scene_samples \
                or not anns[sd["sample_token"]]:
            continue
        c = calib[sd["calibrated_sensor_token"]]
        K = np.array(c["camera_intrinsic"])
        ego_T_cam = make_T(quat_to_rot(c["rotation"]), c["translation"])
        p = lidar_pose[sd["sample_token"]]
        global_T_cam = make_T(quat_to_rot(p["rotation"]), p["translation"]) @ ego_T_cam
        cam = CameraSpec(channel[c["sensor_token"]], sd["width"], sd["height"], K, ego_T_cam)
        t_ns = time_us[sd["sample_token"]] * 1000
        _, depth, owner = render_view(world, cam, city_T_global @ global_T_cam, t_ns, with_depth=True,
                                      with_owners=True)
        depth, owner = depth.reshape(-1), owner.reshape(-1)
        # OpenCV pixel centres (the renderer's): pixel (u, v) is centred at (u, v).
        u, v_ = np.meshgrid(np.arange(sd["width"], dtype=float), np.arange(sd["height"], dtype=float))
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v_ - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        rays = rays.reshape(-1, 3)
        cam_T_global = T_inverse(global_T_cam)
        for a in anns[sd["sample_token"]]:
            w, length, h = a["size"]
            half = np.array([length, w, h]) / 2
            cam_T_box = cam_T_global @ make_T(quat_to_rot(a["rotation"]), a["translation"])
            origin = -cam_T_box[:3, :3].T @ cam_T_box[:3, 3]
            d = rays @ cam_T_box[:3, :3]
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (-half - origin) / d, (half - origin) / d
            enter = np.maximum(np.nanmax(np.minimum(t1, t2), axis=1), 0.1)  # ray z is 1: t = depth
            hit = enter <= np.nanmin(np.maximum(t1, t2), axis=1)
            total[a["token"]] += int(hit.sum())
            own = owner[hit] == actor_of[a["instance_token"]]
            seen[a["token"]] += int(((depth[hit] >= enter[hit] - 0.05) | own).sum())
    return {a["token"]: (seen[a["token"]] / total[a["token"]] if total[a["token"]] else 0.0,
                         a["visibility_token"]) for sample in anns.values() for a in sample}


def agreement(fractions: dict[str, tuple[float, str]]) -> dict:
    """Shares of written tokens in the oracle's bin and within one bin of it, and the confusion counts."""
    pairs = [(oracle_bin(f), int(t)) for f, t in fractions.values()]
    same = [a == b for a, b in pairs]
    near = [abs(a - b) <= 1 for a, b in pairs]
    confusion = collections.Counter(f"oracle {a} written {b}" for a, b in pairs)
    return {"annotations": len(pairs), "same_bin": int(sum(same)), "within_one_bin": int(sum(near)),
            "same_bin_share": float(np.mean(same)) if pairs else float("nan"),
            "within_one_share": float(np.mean(near)) if pairs else float("nan"),
            "confusion": dict(sorted(confusion.items()))}


def measure_cost(log_dir: Path, rig_name: str | None, scale: float, skip_first: bool = True) -> dict:
    """CPU seconds of the converter's visibility per sample on the source log (every annotated sweep
    a sample), in ``rig_name``'s cameras (None: the log's own), split into the occluder points and the
    ray pass; ``skip_first`` leaves out the first sample (it pays numba's cache load)."""
    from converters.av2.reader import read_log
    from nuav2.geometry import egoS_T_egoT_from_heights
    from nuav2.nuscenes_db.annotations import key_boxes
    from nuav2.nuscenes_db.visibility import box_visibility, cameras_in_source_ego, occluder_points
    from nuav2.rig import load_rig

    scene = read_log(Path(log_dir))
    rig = scene.rig.with_origin_height(0.0) if rig_name is None else load_rig(rig_name, scale)
    egoS_T_egoT = egoS_T_egoT_from_heights(scene.rig.origin_height_m, rig.origin_height_m)
    cams = cameras_in_source_ego(rig.cameras, egoS_T_egoT)
    boxes = key_boxes(scene, scene.sweep_timestamps_ns, np.eye(4))
    occ_s, ray_s, samples, n_boxes, n_points = 0.0, 0.0, 0, 0, 0
    first = True
    for s, ref in enumerate(scene.lidar_sweeps):
        here = boxes.sample_index == s
        if not np.any(here):
            continue
        pts = scene.sweep(ref).xyz_ego
        t0 = time.process_time()
        occ = occluder_points(pts, boxes.ego_T_box[here], boxes.size_lwh[here])
        t1 = time.process_time()
        box_visibility(boxes.ego_T_box[here], boxes.size_lwh[here], cams, occ)
        t2 = time.process_time()
        if not (first and skip_first):
            occ_s, ray_s, samples = occ_s + t1 - t0, ray_s + t2 - t1, samples + 1
            n_boxes, n_points = n_boxes + int(here.sum()), n_points + len(pts)
        first = False
    per = max(samples, 1)
    return {"samples_timed": samples, "cameras": len(cams), "boxes_per_sample": n_boxes / per,
            "points_per_sample": n_points / per, "occluder_cpu_s_per_sample": occ_s / per,
            "rays_cpu_s_per_sample": ray_s / per, "cpu_s_per_sample": (occ_s + ray_s) / per}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m nuav2.bench.visibility_check",
                                description=__doc__.split("\n")[0])
    p.add_argument("dataroot", type=path)
    p.add_argument("log_dir", type=path)
    p.add_argument("--version", default="v1.0-nuav2")
    p.add_argument("--rig", default=None,
                   help="the conversion's --rig for the timing (default: the log's own cameras)")
    p.add_argument("--scale", type=float, default=1.0, help="the conversion's --scale for the timing")
    p.add_argument("--json", type=path, default=None, help="also write the result here")
    args = p.parse_args(argv)
    result = {"dataroot": str(args.dataroot), "log_dir": str(args.log_dir),
              **agreement(oracle_fractions(args.dataroot, args.log_dir, args.version)),
              "cost": measure_cost(args.log_dir, args.rig, args.scale)}
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
