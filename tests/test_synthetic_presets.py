"""Realism presets: config semantics, the official av2 loaders on every preset, determinism, and
factors that change only what they add (labels, lidar) while the rest stays byte-identical."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from av2.datasets.sensor.av2_sensor_dataloader import AV2SensorDataLoader
from av2.map.map_api import ArgoverseStaticMap, RasterLayerType
from av2.structures.sweep import Sweep
from av2.utils.io import read_img

from nuav2.cli import main as cli_main
from nuav2.synth import FACTORS, LAYOUTS, PRESETS, SynthConfig, build_world, generate_log, load_world
from nuav2.synth.config import PRESET_FACTORS
from nuav2.synth.world import EGO_ORIGIN_HEIGHT_M, WORLD_FILE, clear_world_cache

TINY = dict(seconds=0.3, lidar_azimuth_steps=96, image_scale=0.0625, map_margin_m=20.0, texture_res_m=0.1)
LEGACY_KEYS = {
    "seconds",
    "image_scale",
    "lidar_azimuth_steps",
    "lidar_max_range_m",
    "n_parked",
    "n_moving",
    "n_pedestrians",
    "ego_speed_mps",
    "lane_change",
    "include_stereo",
    "texture_res_m",
    "map_margin_m",
    "city",
    "jpeg_quality",
}


def test_presets_resolve_factors_and_serialise_like_before():
    assert SynthConfig().factors == frozenset() and SynthConfig().preset == "easy"
    # An easy config serialises exactly as before the presets, so its log id (and bytes) are unchanged.
    assert set(SynthConfig().to_dict()) == LEGACY_KEYS
    assert build_world(0, SynthConfig()).log_id == "aad08f97-8e98-5285-b03e-168e0a2c9b84"
    assert SynthConfig.for_preset("hard").factors == frozenset(FACTORS)
    assert SynthConfig.for_preset("medium").factors == PRESET_FACTORS["medium"]
    assert PRESET_FACTORS["easy"] < PRESET_FACTORS["medium"] < PRESET_FACTORS["hard"]
    assert SynthConfig(preset="hard") == SynthConfig.for_preset("hard")
    for cfg in (
        SynthConfig.for_preset("easy", relief=True),
        SynthConfig.for_preset("hard", shadows=False),
        SynthConfig.for_preset("medium", layout="curved", n_cyclists=0),
    ):
        assert SynthConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    one = SynthConfig.for_preset("easy", relief=True)
    assert one.factors == {"relief"} and one.to_dict()["relief"] is True
    assert SynthConfig.for_preset("hard", shadows=False).to_dict()["shadows"] is False
    with pytest.raises(ValueError, match="preset"):
        SynthConfig.for_preset("extreme")
    with pytest.raises(ValueError, match="layout"):
        SynthConfig(layout="roundabout")
    with pytest.raises(ValueError, match="relief"):
        SynthConfig(relief="yes")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Tiny logs of every preset (medium twice, for byte-determinism), read by the official loaders."""
    root = tmp_path_factory.mktemp("presets")
    out = {}
    for preset, seed in (("easy", 3), ("medium", 1), ("hard", 3)):
        cfg = SynthConfig.for_preset(preset, **TINY)
        log_dir = generate_log(root / preset, seed=seed, config=cfg)
        loader = AV2SensorDataLoader(data_dir=root / preset / "train", labels_dir=root / preset / "train")
        out[preset] = (log_dir, loader, load_world(log_dir))
    clear_world_cache()
    out["medium_again"] = generate_log(
        root / "again", seed=1, config=SynthConfig.for_preset("medium", **TINY)
    )
    return out


