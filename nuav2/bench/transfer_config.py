"""What ``nuav2 bench transfer`` builds and trains: worlds, conversions, runs (three sizes).

- ``full``: the benchmark (2 h 04 min on 2 cores, measured in docs/transfer.md): 24 training worlds
  and 6 test worlds of 1 s (10 keyframes each), four training sets, two training seeds, 1200-step
  runs, fine-tuning on 5 / 10 / 25 % of the oracle training set (1, 2 and 6 of its 24 scenes)
  from scratch and from the nuAV2 model, 400 steps each.
- ``quick``: the same pipeline smaller (under 30 min): 6 + 2 worlds, 160-step runs (50 for Table 2).
- ``smoke``: plumbing only (CI): 1 + 1 tiny worlds, no render mode, a few steps.

Training runs go two at a time in worker processes with one torch thread each (two runs keep
both cores busy, one 2-thread run about 1.1), conversions two logs at a time.

Train and test worlds never share a seed, and they lie in different cities (the test worlds are
a held-out city, as in Lilja et al.'s far-extrapolation folds), so no test keyframe is near a
training one; the splitter's leakage report checks it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from nuav2.mapping.config import MapModelConfig

SIZES = ("smoke", "quick", "full")
TABLE1_SETS = ("native", "warp", "render", "truth")  # training sets = conversion modes of the train worlds
SET_LABELS = {
    "native": "AV2 (native rig)",
    "warp": "nuAV2 (warp)",
    "render": "nuAV2 (render)",
    "truth": "oracle (target-rig truth)",
}
PAPER_TABLE1 = {  # MapGS Table 1, direct generalisation to nuScenes val (camera, 4 epochs) and the oracle
    "native": {"divider": 1.3, "ped_crossing": 0.4, "boundary": 1.0, "centerline": 2.1, "mAP": 1.2},
    "render": {"divider": 3.1, "ped_crossing": 3.2, "boundary": 6.4, "centerline": 12.4, "mAP": 6.3},
    "truth": {"divider": 16.5, "ped_crossing": 12.7, "boundary": 30.6, "centerline": 26.5, "mAP": 21.6},
}
PAPER_RATIOS = {"nuav2_over_av2": 4.25, "nuav2_over_oracle": 0.29}
PAPER_TABLE2 = {  # MapGS Table 2: nuScenes fraction -> (scratch, nuAV2-pretrained) mAP
    0.05: (14.6, 20.1),
    0.10: (17.3, 21.1),
    0.25: (20.4, 23.0),
    1.0: (21.6, 24.7),
}


@dataclass(frozen=True)
class TransferConfig:
    size: str = "full"
    preset: str = "medium"  # synthetic realism preset (nuav2.synth.PRESETS); "easy" = the original world
    train_worlds: int = 24
    test_worlds: int = 6
    seconds: float = 1.0  # log length: 10 keyframes at 10 Hz (more, shorter worlds: docs/transfer.md)
    synth_image_scale: float = 0.125  # AV2 cameras at 1/8 (256 x 194)
    train_seed0: int = 1000
    test_seed0: int = 9000
    train_city: str = "PIT"
    test_city: str = "WDC"
    layouts: tuple[str, ...] | None = None  # None: every layout the synthetic world has
    target_rig: str = "nuscenes"
    target_scale: float = 0.125  # nuScenes cameras at 1/8 (200 x 112)
    recon_preset: str = "fast"
    sets: tuple[str, ...] = TABLE1_SETS
    pretrain_set: str = "render"  # nuAV2: what Table 2 pre-trains on
    seeds: tuple[int, ...] = (0, 1)
    steps: int = 1200
    eval_points: int = 4  # learning-curve evaluations per run (the last one at the final step)
    fractions: tuple[float, ...] = (0.05, 0.10, 0.25)
    subset_seed: int = 0  # which scenes form each fraction (nested subsets, one draw for all runs)
    finetune_steps: int = 400
    batch_size: int = 2
    lr: float = 2e-3
    threads: int = 1  # torch threads per training run
    workers: int = 2  # training runs at once (worker processes; 1: in the main process)
    rotations_deg: tuple[float, ...] = (-20.0, -10.0, 10.0, 20.0)  # BEV rotation augmentation angles
    version: str = "v1.0-nuav2"
    model: MapModelConfig = field(default_factory=MapModelConfig)

    def __post_init__(self) -> None:
        from nuav2.synth import PRESETS

        if self.preset not in PRESETS:
            raise ValueError(f"--preset {self.preset!r}: must be one of {PRESETS}")
        if self.size not in SIZES:
            raise ValueError(f"size must be one of {SIZES}, got {self.size!r}")
        unknown = [s for s in self.sets if s not in TABLE1_SETS]
        if unknown or "truth" not in self.sets:
            raise ValueError(
                f"sets must be among {TABLE1_SETS} and include 'truth' (the oracle and the "
                f"test set), got {self.sets}"
            )
        if self.fractions and self.pretrain_set not in self.sets:
            raise ValueError(f"pretrain_set {self.pretrain_set!r} is not among the sets {self.sets}")
        if self.train_worlds < 1 or self.test_worlds < 1 or not self.seeds:
            raise ValueError("need at least one train world, one test world and one seed")
        if self.train_city == self.test_city:
            raise ValueError(
                "train and test worlds must lie in different cities (geo-disjoint by construction)"
            )
        if self.workers < 1 or self.threads < 1:
            raise ValueError(f"workers and threads must be >= 1, got {self.workers}, {self.threads}")
        if any(not 0 < f <= 1 for f in self.fractions):
            raise ValueError(f"fractions must be in (0, 1], got {self.fractions}")

    @staticmethod
    def for_size(size: str, **overrides) -> TransferConfig:
        if size == "full":
            base = TransferConfig()
        elif size == "quick":
            base = TransferConfig(
                size="quick",
                train_worlds=6,
                test_worlds=2,
                steps=160,
                eval_points=2,
                finetune_steps=50,
                fractions=(0.25, 0.5),
            )
        elif size == "smoke":
            base = TransferConfig(
                size="smoke",
                train_worlds=1,
                test_worlds=1,
                seconds=0.3,
                sets=("native", "warp", "truth"),
                pretrain_set="warp",
                seeds=(0,),
                steps=3,
                eval_points=1,
                fractions=(1.0,),
                finetune_steps=2,
                batch_size=1,
            )
        else:
            raise ValueError(f"size must be one of {SIZES}, got {size!r}")
        return replace(base, **overrides)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def eval_every(self) -> int:
        return max(1, self.steps // max(1, self.eval_points))
