"""Top-level reconstruction API: ``reconstruct(scene, config) -> SplatScene`` and the writer's provider.

    from nuav2.recon import ReconConfig, reconstruct, render_provider
    splat = reconstruct(scene_log, ReconConfig.fast())
    source = render_provider(splat, min_confidence=0.5)   # a writer ImageSource for --mode render

Reconstruction = seed (LiDAR, ground, colours, sky; :mod:`nuav2.splat.init`) then optimise
(:mod:`nuav2.splat.train`). The returned scene carries its source cameras in ``info`` so the
quality gate can judge target renders without the log.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from nuav2.scene import SceneLog
from nuav2.splat.densify import DensifyConfig
from nuav2.splat.device import check_device_name, device_label, resolve_device
from nuav2.splat.init import InitConfig, SourceView, initial_scene, source_views
from nuav2.splat.quality import QualityConfig, SourceCoverage
from nuav2.splat.render_target import SplatImageSource, SplatRenderer
from nuav2.splat.scene_model import SplatScene
from nuav2.splat.train import CHECKPOINT_FILE, TrainConfig, Trainer, spread
from nuav2.threads import numba_threads

log = logging.getLogger(__name__)

# The presets' training cap on a long log: this many iterations per training image (TrainConfig.for_views).
# ``default`` trains towards the held-out plateau (4 per image: the patience rule, not the cap, ends a
# 15 s log); ``fast`` is time-boxed to what its old fixed 600 iterations cost on a 15 s log (1.4 per
# image: 1,470 steps, less CPU than before on four 15 s logs, +1.2 to +5.7 dB; docs/reconstruction.md,
# "`fast` within the old time per log"). Logs up to ~6 s keep the 600-step floor.
ITERATIONS_PER_VIEW = 4.0
FAST_ITERATIONS_PER_VIEW = 1.4
# ``default`` ends a plateau with a cool-down of a tenth of the steps run: positions to their final
# learning rate, every other rate to a tenth (15 s `easy` log: +0.34 dB, ground +0.74, for 11 % more
# CPU; docs/reconstruction.md, "A cool-down after the plateau"). ``fast`` is time-boxed instead.
DEFAULT_TRAIN = TrainConfig(iterations_per_view=ITERATIONS_PER_VIEW, cooldown_frac=0.1, cooldown_lr_end=0.1)


@dataclass(frozen=True)
class ReconConfig:
    """Everything that shapes a reconstruction.

    Training resolution: ``image_scale`` x the log's camera images when given, else scaled so the
    widest camera is ``train_width_px`` wide (256 px = the default synthetic log's own size,
    1/8 of a real AV2 ring camera), so one preset fits synthetic and real logs alike.

    ``device``: where training and rendering run (:mod:`nuav2.splat.device`): ``auto`` = CUDA with
    gsplat when both are usable, else the CPU kernels; ``cpu``; ``cuda`` (or ``cuda:N``), an error
    where CUDA or gsplat is missing. Seeding always runs on the CPU (numpy).
    """

    image_scale: float | None = None
    train_width_px: int = 256
    frame_stride: int = 1  # use every k-th image of each camera
    holdout_every: int = 0  # hold out every k-th image of each camera (0: none) for evaluation
    validation_every: int = 10  # early-stop images when nothing else is held out (see validation_views)
    channels: tuple[str, ...] | None = None  # source cameras (None: all ring cameras of the rig)
    sh_degree: int = 0
    seed: int = 0
    threads: int = 2  # torch's, the seeding's and the numba kernels' threads (same trained scene for any)
    device: str = "auto"
    init: InitConfig = field(default_factory=InitConfig)
    train: TrainConfig = field(default_factory=lambda: DEFAULT_TRAIN)
    quality: QualityConfig = field(default_factory=QualityConfig)

    def __post_init__(self) -> None:
        if self.image_scale is not None and not self.image_scale > 0:
            raise ValueError(f"ReconConfig.image_scale must be > 0, got {self.image_scale}")
        if self.train_width_px < 8:
            raise ValueError(f"ReconConfig.train_width_px must be >= 8, got {self.train_width_px}")
        if self.frame_stride < 1 or self.holdout_every < 0:
            raise ValueError("ReconConfig.frame_stride must be >= 1 and holdout_every >= 0")
        if not 0 <= self.sh_degree <= 3:
            raise ValueError(f"ReconConfig.sh_degree must be in 0..3, got {self.sh_degree}")
        check_device_name(self.device)
        # reconstruct() hands its own seed and threads to the trainer; a different value set on
        # ``train`` would be silently replaced, so it is refused here instead.
        for name in ("seed", "threads"):
            mine, theirs = getattr(self, name), getattr(self.train, name)
            if theirs not in (getattr(TrainConfig, name), mine):  # the class attribute is the field's default
                raise ValueError(f"ReconConfig.train.{name}={theirs} is not used (reconstruct() trains with "
                                 f"ReconConfig.{name}={mine}); set ReconConfig.{name} instead")

    @staticmethod
    def fast() -> ReconConfig:
        """CI-sized demo, time-boxed: ~40 s on 2 cores for the default synthetic log (2 s, 1/8-res
        cameras); 600 iterations, or 1.4 per training image on a longer log (1,470 on a 15 s log: the
        time 600 iterations took there before the cap followed the log) unless the held-out images
        stop improving first."""
        return ReconConfig(
            frame_stride=2, sh_degree=0,
            init=InitConfig(max_background=60_000, ground_spacing_m=0.3, ground_radius_m=25.0),
            train=TrainConfig(iterations=600, iterations_per_view=FAST_ITERATIONS_PER_VIEW,
                              pyramid=(0.5, 1.0), pyramid_until=(0.3,),
                              densify=DensifyConfig(start=100, every=100, stop=500, budget=90_000,
                                                    reset_every=0)))

    @staticmethod
    def default() -> ReconConfig:
        """The benchmark's 'default' budget (= ``ReconConfig()``): 2000 iterations (4 per training image on a
        longer log; the patience rule stops earlier, then a cool-down), <= 100k Gaussians, ~3 min on 2
        cores for the default synthetic log. More Gaussians fit the source views better but not the target rig
        (see docs/reconstruction.md)."""
        return ReconConfig()

    def scale_for(self, scene: SceneLog) -> float:
        """Training-image scale for ``scene``'s cameras."""
        if self.image_scale is not None:
            return float(self.image_scale)
        widest = max((c.width for c in scene.rig.cameras), default=self.train_width_px)
        return min(1.0, self.train_width_px / widest)

    @staticmethod
    def preset(name: str) -> ReconConfig:
        """``fast`` or ``default`` (the convert pipeline's ``--recon`` presets)."""
        presets = {"fast": ReconConfig.fast, "default": ReconConfig.default}
        if name not in presets:
            raise ValueError(f"unknown reconstruction preset {name!r}; known: {sorted(presets)}")
        return presets[name]()

    def with_iterations(self, n: int) -> ReconConfig:
        """This config with a fixed cap of ``n`` iterations, whatever the log's length."""
        return replace(self, train=replace(self.train, iterations=int(n), iterations_per_view=0.0))

    def to_dict(self) -> dict:
        return asdict(self)


