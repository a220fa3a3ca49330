"""Helpers of the end-to-end tests: run the CLI in-process, convert under umask 022, read tables."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from test_writer_support import add_blank_images, link_log

VERSION = "v1.0-nuav2"
GOOD_VECTOR = {"pts": [[0.0, -5.0], [0.0, 5.0]], "pts_num": 2, "cls_name": "divider", "type": 0,
               "confidence_level": 0.9}  # one well-formed MapTR prediction vector
FIXTURE_ID = "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"  # in av2's TRAIN list (index 469): scene-2469
OTHER_ID = "00000002-0510-35b0-a2fa-b4cea13a6d76"  # in no av2 list: a 3000-9999 name
SYNTH_SECONDS = "0.5"


@contextlib.contextmanager
def umask(mask: int) -> Iterator[None]:
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def cli(*argv: object) -> tuple[int, str, str]:
    """Run ``nuav2 ARGV`` in this process: (exit code, stdout, stderr)."""
    from nuav2.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def cli_bound_by_modes(*argv: object) -> tuple[int, str, str]:
    """Run ``nuav2 ARGV`` as a child process that file modes bind: as root, under ``setpriv`` without
    the capabilities that let root read or write past them (CI runs as root); skips if that is not
    possible here."""
    import pytest

    prefix: list[str] = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: file modes cannot be made to bind")
        prefix = ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]
    proc = subprocess.run([*prefix, sys.executable, "-m", "nuav2", *map(str, argv)],
                          capture_output=True, text=True, timeout=600)
    return proc.returncode, proc.stdout, proc.stderr


def convert(src: Path, out: Path, *flags: str) -> dict:
    """``nuav2 convert av2 SRC OUT`` under umask 022; returns the printed summary."""
    with umask(0o022):
        code, stdout, stderr = cli("convert", "av2", src, out, "--no-progress", *flags)
    assert code == 0, stderr
    return json.loads(stdout.strip().splitlines()[-1])


def imaged_copy(fixture_log: Path, calibration: Path, split_dir: Path, log_id: str) -> Path:
    """The real fixture log under ``split_dir/log_id`` with calibration and blank camera images."""
    log_dir = link_log(fixture_log, split_dir, log_id, calibration)
    add_blank_images(log_dir, calibration)
    return log_dir


def table(db: Path, name: str) -> list[dict]:
    return json.loads((db / VERSION / f"{name}.json").read_text())


def logs_meta(db: Path) -> list[dict]:
    return json.loads((db / VERSION / "nuav2_logs.json").read_text())


def copy_db(db: Path, dest: Path) -> Path:
    """A database of its own: the tables copied (tests damage or rewrite them), the data linked."""
    dest.mkdir(parents=True)
    for entry in db.iterdir():
        if entry.name == VERSION:
            shutil.copytree(entry, dest / VERSION)
        else:
            (dest / entry.name).symlink_to(entry.resolve())
    return dest


def first_sample_token(db: Path) -> str:
    """The token of the first record in ``db``'s sample table."""
    return json.loads((db / VERSION / "sample.json").read_text())[0]["token"]


def results_file(path: Path, token: str, vectors: list) -> Path:
    """A MapTR result file (nuscmap_results.json layout) predicting ``vectors`` for one sample."""
    path.write_text(json.dumps({"meta": {"use_camera": True},
                                "results": [{"sample_token": token, "vectors": vectors}]}))
    return path
