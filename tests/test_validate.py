"""`nuav2 validate`: passes on a database the real devkit loads, fails precisely on broken copies."""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nuscenes.nuscenes import NuScenes
from PIL import Image
from tiny_nuscenes_db import LOCATION, SAMPLE_PERIOD_US, T0_US, VERSION, map_expansion, tok, write_tiny_db

from nuav2.cli import main
from nuav2.nuscenes_db.validate import SCHEMA, image_size, validate_database
from nuav2.nuscenes_db.validate_map import validate_map_expansion


@pytest.fixture(scope="session")
def tiny_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_tiny_db(tmp_path_factory.mktemp("tiny") / "nuscenes")


# ------------------------------------------------------------------ mutation helpers
def _table(root: Path, name: str) -> list[dict]:
    return json.loads((root / VERSION / f"{name}.json").read_text())


def _save(root: Path, name: str, recs) -> None:
    (root / VERSION / f"{name}.json").write_text(json.dumps(recs))


def _edit(name: str, fn: Callable[[list[dict]], None]) -> Callable[[Path], None]:
    def mutate(root: Path) -> None:
        recs = _table(root, name)
        fn(recs)
        _save(root, name, recs)
    return mutate


def _edit_map(fn: Callable[[dict], None]) -> Callable[[Path], None]:
    def mutate(root: Path) -> None:
        path = root / "maps" / "expansion" / f"{LOCATION}.json"
        obj = json.loads(path.read_text())
        fn(obj)
        path.write_text(json.dumps(obj))
    return mutate


def _sd(recs: list[dict], channel: str, key_frame: bool | None = None) -> list[dict]:
    """sample_data rows of a channel in time order (optionally only key frames or only sweeps)."""
    rows = [r for r in recs if f"/{channel}/" in r["filename"]
            and (key_frame is None or r["is_key_frame"] == key_frame)]
    return sorted(rows, key=lambda r: r["timestamp"])


def _first_file(root: Path, pattern: str) -> Path:
    return sorted(root.glob(pattern))[0]


def _bowtie(obj: dict) -> None:
    lane_poly = next(p for p in obj["polygon"] if p["token"] == tok("poly", "lane"))
    ext = lane_poly["exterior_node_tokens"]
    ext[2], ext[3] = ext[3], ext[2]  # (40,48) (140,48) (40,52) (140,52): self-intersecting


def _set(recs: list[dict], i: int, **fields) -> None:
    recs[i].update(fields)


def _kf_twice(recs: list[dict]) -> None:
    sweep = _sd(recs, "CAM_FRONT", key_frame=False)[0]
    sweep["is_key_frame"] = True


def _sweep_wrong_sample(recs: list[dict]) -> None:
    _sd(recs, "LIDAR_TOP", key_frame=False)[0]["sample_token"] = tok("sample", 2)


def _sweep_first_sample(recs: list[dict]) -> None:
    _sd(recs, "CAM_BACK", key_frame=False)[0]["sample_token"] = tok("sample", 0)


def _sweep_between_sample_and_key_image(recs: list[dict]) -> None:
    """A CAM_BACK sweep 5 ms after sample 1's time, 4 ms before sample 1's CAM_BACK key image."""
    sweep = _sd(recs, "CAM_BACK", key_frame=False)[0]
    sweep["timestamp"] = T0_US + SAMPLE_PERIOD_US + 5_000
    sweep["sample_token"] = tok("sample", 2)


def _lidar_cycle(recs: list[dict]) -> None:
    rows = _sd(recs, "LIDAR_TOP")
    rows[-1]["next"], rows[0]["prev"] = rows[0]["token"], rows[-1]["token"]


def _swap_lidar_ts(recs: list[dict]) -> None:
    rows = _sd(recs, "LIDAR_TOP", key_frame=False)
    rows[1]["timestamp"] = rows[0]["timestamp"]


def _nan_pose(recs: list[dict]) -> None:
    recs[2]["translation"] = [math.nan, 1.0, 0.0]


def _drop_map_log(recs: list[dict]) -> None:
    recs[0]["log_tokens"] = []


