"""One keyframe as a picture: camera images with the map vectors drawn on the ground, plus a BEV panel.

Vectors are LIDAR_TOP-frame xy (MapTR's GT and prediction format). To draw them in a camera
they are lifted onto the ground plane of the keyframe's ego frame (z = ``ground_z_ego``; 0 for
nuScenes-style ground-level origins), carried through ``lidar2img`` (which includes the
camera's own ego pose) and clipped at a near plane. Colours follow the MapGS paper's figures:
divider yellow, boundary red, crossing blue, centerline green. GT is drawn solid, predictions
thinner with dots at their points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_bytes
from nuav2.evaluate.vector_files import load_predictions as read_results
from nuav2.geometry import F64, T_from_quat_trans, quat_to_rot
from nuav2.maptr.dataset import load_image_rgb
from nuav2.maptr.infos import NUSCENES_CAMERAS, lidar2img, sample_info
from nuav2.maptr.vectorize import CLASSES, MapGT

CLASS_COLORS_RGB = {
    "divider": (255, 200, 0),
    "boundary": (230, 30, 30),
    "ped_crossing": (30, 90, 255),
    "centerline": (40, 190, 40),
}
NEAR_PLANE_M = 0.5
DENSIFY_M = 0.5
CAMERA_RANGE_M = 1000.0  # vectors are cut to this half-extent box for the cameras (beyond: at the horizon)
BEV_MARGIN_M = 1.0  # ... and to the BEV patch grown by this much before the BEV panel

Scored = list[tuple[str, F64, float]]


def ground_points_lidar(xy_lidar: np.ndarray, lidar2ego: np.ndarray, ground_z_ego: float = 0.0) -> F64:
    """Lift LIDAR_TOP-frame xy onto the ego ground plane z_ego = ``ground_z_ego`` (exact if tilted)."""
    xy = np.asarray(xy_lidar, dtype=np.float64).reshape(-1, 2)
    T = np.asarray(lidar2ego, dtype=np.float64)
    r = T[2, :3]
    if abs(r[2]) < 1e-6:
        raise ValueError("LIDAR_TOP z axis is parallel to the ground; cannot lift vectors onto it")
    z = (ground_z_ego - T[2, 3] - r[0] * xy[:, 0] - r[1] * xy[:, 1]) / r[2]
    return np.column_stack([xy, z])


def densify(xy: np.ndarray, step_m: float = DENSIFY_M) -> F64:
    """Insert points so no segment is longer than ``step_m`` (ground lines stay on the ground when cut)."""
    pts = np.asarray(xy, dtype=np.float64)
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step_m)))
        out.append(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
    return np.concatenate(out)


def clip_polyline(xy: np.ndarray, half_extent_xy: tuple[float, float]) -> list[F64]:
    """The parts of a polyline inside the box |x| <= hx, |y| <= hy, as polylines (each segment cut
    at the box's sides in turn). Drawing works on these: a prediction's huge coordinates (1e20 m)
    cannot blow up densifying or overflow pixel coordinates, and what lies in the box is unchanged."""
    pts = np.asarray(xy, dtype=np.float64)[:, :2]
    hx, hy = half_extent_xy
    if len(pts) < 2:
        return []
    if np.all(np.abs(pts) <= (hx, hy)):
        return [pts]
    a, b = pts[:-1].copy(), pts[1:].copy()
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    cut_a, cut_b = np.zeros(len(a), dtype=bool), np.zeros(len(a), dtype=bool)
    for k, bound in ((0, hx), (0, -hx), (1, hy), (1, -hy)):
        o = 1 - k
        out_a, out_b = a[:, k] * np.sign(bound) > abs(bound), b[:, k] * np.sign(bound) > abs(bound)
        ok &= ~(out_a & out_b)
        for out, p, q, cut in ((out_a & ok & ~out_b, a, b, cut_a), (out_b & ok & ~out_a, b, a, cut_b)):
            if out.any():  # move p (outside) to the side, measured from q (inside): exact for huge p
                p[out] = _cut(q[out], p[out], k, o, bound)
                cut |= out
    ok &= np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    lo, hi = np.array([-hx, -hy]), np.array([hx, hy])
    a, b = np.clip(a, lo, hi), np.clip(b, lo, hi)
    parts: list[list[np.ndarray]] = []
    for i in np.flatnonzero(ok):
        if i > 0 and ok[i - 1] and not cut_b[i - 1] and not cut_a[i]:
            parts[-1].append(b[i])
        else:
            parts.append([a[i], b[i]])
    return [np.array(part) for part in parts]


def _cut(inside: F64, outside: F64, k: int, o: int, bound: float) -> F64:
    """Where segments from ``inside`` to ``outside`` cross coordinate ``k`` = ``bound``, computed
    exactly (fractions): a visible cut of a line between 1e20 m points is a small difference of
    huge numbers, which float arithmetic would lose."""
    from fractions import Fraction

    out = np.empty_like(inside)
    out[:, k] = bound
    for i, (q, p) in enumerate(zip(inside.tolist(), outside.tolist())):
        qk, qo, pk, po = map(Fraction, (q[k], q[o], p[k], p[o]))
        out[i, o] = float(qo + (po - qo) * (Fraction(bound) - qk) / (pk - qk))
    return out


def project_segments(xyz_lidar: np.ndarray, lidar2img_4x4: np.ndarray, near_m: float = NEAR_PLANE_M) -> F64:
    """(S, 2, 2) pixel segments of a 3-D polyline, each segment clipped at depth ``near_m``."""
    P = np.asarray(lidar2img_4x4, dtype=np.float64)
    hom = np.column_stack([xyz_lidar, np.ones(len(xyz_lidar))]) @ P.T  # (N, 4): u*z, v*z, z, 1
    a, b = hom[:-1, :3], hom[1:, :3]
    za, zb = a[:, 2], b[:, 2]
    keep = (za >= near_m) | (zb >= near_m)
    a, b, za, zb = a[keep], b[keep], za[keep], zb[keep]
    t = np.where(za < near_m, (near_m - za) / np.where(zb != za, zb - za, 1.0), 0.0)
    a = a + (b - a) * t[:, None]
    t = np.where(zb < near_m, (near_m - zb) / np.where(za != zb, za - zb, 1.0), 0.0)
    b = b + (a - b) * t[:, None]
    seg = np.stack([a[:, :2] / a[:, 2:3], b[:, :2] / b[:, 2:3]], axis=1)
    return seg[np.all(np.isfinite(seg), axis=(1, 2))]


def load_predictions(path: str | Path) -> dict[str, Scored]:
    """A MapTR results json (the reader ``nuav2 eval`` uses) as float64 xy arrays per vector."""
    try:
        return {token: [(cls, _xy_of(pts, path, token), float(score)) for cls, pts, score in vecs]
                for token, vecs in read_results(path).items()}
    except FileNotFoundError as e:
        raise ValueError(str(e)) from None


def _xy_of(pts, path: str | Path, token: str) -> F64:
    arr = np.asarray(pts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"{path}: sample {token}: a vector's pts must be (N, 2) or (N, 3), got {arr.shape}")
    return arr[:, :2]


def _color_bgr(cls: str) -> tuple[int, int, int]:
    r, g, b = CLASS_COLORS_RGB.get(cls, (200, 200, 200))
    return b, g, r


def _draw_segments(img: np.ndarray, seg: F64, color, thickness: int) -> None:
    import cv2

    lim = 4 * max(img.shape)  # keep cv2's integer coordinates sane; it clips to the image itself
    for (x0, y0), (x1, y1) in np.clip(seg, -lim, lim):
        cv2.line(
            img,
            (int(round(x0)), int(round(y0))),
            (int(round(x1)), int(round(y1))),
            color,
            thickness,
            cv2.LINE_AA,
        )


def _camera_tile(
    info_cam: dict, vectors, preds: Scored, lidar2ego: F64, ground_z_ego: float, height: int
) -> np.ndarray:
    import cv2

    img = load_image_rgb(info_cam["data_path"])[:, :, ::-1].copy()  # BGR for cv2 drawing
    h, w = img.shape[:2]
    new_w = max(1, round(w * height / h))
    img = cv2.resize(img, (new_w, height), interpolation=cv2.INTER_AREA)
    sx, sy = new_w / w, height / h  # pixel centres map (x + 0.5) * s - 0.5
    A = np.array([[sx, 0, 0.5 * sx - 0.5, 0], [0, sy, 0.5 * sy - 0.5, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    P = A @ lidar2img(info_cam)
    thick = max(1, round(height / 135))
    box = (CAMERA_RANGE_M, CAMERA_RANGE_M)

    def segments(pts: np.ndarray) -> F64:
        parts = [project_segments(ground_points_lidar(densify(part), lidar2ego, ground_z_ego), P)
                 for part in clip_polyline(pts, box)]
        return np.concatenate(parts) if parts else np.zeros((0, 2, 2))

    for cls, pts in vectors:
        _draw_segments(img, segments(pts), _color_bgr(cls), 2 * thick)
    for cls, pts, _ in preds:
        seg = segments(pts)
        _draw_segments(img, seg, (255, 255, 255), thick + 2)
        _draw_segments(img, seg, _color_bgr(cls), thick)
    cv2.putText(
        img, info_cam["type"], (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA
    )
    return img


def bev_panel(
    vectors,
    preds: Scored,
    height_px: int,
    half_extent_xy: tuple[float, float] = (15.0, 30.0),
) -> np.ndarray:
    """Top view of the patch: lidar x to the right, lidar y (forward) up, ego at the centre."""
    import cv2

    hx, hy = half_extent_xy
    ppm = height_px / (2 * hy)
    width_px = max(1, round(2 * hx * ppm))
    img = np.full((height_px, width_px, 3), 255, np.uint8)

    def px(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([(xy[:, 0] + hx) * ppm, (hy - xy[:, 1]) * ppm])

    ego = px(np.array([[-0.9, -1.0], [0.9, -1.0], [0.9, 3.0], [-0.9, 3.0]]))
    cv2.fillPoly(img, [np.round(ego).astype(np.int32)], (120, 120, 120))
    thick = max(1, round(height_px / 240))
    box = (hx + BEV_MARGIN_M, hy + BEV_MARGIN_M)

    def draw(pts: np.ndarray, color, thickness: int) -> None:
        for part in clip_polyline(pts, box):
            p = px(part)
            _draw_segments(img, np.stack([p[:-1], p[1:]], axis=1), color, thickness)

    for cls, pts in vectors:
        draw(pts, _color_bgr(cls), 2 * thick)
    for cls, pts, _ in preds:
        draw(pts, _color_bgr(cls), thick)
        inside = np.asarray(pts, dtype=np.float64)[:, :2]
        inside = inside[np.all(np.abs(inside) <= box, axis=1)]
        for x, y in np.round(px(inside)).astype(int):
            cv2.circle(img, (int(x), int(y)), thick + 1, _color_bgr(cls), -1, cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (width_px - 1, height_px - 1), (0, 0, 0), 1)
    return img


def camera_rows(cams: dict[str, dict]) -> list[list[str]]:
    """Cameras in two rows as a driver sees them: forward-looking ones left to right on top,
    the others left to right below (nuScenes: FRONT_LEFT FRONT FRONT_RIGHT / BACK_LEFT BACK BACK_RIGHT)."""
    yaw = {}
    for ch, cam in cams.items():
        axis = quat_to_rot(cam["sensor2ego_rotation"])[:, 2]  # optical axis in the ego frame
        yaw[ch] = math.degrees(math.atan2(axis[1], axis[0]))
    front = sorted((c for c in cams if abs(yaw[c]) <= 90.0), key=lambda c: -yaw[c])
    back = sorted((c for c in cams if abs(yaw[c]) > 90.0), key=lambda c: yaw[c] % 360.0)
    return [row for row in (front, back) if row]


def _grid(tiles: dict[str, np.ndarray], rows: list[list[str]]) -> np.ndarray:
    """Tiles (all one height) packed row by row, each row centred."""
    tile_h = max(t.shape[0] for t in tiles.values())
    widths = [sum(tiles[c].shape[1] for c in row) for row in rows]
    canvas = np.zeros((len(rows) * tile_h, max(widths), 3), np.uint8)
    for r, (row, width) in enumerate(zip(rows, widths)):
        x = (canvas.shape[1] - width) // 2
        for c in row:
            t = tiles[c]
            canvas[r * tile_h : r * tile_h + t.shape[0], x : x + t.shape[1]] = t
            x += t.shape[1]
    return canvas


def render_sample(
    nusc,
    sample_token: str,
    out_path: str | Path,
    *,
    gt: MapGT | None = None,
    predictions: Scored | None = None,
    score_thr: float = 0.4,
    cameras: Sequence[str] | None = None,
    tile_height: int = 270,
    ground_z_ego: float = 0.0,
    classes: Sequence[str] = CLASSES,
) -> Path:
    """Write the picture of one keyframe to ``out_path`` (PNG/JPEG by suffix) and return the path."""
    import cv2

    gt = gt or MapGT(nusc.dataroot)
    info = sample_info(nusc, sample_token, 0, max_sweeps=0, cameras=cameras)
    lidar2ego = T_from_quat_trans(info["lidar2ego_rotation"], info["lidar2ego_translation"])
    vectors = [(c, p) for c, p in gt.sample_vectors(nusc, sample_token) if c in classes]
    preds = [(c, p, s) for c, p, s in (predictions or []) if s >= score_thr and c in classes and len(p) >= 2]
    tiles = {
        ch: _camera_tile(cam, vectors, preds, lidar2ego, ground_z_ego, tile_height)
        for ch, cam in info["cams"].items()
    }
    grid = (
        _grid(tiles, camera_rows(info["cams"]))
        if tiles
        else np.zeros((tile_height, tile_height, 3), np.uint8)
    )
    bev = bev_panel(vectors, preds, grid.shape[0], (gt.patch[1] / 2.0, gt.patch[0] / 2.0))
    canvas = np.concatenate([grid, bev], axis=1)
    out_path = Path(out_path)
    ok, buf = cv2.imencode(out_path.suffix or ".png", canvas)
    if not ok:
        raise ValueError(f"{out_path}: cannot encode an image with suffix {out_path.suffix!r}")
    atomic_write_bytes(out_path, buf.tobytes())
    return out_path


def render(
    dataroot: str | Path,
    version: str,
    sample_token: str,
    out_path: str | Path,
    pred_path: str | Path | None = None,
    score_thr: float = 0.4,
    tile_height: int = 270,
) -> Path:
    """``nuav2 viz``: open the database, optionally a MapTR results json, and render one keyframe."""
    from nuscenes.nuscenes import NuScenes

    all_preds = None if pred_path is None else load_predictions(pred_path)  # a bad file fails before the load
    nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    try:
        nusc.get("sample", sample_token)
    except KeyError as e:
        raise ValueError(f"--sample {sample_token}: no sample with this token in {dataroot}/{version}") from e
    preds = None
    if all_preds is not None:
        if sample_token not in all_preds:
            raise ValueError(f"{pred_path}: no predictions for sample {sample_token}")
        preds = all_preds[sample_token]
    return render_sample(
        nusc, sample_token, out_path, predictions=preds, score_thr=score_thr, tile_height=tile_height
    )


__all__ = [
    "CLASS_COLORS_RGB",
    "NUSCENES_CAMERAS",
    "bev_panel",
    "clip_polyline",
    "ground_points_lidar",
    "load_predictions",
    "project_segments",
    "render",
    "render_sample",
]
