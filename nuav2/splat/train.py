"""The optimisation loop: random source views, coarse-to-fine, densify under a budget, resumable.

Each iteration renders one source view (a random camera image, at the current pyramid
level's resolution) with background + objects at the image's timestamp + sky, and minimises
L1/SSIM against the photo (ego-body pixels masked), a LiDAR depth term and a sky opacity term.
Runs are deterministic for a seed (torch, numpy Generator and thread count are fixed and
saved in checkpoints), so ``train(..., resume=True)`` continues exactly where a killed run's
last checkpoint left off.
"""

from __future__ import annotations

import io
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64, T_inverse
from nuav2.progress import progress_bar
from nuav2.scene import SceneLog
from nuav2.splat.densify import DensifyConfig, DensifyStrategy
from nuav2.splat.init import SourceView, project
from nuav2.splat.losses import depth_loss, photometric_loss, psnr, sky_loss
from nuav2.splat.scene_model import GaussianSet, SplatScene

log = logging.getLogger(__name__)

CHECKPOINT_FILE = "checkpoint.pt"
CHECKPOINT_FORMAT = "nuav2-splat-train/1"


@dataclass(frozen=True)
class TrainConfig:
    iterations: int = 2000
    pyramid: tuple[float, ...] = (0.5, 1.0)  # resolution factors of the training images ...
    pyramid_until: tuple[float, ...] = (0.25,)  # ... switching at these fractions of the run
    sh_degree_every: int = 500  # raise the active SH degree every this many iterations
    lambda_ssim: float = 0.2
    lambda_depth: float = 0.05
    lambda_sky: float = 0.05
    depth_trim: float = 0.95
    lr_means: float = 1.6e-4  # x extent, decays x0.01 over the run
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 1.25e-4
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_sky: float = 0.01
    lr_final_frac: float = 0.01
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    extent_min_m: float = 20.0
    seed: int = 0
    threads: int = 2
    checkpoint_every: int = 0  # 0: only at the end (when a checkpoint dir is given)
    time_budget_s: float | None = None  # stop early once training has used this much wall time


@dataclass
class ViewData:
    """A training view's targets at the training resolution: image, valid mask, sky, LiDAR depth."""

    view: SourceView
    sky: np.ndarray  # (H, W) bool
    depth_uvz: np.ndarray  # (M, 3) float32, rig pixel convention
    _levels: dict = field(default_factory=dict, repr=False)

    def at(self, level: float) -> tuple:
        """(camera, image, valid, sky, depth samples) as tensors at a pyramid level."""
        if level not in self._levels:
            cam = self.view.cam.scaled(level) if level != 1.0 else self.view.cam
            img = self.view.image_u8()
            valid = self.view.valid
            sky = self.sky
            if level != 1.0:
                size = (cam.width, cam.height)
                img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
                valid = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
                sky = cv2.resize(sky.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
            uvz = self.depth_uvz.copy()
            sx, sy = cam.width / self.view.cam.width, cam.height / self.view.cam.height
            uvz[:, 0] = (uvz[:, 0] + 0.5) * sx - 0.5
            uvz[:, 1] = (uvz[:, 1] + 0.5) * sy - 0.5
            self._levels[level] = (cam, torch.from_numpy(np.ascontiguousarray(img)), torch.from_numpy(valid),
                                   torch.from_numpy(sky), torch.from_numpy(uvz))
        cam, img, valid, sky, uvz = self._levels[level]
        return cam, img.float() / 255.0, valid, sky, uvz


def lidar_depth_samples(scene: SceneLog, view: SourceView, scene_T_city: F64, max_points: int = 20_000,
                        max_depth_m: float = 150.0, sweep_cache: dict | None = None) -> np.ndarray:
    """LiDAR z-depth in a view from the sweep nearest its timestamp: (M, 3) u, v, z float32.

    ``sweep_cache`` (sweep timestamp -> scene-frame points) avoids re-reading a sweep that
    several views share."""
    if not scene.lidar_sweeps:
        return np.zeros((0, 3), np.float32)
    ts = scene.sweep_timestamps_ns
    ref = scene.lidar_sweeps[int(np.argmin(np.abs(ts - view.timestamp_ns)))]
    key = int(ref.timestamp_ns)
    if sweep_cache is None or key not in sweep_cache:
        scene_T_ego = scene_T_city @ scene.city_T_ego_at(key)
        pts = scene.sweep(ref).xyz_ego @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3]
        if sweep_cache is not None:
            sweep_cache.clear()  # views come grouped by camera, sorted by time: keep one sweep
            sweep_cache[key] = pts
    else:
        pts = sweep_cache[key]
    cam_T_scene = T_inverse(scene_T_city @ view.city_T_cam)
    proj = project(pts, view.cam, cam_T_scene, near=0.5)
    ok = proj.z < max_depth_m
    uvz = np.column_stack([proj.u[ok], proj.v[ok], proj.z[ok]]).astype(np.float32)
    pv = np.clip(np.round(uvz[:, 1]).astype(int), 0, view.cam.height - 1)
    pu = np.clip(np.round(uvz[:, 0]).astype(int), 0, view.cam.width - 1)
    uvz = uvz[view.valid[pv, pu]]
    return uvz[:max_points]