@pytest.mark.parametrize("preset", PRESETS)
def test_official_av2_loaders_read_every_preset(logs, preset):
    log_dir, loader, world = logs[preset]
    log_id = world.log_id
    assert loader.get_log_ids() == [log_id]
    lidar_ts = loader.get_ordered_log_lidar_timestamps(log_id)
    assert lidar_ts == world.timeline.sweeps_ns.tolist()
    avm = ArgoverseStaticMap.from_map_dir(log_dir / "map", build_raster=True)
    assert len(avm.vector_lane_segments) == len(world.map_layout.lanes)
    heights = []
    for ts in lidar_ts:
        city_SE3_ego = loader.get_city_SE3_ego(log_id, ts)
        np.testing.assert_allclose(city_SE3_ego.transform_matrix, world.city_T_ego_at(ts), atol=1e-9)
        sweep = Sweep.from_feather(loader.get_lidar_fpath(log_id, ts))
        assert len(sweep) > 1000 and np.all(np.isfinite(sweep.xyz))
        for cam in world.camera_channels:
            path = loader.get_closest_img_fpath(log_id, cam, ts)
            assert path is not None and read_img(path).shape[:2] == (
                world.rig.camera(cam).height,
                world.rig.camera(cam).width,
            )
        labels = loader.get_labels_at_lidar_timestamp(log_id, ts)
        assert 0 < len(labels.cuboids) <= len(world.actors)
        xyz = city_SE3_ego.translation[None]
        assert avm.get_raster_layer_points_boolean(xyz, RasterLayerType.DRIVABLE_AREA).all()
        heights.append(avm.raster_ground_height_layer.get_ground_height_at_xy(xyz)[0])
        # The raster holds the surface under the ego (float16: a few cm; nearest 0.3 m cell on a grade).
        assert xyz[0, 2] - heights[-1] == pytest.approx(EGO_ORIGIN_HEIGHT_M, abs=0.08)
    ann = pd.read_feather(log_dir / "annotations.feather")
    assert set(ann["category"]) >= {"REGULAR_VEHICLE", "PEDESTRIAN"}
    if world.config.content:
        assert "BICYCLIST" in set(ann["category"])
    raster = avm.raster_ground_height_layer.array
    spread = float(np.nanmax(raster) - np.nanmin(raster))
    assert (spread > 0.5) == world.config.relief  # relief shows in AV2's ground height raster


def test_same_seed_same_bytes_and_world_file_rebuilds(logs):
    def tree(root: Path) -> dict[str, bytes]:
        return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}

    a, b = tree(logs["medium"][0]), tree(logs["medium_again"])
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a)
    rec = json.loads((logs["hard"][0] / WORLD_FILE).read_text())
    assert (
        rec["config"]["preset"] == "hard" and rec["layout"] in LAYOUTS and set(rec["factors"]) == set(FACTORS)
    )


def test_label_and_lidar_factors_change_only_their_files(tmp_path):
    """easy + label_noise / + lidar_noise: the camera images are the easy log's, byte for byte."""
    trees = {}
    for name, extra in (("easy", {}), ("labels", {"label_noise": True}), ("lidar", {"lidar_noise": True})):
        log = generate_log(tmp_path / name, seed=2, config=SynthConfig.for_preset("easy", **TINY, **extra))
        trees[name] = {str(p.relative_to(log)): p.read_bytes() for p in sorted(log.rglob("*")) if p.is_file()}
    jpgs = [k for k in trees["easy"] if k.endswith(".jpg")]
    lidar = [k for k in trees["easy"] if "/lidar/" in k]
    assert jpgs and lidar
    for name in ("labels", "lidar"):
        assert all(trees[name][k] == trees["easy"][k] for k in jpgs), name
    assert all(trees["labels"][k] == trees["easy"][k] for k in lidar)
    assert trees["labels"]["annotations.feather"] != trees["easy"]["annotations.feather"]
    assert all(trees["lidar"][k] != trees["easy"][k] for k in lidar)


def test_cli_preset_and_layout(tmp_path, capsys):
    rc = cli_main(
        [
            "synth",
            str(tmp_path),
            "--preset",
            "medium",
            "--layout",
            "arterial",
            "--seed",
            "2",
            "--seconds",
            "0.2",
            "--lidar-azimuth-steps",
            "64",
            "--scale",
            "0.0625",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["preset"] == "medium" and out["layout"] == "arterial" and "relief" in out["factors"]
    assert load_world(out["log_dir"]).layout_name == "arterial"
    with pytest.raises(SystemExit):
        cli_main(["synth", str(tmp_path), "--preset", "extreme"])
