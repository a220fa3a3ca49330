"""The reconstructed scene (Street Gaussians style): static background, moving objects, sky.

- :class:`GaussianSet` holds the raw parameters one rasterizer call consumes (means, wxyz
  quaternions, log-scales, opacity logits, SH colour coefficients).
- :class:`TrackPoses` / :class:`ObjectModel`: one Gaussian set per *moving* track, living in
  its box frame and placed at any time by the track's interpolated ``scene_T_box``; outside
  its annotated span the object is absent.
- :class:`SkyModel` (:mod:`nuav2.splat.sky`): a lat-long texture looked up by view direction with
  ``grid_sample``, composited where the Gaussians leave the pixel transparent.
- :class:`SplatScene` renders all of them in one rasterizer call, in a *scene-local* float32
  frame: ``city_T_scene`` is a float64 translation to the first ego pose, so float32 never
  sees city-scale coordinates.

Camera poses handed to :meth:`SplatScene.render` are in the city frame (float64, OpenCV
camera axes: x right, y down, z forward), with the rig convention that pixel (u, v) has its
centre at (u, v); the rasterizer's pixel centres sit at +0.5, so K is shifted on the way in.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64, PoseTable, T_inverse, translation_T
from nuav2.rig import CameraSpec
from nuav2.splat.footprint import focal_px, widen_to_training_footprint
from nuav2.splat.sky import SkyModel, inverse_sigmoid, pixel_rays
from nuav2.splat.visible import gather_all, gather_visible

SH_C0 = 0.28209479177387814
PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh")
SCENE_FORMAT = "nuav2-splat-scene/1"


def rgb_to_sh_dc(rgb01: torch.Tensor) -> torch.Tensor:
    """SH DC coefficient whose colour (C0 * c + 0.5) equals ``rgb01``."""
    return (rgb01 - 0.5) / SH_C0


@dataclass
class GaussianSet:
    """Raw Gaussian parameters (leaf tensors the optimiser updates), all float32 on one device.

    means (N,3) metres in the set's own frame; quats (N,4) wxyz; log_scales (N,3);
    opacity_logits (N,); sh (N,K,3) with K = (degree+1)^2.
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor
    _bound: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
        for name, shape in shapes.items():
            if tuple(getattr(self, name).shape) != shape:
                got = tuple(getattr(self, name).shape)
                raise ValueError(f"GaussianSet.{name} must have shape {shape}, got {got}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"GaussianSet.sh must be (N,K,3) with N={n}, got {tuple(self.sh.shape)}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @staticmethod
    def create(means: np.ndarray | torch.Tensor, rgb01: np.ndarray | torch.Tensor,
               scales: np.ndarray | torch.Tensor, *, opacity: float = 0.1, sh_degree: int = 1,
               quats: np.ndarray | torch.Tensor | None = None) -> GaussianSet:
        """New set from positions, colours in [0,1] and per-axis scales (N,3) or (N,) metres."""
        means_t = torch.as_tensor(np.asarray(means, np.float32)).reshape(-1, 3).clone()
        n = len(means_t)
        rgb = torch.as_tensor(np.asarray(rgb01, np.float32)).reshape(n, 3).clamp(0.0, 1.0)
        sc = torch.as_tensor(np.asarray(scales, np.float32))
        sc = (sc.reshape(n, 1).expand(n, 3) if sc.ndim == 1 else sc.reshape(n, 3)).clamp_min(1e-4)
        if quats is None:
            q = torch.zeros(n, 4)
            q[:, 0] = 1.0
        else:
            q = torch.as_tensor(np.asarray(quats, np.float32)).reshape(n, 4).clone()
        sh = torch.zeros(n, (sh_degree + 1) ** 2, 3)
        sh[:, 0] = rgb_to_sh_dc(rgb)
        return GaussianSet(means_t, q, torch.log(sc).contiguous(),
                           torch.full((n,), float(inverse_sigmoid(opacity))), sh)

    @staticmethod
    def empty(sh_degree: int = 1) -> GaussianSet:
        return GaussianSet.create(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), sh_degree=sh_degree)

    @property
    def sh_degree(self) -> int:
        return math.isqrt(self.sh.shape[1]) - 1

    def tensors(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in PARAM_NAMES}

    def bounding_radius(self) -> float:
        """Radius about the set's origin holding every Gaussian's 3-sigma sphere (0 when empty);
        cached until the means or scales change their version (``step_groups_with_grads`` bumps it:
        fused Adam does not)."""
        m, s = self.means, self.log_scales
        b = self._bound
        if not (b and b[0] is m and b[1] == m._version and b[2] is s and b[3] == s._version):
            with torch.no_grad():
                r = float((m.norm(dim=-1) + 3.0 * s.clamp(max=10.0).exp().amax(-1)).amax()) if len(m) else 0.0
            self._bound = b = (m, m._version, s, s._version, r)
        return b[4]

    def requires_grad_(self, flag: bool = True) -> GaussianSet:
        for t in self.tensors().values():
            t.requires_grad_(flag)
        return self

    def replace(self, **tensors: torch.Tensor) -> GaussianSet:
        d = self.tensors()
        d.update(tensors)
        return GaussianSet(**d)

    def select(self, keep: torch.Tensor) -> GaussianSet:
        """Detached subset (bool mask or index tensor)."""
        return GaussianSet(**{k: v.detach()[keep].clone() for k, v in self.tensors().items()})

    def concat(self, other: GaussianSet) -> GaussianSet:
        return GaussianSet(**{k: torch.cat([v.detach(), getattr(other, k).detach()])
                              for k, v in self.tensors().items()})

    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.opacity_logits.detach())

    def to(self, device: torch.device | str) -> GaussianSet:
        """This set on ``device``: itself when already there, else detached copies (build the
        optimizer afterwards: it must hold the tensors that are trained)."""
        if self.means.device == torch.device(device):
            return self
        return GaussianSet(**{k: v.detach().to(device) for k, v in self.tensors().items()})

    def all_finite(self) -> bool:
        return all(bool(torch.isfinite(v).all()) for v in self.tensors().values())

    def state(self) -> dict[str, torch.Tensor]:
        """CPU copies of the parameters (saved files do not depend on the training device)."""
        return {k: v.detach().cpu().clone() for k, v in self.tensors().items()}

    @staticmethod
    def from_state(state: dict[str, torch.Tensor]) -> GaussianSet:
        missing = [k for k in PARAM_NAMES if k not in state]
        if missing:
            raise ValueError(f"Gaussian state lacks {missing}")
        return GaussianSet(**{k: state[k].detach().cpu().clone().float() for k in PARAM_NAMES})


