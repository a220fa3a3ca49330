"""A synthetic log converted in truth mode by the real CLI (shared by the mapping and transfer tests)."""

from __future__ import annotations

from pathlib import Path

from nuav2.cli import main
from nuav2.synth import SynthConfig, generate_log


def synthetic_truth_db(root: Path, seed: int, seconds: float, scale: float) -> tuple[Path, Path]:
    """(log dir, dataroot): one synthetic log and ``nuav2 convert av2 ... --mode truth --rig nuscenes``."""
    log_dir = generate_log(root / "src", seed=seed, config=SynthConfig(seconds=seconds))
    out = root / "db"
    argv = ["convert", "av2", str(log_dir.parent), str(out), "--mode", "truth", "--rig", "nuscenes",
            "--scale", str(scale), "--no-progress"]
    assert main(argv) == 0
    return log_dir, out