def scene_extent(views: list[SourceView], minimum: float) -> float:
    """Radius of the camera centres around their mean (x1.1), at least ``minimum`` metres."""
    c = np.array([v.city_T_cam[:3, 3] for v in views]) if views else np.zeros((1, 3))
    return max(minimum, 1.1 * float(np.linalg.norm(c - c.mean(0), axis=1).max(initial=0.0)))


def named_sets(splat: SplatScene) -> dict[str, GaussianSet]:
    out = {"background": splat.background}
    for o in splat.objects:
        out[f"obj:{o.track.track_id}"] = o.gaussians
    return out


def store_sets(splat: SplatScene, sets: dict[str, GaussianSet]) -> None:
    splat.background = sets["background"]
    for o in splat.objects:
        o.gaussians = sets[f"obj:{o.track.track_id}"]


def base_lr(group_name: str, cfg: TrainConfig, extent: float) -> float:
    """Initial learning rate of an optimizer group named ``<set>/<param>`` or ``sky``."""
    if group_name == "sky":
        return cfg.lr_sky
    lrs = {"means": cfg.lr_means * extent, "quats": cfg.lr_quats, "log_scales": cfg.lr_scales,
           "opacity_logits": cfg.lr_opacity, "sh": cfg.lr_sh_dc}
    return lrs[group_name.rsplit("/", 1)[1]]


def build_optimizer(splat: SplatScene, cfg: TrainConfig, extent: float) -> torch.optim.Adam:
    """One Adam param group per (set, parameter) plus the sky, in a fixed order (checkpointable)."""
    groups = []
    for name, g in named_sets(splat).items():
        g.requires_grad_(True)
        for p in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            groups.append({"params": [getattr(g, p)], "lr": base_lr(f"{name}/{p}", cfg, extent),
                           "name": f"{name}/{p}"})
    splat.sky.texture.requires_grad_(True)
    groups.append({"params": [splat.sky.texture], "lr": cfg.lr_sky, "name": "sky"})
    return torch.optim.Adam(groups, lr=1e-3, eps=1e-15, fused=True)


def pyramid_level(cfg: TrainConfig, step: int) -> float:
    frac = step / max(1, cfg.iterations)
    for level, until in zip(cfg.pyramid, cfg.pyramid_until):
        if frac < until:
            return level
    return cfg.pyramid[-1]


@dataclass
class TrainReport:
    steps: int
    seconds: float
    final_psnr: float
    gaussians: int
    densify: list[dict]
    stopped_early: bool = False
    losses: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


