"""The semantic-prior mask PNG the devkit's ``MapMask`` loads for a location (drivable area = 255).

The devkit reads pixel ``(px, py) = (round(x / res), round(H - y / res))`` for global ``(x, y)``,
so the image's bottom-left is global (0, 0) and a pixel's centre sits at integer pixel
coordinates; a pixel is drivable when its centre lies in (or on) a polygon.
"""

from __future__ import annotations

import hashlib
import io
import math

import cv2
import numpy as np
import shapely
from PIL import Image
from shapely.geometry import Polygon

from nuav2.geometry import F64

RESOLUTION_M = 0.1  # the devkit's native semantic-prior resolution
FOREGROUND = 255  # MapMask.foreground
_SHIFT = 8  # cv2 fractional bits for sub-pixel vertices


def semantic_prior_filename(location: str) -> str:
    """Dataroot-relative PNG path of a location's mask, derived from its name only.

    nuScenes names its masks ``maps/<md5>.png``; deriving the hash from the location lets the
    devkit-compat shim find the mask for ``BitMap(..., 'semantic_prior')`` without reading ``map.json``.
    """
    return f"maps/{hashlib.md5(location.encode()).hexdigest()}.png"


def canvas_edge_for(xy_global: F64, margin_m: float, min_edge_m: float) -> tuple[float, float]:
    """Canvas [width, height] in whole metres spanning [0, max + margin] of the given global points."""
    pts = np.asarray(xy_global, dtype=np.float64).reshape(-1, 2)
    top = pts.max(axis=0) if len(pts) else np.zeros(2)
    w = max(float(math.ceil(top[0] + margin_m)), min_edge_m)
    h = max(float(math.ceil(top[1] + margin_m)), min_edge_m)
    return w, h


def mask_shape(canvas_edge: tuple[float, float], resolution_m: float = RESOLUTION_M) -> tuple[int, int]:
    """(rows, cols) of the mask covering ``canvas_edge`` metres."""
    return int(round(canvas_edge[1] / resolution_m)), int(round(canvas_edge[0] / resolution_m))


def _ring_px(coords: np.ndarray, rows: int, resolution_m: float, origin_px: tuple[int, int]) -> np.ndarray:
    """A ring in cv2 fixed-point pixel coordinates of the window whose top-left pixel is ``origin_px``."""
    xy = np.asarray(coords, dtype=np.float64)[:, :2]
    px = np.stack([xy[:, 0] / resolution_m - origin_px[0],
                   rows - xy[:, 1] / resolution_m - origin_px[1]], axis=1)
    return np.round(px * (1 << _SHIFT)).astype(np.int32)


def rasterize_polygons(polygons: list[Polygon], canvas_edge: tuple[float, float],
                       resolution_m: float = RESOLUTION_M) -> np.ndarray:
    """uint8 (rows, cols) mask: FOREGROUND where a pixel centre lies in any polygon (holes respected).

    Each polygon is filled on its own, in the window of its bounds (exterior on, then its holes
    off) and OR-ed in, so one polygon's hole never erases another polygon lying inside it.
    ``cv2.fillPoly`` also fills every pixel an edge passes through, which grew every area by up
    to a pixel (0.1 m): the pixels along the edges are therefore decided by testing their centres.
    """
    rows, cols = mask_shape(canvas_edge, resolution_m)
    mask = np.zeros((rows, cols), np.uint8)
    for poly in polygons:
        if poly.is_empty:
            continue
        x0, y0, x1, y1 = poly.bounds
        # the window spans the whole polygon, off the canvas too (cv2 clips edges at the window's
        # border, and a fill clipped there differs from the polygon's); its overlap is pasted
        c0, c1 = math.floor(x0 / resolution_m) - 1, math.ceil(x1 / resolution_m) + 2
        r0, r1 = math.floor(rows - y1 / resolution_m) - 1, math.ceil(rows - y0 / resolution_m) + 2
        if c0 >= cols or r0 >= rows or c1 <= 0 or r1 <= 0:
            continue
        rings = [_ring_px(np.asarray(r.coords), rows, resolution_m, (c0, r0))
                 for r in (poly.exterior, *poly.interiors)]
        one = np.zeros((r1 - r0, c1 - c0), np.uint8)
        cv2.fillPoly(one, rings[:1], FOREGROUND, lineType=cv2.LINE_8, shift=_SHIFT)
        if len(rings) > 1:
            cv2.fillPoly(one, rings[1:], 0, lineType=cv2.LINE_8, shift=_SHIFT)
        edge = np.zeros_like(one)
        cv2.polylines(edge, rings, isClosed=True, color=1, thickness=1, lineType=cv2.LINE_8, shift=_SHIFT)
        py, px = np.nonzero(cv2.dilate(edge, np.ones((3, 3), np.uint8)))
        covered = shapely.intersects_xy(poly, (px + c0) * resolution_m, (rows - (py + r0)) * resolution_m)
        one[py, px] = np.where(covered, FOREGROUND, 0)
        a, b = max(r0, 0), max(c0, 0)
        window = mask[a:min(r1, rows), b:min(c1, cols)]
        np.maximum(window, one[a - r0:a - r0 + window.shape[0], b - c0:b - c0 + window.shape[1]], out=window)
    return mask


def encode_png(mask: np.ndarray) -> bytes:
    """Deterministic 8-bit grayscale PNG bytes (no timestamps; MapMask compares values to 255)."""
    buf = io.BytesIO()
    image = Image.fromarray(np.ascontiguousarray(mask, dtype=np.uint8), mode="L")
    image.save(buf, format="PNG", compress_level=9)
    return buf.getvalue()
