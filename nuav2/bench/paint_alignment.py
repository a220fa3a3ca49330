"""Do painted lines in an image sit where the map says? Pixel offset of image paint from projected map paint.

Solid painted lane boundaries of the vector map (city frame) are sampled every ``spacing_m`` and
projected with the camera's city pose; around each projected point, paint pixels (thin and
brighter than their surroundings: a top-hat) give a centroid, and its offset across the projected
line is the error. Points with no paint nearby (occluded, washed out) are left out. The same
measure on a ground-truth image gives the floor set by resolution and the paint detector.
"""

from __future__ import annotations

import cv2
import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec
from nuav2.scene import VectorMap

SOLID_PAINT = ("SOLID_WHITE", "SOLID_YELLOW", "DOUBLE_SOLID_WHITE", "DOUBLE_SOLID_YELLOW")


def painted_boundary_points(vector_map: VectorMap, spacing_m: float = 0.5) -> tuple[F64, F64]:
    """(N, 3) city points along the solid painted lane boundaries (each shared boundary once) and their
    (N, 3) unit tangents."""
    seen: set[bytes] = set()
    out, tangents = [], []
    for lane in vector_map.lane_segments.values():
        sides = ((lane.left_boundary, lane.left_mark_type), (lane.right_boundary, lane.right_mark_type))
        for line, mark in sides:
            line = np.asarray(line, dtype=np.float64)
            if mark not in SOLID_PAINT or len(line) < 2:
                continue
            key = np.round(np.sort(line[[0, -1], :2], axis=0), 2).tobytes()
            if key in seen:
                continue
            seen.add(key)
            seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
            s = np.concatenate([[0.0], np.cumsum(seg)])
            if s[-1] <= 0:
                continue
            q = np.arange(0.0, s[-1], spacing_m)
            out.append(np.column_stack([np.interp(q, s, line[:, k]) for k in range(3)]))
            seg_dir = np.diff(line, axis=0) / np.maximum(seg, 1e-12)[:, None]
            tangents.append(seg_dir[np.clip(np.searchsorted(s, q, side="right") - 1, 0, len(seg) - 1)])
    if not out:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(out), np.concatenate(tangents)


def paint_response(image: np.ndarray, kernel_px: int = 9, contrast: float = 30.0) -> np.ndarray:
    """float32 (H, W): white top-hat of the grey image where >= ``contrast`` (thin bright lines), else 0.

    A top-hat keeps what is brighter than its surroundings over less than ``kernel_px``, so lines
    on asphalt pass while wide bright areas (sky, sidewalk) do not.
    """
    gray = cv2.cvtColor(np.ascontiguousarray(image, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kernel_px, kernel_px))
    hat = cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, kernel).astype(np.float32)
    return np.where(hat >= contrast, hat, 0.0).astype(np.float32)


def paint_offsets_px(image: np.ndarray, camera: CameraSpec, city_T_cam: F64, points_city: F64,
                     tangents_city: F64, *, min_depth_m: float = 8.0, max_depth_m: float = 40.0,
                     half_window_px: int = 3) -> np.ndarray:
    """Per visible map-paint point, the pixel distance, across the line, to the paint seen around it.

    Inside a square window the response-weighted centroid of a line's pixels lies on the line's
    centre; its offset from the projected map point, taken along the normal of the projected map
    line (so a window clipping the line lengthwise does not bias it), is the sub-pixel error.
    Points with no paint in their window are dropped; the error is capped by the window.
    """
    if len(points_city) == 0:
        return np.zeros(0)
    cam_T_city = T_inverse(city_T_cam)
    pts = np.asarray(points_city, dtype=np.float64)
    p = pts @ cam_T_city[:3, :3].T + cam_T_city[:3, 3]
    q = (pts + 0.5 * np.asarray(tangents_city, dtype=np.float64)) @ cam_T_city[:3, :3].T + cam_T_city[:3, 3]
    keep = (p[:, 2] > min_depth_m) & (p[:, 2] < max_depth_m) & (q[:, 2] > 0.5 * min_depth_m)
    p, q = p[keep], q[keep]
    K = camera.K

    def uv(x: F64) -> tuple[F64, F64]:
        xn, yn = x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]
        return K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2]

    u, v = uv(p)
    du, dv = (a - b for a, b in zip(uv(q), (u, v)))
    k = int(half_window_px)
    inside = (u >= k) & (u <= camera.width - 1 - k) & (v >= k) & (v <= camera.height - 1 - k)
    u, v, du, dv = u[inside], v[inside], du[inside], dv[inside]
    if len(u) == 0:
        return np.zeros(0)
    resp = paint_response(image)
    offs = np.arange(-k, k + 1)
    dy, dx = np.meshgrid(offs, offs, indexing="ij")
    cols = np.rint(u).astype(int)[:, None] + dx.reshape(1, -1)
    rows = np.rint(v).astype(int)[:, None] + dy.reshape(1, -1)
    w = resp[rows, cols].astype(np.float64)
    total = w.sum(axis=1)
    has = (total > 0) & (np.hypot(du, dv) > 1e-9)
    cu = (w * cols).sum(axis=1)[has] / total[has]
    cv = (w * rows).sum(axis=1)[has] / total[has]
    n = np.column_stack([-dv[has], du[has]]) / np.hypot(du[has], dv[has])[:, None]
    return np.abs((cu - u[has]) * n[:, 0] + (cv - v[has]) * n[:, 1])