@dataclass
class TrackPoses:
    """A track's box poses in the scene frame at its annotated times (float64)."""

    track_id: str
    category: str
    size_lwh: F64  # (3,) median box size
    timestamps_ns: np.ndarray  # (T,) int64, strictly increasing
    scene_T_box: F64  # (T, 4, 4)
    # The object is present from first - margin to last + margin (half a sweep period by default).
    presence_margin_ns: int = 50_000_000
    # Learned per-frame corrections (T, 4): dx, dy, dz (box frame, metres) and dyaw (radians) applied
    # after each annotated pose, interpolated linearly in between (None: the annotated poses as they are).
    pose_delta: torch.Tensor | None = field(default=None, repr=False)
    # A non-rigid actor is modelled as consecutive time segments, each its own object present only in
    # [present_from_ns, present_until_ns) (nuav2.splat.actors.segment_track).
    segment: int | None = None
    present_from_ns: int | None = None
    present_until_ns: int | None = None
    _table: PoseTable | None = field(default=None, init=False, repr=False, compare=False)
    _table_of: tuple = field(default=(), init=False, repr=False, compare=False)

    @property
    def key(self) -> str:
        """Unique name of the object: the track id, plus ``#k`` for segment k of a non-rigid actor."""
        return self.track_id if self.segment is None else f"{self.track_id}#{self.segment}"

    def present(self, timestamp_ns: int) -> bool:
        t = int(timestamp_ns)
        if self.present_from_ns is not None and self.present_until_ns is not None:
            return self.present_from_ns <= t < self.present_until_ns
        return int(self.timestamps_ns[0]) - self.presence_margin_ns <= t <= int(self.timestamps_ns[-1]) + \
            self.presence_margin_ns

    def scene_T_box_at(self, timestamp_ns: int) -> F64:
        """Interpolated box pose (slerp + lerp); the ends hold within the presence margin. The track's
        pose table is built once (seeding and rendering ask for every image's time) and
        rebuilt when ``scene_T_box`` is replaced (:meth:`bake_deltas`)."""
        return self._pose_table().at(int(timestamp_ns)).copy()

    def prefetch(self, timestamps_ns: list[int]) -> None:
        """Compute the poses at these times (those the track is present at) in one call; later
        :meth:`scene_T_box_at` calls read them."""
        present = [int(t) for t in timestamps_ns if self.present(t)]
        if present:
            self._pose_table().prefetch(present)

    def _pose_table(self) -> PoseTable:
        src = (self.scene_T_box, self.timestamps_ns, self.presence_margin_ns)
        if self._table is None or any(a is not b for a, b in zip(self._table_of, src)):
            self._table = PoseTable(self.timestamps_ns, self.scene_T_box, self.presence_margin_ns)
            self._table_of = src
        return self._table

    def delta_at(self, timestamp_ns: int) -> torch.Tensor | None:
        """The learned correction (4,) at a time: linear between the annotated times, held at the ends."""
        if self.pose_delta is None:
            return None
        ts = self.timestamps_ns
        t = min(max(int(timestamp_ns), int(ts[0])), int(ts[-1]))
        hi = int(np.clip(np.searchsorted(ts, t, side="left"), 0, len(ts) - 1))
        lo = max(hi - 1, 0) if ts[hi] != t else hi
        a = 0.0 if hi == lo else (t - int(ts[lo])) / float(int(ts[hi]) - int(ts[lo]))
        return (1.0 - a) * self.pose_delta[lo] + a * self.pose_delta[hi]

    def bake_deltas(self) -> None:
        """Fold the learned corrections into ``scene_T_box`` (the saved scene needs no tensors)."""
        if self.pose_delta is None:
            return
        d = self.pose_delta.detach().cpu().double().numpy()
        box_T_corr = np.zeros((len(d), 4, 4))
        c, s = np.cos(d[:, 3]), np.sin(d[:, 3])
        box_T_corr[:, 0, 0], box_T_corr[:, 0, 1], box_T_corr[:, 1, 0], box_T_corr[:, 1, 1] = c, -s, s, c
        box_T_corr[:, 2, 2] = box_T_corr[:, 3, 3] = 1.0
        box_T_corr[:, :3, 3] = d[:, :3]
        self.scene_T_box = self.scene_T_box @ box_T_corr
        self.pose_delta = None

    def state(self) -> dict:
        d = {"track_id": self.track_id, "category": self.category, "size_lwh": self.size_lwh.tolist(),
             "timestamps_ns": self.timestamps_ns.tolist(), "scene_T_box": self.scene_T_box.tolist(),
             "presence_margin_ns": self.presence_margin_ns, "segment": self.segment,
             "present_from_ns": self.present_from_ns, "present_until_ns": self.present_until_ns}
        if self.pose_delta is not None:
            d["pose_delta"] = self.pose_delta.detach().cpu().clone()
        return d

    @staticmethod
    def from_state(d: dict) -> TrackPoses:
        delta = d.get("pose_delta")
        delta = None if delta is None else delta.detach().cpu().clone().float()
        return TrackPoses(d["track_id"], d["category"], np.asarray(d["size_lwh"], np.float64),
                          np.asarray(d["timestamps_ns"], np.int64), np.asarray(d["scene_T_box"], np.float64),
                          int(d["presence_margin_ns"]), delta, d.get("segment"), d.get("present_from_ns"),
                          d.get("present_until_ns"))


