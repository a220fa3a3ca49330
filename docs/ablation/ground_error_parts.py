"""What the ground's error in written target-rig images is made of (docs/reconstruction.md).

For every key-frame camera image of a converted synthetic log, against the world's exact render (with
the log's true mean exposure taken out, as the ablation's ref. PSNR), splits the ground pixels' squared
error four ways, each pixel in the first that holds it: next to an actor or static structure (within 2 px
of a pixel that is neither ground nor sky), unseen (no image of the log's cameras shows that ground point:
outside every frame, or hidden there: no depth of the 3 x 3 pixels it falls on, in the world's exact
depth image, within 5 % + 10 cm of its own, nor its depth between theirs), on an edge of the truth (Sobel
magnitude of its grey level > 60 on 0-255, grown by 1 px: paint, kerbs, shadow borders), and the rest.
Also: the ground PSNR after a Gaussian blur of the truth alone or of both images (how much of the error is
sharpness and sub-pixel placement), and the aliasing floor (the point-sampled truth against the truth
averaged over 3 x 3 rays per pixel). PSNRs pool the squared error of all images. Prints one JSON object.
Usage (from the repository root):

    nuav2 synth --preset hard --seed 0 LOGS
    nuav2 convert av2 LOGS OUT --mode render --scale 0.125 --recon-preset fast
    python docs/ablation/ground_error_parts.py LOGS/train/<log_id> OUT

Section "Where hard's ground goes" of docs/reconstruction.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

from converters.av2 import read_log
from nuav2.evaluate.against_world import key_camera_images, log_offsets, world_region_masks
from nuav2.geometry import T_inverse, transform_points
from nuav2.maptr.dataset import load_image_rgb
from nuav2.splat.views import project
from nuav2.synth import load_world, render_view
from nuav2.synth.camera_effects import expose, log_reference_gain
from nuav2.warp.depth_proxy import pixel_rays_cam

BLUR_SIGMAS_PX = (0.5, 1.0)
SEEN_DEPTH_TOLERANCE = (0.05, 0.10)  # a source pixel shows the point when their depths agree to 5 % + 10 cm
SUPERSAMPLE = 3


def psnr_of(sq_err_sum: float, n: int) -> float | None:
    """PSNR of ``n`` pixels with this summed squared error (None: no pixels, or no error)."""
    if n == 0 or sq_err_sum <= 0:
        return None
    return round(float(10 * np.log10(255.0**2 / (sq_err_sum / n))), 2)


def source_depths(log_dir: Path, world) -> list[tuple]:
    """(camera, cam_T_city, exact depth image) of every image of the log's ring cameras."""
    scene = read_log(log_dir)
    out = []
    for cam in scene.rig.cameras:
        for frame in scene.camera_frames.get(cam.channel, []):
            city_T_cam = scene.city_T_ego_at(frame.timestamp_ns) @ cam.ego_T_cam
            _, depth = render_view(world, cam, city_T_cam, frame.timestamp_ns, with_depth=True)
            out.append((cam, T_inverse(city_T_cam), depth))
    return out


