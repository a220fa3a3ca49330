"""Hand-made inputs for the warp tests: small cameras, poses and an analytic textured-plane renderer.

The renderer here is deliberately independent of nuav2.warp: ray/plane and ray/box by direct
formulas, colour as a closed-form function of the hit point, so a warp can be checked against
the exact image of another view.
"""

from __future__ import annotations

import numpy as np

from nuav2.geometry import make_T
from nuav2.rig import CameraSpec

# OpenCV camera axes (x right, y down, z forward) for a vehicle-style frame (x forward, y left, z up).
EGO_R_CAM_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera(width: int = 64, height: int = 48, f: float = 50.0, channel: str = "CAM") -> CameraSpec:
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return CameraSpec(channel, width, height, K, np.eye(4))


def rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(pitch: float) -> np.ndarray:
    c, s = np.cos(pitch), np.sin(pitch)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def city_T_cam(x: float, y: float, z: float, yaw: float = 0.0, pitch_down: float = 0.0) -> np.ndarray:
    """Camera at (x, y, z) looking along yaw (about +z), tilted down by ``pitch_down`` radians."""
    R = rot_z(yaw) @ rot_y(pitch_down) @ EGO_R_CAM_FORWARD
    return make_T(R, [x, y, z])


def pixel_rays_city(cam: CameraSpec, T: np.ndarray) -> np.ndarray:
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    d = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(u)], -1)
    return d.reshape(-1, 3) @ T[:3, :3].T


def ground_texture(xy: np.ndarray) -> np.ndarray:
    """Smooth colour field on the ground (values in [0.1, 0.9])."""
    x, y = xy[:, 0], xy[:, 1]
    return np.stack([0.5 + 0.4 * np.sin(0.7 * x + 0.3 * y), 0.5 + 0.4 * np.cos(0.5 * y - 0.2 * x),
                     0.5 + 0.4 * np.sin(0.3 * x * 0.5 + 0.9)], -1)


def sky_colour(dirs: np.ndarray) -> np.ndarray:
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    az = np.arctan2(d[:, 1], d[:, 0])
    return np.stack([0.3 + 0.3 * d[:, 2], 0.5 + 0.2 * np.sin(3 * az), np.full(len(d), 0.8)], -1)


def render_plane_world(cam: CameraSpec, T: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray, tuple]] = (),
                       ground_z: float | None = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact image (float32 H, W, 3) and camera-z depth (inf for sky) of a textured plane + coloured boxes.

    ``boxes``: (city_T_box, size_lwh, rgb) with a flat colour per box.
    """
    d = pixel_rays_city(cam, T)
    o = T[:3, 3]
    t = np.full(len(d), np.inf)
    down = (d[:, 2] < -1e-12) & (ground_z is not None)
    if ground_z is not None:
        t[down] = (ground_z - o[2]) / d[down, 2]
    t[t <= 0] = np.inf
    img = sky_colour(d)
    hit = np.isfinite(t)
    img[hit] = ground_texture((o + t[hit, None] * d[hit])[:, :2])
    for box_T, size, rgb in boxes:
        inv = np.linalg.inv(box_T)
        ob = inv[:3, :3] @ o + inv[:3, 3]
        db = d @ inv[:3, :3].T
        half = 0.5 * np.asarray(size)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - ob) / db
            t2 = (half - ob) / db
        lo = np.nanmax(np.minimum(t1, t2), axis=1)
        hi = np.nanmin(np.maximum(t1, t2), axis=1)
        tb = np.where((lo <= hi) & (lo > 0), lo, np.inf)
        closer = tb < t
        t[closer] = tb[closer]
        img[closer] = rgb
    return img.reshape(cam.height, cam.width, 3).astype(np.float32), t.reshape(cam.height, cam.width)
