"""Shared by the executor tests (no tests here): three small synthetic logs, their `--workers 1` tables."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from nuav2.cli import main
from nuav2.synth import SynthConfig, generate_log

VERSION = "v1.0-nuav2"
SEEDS = (1, 2, 3)
TINY = SynthConfig(seconds=0.5, n_parked=2, n_moving=1, n_pedestrians=0)


def tables(out: Path) -> dict[str, bytes]:
    """Every file of the merged table folder, by name (the bytes a byte-identity test compares)."""
    return {p.name: p.read_bytes() for p in sorted((out / VERSION).iterdir())}


def convert(src: Path, out: Path, *extra: str) -> int:
    return main(["convert", "av2", str(src), str(out), "--no-progress", *extra])


def corrupt_copy(src: Path, dst: Path, bad_log: str) -> Path:
    """``src`` copied to ``dst``, one LiDAR sweep of ``bad_log`` replaced by garbage; returns that sweep."""
    shutil.copytree(src, dst)
    sweep = sorted((dst / bad_log / "sensors" / "lidar").iterdir())[0]
    sweep.write_bytes(b"this is not a feather file")
    return sweep


@pytest.fixture(scope="session")
def synth_split(tmp_path_factory) -> Path:
    """A split folder with three 0.5 s synthetic logs."""
    root = tmp_path_factory.mktemp("executor_logs")
    for seed in SEEDS:
        generate_log(root / "av2", seed=seed, config=TINY)
    return root / "av2" / "train"


@pytest.fixture(scope="session")
def reference_out(synth_split: Path, tmp_path_factory) -> Path:
    """The dataroot of the plain ``--workers 1`` conversion of the three logs."""
    out = tmp_path_factory.mktemp("executor_reference") / "out"
    assert convert(synth_split, out) == 0
    return out


@pytest.fixture(scope="session")
def reference_tables(reference_out: Path) -> dict[str, bytes]:
    """The tables of the plain ``--workers 1`` conversion, which every executor must reproduce."""
    return tables(reference_out)


def infos_files(dataroot: Path, out: Path, *extra: str) -> dict[str, bytes]:
    """``nuav2 infos`` of ``dataroot`` into ``out``: {file name: bytes}."""
    argv = ["infos", str(dataroot), "--version", VERSION, "--out", str(out), "--no-progress", *extra]
    assert main(argv) == 0
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


def descendants_named(names: set[str]) -> list[int]:
    """Pids of processes started by this one (at any depth) whose command name is in ``names``."""
    parents: dict[int, int] = {}
    comm: dict[int, str] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        pid = int(text.split(" ", 1)[0])
        comm[pid] = text[text.index("(") + 1:text.rindex(")")]
        parents[pid] = int(text.rsplit(")", 1)[1].split()[1])
    found = []
    for pid, name in comm.items():
        p = pid
        while p in parents and p != os.getpid() and p > 1:
            p = parents[p]
        if p == os.getpid() and pid != os.getpid() and name in names:
            found.append(pid)
    return found