def unseen(points_city: np.ndarray, sources: list[tuple]) -> np.ndarray:
    """(N,) True where no source image shows the (N, 3) city points."""
    seen = np.zeros(len(points_city), bool)
    for cam, cam_T_city, depth in sources:
        hit = project(points_city, cam, cam_T_city)
        ui, vi, zi = np.floor(hit.u + 0.5).astype(np.int64), np.floor(hit.v + 0.5).astype(np.int64), hit.z
        tol = SEEN_DEPTH_TOLERANCE[0] * zi + SEEN_DEPTH_TOLERANCE[1]
        lo = np.full(len(zi), np.inf)
        hi = np.full(len(zi), -np.inf)
        ok = np.zeros(len(zi), bool)
        for dv in (-1, 0, 1):  # the 3 x 3 pixels around: at grazing angles one pixel spans metres of depth
            for du in (-1, 0, 1):
                d = depth[np.clip(vi + dv, 0, cam.height - 1), np.clip(ui + du, 0, cam.width - 1)]
                ok |= np.abs(d - zi) < tol
                lo, hi = np.minimum(lo, d), np.maximum(hi, d)
        ok |= (lo <= zi) & (zi <= hi)  # the point lies between the depths its neighbourhood shows
        seen[hit.idx[ok]] = True
    return ~seen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="the synthetic AV2 log (nuav2 synth)")
    ap.add_argument("dataroot", type=Path, help="its conversion (nuav2 convert av2 ... --mode warp|render)")
    ap.add_argument("--version", default="v1.0-nuav2")
    args = ap.parse_args()
    world = load_world(args.log_dir)
    gain = log_reference_gain(args.log_dir)
    images = key_camera_images(args.dataroot, args.version, log_offsets(args.dataroot, args.version))
    sources = source_depths(args.log_dir, world)
    parts = {k: [0.0, 0] for k in ("next_to_objects_or_structure", "unseen", "truth_edges", "rest", "ground")}
    blur = {f"{which}_blurred_{s}": 0.0 for which in ("truth", "both") for s in BLUR_SIGMAS_PX}
    aliasing = 0.0
    for im in images:
        # one exact render gives truth, depth and labels (ground and sky as truth_view labels them)
        truth, depth, labels = render_view(world, im.camera, im.city_T_cam, im.timestamp_ns, with_depth=True,
                                           with_labels=True)
        img = load_image_rgb(str(im.path))
        written = (img if gain is None else expose(img, 1.0 / np.asarray(gain))).astype(np.float64)
        masks = world_region_masks(labels)
        ground = masks["ground"]
        t = truth.astype(np.float64)
        sq = ((written - t) ** 2).mean(-1)
        solid = ~(ground | masks["sky"])
        near = ndi.binary_dilation(solid, iterations=2) & ground
        vv, uu = np.nonzero(ground & ~near)
        city_xyz = transform_points(im.city_T_cam, pixel_rays_cam(im.camera)[vv, uu] * depth[vv, uu, None])
        hidden = np.zeros_like(ground)
        hidden[vv, uu] = unseen(city_xyz, sources)
        grey = t.mean(-1)
        edges = ndi.binary_dilation(np.hypot(ndi.sobel(grey, 0), ndi.sobel(grey, 1)) > 60, iterations=1)
        edges &= ground & ~near & ~hidden
        for key, m in (("next_to_objects_or_structure", near), ("unseen", hidden), ("truth_edges", edges),
                       ("rest", ground & ~near & ~hidden & ~edges), ("ground", ground)):
            parts[key][0] += float(sq[m].sum())
            parts[key][1] += int(m.sum())
        for s in BLUR_SIGMAS_PX:
            tb = ndi.gaussian_filter(t, (s, s, 0))
            blur[f"truth_blurred_{s}"] += float(((written - tb) ** 2).mean(-1)[ground].sum())
            wb = ndi.gaussian_filter(written, (s, s, 0))
            blur[f"both_blurred_{s}"] += float(((wb - tb) ** 2).mean(-1)[ground].sum())
        big = im.camera.scaled(SUPERSAMPLE)
        hi = render_view(world, big, im.city_T_cam, im.timestamp_ns).astype(np.float64)
        h, w = truth.shape[:2]
        averaged = hi.reshape(h, SUPERSAMPLE, w, SUPERSAMPLE, 3).mean((1, 3))
        aliasing += float(((t - averaged) ** 2).mean(-1)[ground].sum())
    total, n = parts["ground"]
    out = {"log": args.log_dir.name, "images": len(images), "ground_psnr_db": psnr_of(total, n),
           "parts": {k: {"pixel_share": round(v[1] / max(n, 1), 3),
                         "error_share": round(v[0] / max(total, 1e-9), 3), "psnr_db": psnr_of(*v)}
                     for k, v in parts.items() if k != "ground"},
           "ground_psnr_without_edge_error_db": psnr_of(total - parts["truth_edges"][0], n),
           "blurred_psnr_db": {k: psnr_of(v, n) for k, v in blur.items()},
           f"aliasing_floor_psnr_db_{SUPERSAMPLE}x{SUPERSAMPLE}": psnr_of(aliasing, n)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
