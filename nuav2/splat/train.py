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
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from nuav2.atomic import atomic_write_bytes
from nuav2.progress import progress_bar
from nuav2.scene import SceneLog
from nuav2.splat._photometric import fused_photometric_loss
from nuav2.splat.densify import DensifyConfig, DensifyStrategy
from nuav2.splat.device import to_cpu
from nuav2.splat.losses import depth_loss, flatness_loss, photo_behind_mask, photometric_loss, psnr, sky_loss
from nuav2.splat.optimizer import base_lr, build_optimizer, named_sets, step_groups_with_grads, store_sets
from nuav2.splat.pose_prior import pose_prior, track_tensors
from nuav2.splat.scene_model import SplatScene
from nuav2.splat.train_views import ViewData, lidar_depth_by_view
from nuav2.splat.views import SourceView

log = logging.getLogger(__name__)

CHECKPOINT_FILE = "checkpoint.pt"
CHECKPOINT_FORMAT = "nuav2-splat-train/1"


@dataclass(frozen=True)
class TrainConfig:
    iterations: int = 2000
    # The cap follows the log: at least this many iterations per training image (0: ``iterations``
    # whatever the log). A 15 s log has 7x the images of a 2 s one; each stretch of road is seen by
    # the images of a few seconds, so a fixed count trains a long log's every stretch 7x less.
    iterations_per_view: float = 0.0
    pyramid: tuple[float, ...] = (0.5, 1.0)  # resolution factors of the training images ...
    pyramid_until: tuple[float, ...] = (0.25,)  # ... switching at these fractions of the run
    sh_degree_every: int = 500  # raise the active SH degree every this many iterations
    lambda_ssim: float = 0.2
    lambda_depth: float = 0.05
    lambda_sky: float = 0.05
    # The background's Gaussians are pulled towards flat discs (x the mean smallest scale in metres;
    # 0: off): +0.05 to +0.37 dB on the nuScenes rig's ground of nine runs, 2 s and 15 s logs
    # (docs/reconstruction.md, "Flat background Gaussians"). Objects are left alone.
    lambda_flat: float = 10.0
    depth_trim: float = 0.95
    lr_means: float = 1.6e-4  # x extent, decays x0.01 over the run
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 1.25e-4
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lr_sky: float = 0.01
    lr_final_frac: float = 0.01
    # Moving tracks' box poses are refined (per-frame corrections, nuav2.splat.scene_model.TrackPoses)
    # from ``pose_start`` on, with a smoothness prior on their second differences and a pull to zero.
    lr_pose: float = 1e-3  # 0: the (smoothed) annotated poses as they are
    pose_start: int = 100
    lambda_pose_smooth: float = 1.0
    lambda_pose: float = 0.1
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    extent_min_m: float = 20.0
    seed: int = 0
    threads: int = 2
    checkpoint_every: int = 0  # 0: only at the end (when a checkpoint dir is given)
    time_budget_s: float | None = None  # stop early once training has used this much wall time
    # Early stop (with validation views): every ``eval_every`` steps the mean PSNR of up to
    # ``eval_views`` held-out images is measured. After ``patience`` measurements in a row without a
    # gain of ``min_delta_db`` over the best so far, densification ends (if still on), and at the next
    # such plateau training ends (not before ``min_iterations``).
    eval_every: int = 100
    eval_views: int = 8
    # Resolution of the measurement (x the training images); None: the pyramid's last level, the one
    # training ends at. At half resolution the held-out PSNR of a 15 s log levelled off at 1,800-2,100
    # steps while the full-resolution and target-rig PSNR rose 1 dB more (docs/reconstruction.md).
    eval_level: float | None = None
    patience: int = 3  # 0: never stop early (validation is still measured and reported)
    min_delta_db: float = 0.1
    min_iterations: int = 0
    # A run that stops at a plateau before the cap ends with its position LR decayed only part of the way
    # (the decay is a fraction of the cap). With ``cooldown_frac`` > 0 the plateau starts a cool-down of
    # that fraction of the steps run (at least ``cooldown_min``): the position and sky LR go on to their
    # final value and every other LR falls geometrically to ``cooldown_lr_end`` x its own; then it stops.
    cooldown_frac: float = 0.0
    cooldown_min: int = 100
    cooldown_lr_end: float = 1.0
    # False: the position and sky LR stay where the plateau left them (with ``cooldown_lr_end`` = 1 the
    # cool-down is then plain extra steps at unchanged rates, the control of docs/reconstruction.md).
    cooldown_positions: bool = True

    def for_views(self, n_views: int) -> TrainConfig:
        """This config for ``n_views`` training images: ``iterations`` raised to ``iterations_per_view`` x
        ``n_views`` where that is more, with densification's stop moved in proportion (the patience rule
        still ends the run at a plateau). A seeding-only config (0 iterations) stays one."""
        if self.iterations <= 0:
            return self
        n = max(self.iterations, math.ceil(self.iterations_per_view * n_views))
        if n == self.iterations:
            return self
        stop = round(self.densify.stop * n / max(1, self.iterations))
        return replace(self, iterations=n, densify=replace(self.densify, stop=stop))


