"""``--version`` may be left out of the analysis commands when DATAROOT holds one table folder (what
``nuav2 convert`` makes); with none or several the command stops before any work with one line
listing what is there. Run on a real database made by ``nuav2 synth`` + ``nuav2 convert``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from e2e_helpers import GOOD_VECTOR, VERSION, cli, copy_db, first_sample_token, results_file

pytest_plugins = ["test_writer_support", "e2e_support"]


def _argv(name: str, db: Path, tmp_path: Path) -> list[object]:
    """Command ``name`` on ``db`` without --version (cheap flags: a check, not a benchmark)."""
    pred = results_file(tmp_path / "pred.json", first_sample_token(db), [GOOD_VECTOR])
    return {"validate": ["validate", db, "--no-images", "--json"],
            "split": ["split", db],
            "infos": ["infos", db, "--out", tmp_path / "infos", "--no-progress"],
            "eval": ["eval", pred, "--dataroot", db, "--json"],
            "viz": ["viz", db, "--sample", first_sample_token(db), "--out", tmp_path / "v.png"],
            "bench_loader": ["bench", "loader", db, "--samples", "1", "--json"]}[name]


COMMANDS = ("validate", "split", "infos", "eval", "viz", "bench_loader")


@pytest.mark.parametrize("name", COMMANDS)
def test_the_only_table_folder_is_the_default_version(name, native_synth_db, tmp_path, caplog) -> None:
    db = copy_db(native_synth_db, tmp_path / "db")
    with caplog.at_level("INFO", logger="nuav2.cli"):
        code, out, err = cli(*_argv(name, db, tmp_path))
    assert code == 0, err
    assert f"--version {VERSION} (the only table folder in {db})" in caplog.text
    if name == "validate":
        assert json.loads(out)["ok"] is True
    if name == "split":
        assert (db / VERSION / "splits.json").is_file()
    if name == "infos":
        assert any(p.suffix == ".pkl" for p in (tmp_path / "infos").iterdir())
    if name == "eval":
        assert json.loads(out)["n_samples"] > 0
    if name == "viz":
        assert (tmp_path / "v.png").stat().st_size > 0
    if name == "bench_loader":
        assert json.loads(out)["samples"] == 1


@pytest.mark.parametrize("name", COMMANDS)
def test_several_or_no_table_folders_need_version_and_are_listed(name, native_synth_db, tmp_path) -> None:
    db = copy_db(native_synth_db, tmp_path / "db")
    shutil.copytree(db / VERSION, db / "v1.0-other")
    argv = _argv(name, db, tmp_path)
    code, _, err = cli(*argv)
    assert code == 2
    assert f"--version: give the table folder; {db} holds several ({VERSION}, v1.0-other)" in err
    assert "Traceback" not in err and "internal error" not in err
    empty = tmp_path / "empty_root"
    empty.mkdir()
    code, _, err = cli(*[empty if a == db else a for a in argv])
    assert code == 2 and f"{empty} holds none (no folder with a scene.json)" in err, err