def _remove(rel: str) -> Callable[[Path], None]:
    def mutate(root: Path) -> None:
        target = _first_file(root, rel)
        target.unlink()
    return mutate


def _truncate_lidar(root: Path) -> None:
    path = _first_file(root, "sweeps/LIDAR_TOP/*.bin")
    path.write_bytes(path.read_bytes()[:-7])


def _no_table(name: str) -> Callable[[Path], None]:
    return lambda root: (root / VERSION / f"{name}.json").unlink()


def _text(name: str, text: str) -> Callable[[Path], None]:
    return lambda root: (root / VERSION / f"{name}.json").write_text(text)


def _write_splits(obj) -> Callable[[Path], None]:
    return lambda root: (root / VERSION / "splits.json").write_text(json.dumps(obj))


def _remove_map_file(root: Path) -> None:
    (root / "maps" / "expansion" / f"{LOCATION}.json").unlink()


LANE, CONN = tok("lane"), tok("connector")
# (case id, mutation, table the problem is reported under, substring of the problem line)
BROKEN: list[tuple[str, Callable[[Path], None], str, str]] = [
    ("dangling_token", _edit("sample_data", lambda r: _set(r, 0, calibrated_sensor_token="f" * 32)),
     "sample_data", f"calibrated_sensor_token: '{'f' * 32}' not found in calibrated_sensor"),
    ("dangling_attribute", _edit("sample_annotation", lambda r: _set(r, 1, attribute_tokens=["nope"])),
     "sample_annotation", "attribute_tokens: 'nope' not found in attribute"),
    ("missing_file", _remove("sweeps/CAM_FRONT/*.jpg"), "sample_data", "file not found: "),
    ("wrong_image_size", _edit("sample_data", lambda r: _set(r, 0, width=1600, height=900)),
     "sample_data", "1600x900 but the image header of samples/CAM_FRONT/"),
    ("non_unit_quaternion", _edit("ego_pose", lambda r: _set(r, 3, rotation=[1.0, 0.1, 0.0, 0.0])),
     "ego_pose", "rotation: not a unit quaternion: |q| = 1.004987562"),
    ("non_unit_calibration",
     _edit("calibrated_sensor", lambda r: _set(r, 0, rotation=[0.5, 0.5, 0.5, 0.5001])),
     "calibrated_sensor", "not a unit quaternion"),
    ("broken_prev_next", _edit("sample", lambda r: _set(r, 1, next="")),
     "sample", f"next: is empty but {tok('sample', 2)} follows it in scene scene-0001"),
    ("asymmetric_prev", _edit("sample", lambda r: _set(r, 2, prev=tok("sample", 0))),
     "sample",
     f"prev: prev/next not symmetric: prev is {tok('sample', 0)} but its next is '{tok('sample', 1)}'"),
    ("cycle", _edit("sample_data", _lidar_cycle), "sample_data", "cycle or out-of-order list"),
    ("first_last_token", _edit("scene", lambda r: _set(r, 0, last_sample_token=tok("sample", 1))),
     "scene", f"last_sample_token: is '{tok('sample', 1)}' but the latest sample of scene scene-0001 is"),
    ("annotation_list", _edit("instance", lambda r: _set(r, 0, first_annotation_token=tok("ann", "car", 1))),
     "instance", "first_annotation_token: is"),
    ("duplicate_timestamp", _edit("sample_data", _swap_lidar_ts), "sample_data", "not strictly increasing"),
    ("two_key_frames", _edit("sample_data", _kf_twice), "sample",
     "2 key-frame sample_data for channel CAM_FRONT (the devkit keeps the last)"),
    ("sweep_sample", _edit("sample_data", _sweep_wrong_sample), "sample_data",
     f"sweep points at sample {tok('sample', 2)} but the next key frame"),
    ("sweep_before_sample", _edit("sample_data", _sweep_first_sample), "sample_data",
     "and the first sample at or after its timestamp is " + tok("sample", 1)),
    ("missing_connectivity", _edit_map(lambda m: m["connectivity"].pop(LANE)), f"expansion/{LOCATION}",
     f"{LANE} connectivity: lane has no connectivity entry"),
    ("dangling_connectivity", _edit_map(lambda m: m["connectivity"][CONN]["incoming"].append("ghost")),
     f"expansion/{LOCATION}", "incoming 'ghost' is not a lane or lane_connector"),
    ("invalid_polygon", _edit_map(_bowtie), f"expansion/{LOCATION}",
     f"polygon {tok('poly', 'lane')} is invalid (Self-intersection"),
    ("arcline_radius_0", _edit_map(lambda m: m["arcline_path_3"][LANE][0].update(radius=0)),
     f"expansion/{LOCATION}", "piece 0: radius must be a finite non-zero number"),
    ("missing_arcline", _edit_map(lambda m: m["arcline_path_3"].pop(CONN)), f"expansion/{LOCATION}",
     "lane_connector has no arcline path"),
    ("missing_layer", _edit_map(lambda m: m.pop("walkway")), f"expansion/{LOCATION}",
     "walkway: layer missing"),
    ("old_map_version", _edit_map(lambda m: m.update(version="1.10")), f"expansion/{LOCATION}",
     "'1.10' < '1.3' by string comparison"),
    ("zero_canvas", _edit_map(lambda m: m.update(canvas_edge=[300.0, 0])), f"expansion/{LOCATION}",
     "canvas_edge: must be [width, height] with both > 0"),
    ("negative_node", _edit_map(lambda m: m["node"][0].update(x=-3.0)), f"expansion/{LOCATION}",
     "negative coordinate (-3.0, 52.0)"),
    ("dangling_divider_node", _edit_map(lambda m: m["lane"][0]["left_lane_divider_segments"][0].update(
        node_token="gone")), f"expansion/{LOCATION}", "node_token 'gone' not found in node"),
    ("missing_expansion", _remove_map_file, f"expansion/{LOCATION}", "map expansion file missing"),
    ("missing_table", _no_table("visibility"), "visibility", "table file missing"),
    ("bad_json", _text("sensor", "[{"), "sensor", "cannot parse"),
    ("table_not_list", _text("log", "{}"), "log", "holds a JSON dict, not a list of records"),
    ("duplicate_token", _edit("category", lambda r: r.append(dict(r[0]))), "category",
     f"{tok('cat', 'vehicle.car')} token: duplicate token (records #0 and #2)"),
    ("missing_field", _edit("sample", lambda r: r[0].pop("timestamp")), "sample", "timestamp: missing field"),
    ("wrong_type", _edit("sample_data", lambda r: _set(r, 4, is_key_frame="yes")), "sample_data",
     "is_key_frame: must be a boolean, got str 'yes'"),
    ("nan_translation", _edit("ego_pose", _nan_pose), "ego_pose", "translation: contains NaN or Inf"),
    ("two_attributes", _edit("sample_annotation", lambda r: r[0]["attribute_tokens"].append(
        tok("attr", "pedestrian.moving"))), "sample_annotation", "2 attributes: the detection eval raises"),
    ("negative_size", _edit("sample_annotation", lambda r: _set(r, 0, size=[1.9, 0.0, 1.6])),
     "sample_annotation", "box size must be positive"),
    ("scene_name", _edit("scene", lambda r: _set(r, 0, name="tiny-1")), "scene",
     "'tiny-1' is not 'scene-NNNN'"),
    ("split_unknown_scene", _write_splits({"train": ["scene-0001", "scene-0999"]}), "splits",
     "scene 'scene-0999' is not in the scene table"),
    ("lidar_intrinsic", _edit("calibrated_sensor", lambda r: _set(r, 2, camera_intrinsic=[[1, 0, 0]])),
     "calibrated_sensor", "camera_intrinsic: must be [] for a lidar sensor"),
    ("camera_focal", _edit("calibrated_sensor",
                           lambda r: _set(r, 0, camera_intrinsic=[[-5.0, 0, 80], [0, 5.0, 45], [0, 0, 1]])),
     "calibrated_sensor", "focal lengths must be positive, got fx=-5.0"),
    ("bad_modality", _edit("sensor", lambda r: _set(r, 0, modality="sonar")), "sensor",
     "modality: 'sonar' is not one of"),
    ("lidar_size", _truncate_lidar, "sample_data", "is not a multiple of 20"),
    ("log_not_in_map", _edit("map", _drop_map_log), "log", "log is in no map record's log_tokens"),
    ("missing_map_png", _remove("maps/*.png"), "map", "map mask not readable"),
    ("nbr_samples", _edit("scene", lambda r: _set(r, 0, nbr_samples=4)), "scene",
     "nbr_samples: is 4 but the scene has 3 samples"),
]


