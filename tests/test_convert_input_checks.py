"""``nuav2 convert av2``: command lines that can never convert are one line naming the flag or path,
exit 2, and nothing written: a --scale past the largest image, a --rig file that cannot be read,
OUT inside SRC (or SRC inside a folder convert writes in OUT) and empty SRC / OUT.

Every check here fails before a log is read, so the logs are fakes holding only the pose file."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

MAX_IMAGE_SIDE_PX = 16384  # nuav2.convert.MAX_IMAGE_SIDE_PX (asserted below)
LOG_ID = "0c6e62d7-bdfa-3061-8d3d-03b13aa21f68"


def run(*argv: object) -> tuple[int, str]:
    """``nuav2 ARGV`` in this process: (exit code, stderr); argparse's own errors exit too."""
    from nuav2.cli import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as e:
            code = e.code
    return code, err.getvalue()


def fake_split(root: Path) -> Path:
    """``root/train/<LOG_ID>`` holding only the pose file: found by find_logs, never read here."""
    log = root / "train" / LOG_ID
    log.mkdir(parents=True)
    (log / "city_SE3_egovehicle.feather").write_bytes(b"")
    return log.parent


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def refused(code: int, err: str, *words: str) -> None:
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)


# ------------------------------------------------------------------ --scale past the largest image


@pytest.mark.parametrize("scale, size", [("1e9", "CAM_FRONT 1600000000000x900000000000 px"),
                                         ("10.25", "CAM_FRONT 16400x9225 px"),
                                         ("1e308", "CAM_FRONT wider than 1e308 px")])
def test_scale_past_the_largest_image_is_refused_before_out(tmp_path: Path, scale: str, size: str):
    src, out = fake_split(tmp_path / "src"), tmp_path / "out"
    code, err = run("convert", "av2", src, out, "--mode", "warp", "--scale", scale, "--no-progress")
    refused(code, err, "--scale", size, f"max {MAX_IMAGE_SIDE_PX} px a side")
    assert not out.exists()


def test_scale_up_to_the_largest_image_is_accepted():
    from nuav2 import convert
    from nuav2.convert import ConvertOptions

    assert convert.MAX_IMAGE_SIDE_PX == MAX_IMAGE_SIDE_PX
    ConvertOptions(mode="warp", scale=10.24).check()  # nuScenes' 1600 px -> exactly 16384
    ConvertOptions(mode="render", rig="av2", scale=8).check()  # AV2's 2048 px -> 16384


@pytest.mark.parametrize("value", ["1.5", "-1", "nan", "inf"])
def test_min_confidence_outside_0_1_is_refused_before_out(tmp_path: Path, value: str):
    """A confidence is in [0, 1]: above 1 dropped every sample after the whole reconstruction (and
    was blamed on camera sync); nan and negatives were accepted and dropped nothing."""
    src, out = fake_split(tmp_path / "src"), tmp_path / "out"
    code, err = run("convert", "av2", src, out, "--mode", "render", "--min-confidence", value,
                    "--no-progress")
    refused(code, err, "--min-confidence")
    assert not out.exists()
    from nuav2.convert import ConvertError, ConvertOptions

    with pytest.raises(ConvertError, match=r"--min-confidence must be a number in \[0, 1\]"):
        ConvertOptions(mode="render", min_confidence=float(value)).check()


def test_rig_spec_wider_than_the_largest_image_is_refused(tmp_path: Path):
    import json

    from nuav2.rig import load_rig

    spec = load_rig("nuscenes").to_dict()
    spec["cameras"][2]["width"] = MAX_IMAGE_SIDE_PX + 1
    rig = tmp_path / "wide.json"
    rig.write_text(json.dumps(spec))
    out = tmp_path / "out"
    code, err = run("convert", "av2", fake_split(tmp_path / "src"), out, "--mode", "warp", "--rig", rig)
    refused(code, err, f"--rig {rig}", f"{spec['cameras'][2]['channel']} {MAX_IMAGE_SIDE_PX + 1}x900 px")
    assert not out.exists()


def test_scale_in_native_mode_is_a_usage_error(tmp_path: Path):
    out = tmp_path / "out"
    code, err = run("convert", "av2", fake_split(tmp_path / "src"), out, "--scale", "1e9")
    refused(code, err, "--scale", "--mode native")
    assert not out.exists()


# ------------------------------------------------------------------ --rig files that cannot be read


@pytest.mark.parametrize("kind, words", [("binary", ["not a UTF-8 text file", "0xff"]),
                                         ("folder", ["cannot read the rig spec", "Is a directory"]),
                                         ("not json", ["not valid JSON"])])
def test_unreadable_rig_file_names_the_flag_and_file(tmp_path: Path, kind: str, words: list[str]):
    rig = tmp_path / "r" / "rig.json"
    rig.parent.mkdir()
    if kind == "binary":
        rig.write_bytes(b"\xff\xfe\x00")
    elif kind == "folder":
        rig.mkdir()
    else:
        rig.write_text("{nope")
    out = tmp_path / "out"
    code, err = run("convert", "av2", fake_split(tmp_path / "src"), out, "--mode", "warp", "--rig", rig)
    refused(code, err, "--rig: ", str(rig), *words)
    assert not out.exists()


# ------------------------------------------------------------------ OUT and SRC overlapping, empty


def test_out_inside_src_or_a_log_is_refused_and_nothing_written(tmp_path: Path):
    split = fake_split(tmp_path / "av2")
    log = split / LOG_ID
    before = tree(tmp_path)
    for src, out, words in [(log, log / "out", ["is inside SRC"]),
                            (split, split, ["is SRC"]),
                            (split, split / "nuscenes", ["is inside SRC"]),
                            (split, log, ["is inside SRC"]),
                            (tmp_path / "av2", split / "x" / ".." / "y", ["is inside SRC"])]:
        code, err = run("convert", "av2", src, out, "--no-progress")
        refused(code, err, f"OUT {out} ", f" {src}", *words)
        assert tree(tmp_path) == before, (src, out)


