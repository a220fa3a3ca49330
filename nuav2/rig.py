"""Sensor rigs as data: cameras, lidars and the vehicle frame, loaded from ``rig_specs/*.json``.

A rig spec is the only thing a user writes to get a dataset in a new camera layout, so the
loader is strict: every error names the file and the field that is wrong.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from nuav2.geometry import F64, T_from_quat_trans, T_to_quat_trans, translation_T

RIG_SPEC_DIR = Path(__file__).resolve().parent.parent / "rig_specs"
CHANNEL_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")  # at most 64: it goes into every file name
KEYFRAME_LIDAR = "LIDAR_TOP"  # what the devkit, MapTR and the detection eval read from sample['data']
CAMERA_FIELDS = {"channel", "width", "height", "fx", "fy", "cx", "cy", "translation", "rotation",
                 "ego_mask_polygons"}
LIDAR_FIELDS = {"channel", "translation", "rotation"}
UNIT_QUAT_TOL = 1e-6


class RigSpecError(ValueError):
    """A rig spec file is malformed; the message names the file and field."""


def scaled_side(px: int, scale: float) -> int:
    """An image side of ``px`` pixels at ``scale``: rounded, at least 1 (OverflowError when infinite)."""
    return max(1, int(round(px * scale)))


# Where warp reads a source image's colours (its bilinear taps, and the exposure samples it harmonises
# with), the ego mask is grown by this much: a tap one pixel off the body and JPEG's chroma bleed carry
# the body's paint. Found by review: the body's edge colour, inpainted over the unseen strip behind the
# ego, tinted about a tenth of CAM_BACK. (Render mode's training mask is the exact one: grown by 2 px
# of its reduced images it dropped the ground right behind the ego, CAM_BACK's view, from training.)
EGO_COLOUR_MARGIN_PX = 2


@dataclass(frozen=True)
class CameraSpec:
    """One pinhole camera: intrinsics at ``width`` x ``height`` and its pose in the ego frame."""

    channel: str
    width: int
    height: int
    K: F64
    ego_T_cam: F64
    # Polygons (pixel coordinates at this resolution) covering the ego vehicle's own body.
    ego_mask_polygons: tuple[F64, ...] = ()

    def scaled(self, scale: float) -> CameraSpec:
        """Same camera at ``scale`` times the resolution; pixel centres map (x+0.5)*s-0.5."""
        w, h = scaled_side(self.width, scale), scaled_side(self.height, scale)
        sx, sy = w / self.width, h / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        polys = tuple(np.column_stack([(p[:, 0] + 0.5) * sx - 0.5, (p[:, 1] + 0.5) * sy - 0.5])
                      for p in self.ego_mask_polygons)
        return replace(self, width=w, height=h, K=K, ego_mask_polygons=polys)

    def ego_mask(self, margin_px: int = 0) -> np.ndarray:
        """Boolean (H, W) image, True where the ego body hides the scene, grown by ``margin_px`` pixels
        (:data:`EGO_COLOUR_MARGIN_PX` where colours are read: see there)."""
        import cv2

        mask = np.zeros((self.height, self.width), np.uint8)
        for poly in self.ego_mask_polygons:
            cv2.fillPoly(mask, [np.round(poly).astype(np.int32)], 1)
        if margin_px > 0 and self.ego_mask_polygons:
            mask = cv2.dilate(mask, np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8))
        return mask.astype(bool)


@dataclass(frozen=True)
class LidarSpec:
    """A lidar (real or virtual) and its pose in the ego frame."""

    channel: str
    ego_T_lidar: F64


@dataclass(frozen=True)
class Rig:
    """A vehicle's sensor layout. ``origin_height_m`` is the ego origin's height above ground."""

    name: str
    origin_height_m: float
    cameras: tuple[CameraSpec, ...]
    lidars: tuple[LidarSpec, ...]
    keyframe_lidar: str
    description: str = ""
    source_path: str = ""
    scale: float = 1.0
    extra: dict = field(default_factory=dict, compare=False)

    @property
    def camera_channels(self) -> list[str]:
        return [c.channel for c in self.cameras]

    def camera(self, channel: str) -> CameraSpec:
        for c in self.cameras:
            if c.channel == channel:
                return c
        raise KeyError(f"rig {self.name!r} has no camera {channel!r}; it has {self.camera_channels}")

    def lidar(self, channel: str) -> LidarSpec:
        for lid in self.lidars:
            if lid.channel == channel:
                return lid
        raise KeyError(f"rig {self.name!r} has no lidar {channel!r}")

    def scaled(self, scale: float) -> Rig:
        """Rig with every camera's resolution (and intrinsics) multiplied by ``scale``."""
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        return replace(self, cameras=tuple(c.scaled(scale) for c in self.cameras), scale=self.scale * scale)

    def with_origin_height(self, origin_height_m: float) -> Rig:
        """Same physical sensors expressed in a vehicle frame whose origin is at another height."""
        oldT_new = translation_T(z=origin_height_m - self.origin_height_m)
        newT_old = np.linalg.inv(oldT_new)
        cams = tuple(replace(c, ego_T_cam=newT_old @ c.ego_T_cam) for c in self.cameras)
        lids = tuple(replace(lid, ego_T_lidar=newT_old @ lid.ego_T_lidar) for lid in self.lidars)
        return replace(self, cameras=cams, lidars=lids, origin_height_m=origin_height_m)

    def with_cameras(self, cameras: tuple[CameraSpec, ...]) -> Rig:
        return replace(self, cameras=cameras)

    def to_dict(self) -> dict:
        """Serialisable form, the inverse of :func:`rig_from_dict` (at scale 1)."""
        cams = []
        for c in self.cameras:
            q, t = T_to_quat_trans(c.ego_T_cam)
            cams.append({
                "channel": c.channel, "width": c.width, "height": c.height,
                "fx": float(c.K[0, 0]), "fy": float(c.K[1, 1]),
                "cx": float(c.K[0, 2]), "cy": float(c.K[1, 2]),
                "translation": t.tolist(), "rotation": q.tolist(),
                "ego_mask_polygons": [p.tolist() for p in c.ego_mask_polygons],
            })
        lids = []
        for lid in self.lidars:
            q, t = T_to_quat_trans(lid.ego_T_lidar)
            lids.append({"channel": lid.channel, "translation": t.tolist(), "rotation": q.tolist()})
        return {"name": self.name, "description": self.description, "origin_height_m": self.origin_height_m,
                "keyframe_lidar": self.keyframe_lidar, "cameras": cams, "lidars": lids}