def default_channels(scene: SceneLog) -> list[str] | None:
    """The source cameras to train on: AV2's seven ring cameras when present (the stereo pair
    adds little viewpoint), else every camera of the rig (None)."""
    ring = [c.channel for c in scene.rig.cameras if c.channel.startswith("ring_")]
    return ring or None


def split_views(views: list[SourceView], every: int, *, keep_every: bool = False
                ) -> tuple[list[SourceView], list[SourceView]]:
    """Split each camera's images (in time order) by position: every ``every``-th image goes to the second
    list (held out; 0: none), the rest to the first; with ``keep_every`` the other way round (a frame
    stride: every ``every``-th image is kept, the rest go to the second list)."""
    if every <= 0:
        return views, []
    first, second = [], []
    per_channel: dict[str, int] = {}
    for v in views:
        k = per_channel.get(v.channel, 0)
        per_channel[v.channel] = k + 1
        if keep_every:
            (first if k % every == 0 else second).append(v)
        else:
            (second if k % every == every // 2 else first).append(v)
    return first, second


def reconstruct(scene: SceneLog, config: ReconConfig | None = None, *, progress: bool = True,
                checkpoint_dir: str | Path | None = None, resume: bool = False) -> SplatScene:
    """Reconstruct ``scene`` as Gaussians (background + moving objects + sky), deterministic by seed.

    With ``checkpoint_dir`` the trainer saves there (every ``train.checkpoint_every`` steps and
    at the end); ``resume`` continues from the checkpoint found there, whichever device wrote it.
    The scene comes back on ``config.device`` (``splat.info["device"]`` names it). numba's kernels run on
    ``config.threads`` threads (numba's default is every core); the result does not depend on it
    (``nuav2.splat._functions.BACKWARD_GROUPS``).
    """
    cfg = config or ReconConfig()
    with numba_threads(cfg.threads):
        return _reconstruct(scene, cfg, progress, checkpoint_dir, resume)


def _reconstruct(scene: SceneLog, cfg: ReconConfig, progress: bool, checkpoint_dir: str | Path | None,
                 resume: bool) -> SplatScene:
    device = resolve_device(cfg.device)  # before any work: an unusable device is one error up front
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    t0 = time.perf_counter()
    channels = list(cfg.channels) if cfg.channels else default_channels(scene)
    views = source_views(scene, cfg.scale_for(scene), channels=channels)
    if not views:
        raise ValueError(f"log {scene.log_id}: no camera images to reconstruct from")
    used, skipped = split_views(views, cfg.frame_stride, keep_every=True)
    train_views, held = split_views(used, cfg.holdout_every)
    validation = validation_views(train_views, held, skipped, cfg)
    if validation and not (held or skipped):  # carved out of the training images
        keep = {id(v) for v in validation}
        train_views = [v for v in train_views if id(v) not in keep]
    others = list({id(v): v for v in [*held, *validation]}.values())
    init = initial_scene(scene, train_views, cfg.init, sh_degree=cfg.sh_degree, seed=cfg.seed,
                         progress=progress, other_views=others, threads=cfg.threads)
    t_init = time.perf_counter() - t0
    train_cfg = replace(cfg.train, seed=cfg.seed, threads=cfg.threads).for_views(len(train_views))
    if init.budget is not None:  # the Gaussian budget follows the scene (nuav2.splat.budget)
        train_cfg = replace(train_cfg, densify=replace(train_cfg.densify, budget=init.budget))
    trainer = Trainer(init.scene.to(device), scene, train_views, init.sky_masks, train_cfg,
                      validation=validation)
    ckpt = Path(checkpoint_dir) if checkpoint_dir is not None else None
    if ckpt is not None:
        ckpt.mkdir(parents=True, exist_ok=True)
        if resume and (ckpt / CHECKPOINT_FILE).is_file():
            trainer.load(ckpt / CHECKPOINT_FILE)
            log.info("resumed %s at step %d", scene.log_id, trainer.step)
    report = trainer.run(progress=progress, checkpoint_dir=ckpt)
    splat = trainer.splat
    for o in splat.objects:  # refined box poses become the track's poses
        o.track.bake_deltas()
    splat.info.update({
        "log_id": scene.log_id, "source": scene.source, "init_stats": init.stats, "init_seconds": t_init,
        "train": {k: v for k, v in report.to_dict().items() if k != "losses"},
        "source_views": [view_record(v) for v in train_views],
        "heldout_views": [view_record(v) for v in held],
        "validation_views": [view_record(v) for v in validation],
        "exposure": init.exposure.to_dict() if init.exposure is not None else None,
        "config": cfg.to_dict(), "device": device_label(device),
    })
    return splat


def validation_views(train: list[SourceView], held: list[SourceView], skipped: list[SourceView],
                     cfg: ReconConfig) -> list[SourceView]:
    """Images the early-stop rule measures, never trained on: the frames ``frame_stride`` skips when there are
    any (so reported held-out images stay independent of the stop), else the held-out images, else every
    ``validation_every``-th training image; spread over the log, at most ``train.eval_views``."""
    if cfg.train.eval_every <= 0 or cfg.train.eval_views <= 0:
        return []
    pool = skipped or held or (split_views(train, cfg.validation_every)[1] if cfg.validation_every else [])
    return spread(pool, cfg.train.eval_views)


def view_record(v: SourceView) -> dict:
    """A source camera image as plain data (enough to rebuild its pose and intrinsics)."""
    return {"index": int(v.index), "channel": v.channel, "timestamp_ns": int(v.timestamp_ns),
            "path": str(v.path), "width": v.cam.width, "height": v.cam.height, "K": v.cam.K.tolist(),
            "city_T_cam": np.asarray(v.city_T_cam).tolist()}


def views_from_records(records: list[dict]) -> list[SourceView]:
    """Inverse of :func:`view_record` (no ego mask: coverage only needs poses and intrinsics)."""
    from nuav2.rig import CameraSpec

    out = []
    for i, r in enumerate(records):
        K = np.asarray(r["K"], np.float64)
        cam = CameraSpec(r["channel"], int(r["width"]), int(r["height"]), K, np.eye(4))
        out.append(SourceView(int(r.get("index", i)), r["channel"], int(r["timestamp_ns"]), Path(r["path"]),
                              cam, np.asarray(r["city_T_cam"], np.float64),
                              np.ones((cam.height, cam.width), bool)))
    return out


def coverage_for(splat: SplatScene, config: QualityConfig | None = None, *, with_depth: bool = True,
                 progress: bool = False) -> SourceCoverage:
    """The quality gate's model of what the source cameras saw (from ``splat.info``)."""
    records = splat.info.get("source_views")
    if not records:
        raise ValueError("this reconstruction records no source views; cannot judge coverage")
    return SourceCoverage.from_views(splat, views_from_records(records), config or QualityConfig(),
                                     with_depth=with_depth, progress=progress)


def render_provider(splat: SplatScene, *, min_confidence: float = 0.0, quality: bool = True,
                    quality_config: QualityConfig | None = None, at_sweeps: bool = False,
                    progress: bool = False) -> SplatImageSource:
    """A writer ``ImageSource`` (render mode) over ``splat``; its ``renderer`` is the plain RenderFn
    and keeps per-image quality records (``renderer.records``)."""
    if not 0.0 <= min_confidence <= 1.0:  # NaN fails too: it would drop nothing
        raise ValueError(f"min_confidence must be in [0, 1], got {min_confidence}")
    if min_confidence > 0 and not quality:
        raise ValueError("min_confidence needs the quality gate (quality=True)")
    qcfg = quality_config or QualityConfig()
    coverage = coverage_for(splat, qcfg, progress=progress) if quality else None
    return SplatImageSource(SplatRenderer(splat, coverage, qcfg), min_confidence=min_confidence,
                            at_sweeps=at_sweeps)


def render_image_source(scene: SceneLog, out_rig=None, *, preset: str = "default",
                        config: ReconConfig | None = None, min_confidence: float = 0.0,
                        quality: bool = True, progress: bool = False,
                        checkpoint_dir: str | Path | None = None, device: str | None = None
                        ) -> SplatImageSource:
    """Render mode's writer ``ImageSource`` for one log: reconstruct it (``config`` or ``preset``),
    then render each output camera at each sample, both on ``device`` (None: the config's). ``out_rig``
    is accepted for symmetry with the warp source; the writer passes the output rig to ``shots``/``store``
    itself."""
    cfg = config or ReconConfig.preset(preset)
    if device is not None:
        cfg = replace(cfg, device=device)
    splat = reconstruct(scene, cfg, progress=progress, checkpoint_dir=checkpoint_dir,
                        resume=checkpoint_dir is not None)
    return render_provider(splat, min_confidence=min_confidence, quality=quality, progress=progress)