@dataclass
class ObjectModel:
    """A moving track's Gaussians in its box frame (x along length, z up, origin at the box centre)."""

    track: TrackPoses
    gaussians: GaussianSet


def raster_K(K: F64) -> F64:
    """Rig intrinsics (pixel u centred at u) -> rasterizer intrinsics (pixel j centred at j + 0.5)."""
    Kr = np.array(K, dtype=np.float64, copy=True)
    Kr[0, 2] += 0.5
    Kr[1, 2] += 0.5
    return Kr


class SceneRender(NamedTuple):
    """One camera's render: rgb (H,W,3) in [0,1] with sky, alpha (H,W), depth (H,W) z-depth of the
    Gaussians (0 where alpha is 0), the rasterizer meta, which rows of the gathered Gaussians
    came from which set (``"background"`` or a track id) and which of them were rasterized."""

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    meta: dict
    slices: dict[str, slice]
    index: torch.Tensor  # rows of the gathered Gaussians that reached the rasterizer (meta's rows)


@dataclass
class SplatScene:
    """Everything a reconstruction produced; render it from any camera at any time."""

    city_T_scene: F64  # (4, 4) float64 translation to the first ego pose
    background: GaussianSet
    objects: list[ObjectModel]
    sky: SkyModel
    near: float = 0.1
    far: float = 1000.0
    radius_clip: float = 0.0
    info: dict = field(default_factory=dict)
    backend: str = "auto"  # the rasterizer's backend (nuav2.splat.rasterize); not saved with the scene
    # Above the training resolution, widen Gaussians to their trained footprint (nuav2.splat.footprint);
    # False renders them as trained, eroded at finer pixels. Not saved with the scene.
    keep_training_footprint: bool = True
    _train_focal: tuple = field(default=(None, None), init=False, repr=False, compare=False)  # (records, f)

    @property
    def scene_T_city(self) -> F64:
        return T_inverse(self.city_T_scene)

    @property
    def sh_degree(self) -> int:
        return self.background.sh_degree

    @property
    def device(self) -> torch.device:
        """Where the scene's tensors live (and so where it trains and renders)."""
        return self.background.means.device

    def to(self, device: torch.device | str) -> SplatScene:
        """Move every tensor (Gaussians, learned box corrections, sky) to ``device``, in place;
        returns the scene. Build optimizers afterwards."""
        self.background = self.background.to(device)
        for o in self.objects:
            o.gaussians = o.gaussians.to(device)
            if o.track.pose_delta is not None:
                o.track.pose_delta = o.track.pose_delta.detach().to(device)
        self.sky = self.sky.to(device)
        return self

    @property
    def train_focal_px(self) -> float | None:
        """The finest pixel the scene was trained at: the largest focal length (pixels) of the training images
        recorded in ``info["source_views"]`` (None while training, or for a scene without the record)."""
        records = self.info.get("source_views") or []
        if self._train_focal[0] is not records:  # once per record list, not per render (1.4 ms on 15 s)
            self._train_focal = (records, max((focal_px(r["K"]) for r in records), default=None))
        return self._train_focal[1]

    def num_gaussians(self) -> int:
        return len(self.background) + sum(len(o.gaussians) for o in self.objects)

    def gather(self, timestamp_ns: int,
               objects: bool = True) -> tuple[dict[str, torch.Tensor], dict[str, slice]]:
        """All Gaussians in the scene frame at ``timestamp_ns`` (objects moved along their tracks),
        concatenated; autograd flows back to every set's parameters."""
        return gather_all(self, timestamp_ns, objects)

    def render(self, cam: CameraSpec, city_T_cam: F64, timestamp_ns: int, *, sh_degree: int | None = None,
               with_sky: bool = True, objects: bool = True) -> SceneRender:
        """Render ``cam`` (at its own resolution) posed at ``city_T_cam`` with actors at ``timestamp_ns``."""
        from nuav2.splat import rasterize
        from nuav2.splat._inputs import prepare_cameras

        scene_T_cam = self.scene_T_city @ np.asarray(city_T_cam, np.float64)
        # A NaN or non-rigid pose gathers no Gaussians, and the empty-view path below would return
        # sky (judged fully covered): check it as rasterize would.
        prepare_cameras(scene_T_cam, cam.K)
        g, slices, index = gather_visible(self, timestamp_ns, cam, scene_T_cam, objects)
        deg = self.sh_degree if sh_degree is None else min(sh_degree, self.sh_degree)
        dev = self.device
        if len(index) == 0:
            h, w = cam.height, cam.width
            alpha = torch.zeros(h, w, device=dev)
            out_rgb, out_depth, meta = torch.zeros(h, w, 3, device=dev), torch.zeros(h, w, device=dev), {}
        else:
            sh = g["sh"][:, : (deg + 1) ** 2]
            if deg == 0:  # view-independent: plain RGB skips the per-Gaussian view directions
                colors, raster_deg = (SH_C0 * sh[:, 0] + 0.5).clamp_min(0.0), None
            else:
                colors, raster_deg = sh, deg
            log_scales = g["log_scales"]
            if self.keep_training_footprint:
                log_scales = widen_to_training_footprint(log_scales, g["means"], scene_T_cam, focal_px(cam.K),
                                                         self.train_focal_px)
            out = rasterize(g["means"], g["quats"], log_scales, g["opacity_logits"], colors, scene_T_cam,
                            raster_K(cam.K), cam.width, cam.height, near=self.near, far=self.far,
                            sh_degree=raster_deg, radius_clip=self.radius_clip, backend=self.backend)
            out_rgb, alpha, out_depth, meta = out.rgb, out.alpha, out.depth, out.meta
        rgb = out_rgb
        if with_sky:
            sky = self.sky(pixel_rays(cam, scene_T_cam, dev))
            rgb = out_rgb + (1.0 - alpha)[..., None] * sky
        return SceneRender(rgb, alpha, out_depth, meta, slices, index)

    # ---- persistence ---------------------------------------------------------------------------

    def state(self) -> dict:
        return {"format": SCENE_FORMAT, "city_T_scene": self.city_T_scene.tolist(),
                "background": self.background.state(),
                "objects": [{"track": o.track.state(), "gaussians": o.gaussians.state()}
                            for o in self.objects],
                "sky": self.sky.texture.detach().cpu().clone(), "near": self.near, "far": self.far,
                "radius_clip": self.radius_clip, "info": dict(self.info)}

    @staticmethod
    def from_state(state: dict, src: str = "<state>") -> SplatScene:
        """The scene of :meth:`state`, on the CPU (``.to(device)`` moves it)."""
        if not isinstance(state, dict) or state.get("format") != SCENE_FORMAT:
            raise ValueError(f"{src}: not a nuav2 splat scene (format must be {SCENE_FORMAT!r})")
        tex = state["sky"]
        sky = SkyModel(tex.shape[1], tex.shape[2])
        with torch.no_grad():
            sky.texture.copy_(tex)
        objects = [ObjectModel(TrackPoses.from_state(o["track"]), GaussianSet.from_state(o["gaussians"]))
                   for o in state["objects"]]
        return SplatScene(np.asarray(state["city_T_scene"], np.float64),
                          GaussianSet.from_state(state["background"]), objects, sky, float(state["near"]),
                          float(state["far"]), float(state["radius_clip"]), dict(state.get("info", {})))

    def save(self, path: str | Path) -> None:
        """Write atomically (torch format, tensors + plain metadata)."""
        buf = io.BytesIO()
        torch.save(self.state(), buf)
        atomic_write_bytes(Path(path), buf.getvalue())

    @staticmethod
    def load(path: str | Path, device: torch.device | str = "cpu") -> SplatScene:
        """Read a scene written by :meth:`save` on any device, onto ``device``."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: splat scene file not found")
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as e:  # noqa: BLE001 - any unpickling failure means a bad file
            raise ValueError(f"{path}: not a readable splat scene ({type(e).__name__}: {e})") from e
        return SplatScene.from_state(state, str(path)).to(device)


def scene_frame_for(city_T_ego_first: F64) -> F64:
    """``city_T_scene``: a pure translation to the first ego position (float64), so scene axes
    are city axes (z up) and scene coordinates stay small."""
    return translation_T(*np.asarray(city_T_ego_first, np.float64)[:3, 3])
