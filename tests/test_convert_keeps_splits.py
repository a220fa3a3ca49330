"""A rerun of ``nuav2 convert`` (or one more log) rebuilds the version folder; the splits other tools
added to ``splits.json`` (``nuav2 split``'s ``geo_*``) must survive it, or loaders and ``eval`` fall
back to other splits without a word."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from e2e_helpers import VERSION, cli


def _synth(root: Path, seed: int) -> None:
    code, _, err = cli("synth", root, "--seed", seed, "--seconds", "0.3", "--lidar-azimuth-steps", "64")
    assert code == 0, err


def _convert(src: Path, out: Path) -> None:
    code, _, err = cli("convert", "av2", src, out, "--mode", "native", "--workers", "1", "--no-progress")
    assert code == 0, err


@pytest.fixture
def split_db(tmp_path: Path) -> tuple[Path, Path]:
    src, out = tmp_path / "logs", tmp_path / "out"
    for seed in (1, 2, 3):
        _synth(src, seed)
    _convert(src / "train", out)
    code, _, err = cli("split", out, "--ratios", "0.34", "0.33", "0.33")
    assert code == 0, err
    return src, out


def test_a_rerun_keeps_the_geo_splits_and_their_report_byte_for_byte(split_db):
    src, out = split_db
    folder = out / VERSION
    before = {name: (folder / name).read_bytes() for name in ("splits.json", "splits_report.json")}
    assert any(k.startswith("geo_") for k in json.loads(before["splits.json"]))
    _convert(src / "train", out)  # every log resumed
    assert {name: (folder / name).read_bytes() for name in before} == before


def test_one_more_log_keeps_the_geo_splits_but_not_their_stale_report(split_db, caplog):
    src, out = split_db
    folder = out / VERSION
    geo = {k: v for k, v in json.loads((folder / "splits.json").read_text()).items() if k.startswith("geo_")}
    _synth(src, 4)
    with caplog.at_level(logging.WARNING):
        _convert(src / "train", out)
    splits = json.loads((folder / "splits.json").read_text())
    assert {k: splits[k] for k in geo} == geo and len(splits["all"]) == 4
    assert not (folder / "splits_report.json").exists()
    assert "rerun `nuav2 split`" in caplog.text


def test_a_split_naming_a_scene_no_longer_there_is_dropped_with_a_warning(split_db, caplog):
    src, out = split_db
    path = out / VERSION / "splits.json"
    splits = json.loads(path.read_text())
    splits["my_val"] = [splits["all"][0]]
    splits["stale"] = ["scene-0000"]
    path.write_text(json.dumps(splits))
    with caplog.at_level(logging.WARNING):
        _convert(src / "train", out)
    after = json.loads(path.read_text())
    assert after["my_val"] == splits["my_val"] and "stale" not in after
    assert "stale" in caplog.text and not (out / VERSION / "splits_report.json").exists()


@pytest.mark.parametrize("key, value", [("mine", [["scene-0001"]]), ("mine", [{"scene": "x"}]), ("all", 5),
                                        ("mine", "scene-0001")])
def test_a_malformed_key_in_splits_json_is_dropped_not_a_crash(split_db, caplog, key, value):
    src, out = split_db
    path = out / VERSION / "splits.json"
    splits = json.loads(path.read_text())
    splits[key] = value
    path.write_text(json.dumps(splits))
    with caplog.at_level(logging.WARNING):
        _convert(src / "train", out)
    after = json.loads(path.read_text())
    assert "mine" not in after and isinstance(after["all"], list) and len(after["all"]) == 3
    assert any(k.startswith("geo_") for k in after)