def _need(d: dict, key: str, where: str, src: str):
    if not isinstance(d, dict) or key not in d:
        raise RigSpecError(f"{src}: missing field '{where}{key}'")
    return d[key]


def _number(v, where: str, src: str) -> float:
    try:
        x = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else float("nan")
    except OverflowError:  # a JSON integer beyond float range
        x = float("inf")
    if not np.isfinite(x):
        raise RigSpecError(f"{src}: field '{where}' must be a finite number, got {v!r}")
    return x


def _known_fields(d: dict, known: set[str], where: str, src: str) -> None:
    """A misspelt optional field (``ego_mask_polygon``) would silently drop what it held."""
    unknown = sorted(set(d) - known)
    if unknown:
        raise RigSpecError(f"{src}: unknown field(s) {unknown} in '{where.rstrip('.')}' "
                           f"(known: {sorted(known)})")


def _text(v, where: str, src: str) -> str:
    if not isinstance(v, str):
        raise RigSpecError(f"{src}: field '{where}' must be a string, got {v!r}")
    return v


def _mask_polygons(c: dict, where: str, src: str) -> tuple[np.ndarray, ...]:
    raw = c.get("ego_mask_polygons", [])
    if not isinstance(raw, list):
        raise RigSpecError(f"{src}: field '{where}ego_mask_polygons' must be a list of polygons, got {raw!r}")
    polys = []
    for j, p in enumerate(raw):
        try:
            arr = np.asarray(p, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            arr = np.zeros((0, 0))
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 3 or not np.all(np.isfinite(arr)):
            raise RigSpecError(
                f"{src}: field '{where}ego_mask_polygons[{j}]' must be >= 3 finite [x, y] points")
        polys.append(arr)
    return tuple(polys)


def _vector(v, n: int, where: str, src: str) -> np.ndarray:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise RigSpecError(f"{src}: field '{where}' must be a list of {n} numbers, got {v!r}")
    return np.array([_number(x, f"{where}[{i}]", src) for i, x in enumerate(v)])


def _pose(d: dict, where: str, src: str) -> np.ndarray:
    t = _vector(_need(d, "translation", where, src), 3, where + "translation", src)
    q = _vector(_need(d, "rotation", where, src), 4, where + "rotation", src)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_QUAT_TOL:
        raise RigSpecError(f"{src}: field '{where}rotation' is not a unit quaternion (norm {norm:.9f})")
    return T_from_quat_trans(q, t)


def _channel(d: dict, where: str, src: str, seen: set[str]) -> str:
    ch = _need(d, "channel", where, src)
    if not isinstance(ch, str) or not CHANNEL_RE.match(ch):
        raise RigSpecError(f"{src}: field '{where}channel' must match {CHANNEL_RE.pattern}, got {ch!r}")
    if ch in seen:
        raise RigSpecError(f"{src}: field '{where}channel' repeats channel {ch!r}")
    seen.add(ch)
    return ch


def rig_from_dict(spec: dict, src: str = "<dict>") -> Rig:
    """Validate and build a :class:`Rig`; every error names ``src`` and the field."""
    if not isinstance(spec, dict):
        raise RigSpecError(f"{src}: top level must be a JSON object")
    name = _text(_need(spec, "name", "", src), "name", src)
    description = _text(spec.get("description", ""), "description", src)
    extra = spec.get("extra", {})
    if not isinstance(extra, dict):
        raise RigSpecError(f"{src}: field 'extra' must be a JSON object, got {extra!r}")
    origin_h = _number(_need(spec, "origin_height_m", "", src), "origin_height_m", src)
    cams_raw = _need(spec, "cameras", "", src)
    if not isinstance(cams_raw, list) or not cams_raw:
        raise RigSpecError(f"{src}: field 'cameras' must be a non-empty list")
    seen: set[str] = set()
    cameras = []
    for i, c in enumerate(cams_raw):
        w = f"cameras[{i}]."
        ch = _channel(c, w, src, seen)
        _known_fields(c, CAMERA_FIELDS, w, src)
        width = _need(c, "width", w, src)
        height = _need(c, "height", w, src)
        for key, v in (("width", width), ("height", height)):
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise RigSpecError(f"{src}: field '{w}{key}' must be a positive integer, got {v!r}")
        fx, fy = (_number(_need(c, k, w, src), w + k, src) for k in ("fx", "fy"))
        for key, v in (("fx", fx), ("fy", fy)):
            if v <= 0:
                raise RigSpecError(f"{src}: field '{w}{key}' must be a positive focal length, got {v}")
        cx, cy = (_number(_need(c, k, w, src), w + k, src) for k in ("cx", "cy"))
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        cameras.append(CameraSpec(ch, width, height, K, _pose(c, w, src), _mask_polygons(c, w, src)))
    lidars_raw = _need(spec, "lidars", "", src)
    if not isinstance(lidars_raw, list):
        raise RigSpecError(f"{src}: field 'lidars' must be a list, got {lidars_raw!r}")
    lidars = []
    for i, lid in enumerate(lidars_raw):
        w = f"lidars[{i}]."
        lidars.append(LidarSpec(_channel(lid, w, src, seen), _pose(lid, w, src)))
        _known_fields(lid, LIDAR_FIELDS, w, src)
    key_lidar = _need(spec, "keyframe_lidar", "", src)
    if key_lidar != KEYFRAME_LIDAR:  # the one LiDAR channel a nuScenes database has
        raise RigSpecError(f"{src}: field 'keyframe_lidar' must be {KEYFRAME_LIDAR!r} (the devkit, MapTR and "
                           f"the detection eval read sample['data']['{KEYFRAME_LIDAR}']), "
                           f"got {key_lidar!r}")
    if key_lidar not in {lid.channel for lid in lidars}:
        raise RigSpecError(f"{src}: field 'lidars' has no {KEYFRAME_LIDAR!r} entry, which 'keyframe_lidar' "
                           f"names")
    known = {"name", "description", "origin_height_m", "keyframe_lidar", "cameras", "lidars", "extra"}
    unknown = sorted(set(spec) - known)
    if unknown:
        raise RigSpecError(f"{src}: unknown top-level field(s) {unknown}")
    return Rig(name=name, origin_height_m=origin_h, cameras=tuple(cameras), lidars=tuple(lidars),
               keyframe_lidar=key_lidar, description=description, source_path=src, extra=dict(extra))


def available_rigs() -> list[str]:
    return sorted(p.stem for p in RIG_SPEC_DIR.glob("*.json"))


def load_rig(name_or_path: str | Path, scale: float = 1.0) -> Rig:
    """Load a rig by built-in name (``nuscenes``, ``av2``, ...) or by JSON path, optionally scaled."""
    p = Path(name_or_path)
    if not p.suffix and not p.is_file() and os.sep not in str(name_or_path):  # a name, not a file
        p = RIG_SPEC_DIR / f"{name_or_path}.json"
        if not p.exists():
            raise RigSpecError(f"unknown rig {name_or_path!r}; built-in rigs: {available_rigs()}")
    if not p.exists():
        raise RigSpecError(f"{p}: rig spec file not found")
    try:
        spec = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise RigSpecError(f"{p}: not valid JSON ({e})") from e
    except UnicodeDecodeError as e:
        raise RigSpecError(f"{p}: not a UTF-8 text file (byte 0x{e.object[e.start]:02x} at offset "
                           f"{e.start}); a rig spec is JSON") from e
    except OSError as e:  # a directory, no permission, an I/O error
        raise RigSpecError(f"{p}: cannot read the rig spec ({e.strerror or e})") from e
    rig = rig_from_dict(spec, str(p))
    return rig.scaled(scale) if scale != 1.0 else rig
