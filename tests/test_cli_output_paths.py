"""Paths on the command line are checked before any work: an empty one (an unset shell variable; ``Path("")``
is the current folder), a benchmark output under a file (it only failed at the end, after all the work),
a split folder given to ``inspect`` for a log, and a synthetic log too long for the road generator."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_convert_input_checks import refused as one_line
from test_convert_input_checks import run


@pytest.mark.parametrize("argv", [("devkit-hook", "status", "--site-dir", ""), ("demo", "--out", ""),
                                  ("synth", ""), ("validate", ""), ("inspect", "")])
def test_an_empty_path_is_refused(argv, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    one_line(*run(*argv), "empty path")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind, flag", [("ablation", "--out"), ("ablation", "--markdown"),
                                        ("exposure", "--out"), ("modes", "--markdown"), ("recon", "--out"),
                                        ("recon", "--plot")])
def test_a_benchmark_output_under_a_file_is_refused_before_the_work(kind, flag, tmp_path: Path):
    afile = tmp_path / "afile"
    afile.write_text("")
    one_line(*run("bench", kind, flag, afile / "x"), flag, f"{afile} is not a folder")


def test_inspect_on_a_split_folder_names_its_logs(tmp_path: Path):
    for name in ("log-a", "log-b"):
        (tmp_path / "train" / name).mkdir(parents=True)
        (tmp_path / "train" / name / "city_SE3_egovehicle.feather").write_bytes(b"")
    one_line(*run("inspect", tmp_path / "train"), "not an AV2 log folder", "log-a, log-b", "give one of them")


def test_synthetic_seconds_past_an_hour_are_refused(tmp_path: Path):
    one_line(*run("synth", tmp_path / "s", "--seconds", "1e9"), "--seconds", "<= 3600")
    one_line(*run("demo", "--out", tmp_path / "d", "--seconds", "1e9"), "--seconds", "<= 3600")
    assert list(tmp_path.iterdir()) == []
