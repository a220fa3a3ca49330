"""The docs/ablation scripts behind figures in docs/: they must still import and parse their flags
after a refactor, and the long-log reconstruction script must pass its flags to the configuration it
runs (its JSON line reports them) and score a real reconstruction."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ABLATION_DIR = Path(__file__).resolve().parents[1] / "docs" / "ablation"
SCRIPTS = sorted(ABLATION_DIR.glob("*.py"))

pytest_plugins = ["test_writer_support", "e2e_support"]  # tiny_synth_log: the CI-sized synthetic log


def test_the_ablation_folder_has_scripts() -> None:
    assert len(SCRIPTS) >= 10, f"docs/ablation lost its scripts: {SCRIPTS}"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_ablation_script_imports_and_prints_its_help(script: Path, monkeypatch, capsys) -> None:
    spec = importlib.util.spec_from_file_location(f"ablation_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # top-level imports only: every script guards its main
    monkeypatch.setattr(sys, "argv", [str(script), "--help"])
    with pytest.raises(SystemExit) as stop:
        module.main()
    assert stop.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_recon_long_log_applies_its_flags_and_scores_the_reconstruction(tiny_synth_log: Path) -> None:
    cmd = [sys.executable, str(ABLATION_DIR / "recon_long_log.py"), str(tiny_synth_log), "--times", "1",
           "--scale", "0.0625", "--iterations-per-view", "2", "--patience", "0", "--lambda-flat", "0",
           "--structure-merge-levels", "0", "--cooldown-frac", "0.1", "--cooldown-lr-end", "1.0",
           "--cooldown-frozen-positions"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    row = json.loads(done.stdout.strip().splitlines()[-1])
    assert row["log"] == tiny_synth_log.name and row["device"] == "cpu"
    assert (row["patience"], row["lambda_flat"], row["structure_merge_levels"]) == (0, 0.0, 0)
    assert (row["iterations_per_view"], row["cooldown_frac"], row["cooldown_lr_end"]) == (2.0, 0.1, 1.0)
    assert row["cooldown_positions"] is False
    assert row["stop_reason"] == "iterations" and row["steps"] >= row["iterations_cap"] > 0
    assert row["gaussians"] > 1000 and row["source_decodes"] > 0
    for key in ("psnr_db", "psnr_ground_db", "last_heldout_psnr_db"):
        assert math.isfinite(row[key]) and row[key] > 15.0, (key, row[key])
