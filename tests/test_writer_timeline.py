"""Keyframe selection, key-image matching, µs uniqueness and deterministic tokens."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nuav2.nuscenes_db.keyframes import (
    build_timeline,
    match_key_images,
    owning_samples,
    plan_samples,
    select_keyframes,
    unique_microseconds,
)
from nuav2.nuscenes_db.tokens import global_token, is_token, make_token

MS = 1_000_000
T0 = 315_973_157_959_879_000  # a real AV2 sweep time


def test_every_sweep_by_default_and_every_fifth_at_2hz():
    sweeps = T0 + np.arange(31) * 100 * MS + np.array([0, 1, -1] * 10 + [0]) * 3 * MS  # jittery 10 Hz
    assert select_keyframes(sweeps, None).tolist() == list(range(31))
    assert select_keyframes(sweeps, 10.0).tolist() == list(range(31))
    assert select_keyframes(sweeps, 2.0).tolist() == [0, 5, 10, 15, 20, 25, 30]
    assert select_keyframes(sweeps, 100.0).tolist() == list(range(31))  # faster than the lidar: all
    with pytest.raises(ValueError, match="positive"):
        select_keyframes(sweeps, 0.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        select_keyframes(np.array([T0, T0]), None)


def test_a_keyframe_rate_above_the_sweep_rate_says_every_sweep_is_a_sample(caplog):
    """Found by review: --keyframe-hz 20 on 10 Hz sweeps gave 10 Hz samples without a word."""
    sweeps = T0 + np.arange(11) * 100 * MS
    with caplog.at_level("WARNING"):
        assert select_keyframes(sweeps, 10.0).tolist() == list(range(11))
        assert select_keyframes(sweeps, 12.0).tolist() == list(range(11))
    assert caplog.text == ""  # at (or jittering around) the sweep rate: nothing to say
    with caplog.at_level("WARNING"):
        assert select_keyframes(sweeps, 20.0).tolist() == list(range(11))
    assert "--keyframe-hz 20 is above the sweep rate (10 Hz): every sweep is a sample" in caplog.text


def test_key_image_is_nearest_within_25ms_and_used_once():
    keys = np.array([T0, T0 + 100 * MS, T0 + 200 * MS])
    images = np.array([T0 - 22 * MS, T0 + 28 * MS, T0 + 124 * MS, T0 + 126 * MS, T0 + 230 * MS])
    assert match_key_images(keys, images).tolist() == [0, 2, -1]  # 30 ms > 25 ms tolerance
    # Two key times nearest to the same image: the nearer one wins it.
    assert match_key_images(np.array([T0, T0 + 10 * MS]), np.array([T0 + 8 * MS])).tolist() == [-1, 0]
    assert match_key_images(keys, np.array([], dtype=np.int64)).tolist() == [-1, -1, -1]


def test_non_key_readings_belong_to_the_following_sample():
    keys = np.array([100, 200, 300])
    assert owning_samples(np.array([50, 100, 150, 250, 301, 900]), keys).tolist() == [0, 0, 1, 2, 2, 2]


def test_microseconds_collisions_are_bumped_deterministically():
    ns = np.array([5_000_100, 5_000_900, 5_000_500, 7_000_000, 5_000_500])
    prio = np.array([1, 0, 0, 0, 2])
    us = unique_microseconds(ns, prio)
    # by (ns, priority): 5_000_100 -> 5000, 5_000_500 (p0) -> 5001, 5_000_500 (p2) -> 5002,
    # 5_000_900 -> 5003
    assert us.tolist() == [5000, 5003, 5001, 7000, 5002]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=3_000), min_size=1, max_size=40))
def test_microseconds_unique_and_order_preserving(offsets_ns):
    ns = T0 + np.array(offsets_ns, dtype=np.int64)
    prio = np.arange(len(ns)) % 3
    us = unique_microseconds(ns, prio)
    assert len(set(us.tolist())) == len(us)
    order = np.lexsort((prio, ns))
    assert np.all(np.diff(us[order]) > 0)
    assert np.all(us >= ns // 1000) and np.all(us - ns // 1000 <= len(ns))


def test_samples_only_where_every_camera_is_synced():
    sweeps = T0 + np.arange(6) * 100 * MS
    cams = {"a": sweeps + 10 * MS, "b": np.delete(sweeps, 2) - 20 * MS}
    key_idx = plan_samples(sweeps, cams, None)
    assert key_idx.tolist() == [0, 1, 3, 4, 5]
    assert plan_samples(sweeps, {}, 5.0).tolist() == [0, 2, 4]
    with pytest.raises(ValueError, match="no LiDAR sweep has an image from every camera"):
        plan_samples(sweeps, {"a": sweeps + 40 * MS}, None)


def test_timeline_links_every_reading_and_labels_are_unique():
    sweeps = T0 + np.arange(5) * 100 * MS
    cams = {"cam": T0 - 10 * MS + np.arange(10) * 50 * MS}  # 20 Hz, -10 ms phase
    tl = build_timeline("LIDAR_TOP", sweeps, np.array([0, 2, 4]), cams)
    assert tl.key_ns.tolist() == sweeps[[0, 2, 4]].tolist()
    lidar = tl.frames["LIDAR_TOP"]
    assert [f.is_key_frame for f in lidar] == [True, False, True, False, True]
    assert [f.sample_index for f in lidar] == [0, 1, 1, 2, 2]
    cam = tl.frames["cam"]
    key_cam = [f for f in cam if f.is_key_frame]
    assert [f.timestamp_ns - T0 for f in key_cam] == [-10 * MS, 190 * MS, 390 * MS]
    assert [f.sample_index for f in key_cam] == [0, 1, 2]
    all_us = [f.timestamp_us for fs in tl.frames.values() for f in fs]
    assert len(set(all_us)) == len(all_us)
    assert tl.key_us.tolist() == [f.timestamp_us for f in lidar if f.is_key_frame]


def test_tokens_are_32_hex_deterministic_and_scoped():
    a = make_token("log-a", "sample", "1")
    assert is_token(a) and a == make_token("log-a", "sample", "1")
    assert a != make_token("log-b", "sample", "1") != make_token("log-a", "sample_data", "1")
    # The three parts cannot run into each other.
    assert make_token("a|b", "c", "d") != make_token("a", "b|c", "d")
    assert global_token("category", "vehicle.car") == make_token("", "category", "vehicle.car")