class Trainer:
    """Holds the scene, its optimizer and the RNG state; ``run`` trains to ``cfg.iterations``."""

    def __init__(self, splat: SplatScene, scene: SceneLog, views: list[SourceView],
                 sky_masks: dict[int, np.ndarray], cfg: TrainConfig) -> None:
        if not views:
            raise ValueError(f"log {scene.log_id}: no source camera images to train on")
        torch.manual_seed(cfg.seed)
        self.splat, self.cfg = splat, cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.extent = scene_extent(views, cfg.extent_min_m)
        scene_T_city = splat.scene_T_city
        cache: dict = {}
        self.data = [ViewData(v, sky_masks.get(v.index, np.zeros((v.cam.height, v.cam.width), bool)),
                              lidar_depth_samples(scene, v, scene_T_city, sweep_cache=cache)) for v in views]
        self.optimizer = build_optimizer(splat, cfg, self.extent)
        self.strategy = DensifyStrategy(cfg.densify, self.extent)
        self.boxes = {f"obj:{o.track.track_id}": o.track.size_lwh for o in splat.objects}
        self.step = 0
        self.losses: list[float] = []

    # ---- schedule ----
    def _set_lr(self) -> None:
        frac = min(1.0, self.step / max(1, self.cfg.iterations))
        decay = self.cfg.lr_final_frac ** frac
        for g in self.optimizer.param_groups:
            if g["name"].endswith("/means") or g["name"] == "sky":
                g["lr"] = base_lr(g["name"], self.cfg, self.extent) * decay

    def _active_sh(self) -> int:
        return min(self.splat.sh_degree, self.step // max(1, self.cfg.sh_degree_every))

    # ---- one iteration ----
    def train_step(self) -> tuple[float, float]:
        cfg = self.cfg
        self._set_lr()
        data = self.data[int(self.rng.integers(len(self.data)))]
        level = pyramid_level(cfg, self.step)
        cam, img, valid, sky, uvz = data.at(level)
        out = self.splat.render(cam, data.view.city_T_cam, data.view.timestamp_ns,
                                sh_degree=self._active_sh())
        m2d = out.meta.get("means2d")
        if m2d is not None:
            m2d.retain_grad()
        loss, _, _ = photometric_loss(out.rgb, img, valid, cfg.lambda_ssim)
        if cfg.lambda_depth > 0 and len(uvz):
            loss = loss + cfg.lambda_depth * depth_loss(out.depth, out.alpha, uvz, cfg.depth_trim)
        if cfg.lambda_sky > 0:
            loss = loss + cfg.lambda_sky * sky_loss(out.alpha, sky)
        value = float(loss.detach())
        if math.isfinite(value):
            loss.backward()
            for group in self.optimizer.param_groups:
                for p in group["params"]:
                    if p.grad is not None:
                        torch.nan_to_num_(p.grad, nan=0.0, posinf=0.0, neginf=0.0)
            if m2d is not None and m2d.grad is not None:
                n_all = max((sl.stop for sl in out.slices.values()), default=0)
                grad = torch.zeros(n_all, 2)
                grad[out.index] = m2d.grad[0]
                visible = torch.zeros(n_all, dtype=torch.bool)
                visible[out.index] = out.meta["radii"][0].gt(0).any(-1)
                for name, sl in out.slices.items():
                    key = name if name == "background" else f"obj:{name}"
                    self.strategy.accumulate(key, grad[sl], visible[sl], cam.width, cam.height)
            self.optimizer.step()
        else:
            log.warning("step %d: non-finite loss, skipped", self.step)
        self.optimizer.zero_grad(set_to_none=True)
        sets = self.strategy.step(self.step, named_sets(self.splat), self.optimizer, self.boxes)
        store_sets(self.splat, sets)
        self.step += 1
        return value, psnr(out.rgb, img, valid)

    def run(self, *, progress: bool = True, checkpoint_dir: Path | None = None,
            stop_at: int | None = None) -> TrainReport:
        """Train to ``cfg.iterations`` (or ``stop_at``, as if killed there after a checkpoint)."""
        cfg = self.cfg
        end = cfg.iterations if stop_at is None else min(cfg.iterations, int(stop_at))
        torch.set_num_threads(cfg.threads)
        t0 = time.perf_counter()
        ema_loss, ema_psnr, stopped = None, None, False
        bar = progress_bar(total=cfg.iterations, initial=self.step, desc="train", unit="it",
                           disable=not progress)
        try:
            while self.step < end:
                loss, p = self.train_step()
                self.losses.append(loss)
                ema_loss = loss if ema_loss is None else 0.9 * ema_loss + 0.1 * loss
                if math.isfinite(p):
                    ema_psnr = p if ema_psnr is None else 0.9 * ema_psnr + 0.1 * p
                bar.update()
                if self.step % 10 == 0:
                    bar.set_postfix(loss=f"{ema_loss:.4f}", psnr=f"{ema_psnr or 0:.2f}",
                                    n=self.splat.num_gaussians())
                every = cfg.checkpoint_every
                if checkpoint_dir is not None and every and self.step % every == 0:
                    self.save(Path(checkpoint_dir) / CHECKPOINT_FILE)
                if cfg.time_budget_s is not None and time.perf_counter() - t0 > cfg.time_budget_s:
                    stopped = True
                    break
        finally:
            bar.close()
        if checkpoint_dir is not None:
            self.save(Path(checkpoint_dir) / CHECKPOINT_FILE)
        for g in named_sets(self.splat).values():
            if not g.all_finite():
                raise FloatingPointError("training produced non-finite Gaussian parameters")
        return TrainReport(self.step, time.perf_counter() - t0, float(ema_psnr or 0.0),
                           self.splat.num_gaussians(), list(self.strategy.history), stopped,
                           list(self.losses))

    # ---- checkpoint / resume ----
    def state(self) -> dict:
        return {"format": CHECKPOINT_FORMAT, "step": self.step, "scene": self.splat.state(),
                "optimizer": self.optimizer.state_dict(), "rng": self.rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(), "losses": list(self.losses),
                "densify_stats": {k: (v.grad, v.count) for k, v in self.strategy.stats.items()},
                "densify_history": list(self.strategy.history)}

    def save(self, path: Path) -> None:
        buf = io.BytesIO()
        torch.save(self.state(), buf)
        atomic_write_bytes(Path(path), buf.getvalue())

    def load(self, path: Path) -> None:
        """Continue from a checkpoint written by :meth:`save` for the same log and config."""
        from nuav2.splat.densify import _Stats

        path = Path(path)
        try:
            st = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as e:  # noqa: BLE001 - any unpickling failure means a bad file
            raise ValueError(f"{path}: not a readable training checkpoint ({type(e).__name__}: {e})") from e
        if not isinstance(st, dict) or st.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"{path}: not a nuav2 training checkpoint")
        splat = SplatScene.from_state(st["scene"], str(path))
        if not np.allclose(splat.city_T_scene, self.splat.city_T_scene):
            raise ValueError(f"{path}: checkpoint belongs to another scene frame (another log?)")
        self.splat.background, self.splat.objects, self.splat.sky = splat.background, splat.objects, splat.sky
        self.optimizer = build_optimizer(self.splat, self.cfg, self.extent)
        self.optimizer.load_state_dict(st["optimizer"])
        self.rng.bit_generator.state = st["rng"]
        torch.set_rng_state(st["torch_rng"])
        self.step = int(st["step"])
        self.losses = list(st.get("losses", []))
        self.strategy.stats = {k: _Stats(g.clone(), c.clone()) for k, (g, c) in st["densify_stats"].items()}
        self.strategy.history = list(st["densify_history"])
        self.boxes = {f"obj:{o.track.track_id}": o.track.size_lwh for o in self.splat.objects}
