"""Bad input to ``synth``, ``demo`` and the ``bench`` commands is one line naming the flag, exit 2, before
any work: flag values are refused while parsing (argparse types mirroring the library's checks), list
flags and the target rig before anything is synthesised; and a ``demo`` rerun into the same --out with
other options replaces its previous log and database instead of failing or merging them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from nuav2.bench.cli_args import (
    lidar_azimuth_steps,
    parse_floats,
    parse_ints,
    synth_image_scale,
    synth_seconds,
)
from nuav2.cli import UsageError, build_parser, main
from nuav2.cli_types import positive_int
from nuav2.synth import SynthConfig


def _refused_while_parsing(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``nuav2 argv``, expect argparse's exit 2, and return its one-line message."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def _refused_before_work(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``nuav2 argv``, expect the command's own exit 2, and return its one-line message."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def _accepts(parse, text: str) -> bool:
    try:
        parse(text)
    except argparse.ArgumentTypeError:
        return False
    return True


def _synth_accepts(**fields) -> bool:
    try:
        SynthConfig(**fields)
    except ValueError:
        return False
    return True


# 1. --seconds / --scale / --lidar-azimuth-steps name the flag, not SynthConfig's field.

@pytest.mark.parametrize("flag, value", [
    ("--scale", "0"), ("--scale", "inf"), ("--scale", "1e9"), ("--seconds", "0"), ("--seconds", "0.05"),
    ("--seconds", "nan"), ("--lidar-azimuth-steps", "7"), ("--seed", "-1"),
])
def test_synth_refuses_bad_values_naming_the_flag(tmp_path, capsys, flag, value):
    out = tmp_path / "o"
    err = _refused_while_parsing(["synth", str(out), flag, value], capsys)
    assert err.startswith(f"nuav2 synth: argument {flag}: ") and "SynthConfig" not in err
    assert not out.exists()


@pytest.mark.parametrize("argv, flag", [
    (["demo", "--seconds", "0"], "--seconds"),
    (["bench", "convert", "--seconds", "-1"], "--seconds"),
    (["bench", "convert", "--image-scale", "0"], "--image-scale"),
    (["bench", "scale", "--seconds", "0.05"], "--seconds"),
    (["bench", "scale", "--image-scale", "inf"], "--image-scale"),
    (["bench", "loader", "--synthetic-seconds", "0"], "--synthetic-seconds"),
    (["bench", "loader", "--synthetic-image-scale", "nan"], "--synthetic-image-scale"),
    (["bench", "exposure", "--seconds", "0"], "--seconds"),
    (["bench", "ablation", "--seconds", "0.01"], "--seconds"),
    (["bench", "ablation", "--image-scale", "-1"], "--image-scale"),
    (["bench", "modes", "--image-scale", "0"], "--image-scale"),
])
def test_synthetic_log_flags_of_demo_and_bench_name_the_flag(capsys, argv, flag):
    err = _refused_while_parsing(argv, capsys)
    assert f"argument {flag}: " in err and "SynthConfig" not in err


@pytest.mark.parametrize("seconds", ["0.04", "0.05", "0.0501", "0.1", "2"])
def test_seconds_bound_is_synthconfigs(seconds):
    assert _accepts(synth_seconds, seconds) == _synth_accepts(seconds=float(seconds))


@pytest.mark.parametrize("scale", ["-0.1", "0", "1e-3", "1", "8", "8.01", "1e9"])
def test_image_scale_bound_is_synthconfigs(scale):
    assert _accepts(synth_image_scale, scale) == _synth_accepts(image_scale=float(scale))


@pytest.mark.parametrize("steps", ["7", "8", "512"])
def test_lidar_steps_bound_is_synthconfigs(steps):
    assert _accepts(lidar_azimuth_steps, steps) == _synth_accepts(lidar_azimuth_steps=int(steps))


# 2. bench eval --seed and bench transfer's training flags are refused while parsing.

def test_bench_eval_seed_names_the_flag(capsys):
    err = _refused_while_parsing(["bench", "eval", "--seed", "-1", "--samples", "3"], capsys)
    assert err.startswith("nuav2 bench eval: argument --seed: must be >= 0")


@pytest.mark.parametrize("flag, value", [
    ("--steps", "-1"), ("--steps", "0"), ("--finetune-steps", "0"), ("--train-worlds", "0"),
    ("--test-worlds", "-2"), ("--workers", "0"), ("--seeds", "-1"), ("--recon-preset", "huge"),
])
def test_bench_transfer_refuses_before_building_worlds(tmp_path, capsys, flag, value):
    out = tmp_path / "transfer"
    err = _refused_while_parsing(["bench", "transfer", "--smoke", "--out", str(out), flag, value], capsys)
    assert err.startswith(f"nuav2 bench transfer: argument {flag}: ")
    assert not out.exists()


# 3. Nonsense that was accepted (or refused late, or without the prefix) is refused while parsing.

@pytest.mark.parametrize("argv, flag", [
    (["bench", "eval", "--samples", "-5"], "--samples"),
    (["bench", "convert", "--repeats", "0"], "--repeats"),
    (["bench", "convert", "--repeats", "-1"], "--repeats"),
    (["bench", "convert", "--keyframe-hz", "0"], "--keyframe-hz"),
    (["bench", "scale", "--logs", "0"], "--logs"),
    (["bench", "scale", "--repeats", "0"], "--repeats"),
    (["bench", "scale", "--scale", "0"], "--scale"),
    (["bench", "modes", "--frame-step", "0"], "--frame-step"),
    (["bench", "modes", "--scale", "-0.5"], "--scale"),
    (["bench", "recon", "--holdout-every", "0"], "--holdout-every"),
    (["bench", "recon", "--holdout-every", "1"], "--holdout-every"),  # would hold out every image
    (["bench", "recon", "--times", "0"], "--times"),
    (["bench", "loader", "--samples", "0"], "--samples"),
    (["bench", "loader", "--image-scale", "0"], "--image-scale"),
    (["bench", "raster", "--counts", "-1"], "--counts"),
    (["bench", "raster", "--sizes", "64x40", "--counts", "0"], "--counts"),
    (["bench", "raster", "--repeats", "0"], "--repeats"),
    (["bench", "raster", "--gsplat-max-contributions", "-1"], "--gsplat-max-contributions"),
    (["bench", "exposure", "--sample", "0"], "--sample"),
    (["bench", "exposure", "--seed", "-1"], "--seed"),
    (["bench", "ablation", "--scale", "0"], "--scale"),
    (["bench", "ablation", "--speed-seconds", "0.01"], "--speed-seconds"),
    (["bench", "ablation", "--speed-seconds", "-1"], "--speed-seconds"),
])
def test_bench_numeric_flags_have_bounds(capsys, argv, flag):
    err = _refused_while_parsing(argv, capsys)
    assert err.startswith(f"nuav2 {argv[0]} {argv[1]}: argument {flag}: ")


def test_raster_sizes_without_counts_is_a_usage_error(capsys):
    err = _refused_before_work(["bench", "raster", "--counts", "5"], capsys)
    assert err == "nuav2 bench: --sizes and --counts go together: give both or neither"


@pytest.mark.parametrize("argv, expected", [
    (["bench", "modes", "--seconds", "2,0.04", "--quiet"], "--seconds: expected comma-separated numbers"),
    (["bench", "modes", "--seconds", "2,inf", "--quiet"], "must be a finite number"),
    (["bench", "modes", "--seeds", "0,-1", "--quiet"], "--seeds: expected comma-separated integers"),
    (["bench", "recon", "--seeds", "-3"], "--seeds: expected comma-separated integers"),
    (["bench", "ablation", "--seeds", "1,x"], "'x' is not an integer"),
    (["bench", "modes", "--rig", "nope", "--quiet"], "--rig: unknown rig 'nope'"),
    (["bench", "ablation", "--rig", "nope"], "--rig: unknown rig 'nope'"),
])
def test_bench_list_flags_and_rig_are_refused_before_any_work(capsys, argv, expected):
    err = _refused_before_work(argv, capsys)
    assert err.startswith("nuav2 bench: ") and expected in err


def test_parse_lists_check_every_entry():
    assert parse_floats("2, 15", "--seconds") == (2.0, 15.0)
    assert parse_ints("0,1,2", "--seeds") == (0, 1, 2)
    for text in ("", "1,-1", "1,0", "nan", "1,inf"):
        with pytest.raises(UsageError, match="^--seconds: "):
            parse_floats(text, "--seconds")
    with pytest.raises(UsageError, match="^--seeds: .*must be >= 0"):
        parse_ints("1,-1", "--seeds")
    with pytest.raises(UsageError, match="^--counts: .*must be >= 1"):
        parse_ints("0", "--counts", positive_int)


@pytest.mark.parametrize("argv", [
    ["synth", "o"], ["demo"], ["bench", "ablation"], ["bench", "convert"], ["bench", "eval"],
    ["bench", "exposure"], ["bench", "loader"], ["bench", "modes"], ["bench", "raster"], ["bench", "recon"],
    ["bench", "scale"], ["bench", "transfer", "--out", "o"],
])
def test_defaults_pass_the_new_bounds(argv):
    args = build_parser().parse_args(argv)
    assert callable(args.func)
    if argv[0] == "bench" and argv[1] in ("modes", "recon", "ablation"):
        assert parse_ints(args.seeds, "--seeds")


# 4. demo: the target rig, scale and reconstruction preset are checked before anything is written.

def test_demo_bad_rig_leaves_nothing_behind(tmp_path, capsys):
    out = tmp_path / "odemo"
    err = _refused_before_work(["demo", "--out", str(out), "--rig", "nope", "--mode", "warp",
                                "--seconds", "0.3", "--scale", "0.1", "--no-progress"], capsys)
    assert err.startswith("nuav2 demo: --rig: unknown rig 'nope'")
    assert not out.exists()


@pytest.mark.parametrize("flag, value, modes", [("--rig", "nope", "warp and render"),
                                                ("--rig", "nuscenes", "warp and render"),
                                                ("--scale", "0.1", "warp and render"),
                                                ("--recon-preset", "default", "render")])
def test_demo_flags_native_mode_does_not_use_are_refused(tmp_path, capsys, flag, value, modes):
    """Found by review: demo --mode native --rig truck5 ran, and recorded "rig": null."""
    out = tmp_path / "odemo"
    err = _refused_before_work(["demo", "--out", str(out), flag, value, "--mode", "native",
                                "--seconds", "0.3", "--no-progress"], capsys)
    assert err == f"nuav2 demo: {flag} applies to --mode {modes} only, not --mode native" and not out.exists()


@pytest.mark.parametrize("flag, value", [("--scale", "inf"), ("--scale", "0"), ("--recon-preset", "nope"),
                                         ("--seed", "-1")])
def test_demo_bad_flag_is_refused_while_parsing(tmp_path, capsys, flag, value):
    out = tmp_path / "odemo"
    err = _refused_while_parsing(["demo", "--out", str(out), flag, value], capsys)
    assert err.startswith(f"nuav2 demo: argument {flag}: ")
    assert not out.exists()


# 5. demo reruns into the same --out with other options just work.

def _demo(out: Path, *options: str) -> dict:
    argv = ["demo", "--out", str(out), "--mode", "warp", "--no-progress", *options]
    assert main(argv) == 0
    return json.loads((out / "demo_summary.json").read_text())["presets"]["easy"]


def test_demo_rerun_with_other_options_replaces_its_log_and_database(tmp_path, capsys):
    out = tmp_path / "odemo"
    first = _demo(out, "--scale", "0.1", "--seconds", "0.3")
    assert first["samples"] == 3
    longer = _demo(out, "--scale", "0.1", "--seconds", "0.5")  # another log: the first one is replaced
    assert longer["samples"] == 5 and longer["converted_logs"] == 1
    assert [p.name for p in (out / "easy" / "av2" / "train").iterdir()] == [Path(longer["log_dir"]).name]
    finer = _demo(out, "--scale", "0.12", "--seconds", "0.5")  # same log, other conversion options
    assert finer["samples"] == 5 and finer["converted_logs"] == 1
    again = _demo(out, "--scale", "0.12", "--seconds", "0.5")  # same options: the converted log is reused
    assert again["samples"] == 5 and again["reused_logs"] == 1
    assert again["quality"]["psnr_db"] == finer["quality"]["psnr_db"]
    capsys.readouterr()