def test_out_inside_a_log_linked_into_src_is_refused(tmp_path: Path):
    real = fake_split(tmp_path / "elsewhere") / LOG_ID
    split = tmp_path / "av2" / "train"
    split.mkdir(parents=True)
    (split / LOG_ID).symlink_to(real, target_is_directory=True)
    out = real / "out"
    code, err = run("convert", "av2", split, out, "--no-progress")
    refused(code, err, f"OUT {out} is inside log {split / LOG_ID}")
    assert not out.exists()


def test_src_inside_a_folder_convert_writes_is_refused(tmp_path: Path):
    out = tmp_path / "data"
    for folder in ("samples", "sweeps", "maps", "can_bus", "v1.0-nuav2", ".nuav2_shards"):
        split = fake_split(out / folder / "av2")
        before = tree(tmp_path)
        code, err = run("convert", "av2", split, out, "--no-progress")
        refused(code, err, f"SRC {split} is inside {out / folder}", f"OUT {out}")
        assert tree(tmp_path) == before


def test_src_elsewhere_inside_out_is_fine(tmp_path: Path):
    """OUT=/data, SRC=/data/av2/train: the check lets it through (the fake log then fails to read)."""
    out = tmp_path / "data"
    code, err = run("convert", "av2", fake_split(out / "av2"), out, "--no-progress")
    assert code == 2 and "no log converted" in err, err
    assert "into the AV2 source" not in err and "writes and removes" not in err


@pytest.mark.parametrize("src, out, name", [("", "OUT", "SRC"), ("SRC/train", "", "OUT")])
def test_empty_src_or_out_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, src: str, out: str,
                                     name: str):
    """Path("") is ".": an unset shell variable would have converted into the current folder."""
    monkeypatch.chdir(tmp_path)
    fake_split(tmp_path / "SRC")
    before = tree(tmp_path)
    code, err = run("convert", "av2", src, out, "--no-progress")
    refused(code, err, f"argument {name}: empty path")
    assert tree(tmp_path) == before


def test_empty_path_in_the_python_api_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    from nuav2.convert import ConvertError, convert_av2

    monkeypatch.chdir(tmp_path)  # where "" would write without the check
    split = fake_split(tmp_path / "src")
    before = tree(tmp_path)
    with pytest.raises(ConvertError, match="OUT: empty path"):
        convert_av2(split, "")
    with pytest.raises(ConvertError, match="SRC: empty path"):
        convert_av2("", tmp_path / "out")
    assert tree(tmp_path) == before


def test_out_as_the_split_folder_of_a_log_given_as_src_is_refused(tmp_path: Path):
    """SRC is one log; OUT its split folder would fill the AV2 split with samples/, sweeps/, ..."""
    split = fake_split(tmp_path / "av2")
    before = tree(tmp_path)
    code, err = run("convert", "av2", split / LOG_ID, split, "--no-progress")
    refused(code, err, f"OUT {split} is the split folder of log {split / LOG_ID}")
    assert tree(tmp_path) == before


def test_out_through_a_symlink_loop_is_one_line(tmp_path: Path):
    split = fake_split(tmp_path / "av2")
    (tmp_path / "loopA").symlink_to(tmp_path / "loopB")
    (tmp_path / "loopB").symlink_to(tmp_path / "loopA")
    for out in (tmp_path / "loopA", tmp_path / "loopA" / "out"):
        code, err = run("convert", "av2", split, out, "--no-progress")
        assert code == 2 and "internal error" not in err, err
        refused(code, err, str(tmp_path / "loopA"))


def test_out_that_is_a_dangling_symlink_is_named_as_such(tmp_path: Path):
    """Found by review: the message was 'cannot create the output directory (File exists)'."""
    split = fake_split(tmp_path / "av2")
    out = tmp_path / "dangling"
    out.symlink_to(tmp_path / "gone")
    code, err = run("convert", "av2", split, out, "--no-progress")
    refused(code, err, f"{out}: OUT is a dangling symbolic link (to {tmp_path / 'gone'})")
    assert not (tmp_path / "gone").exists()


def test_a_second_conversion_into_a_busy_out_is_refused(tmp_path: Path):
    """Found by review: two converts into one OUT at once both reported success, the later merge
    silently replacing the other's database. The folder lock is what a running convert holds."""
    from nuav2.machine_lock import folder_lock

    split = fake_split(tmp_path / "av2")
    out = tmp_path / "out"
    out.mkdir()
    with folder_lock(out) as locked:
        assert locked
        code, err = run("convert", "av2", split, out, "--no-progress")
    refused(code, err, f"{out}: another nuav2 convert is writing into this OUT")
    assert tree(out) == []
    code, err = run("convert", "av2", split, out, "--no-progress")  # free again: this one reads the log
    assert "another nuav2 convert" not in err


def test_only_the_lock_itself_is_reported_as_a_busy_out(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """Found by review: an EAGAIN BlockingIOError from the work (a non-blocking pipe, ...) was reported
    as 'another nuav2 convert is writing into this OUT'."""
    import errno

    import nuav2.convert as convert_mod

    def work_hits_eagain(*args, **kwargs):
        raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")

    monkeypatch.setattr(convert_mod, "_convert_into", work_hits_eagain)
    with pytest.raises(BlockingIOError, match="Resource temporarily unavailable"):
        convert_mod.convert_av2(fake_split(tmp_path / "av2"), tmp_path / "out")