def spread(items: list, n: int) -> list:
    """At most ``n`` items, evenly spaced over the list (all when n <= 0 or the list is short)."""
    if n <= 0 or len(items) <= n:
        return items
    return [items[i] for i in np.linspace(0, len(items) - 1, n).round().astype(int)]


def scene_extent(views: list[SourceView], minimum: float) -> float:
    """Radius of the camera centres around their mean (x1.1), at least ``minimum`` metres."""
    c = np.array([v.city_T_cam[:3, 3] for v in views]) if views else np.zeros((1, 3))
    return max(minimum, 1.1 * float(np.linalg.norm(c - c.mean(0), axis=1).max(initial=0.0)))


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
    stop_reason: str = "iterations"  # "iterations", "plateau" (validation PSNR) or "time budget"
    densify_stopped_at: int | None = None  # densification ended early here (validation plateau)
    validation: list[list[float]] = field(default_factory=list)  # [step, mean held-out PSNR dB]
    iterations: int | None = None  # the cap this run had (TrainConfig.for_views: it follows the log)
    cooldown: list[int] | None = None  # [first step, steps] of the cool-down after the plateau

    def to_dict(self) -> dict:
        return asdict(self)


class Trainer:
    """Holds the scene, its optimizer and the RNG state; ``run`` trains to ``cfg.iterations``.

    Training runs where the scene's tensors are (``splat.to(device)`` first): targets, masks,
    optimizer state and densification statistics follow it; random draws come from the CPU
    generators, so the checkpoint's RNG states serve every device."""

    def __init__(self, splat: SplatScene, scene: SceneLog, views: list[SourceView],
                 sky_masks: dict[int, np.ndarray], cfg: TrainConfig,
                 validation: list[SourceView] = ()) -> None:
        if not views:
            raise ValueError(f"log {scene.log_id}: no source camera images to train on")
        torch.manual_seed(cfg.seed)
        self.splat, self.cfg = splat, cfg
        self.device = splat.device
        self.name = scene.log_id[:8]
        self._track_base: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        if cfg.lr_pose > 0:
            for o in splat.objects:
                if o.track.pose_delta is None:
                    o.track.pose_delta = torch.zeros(len(o.track.timestamps_ns), 4, device=self.device)
        no_depth = np.zeros((0, 3), np.float32)
        self.val_data = [ViewData(v, np.zeros((v.cam.height, v.cam.width), bool), no_depth, self.device)
                         for v in spread(list(validation), cfg.eval_views)]
        self.validation: list[list[float]] = []  # [step, PSNR] per measurement
        self.best_val, self.bad_evals, self.plateau = -math.inf, 0, False
        self.cool: tuple[int, int] | None = None  # (first step, steps) of the cool-down once it started
        self.rng = np.random.default_rng(cfg.seed)
        self.extent = scene_extent(views, cfg.extent_min_m)
        scene_T_city = splat.scene_T_city
        depths = lidar_depth_by_view(scene, views, scene_T_city, threads=cfg.threads)
        self.data = [ViewData(v, sky_masks.get(v.index, np.zeros((v.cam.height, v.cam.width), bool)), uvz,
                              self.device) for v, uvz in zip(views, depths)]
        self.optimizer = build_optimizer(splat, cfg, self.extent)
        self.strategy = DensifyStrategy(cfg.densify, self.extent)
        self.boxes = {f"obj:{o.track.key}": o.track.size_lwh for o in splat.objects}
        self.step = 0
        self.losses: list[float] = []

    # ---- schedule ----
    def _set_lr(self) -> None:
        cfg = self.cfg
        if self.cool is None:
            frac, other = min(1.0, self.step / max(1, cfg.iterations)), 1.0
        else:  # the cool-down: from where the schedule was to its end
            start, n = self.cool
            t = min(1.0, (self.step - start) / max(1, n))
            frac0 = min(1.0, start / max(1, cfg.iterations))
            frac = frac0 + (1.0 - frac0) * t if cfg.cooldown_positions else frac0
            other = cfg.cooldown_lr_end ** t
        decay = cfg.lr_final_frac ** frac
        for g in self.optimizer.param_groups:
            if g["name"].endswith("/means") or g["name"] == "sky":
                g["lr"] = base_lr(g["name"], cfg, self.extent) * decay
            elif g["name"].startswith("pose:"):
                g["lr"] = (cfg.lr_pose if self.step >= cfg.pose_start else 0.0) * other
            elif other != 1.0:
                g["lr"] = base_lr(g["name"], cfg, self.extent) * other

    def _active_sh(self) -> int:
        return min(self.splat.sh_degree, self.step // max(1, self.cfg.sh_degree_every))

    def _pose_prior(self, rendered: dict[str, slice]) -> torch.Tensor | float:
        """The pose prior of the objects this step rendered (the ones whose corrections it updates)."""
        total: torch.Tensor | float = 0.0
        for o in self.splat.objects:
            d = o.track.pose_delta
            if d is None or not d.requires_grad or o.track.key not in rendered:
                continue
            if o.track.key not in self._track_base:
                self._track_base[o.track.key] = track_tensors(o.track)
            total = total + pose_prior(o.track, self.cfg.lambda_pose, self.cfg.lambda_pose_smooth,
                                       self._track_base[o.track.key])
        return total

    # ---- one iteration ----
    def train_step(self, measure_psnr: bool = True) -> tuple[float, float]:
        """One iteration: (loss, PSNR of the rendered training image; NaN unless ``measure_psnr``, which
        costs a full-image pass: ``run`` measures it only on the steps whose progress line shows it)."""
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
        # the fused numba loss on the CPU (same value and gradient, a tenth of the time)
        photometric = fused_photometric_loss if out.rgb.device.type == "cpu" else photometric_loss
        loss, _, _ = photometric(photo_behind_mask(out.rgb, img, valid), img, valid, cfg.lambda_ssim)
        if cfg.lambda_depth > 0 and len(uvz):
            loss = loss + cfg.lambda_depth * depth_loss(out.depth, out.alpha, uvz, cfg.depth_trim)
        if cfg.lambda_sky > 0:
            loss = loss + cfg.lambda_sky * sky_loss(out.alpha, sky)
        loss = loss + self._pose_prior(out.slices)
        if cfg.lambda_flat > 0:
            loss = loss + cfg.lambda_flat * flatness_loss(self.splat.background.log_scales)
        value = float(loss.detach())
        if math.isfinite(value):
            loss.backward()
            self._zero_grads_of_culled(out.slices)
            if m2d is not None and m2d.grad is not None:
                self._accumulate(out, m2d.grad[0], cam.width, cam.height)
            step_groups_with_grads(self.optimizer)
        else:
            log.warning("step %d: non-finite loss, skipped", self.step)
            self.optimizer.zero_grad(set_to_none=True)
        sets = self.strategy.step(self.step, named_sets(self.splat), self.optimizer, self.boxes)
        store_sets(self.splat, sets)
        self.step += 1
        return value, psnr(out.rgb, img, valid) if measure_psnr else math.nan

    def _zero_grads_of_culled(self, rendered: dict[str, slice]) -> None:
        """Zero gradients for the present objects the view culled, as when every present object was
        gathered whole: Adam's momentum keeps moving them between the views that see them (dense
        Adam, as 3DGS). Leaving them alone (sparse Adam) cost objects 0.1-0.5 dB at equal iterations."""
        for o in self.splat.objects:
            if o.track.key in rendered:
                for p in o.gaussians.tensors().values():
                    if p.grad is None:
                        p.grad = torch.zeros_like(p)

    def _accumulate(self, out, grad_px: torch.Tensor, width: int, height: int) -> None:
        """Hand one render's means2d gradients (pixel units, rasterized rows only) and visibility to
        densification, per Gaussian set, on the training device (a CPU-rendered meta is moved)."""
        index = out.index.to(self.device)
        grad_px = grad_px.to(self.device)
        visible = out.meta["radii"][0].gt(0).any(-1).to(self.device)
        for name, sl in out.slices.items():  # index is sorted and each set's rows are contiguous
            lo, hi = (int(x) for x in torch.searchsorted(index, torch.tensor([sl.start, sl.stop],
                                                                             device=index.device)))
            key = name if name == "background" else f"obj:{name}"
            self.strategy.accumulate(key, grad_px[lo:hi], visible[lo:hi], width, height,
                                     rows=index[lo:hi] - sl.start, n=sl.stop - sl.start)

    def validate(self, level: float | None = None) -> float | None:
        """Mean PSNR of the validation views at ``level`` x the training resolution (default: ``eval_level``,
        else the pyramid's last level; None: no views)."""
        if not self.val_data:
            return None
        if level is None:
            level = self.cfg.eval_level if self.cfg.eval_level is not None else self.cfg.pyramid[-1]
        vals = []
        with torch.no_grad():
            for d in self.val_data:
                cam, img, valid, _, _ = d.at(level)
                v = d.view
                out = self.splat.render(cam, v.city_T_cam, v.timestamp_ns, sh_degree=self._active_sh())
                vals.append(psnr(out.rgb, img, valid))
        return float(np.mean([v for v in vals if math.isfinite(v)] or [0.0]))

    def _check_plateau(self) -> None:
        """Measure validation PSNR when due and apply the patience rule."""
        cfg = self.cfg
        if self.cool is not None:
            if self.step >= self.cool[0] + self.cool[1]:
                self.validation.append([self.step, self.validate()])
                self.plateau = True
            return
        if not self.val_data or cfg.eval_every <= 0 or self.step % cfg.eval_every != 0:
            return
        v = self.validate()
        self.validation.append([self.step, v])
        if v > self.best_val + cfg.min_delta_db:  # (the best moves only on a real gain, as Keras does)
            self.best_val, self.bad_evals = v, 0
        elif pyramid_level(cfg, self.step) < cfg.pyramid[-1]:
            # Measured at the final resolution, the coarse stage gains slowly: no plateau until training
            # is at that resolution (a 15 s log's `default` run stopped 600 steps after its coarse stage).
            self.bad_evals = 0
        else:
            self.bad_evals += 1
        if cfg.patience > 0 and self.bad_evals >= cfg.patience and self.step >= cfg.min_iterations:
            if self.strategy.active(self.step):  # more Gaussians stopped helping: refine what there is
                self.strategy.stopped_at = self.step
                self.bad_evals = 0
            elif cfg.cooldown_frac > 0:
                self.cool = (self.step, max(cfg.cooldown_min, round(cfg.cooldown_frac * self.step)))
            else:
                self.plateau = True

    def run(self, *, progress: bool = True, checkpoint_dir: Path | None = None,
            stop_at: int | None = None) -> TrainReport:
        """Train to ``cfg.iterations``, or until validation PSNR stops improving (``patience``), or
        ``stop_at`` (as if killed there after a checkpoint). ``progress``: a bar on a terminal, else a
        log line every few seconds (:func:`nuav2.progress.progress_bar`), with the current PSNR, held-out
        PSNR and Gaussian count."""
        cfg = self.cfg
        end = cfg.iterations if stop_at is None else min(cfg.iterations, int(stop_at))
        torch.set_num_threads(cfg.threads)
        t0 = time.perf_counter()
        ema_psnr, reason = None, "iterations"
        bar = progress_bar(total=cfg.iterations, initial=self.step, desc=f"train {self.name}", unit="it",
                           disable=not progress, leave=False)
        try:
            while self.step < end and not self.plateau:
                shown = (self.step + 1) % 10 == 0 or self.step + 1 in (1, end)  # the steps the bar shows
                loss, p = self.train_step(measure_psnr=shown)
                self.losses.append(loss)
                if math.isfinite(p):  # (every 10th step: the average runs over about the last 30)
                    ema_psnr = p if ema_psnr is None else 0.7 * ema_psnr + 0.3 * p
                self._check_plateau()
                if shown:
                    status = {"psnr": f"{ema_psnr or 0.0:.2f}", "gaussians": self.splat.num_gaussians()}
                    if self.validation:
                        status["held-out psnr"] = f"{self.validation[-1][1]:.2f}"
                    bar.set_postfix(status, refresh=False)
                bar.update()
                every = cfg.checkpoint_every
                if checkpoint_dir is not None and every and self.step % every == 0:
                    self.save(Path(checkpoint_dir) / CHECKPOINT_FILE)
                if cfg.time_budget_s is not None and time.perf_counter() - t0 > cfg.time_budget_s:
                    reason = "time budget"
                    break
        finally:
            bar.close()
        if self.plateau:
            reason = "plateau"
        if checkpoint_dir is not None:
            self.save(Path(checkpoint_dir) / CHECKPOINT_FILE)
        for g in named_sets(self.splat).values():
            if not g.all_finite():
                raise FloatingPointError("training produced non-finite Gaussian parameters")
        return TrainReport(self.step, time.perf_counter() - t0, float(ema_psnr or 0.0),
                           self.splat.num_gaussians(), list(self.strategy.history), reason != "iterations",
                           list(self.losses), reason, self.strategy.stopped_at,
                           [list(x) for x in self.validation], self.cfg.iterations,
                           list(self.cool) if self.cool is not None else None)

    # ---- checkpoint / resume ----
    def state(self) -> dict:
        """Everything a resumed run needs, with every tensor on the CPU (device-independent file)."""
        return {"format": CHECKPOINT_FORMAT, "step": self.step, "scene": self.splat.state(),
                "optimizer": to_cpu(self.optimizer.state_dict()), "rng": self.rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(), "losses": list(self.losses),
                "densify_stats": {k: (v.grad.cpu(), v.count.cpu()) for k, v in self.strategy.stats.items()},
                "densify_history": list(self.strategy.history),
                "densify_stopped_at": self.strategy.stopped_at,
                "validation": [list(x) for x in self.validation], "best_val": self.best_val,
                "bad_evals": self.bad_evals, "plateau": self.plateau, "cooldown": self.cool}

    def save(self, path: Path) -> None:
        buf = io.BytesIO()
        torch.save(self.state(), buf)
        atomic_write_bytes(Path(path), buf.getvalue())

    def load(self, path: Path) -> None:
        """Continue from a checkpoint written by :meth:`save` for the same log and config, on this
        trainer's device whichever device wrote it (read with ``map_location``)."""
        from nuav2.splat.densify import _Stats

        path = Path(path)
        try:
            st = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as e:  # noqa: BLE001 - any unpickling failure means a bad file
            raise ValueError(f"{path}: not a readable training checkpoint ({type(e).__name__}: {e})") from e
        if not isinstance(st, dict) or st.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"{path}: not a nuav2 training checkpoint")
        splat = SplatScene.from_state(st["scene"], str(path)).to(self.device)
        if not np.allclose(splat.city_T_scene, self.splat.city_T_scene):
            raise ValueError(f"{path}: checkpoint belongs to another scene frame (another log?)")
        self.splat.background, self.splat.objects, self.splat.sky = splat.background, splat.objects, splat.sky
        self.optimizer = build_optimizer(self.splat, self.cfg, self.extent)
        self.optimizer.load_state_dict(st["optimizer"])
        self.rng.bit_generator.state = st["rng"]
        torch.set_rng_state(st["torch_rng"])
        self.step = int(st["step"])
        self.losses = list(st.get("losses", []))
        self.strategy.stats = {k: _Stats(g.to(self.device, copy=True), c.to(self.device, copy=True))
                               for k, (g, c) in st["densify_stats"].items()}
        self.strategy.history = list(st["densify_history"])
        self.strategy.stopped_at = st.get("densify_stopped_at")
        self.boxes = {f"obj:{o.track.key}": o.track.size_lwh for o in self.splat.objects}
        self.validation = [list(x) for x in st.get("validation", [])]
        self.best_val = float(st.get("best_val", -math.inf))
        self.bad_evals, self.plateau = int(st.get("bad_evals", 0)), bool(st.get("plateau", False))
        self.cool = tuple(st["cooldown"]) if st.get("cooldown") else None