def _grouped(out: str) -> list[tuple[str, str]]:
    """(table heading, problem line) pairs from the CLI's grouped text output."""
    pairs, table = [], None
    for line in out.splitlines():
        if line.startswith("[") and "] " in line:
            table = line[1:line.index("]")]
        elif line.startswith("  ") and table is not None:
            pairs.append((table, line.strip()))
    return pairs


def _broken_copy(tiny_db: Path, tmp_path: Path, mutate: Callable[[Path], None]) -> Path:
    root = tmp_path / "nuscenes"
    shutil.copytree(tiny_db, root)
    mutate(root)
    return root


# ------------------------------------------------------------------------ tests
def test_tiny_db_loads_in_the_real_devkit(tiny_db: Path) -> None:
    nusc = NuScenes(version=VERSION, dataroot=str(tiny_db), verbose=False)
    assert len(nusc.sample) == 3
    assert set(nusc.sample[1]["data"]) == {"CAM_FRONT", "CAM_BACK", "LIDAR_TOP"}
    assert nusc.get("log", nusc.scene[0]["log_token"])["map_token"] == nusc.map[0]["token"]


def test_clean_database_passes(tiny_db: Path, capsys: pytest.CaptureFixture) -> None:
    rc = main(["validate", str(tiny_db), "--version", VERSION, "--devkit", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert out.startswith("OK: ") and "sample_data 21" in out and "map 1" in out


@pytest.mark.parametrize("case, mutate, table, expected", BROKEN, ids=[c[0] for c in BROKEN])
def test_broken_copy_fails_with_precise_message(tiny_db: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                case: str, mutate, table: str, expected: str) -> None:
    root = _broken_copy(tiny_db, tmp_path, mutate)
    rc = main(["validate", str(root), "--version", VERSION, "--quiet"])
    out = capsys.readouterr().out
    assert rc == 1, out
    assert out.startswith("FAIL: ")
    lines = _grouped(out)
    assert any(t == table and expected in line for t, line in lines), \
        f"{case}: wanted [{table}] {expected!r}\n{out}"
    assert not any("crashed" in line for _, line in lines), out
    assert len(lines) <= 2, f"{case}: one defect should not cascade:\n{out}"


def test_sweep_may_belong_to_the_first_sample_after_it(tiny_db: Path, tmp_path: Path) -> None:
    """Both readings of "the sample that follows it" are accepted: by key frame and by sample time."""
    root = _broken_copy(tiny_db, tmp_path, _edit("sample_data", _sweep_between_sample_and_key_image))
    report = validate_database(root, VERSION)
    assert report.ok, report.format_text()


def test_devkit_flag_reports_the_devkit_failure(tiny_db: Path, tmp_path: Path, capsys) -> None:
    root = _broken_copy(tiny_db, tmp_path, _edit("map", _drop_map_log))
    rc = main(["validate", str(root), "--version", VERSION, "--devkit", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 1
    assert any(t == "devkit" and "NuScenes(version='v1.0-tiny') raised KeyError" in line
               for t, line in _grouped(out)), out
    with pytest.raises(KeyError):  # the checker's claim, verified against the devkit itself
        NuScenes(version=VERSION, dataroot=str(root), verbose=False)


def test_devkit_flag_opens_the_map_like_maptr(tiny_db: Path, tmp_path: Path) -> None:
    root = _broken_copy(tiny_db, tmp_path, _edit_map(lambda m: m["connectivity"].pop(CONN)))
    report = validate_database(root, VERSION, devkit=True, check_files=False)
    devkit = [p for p in report.problems if p.check == "devkit"]
    assert len(devkit) == 1 and "ValueError" in devkit[0].message and CONN in devkit[0].message


def test_version_folder_missing(tiny_db: Path, capsys) -> None:
    """A missing folder is bad input like for every command: one line on stderr, exit 2."""
    rc = main(["validate", str(tiny_db), "--version", "v9-none", "--quiet"])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert err.strip().count("\n") == 0 and "--version v9-none" in err and VERSION in err
    rc = main(["validate", str(tiny_db / "nope"), "--version", VERSION, "--quiet"])
    assert rc == 2 and "dataroot not found" in capsys.readouterr().err
    for version in ("", ".", "..", f"x/{VERSION}"):  # not DATAROOT itself or a folder elsewhere
        rc = main(["validate", str(tiny_db), "--version", version, "--quiet"])
        assert rc == 2 and "--version" in capsys.readouterr().err


def test_version_folder_without_tables_is_a_report(tmp_path: Path, capsys) -> None:
    (tmp_path / "v1").mkdir()
    rc = main(["validate", str(tmp_path), "--version", "v1", "--quiet"])
    assert rc == 1 and "FAIL" in capsys.readouterr().out


def test_problems_are_capped_per_kind_but_all_counted(tiny_db: Path, tmp_path: Path, capsys) -> None:
    root = _broken_copy(tiny_db, tmp_path, lambda r: shutil.rmtree(r / "sweeps"))
    n_sweeps = sum(not r["is_key_frame"] for r in _table(root, "sample_data"))
    rc = main(["validate", str(root), "--version", VERSION, "--max-per-kind", "3", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 1
    assert sum("file not found" in line for _, line in _grouped(out)) == 3
    assert f"... and {n_sweeps - 3} more filename problem(s)" in out
    assert f"FAIL: {root} version {VERSION}: {n_sweeps} problem(s)" in out


def test_skipping_files_ignores_missing_files(tiny_db: Path, tmp_path: Path) -> None:
    root = _broken_copy(tiny_db, tmp_path, lambda r: shutil.rmtree(r / "sweeps"))
    assert validate_database(root, VERSION, check_files=False).ok
    assert not validate_database(root, VERSION).ok


def test_json_output_is_machine_readable(tiny_db: Path, tmp_path: Path, capsys) -> None:
    root = _broken_copy(tiny_db, tmp_path, _edit("scene", lambda r: _set(r, 0, nbr_samples=7)))
    assert main(["validate", str(root), "--version", VERSION, "--json", "--quiet"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False and report["n_problems"] == 1
    assert report["problems"][0]["table"] == "scene" and report["problems"][0]["field"] == "nbr_samples"


_FIELDS = [(t, f) for t, fields in SCHEMA.items() for f in ("token", *fields)]


_ALWAYS_WRONG = ("delete", {"x": 1}, None, 1.5)  # no schema field accepts these
_JUNK = _ALWAYS_WRONG + ([[]], [1, "a"], 2**70, -1, True, "", "zz", math.nan, [math.inf, 0, 0, 1])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(_FIELDS), st.integers(0, 100), st.sampled_from(_JUNK))
def test_any_malformed_field_is_reported_never_raised(tiny_db: Path, table_field, row: int, bad) -> None:
    table, name = table_field
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        shutil.copytree(tiny_db / VERSION, root / VERSION)
        (root / "maps").symlink_to(tiny_db / "maps")
        recs = _table(root, table)
        rec = recs[row % len(recs)]
        if isinstance(bad, str) and bad == "delete":
            rec.pop(name)
        else:
            rec[name] = bad
        _save(root, table, recs)
        report = validate_database(root, VERSION, check_files=False)
    assert not any(p.check == "internal" for p in report.problems), report.format_text()
    if any(bad is w or bad == w for w in _ALWAYS_WRONG):
        assert any(p.table == table and p.field == name and p.check == "schema" for p in report.problems), \
            report.format_text()


_MAP_FIELDS = [("node", "x"), ("node", "y"), ("line", "node_tokens"), ("polygon", "exterior_node_tokens"),
               ("polygon", "holes"), ("drivable_area", "polygon_tokens"), ("lane", "polygon_token"),
               ("lane", "left_lane_divider_segments"), ("lane_connector", "polygon_token"),
               ("lane_divider", "line_token"), ("ped_crossing", "polygon_token"),
               ("road_segment", "polygon_token")]


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(_MAP_FIELDS), st.integers(0, 100),
       st.sampled_from(["delete", {"x": 1}, None, [[1]], "ghost", math.nan]))
def test_any_malformed_map_field_is_reported_never_raised(layer_field, row: int, bad) -> None:
    layer, name = layer_field
    obj = map_expansion()
    rec = obj[layer][row % len(obj[layer])]
    if bad == "delete":
        rec.pop(name)
    else:
        rec[name] = bad
    problems: list[tuple] = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.json"
        path.write_text(json.dumps(obj))
        validate_map_expansion(path, "m", lambda *p: problems.append(p))
    assert problems, (layer, name, bad)
    assert any(tok_ == rec["token"] and fld.startswith(layer) for _, tok_, fld, _, _ in problems), problems


# ------------------------------------------------------------------ image headers
@pytest.mark.parametrize("fmt, kwargs", [("JPEG", {}), ("JPEG", {"progressive": True}),
                                         ("JPEG", {"exif": b"Exif\x00\x00" + b"\x00" * 60000}),
                                         ("JPEG", {"subsampling": 0, "quality": 95}), ("PNG", {})])
def test_image_size_matches_pil(tmp_path: Path, fmt: str, kwargs: dict) -> None:
    path = tmp_path / f"img.{fmt.lower()}"
    img = Image.fromarray(np.random.default_rng(1).integers(0, 255, (37, 83, 3), dtype=np.uint8))
    img.save(path, format=fmt, **kwargs)
    with Image.open(path) as oracle:
        assert image_size(path) == oracle.size == (83, 37)


def test_image_size_explains_bad_files(tmp_path: Path) -> None:
    good = tmp_path / "a.jpg"
    Image.new("RGB", (16, 8)).save(good, format="JPEG")
    data = good.read_bytes()
    cases = {"empty.jpg": b"", "text.jpg": b"hello", "cut.jpg": data[:20]}
    for name, blob in cases.items():
        (tmp_path / name).write_bytes(blob)
        msg = image_size(tmp_path / name)
        assert isinstance(msg, str) and ("JPEG" in msg), (name, msg)
    assert "not readable" in image_size(tmp_path / "absent.jpg")


def test_converter_output_validates(av2_fixture_log: Path, av2_fixture_calibration: Path, tmp_path: Path,
                                    capsys) -> None:
    """The real writer's output on the real AV2 fixture passes, devkit included; a broken copy fails."""
    from nuav2.convert import ConvertOptions, convert_av2

    out = tmp_path / "nuav2"
    result = convert_av2(av2_fixture_log, out, ConvertOptions(calibration_dir=av2_fixture_calibration,
                                                              require_cameras=False, show_progress=False))
    assert result.converted and not result.failed
    rc = main(["validate", str(out), "--version", result.version, "--devkit", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert text.startswith("OK: ")

    expansion = next((out / "maps" / "expansion").glob("*.json"))
    obj = json.loads(expansion.read_text())
    lane = obj["lane"][0]["token"]
    del obj["connectivity"][lane]
    expansion.write_text(json.dumps(obj))
    rc = main(["validate", str(out), "--version", result.version, "--quiet"])
    lines = _grouped(capsys.readouterr().out)
    assert rc == 1
    assert lines == [(f"expansion/{expansion.stem}", f"connectivity: {lane} connectivity: lane has no "
                      "connectivity entry (MapTR's converter calls get_incoming/outgoing_lane_ids and gets "
                      "ValueError)")]
