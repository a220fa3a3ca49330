"""Backward warp: colour every target pixel from the source images that see its 3D point.

For each target pixel the depth proxy gives a city point at the target time (or a direction at
infinity). For each source image (its own timestamp and ego pose) the point is moved with its box
when it lies on an actor, projected into the source camera, kept if the source's own depth proxy
says nothing is in front of it (inverse depth sampled bilinearly: exact across planes) and it is
not on the ego body, and its colour is sampled bilinearly. Sources are blended with weights from
the angle between the target and source rays, the distance to the source image border (feathers
the seams) and the time offset. Pixels no source sees get weight 0 and are filled afterwards.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec
from nuav2.warp._kernels import blend_to_uint8_kernel, warp_source_kernel
from nuav2.warp.depth_proxy import DepthProxy

FILL_MODES = ("color", "inpaint")


@dataclass(frozen=True)
class BlendConfig:
    angle_sigma_rad: float = 0.25  # Gaussian fall-off of the weight with the target/source ray angle
    border_frac: float = 0.06  # feather width at the source image border, fraction of min(W, H)
    time_tau_ns: float = 50e6  # weight exp(-|dt| / tau)
    inv_depth_rel_tol: float = 0.04  # visible if 1/z >= (1 - tol) / z_source
    inf_inv_depth: float = 1e-3  # a source inverse depth below this "sees infinity"
    near_m: float = 0.1
    min_weight: float = 1e-4  # floor of each factor, so a point seen once is never dropped


@dataclass(frozen=True)
class SourceView:
    """One source image with its pose and its own depth proxy (possibly at a lower resolution)."""

    image: np.ndarray  # (H, W, 3): float32 0..1, or uint8 0..255 (a quarter of the memory in caches)
    camera: CameraSpec
    city_T_cam: F64
    timestamp_ns: int
    vis_camera: CameraSpec  # the camera the inverse depth map was rendered with
    inv_depth: np.ndarray  # float32 (h, w), 0 at infinity
    valid: np.ndarray | None = None  # bool (H, W): False where the ego body hides the scene

    def __post_init__(self) -> None:
        c = self.camera
        if self.image.shape != (c.height, c.width, 3) or self.image.dtype not in (np.float32, np.uint8):
            raise ValueError(f"source {c.channel}: image must be float32 or uint8 {(c.height, c.width, 3)}, "
                             f"got {self.image.dtype} {self.image.shape}")
        if self.inv_depth.shape != (self.vis_camera.height, self.vis_camera.width):
            raise ValueError(f"source {c.channel}: inverse depth shape {self.inv_depth.shape} does not match "
                             f"its visibility camera {(self.vis_camera.height, self.vis_camera.width)}")


@dataclass(frozen=True)
class WarpResult:
    rgb: np.ndarray  # float32 (H, W, 3), 0 where uncovered
    weight: np.ndarray  # float32 (H, W), summed blend weight (0 = no source sees the pixel)
    n_sources: np.ndarray  # uint8 (H, W), how many sources contributed

    @property
    def coverage(self) -> np.ndarray:
        return self.weight > 0


def warp_from_sources(target: DepthProxy, sources: Sequence[SourceView], target_timestamp_ns: int,
                      motions: Sequence[F64 | None] | None = None, config: BlendConfig | None = None
                      ) -> WarpResult:
    """Blend the sources into the target view (see module doc); one compiled loop over pixels per source.

    ``motions[i]`` maps target box index -> (4, 4) ``city(t_source) <- city(t_target)`` motion of that
    box for source i (NaN matrix: box absent at that time; None: no boxes, so actor pixels get no
    colour from that source).
    """
    shape = (target.camera.height, target.camera.width)
    acc, wsum, count = accumulate_sources(target, sources, target_timestamp_ns, motions, config)
    rgb = np.where(wsum[:, None] > 0, acc / np.maximum(wsum, 1e-300)[:, None], 0.0)
    return WarpResult(rgb.reshape(*shape, 3).astype(np.float32), wsum.reshape(shape).astype(np.float32),
                      np.minimum(count, 255).astype(np.uint8).reshape(shape))


def warp_to_uint8(target: DepthProxy, sources: Sequence[SourceView], target_timestamp_ns: int,
                  motions: Sequence[F64 | None] | None = None, config: BlendConfig | None = None,
                  background: tuple[float, float, float] = (0.5, 0.5, 0.5), mode: str = "inpaint",
                  inpaint_radius: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """uint8 (H, W, 3) filled image and bool coverage, byte for byte ``to_uint8(fill_uncovered(...))`` of
    :func:`warp_from_sources`, without its float images: the writer's path, where they cost a tenth of
    the blend (arguments as there and in :func:`fill_uncovered`)."""
    check_fill_mode(mode)
    acc, wsum, _ = accumulate_sources(target, sources, target_timestamp_ns, motions, config)
    shape = (target.camera.height, target.camera.width)
    img8 = np.empty((*shape, 3), np.uint8)
    hole8 = np.empty(shape, np.uint8)
    n_holes = blend_to_uint8_kernel(acc, wsum, img8, hole8)
    hole = hole8.view(np.bool_)
    if n_holes == 0:
        return img8, ~hole
    if mode == "color" or n_holes == hole.size:
        img8[hole] = to_uint8(np.asarray(background, np.float32))
    else:  # filled pixels: uint8 -> / 255 float32 -> * 255 -> rint gives back every uint8, so no round trip
        cv2.inpaint(img8, hole8, inpaint_radius, cv2.INPAINT_TELEA, dst=img8)
    return img8, ~hole


def accumulate_sources(target: DepthProxy, sources: Sequence[SourceView], target_timestamp_ns: int,
                       motions: Sequence[F64 | None] | None = None, config: BlendConfig | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat float64 weighted colour sums (N, 3), weight sums (N,) and int64 source counts (N,): the blend."""
    config = config or BlendConfig()
    cam = target.camera
    n = cam.height * cam.width
    acc = np.zeros((n, 3), np.float64)
    wsum = np.zeros(n, np.float64)
    count = np.zeros(n, np.int64)
    depth_T = np.ascontiguousarray(target.depth, dtype=np.float64)
    box_index = np.ascontiguousarray(target.box_index, dtype=np.int64)
    city_T_camT = np.ascontiguousarray(target.city_T_cam, dtype=np.float64)
    K_T = np.ascontiguousarray(cam.K, dtype=np.float64)
    no_valid = np.ones((1, 1), dtype=np.bool_)
    for i, src in enumerate(sources):
        motion = motions[i] if motions is not None else None
        motion = (np.zeros((0, 4, 4)) if motion is None
                  else np.ascontiguousarray(np.asarray(motion, dtype=np.float64).reshape(-1, 4, 4)))
        dt_ns = abs(int(src.timestamp_ns) - int(target_timestamp_ns))
        time_w = max(float(np.exp(-dt_ns / config.time_tau_ns)), config.min_weight)
        border_px = max(config.border_frac * min(src.camera.width, src.camera.height), 1e-9)
        warp_source_kernel(depth_T, K_T, city_T_camT, box_index, motion, np.ascontiguousarray(src.image),
                           1.0 / 255.0 if src.image.dtype == np.uint8 else 1.0,
                           np.ascontiguousarray(src.camera.K, dtype=np.float64),
                           np.ascontiguousarray(T_inverse(src.city_T_cam)),
                           np.ascontiguousarray(np.asarray(src.city_T_cam, dtype=np.float64)[:3, 3]),
                           np.ascontiguousarray(src.inv_depth, dtype=np.float32),
                           np.ascontiguousarray(src.vis_camera.K, dtype=np.float64),
                           no_valid if src.valid is None else np.ascontiguousarray(src.valid, dtype=np.bool_),
                           src.valid is not None, time_w, config.near_m, config.inv_depth_rel_tol,
                           config.inf_inv_depth, config.angle_sigma_rad, border_px, config.min_weight,
                           acc, wsum, count)
    return acc, wsum, count


def fill_uncovered(rgb: np.ndarray, covered: np.ndarray,
                   background: tuple[float, float, float] = (0.5, 0.5, 0.5), mode: str = "inpaint",
                   inpaint_radius: int = 3) -> np.ndarray:
    """Give uncovered pixels a defined value: a constant colour, or OpenCV Telea inpainting from covered ones.

    Inpainting falls back to the constant colour when nothing is covered.
    """
    check_fill_mode(mode)
    out = rgb.astype(np.float32, copy=True)
    hole = ~covered
    if not np.any(hole):
        return out
    if mode == "color" or not np.any(covered):
        out[hole] = np.asarray(background, np.float32)
        return out
    img8 = to_uint8(out)
    filled = cv2.inpaint(img8, hole.astype(np.uint8), inpaint_radius, cv2.INPAINT_TELEA)
    out[hole] = filled[hole].astype(np.float32) / 255.0
    return out


def check_fill_mode(mode: str) -> None:
    """Refuse an unknown fill mode (before any blending work)."""
    if mode not in FILL_MODES:
        raise ValueError(f"fill mode must be one of {FILL_MODES}, got {mode!r}")


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """uint8 of 0..1 colours, rounded half to even (float32 in, float32 arithmetic)."""
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
