"""Per-image confidence of a target-rig render: how much of it the source cameras actually saw.

A reconstruction is only trustworthy near what was observed. For a rendered target image we
take a grid of pixels; each pixel the Gaussians cover (alpha >= ``alpha_solid``) becomes a 3D
point from its rendered depth, each sky pixel a direction. A point is *covered* if some source
camera (a) has it inside its image and in front, (b) looks at it from a similar direction
(angle between the two viewing rays <= ``max_angle_deg``), (c) is not much farther from it
than the target camera (distance ratio <= ``max_distance_ratio``: farther means blurrier), and
(d) is not occluded, judged against that source view's rendered depth map at low resolution.
A sky direction is covered if some source camera's field of view contains it.

confidence = covered samples / all samples, in [0, 1]. Moving objects are judged where they
are at the target time (their own motion is not modelled here). Samples on a non-rigid actor
(a walking pedestrian, a cyclist: their limbs are only approximated, see
:mod:`nuav2.splat.actors`) never count as covered, so an image such an actor fills is trusted
less; their share is recorded as ``nonrigid_fraction``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec


@dataclass(frozen=True)
class QualityConfig:
    grid: tuple[int, int] = (48, 27)  # samples across x down the image
    alpha_solid: float = 0.5
    max_angle_deg: float = 25.0
    max_distance_ratio: float = 3.0
    occlusion_rel_tol: float = 0.1
    occlusion_abs_tol_m: float = 0.5
    source_depth_scale: float = 0.25  # resolution of the source depth maps (x the training images)


@dataclass(frozen=True)
class ImageQuality:
    """What the gate records per rendered image."""

    confidence: float
    solid_fraction: float  # of the samples, covered by Gaussians (the rest is sky)
    alpha_mean: float
    samples: int
    nonrigid_fraction: float = 0.0  # of the samples, on a non-rigid actor (not counted as covered)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class SourceCoverage:
    """The source cameras to test against: scene-frame poses, intrinsics and low-res depth maps."""

    cam_T_scene: np.ndarray  # (S, 4, 4)
    K: np.ndarray  # (S, 3, 3)
    sizes: np.ndarray  # (S, 2) width, height
    depth: list[np.ndarray | None]  # per source, (h, w) z-depth at ``depth_scale`` (0: unknown) or None
    depth_scale: float

    @property
    def centres(self) -> np.ndarray:
        return np.einsum("sji,sj->si", self.cam_T_scene[:, :3, :3], -self.cam_T_scene[:, :3, 3])

    @staticmethod
    def from_views(splat, views, cfg: QualityConfig = QualityConfig(), *, with_depth: bool = True,
                   progress: bool = False) -> SourceCoverage:
        """Coverage of a trained ``SplatScene`` by its source ``views`` (``init.SourceView``s);
        ``with_depth`` renders each view's depth map for the occlusion test."""
        from nuav2.progress import progress_bar

        scene_T_city = splat.scene_T_city
        cam_T_scene, Ks, sizes, depths = [], [], [], []
        for v in progress_bar(views, desc="source depth", unit="img", disable=not progress or not with_depth,
                              leave=False):
            cam_T_scene.append(T_inverse(scene_T_city @ v.city_T_cam))
            Ks.append(v.cam.K)
            sizes.append((v.cam.width, v.cam.height))
            if with_depth:
                small = v.cam.scaled(cfg.source_depth_scale)
                with torch.no_grad():
                    out = splat.render(small, v.city_T_cam, v.timestamp_ns, with_sky=False)
                d = out.depth.cpu().numpy().astype(np.float32)
                d[out.alpha.cpu().numpy() < cfg.alpha_solid] = np.inf  # seen through to the sky
                depths.append(d)
            else:
                depths.append(None)
        return SourceCoverage(np.array(cam_T_scene).reshape(-1, 4, 4), np.array(Ks).reshape(-1, 3, 3),
                              np.array(sizes, np.int64).reshape(-1, 2), depths, cfg.source_depth_scale)

    def covered(self, points_scene: F64, target_centre: F64, is_direction: np.ndarray,
                cfg: QualityConfig) -> np.ndarray:
        """(M,) bool: which points (or, where ``is_direction``, unit directions) a source camera sees."""
        m = len(points_scene)
        out = np.zeros(m, bool)
        if m == 0 or len(self.cam_T_scene) == 0:
            return out
        cos_max = np.cos(np.radians(cfg.max_angle_deg))
        to_tgt = points_scene - target_centre
        dist_t = np.linalg.norm(to_tgt, axis=1)
        centres = self.centres
        for s in range(len(self.cam_T_scene)):
            R, t = self.cam_T_scene[s, :3, :3], self.cam_T_scene[s, :3, 3]
            # Directions: rotate only (a point at infinity); points: full transform.
            p = np.where(is_direction[:, None], points_scene @ R.T, points_scene @ R.T + t)
            z = p[:, 2]
            front = z > 1e-3
            zs = np.where(front, z, 1.0)
            u = self.K[s, 0, 0] * p[:, 0] / zs + self.K[s, 0, 2]
            v = self.K[s, 1, 1] * p[:, 1] / zs + self.K[s, 1, 2]
            w, h = self.sizes[s]
            ok = front & (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
            pts = ~is_direction
            if np.any(ok & pts):
                to_src = points_scene - centres[s]
                dist_s = np.linalg.norm(to_src, axis=1)
                cos = np.sum(to_src * to_tgt, axis=1) / np.maximum(dist_s * dist_t, 1e-9)
                near_enough = dist_s <= cfg.max_distance_ratio * np.maximum(dist_t, 1.0)
                ok &= is_direction | ((cos >= cos_max) & near_enough)
                d = self.depth[s]
                if d is not None:
                    dh, dw = d.shape
                    sx, sy = dw / w, dh / h
                    du = np.clip(((u + 0.5) * sx).astype(np.int64), 0, dw - 1)
                    dv = np.clip(((v + 0.5) * sy).astype(np.int64), 0, dh - 1)
                    surf = d[dv, du]
                    ok &= is_direction | (z <= surf * (1 + cfg.occlusion_rel_tol) + cfg.occlusion_abs_tol_m)
            out |= ok
            if out.all():
                break
        return out


def in_boxes(points: F64, scene_T_box: F64, size_lwh: F64, grow: float = 0.1) -> np.ndarray:
    """(N,) bool: points inside any box (grown by ``grow`` x size + 5 cm on each side)."""
    inside = np.zeros(len(points), bool)
    for T, size in zip(np.asarray(scene_T_box).reshape(-1, 4, 4), np.asarray(size_lwh).reshape(-1, 3)):
        p = (points - T[:3, 3]) @ T[:3, :3]
        inside |= np.all(np.abs(p) <= 0.5 * size * (1 + grow) + 0.05, axis=1)
    return inside


def image_quality(rendered_depth: np.ndarray, rendered_alpha: np.ndarray, cam: CameraSpec, scene_T_cam: F64,
                  coverage: SourceCoverage, cfg: QualityConfig = QualityConfig(),
                  nonrigid_boxes: tuple[F64, F64] | None = None) -> ImageQuality:
    """Confidence of one rendered target image from its depth and alpha (H, W) at ``cam``'s size;
    ``nonrigid_boxes`` (scene_T_box (B, 4, 4), sizes (B, 3)) are the non-rigid actors at the image's time."""
    h, w = rendered_alpha.shape
    gx, gy = cfg.grid
    us = (np.arange(gx) + 0.5) * w / gx - 0.5
    vs = (np.arange(gy) + 0.5) * h / gy - 0.5
    uu, vv = np.meshgrid(us, vs)
    iu = np.clip(np.round(uu).astype(np.int64), 0, w - 1).ravel()
    iv = np.clip(np.round(vv).astype(np.int64), 0, h - 1).ravel()
    alpha = rendered_alpha[iv, iu]
    depth = rendered_depth[iv, iu]
    solid = (alpha >= cfg.alpha_solid) & np.isfinite(depth) & (depth > 0)
    K = cam.K
    rays_cam = np.column_stack([(iu - K[0, 2]) / K[0, 0], (iv - K[1, 2]) / K[1, 1], np.ones(len(iu))])
    R, c = scene_T_cam[:3, :3], scene_T_cam[:3, 3]
    pts_cam = rays_cam * np.where(solid, depth, 1.0)[:, None]
    dirs = rays_cam @ R.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = np.where(solid[:, None], pts_cam @ R.T + c, dirs)
    cov = coverage.covered(pts, c, ~solid, cfg)
    nonrigid = np.zeros(len(cov), bool)
    if nonrigid_boxes is not None and len(nonrigid_boxes[0]):
        nonrigid[solid] = in_boxes(pts[solid], *nonrigid_boxes)
    cov &= ~nonrigid
    return ImageQuality(float(cov.mean()), float(solid.mean()), float(rendered_alpha.mean()), int(len(cov)),
                        float(nonrigid.mean()))
