"""Linked-list checks: sample, sample_data and sample_annotation prev/next chains, key frames, timestamps.

Each chain is checked against the order of its records' timestamps within its group (a scene,
a scene and channel, an instance) in one lexsort, so a broken link is named with the record
that should have been there instead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from nuav2.nuscenes_db.validate_tables import _S, LIDAR_NEEDED, TableStore


class LinkChecks(TableStore):
    """prev/next chains and what hangs on them (key frames, the sample a sweep belongs to)."""

    def _check_chain(self, table: str, group: np.ndarray, key: np.ndarray, key_ok: np.ndarray,
                     describe: Callable[[int], str], ends: Sequence[tuple] = ()) -> np.ndarray:
        """Check the doubly linked list of each group against the order of ``key`` (strictly increasing).

        ``group`` is -1 where a record's group is unknown and ``key_ok`` False where its key is
        (both reported elsewhere). ``ends`` lists (group, owner table, owner token, first field,
        first token, last field, last token). Returns the checked rows sorted by (group, key).
        """
        tokens = self.tokens(table)
        n = len(tokens)
        prev_i, next_i = self.resolve(table, "prev", table), self.resolve(table, "next", table)
        valid = (group >= 0) & key_ok
        partial = set(np.unique(group[(group >= 0) & ~key_ok]).tolist())  # groups with an unplaceable record
        rows = np.flatnonzero(valid)
        order = rows[np.lexsort((rows, key[rows], group[rows]))]
        g, k = group[order], key[order]
        same = g[1:] == g[:-1]
        dup = same & (k[1:] == k[:-1])
        for p in np.flatnonzero(dup):
            self.add(table, tokens[order[p + 1]], "timestamp", f"timestamp {k[p + 1]} equals that of "
                     f"{tokens[order[p]]} in {describe(g[p])}: not strictly increasing", "timestamp_order")
        skip = valid & np.isin(group, np.unique(g[1:][dup]))  # ambiguous order: duplicates reported above
        exp_next, exp_prev = np.full(n, -3), np.full(n, -3)
        if len(order):
            exp_next[order[:-1]], exp_next[order[-1]] = np.where(same, order[1:], -1), -1
            exp_prev[order[1:]], exp_prev[order[0]] = np.where(same, order[:-1], -1), -1
        for name, link, back, expected, later in (("next", next_i, prev_i, exp_next, True),
                                                  ("prev", prev_i, next_i, exp_prev, False)):
            for i in np.flatnonzero(valid & ~skip & (link != expected) & (link != -2)):
                msg = _link_message(name, i, int(link[i]), int(expected[i]), back, group, key, valid, tokens,
                                    describe, later)
                if msg:
                    self.add(table, tokens[i], name, msg, "linked_list")
        starts = np.flatnonzero(np.r_[True, ~same]) if len(order) else np.zeros(0, dtype=np.int64)
        stops = np.r_[starts[1:] - 1, len(order) - 1] if len(order) else starts
        head = dict(zip(g[starts].tolist(), order[starts].tolist()))
        tail = dict(zip(g[stops].tolist(), order[stops].tolist()))
        for gid, owner, owner_tok, first_field, first_tok, last_field, last_tok in ends:
            if gid in partial:
                continue
            if gid not in head:
                self.add(owner, owner_tok, first_field, f"{describe(gid)} has no {table} records",
                         "linked_list")
                continue
            for fld, have, want, which in ((first_field, first_tok, head[gid], "earliest"),
                                           (last_field, last_tok, tail[gid], "latest")):
                if have is not None and have != tokens[want]:
                    self.add(owner, owner_tok, fld, f"is {have!r} but the {which} {table} of {describe(gid)} "
                             f"is {tokens[want]}", "linked_list")
        return order

    def _check_sample_list(self) -> None:
        scene_i = self.resolve("sample", "scene_token", "scene")
        ts, ok = self.ints("sample", "timestamp")
        names = self.col("scene", "name", _S, default="?")
        scene_tokens = self.tokens("scene")
        firsts = self.col("scene", "first_sample_token", _S)
        lasts = self.col("scene", "last_sample_token", _S)
        ends = [(i, "scene", scene_tokens[i], "first_sample_token", firsts[i], "last_sample_token", lasts[i])
                for i in range(len(scene_tokens))]
        self._check_chain("sample", scene_i, ts, ok, lambda g: f"scene {names[g]}", ends)

    def _check_annotation_lists(self) -> None:
        table = "sample_annotation"
        inst_i = self.resolve(table, "instance_token", "instance")
        sample_i = self.resolve(table, "sample_token", "sample")
        sample_ts, ts_ok = self.ints("sample", "timestamp")
        at = np.maximum(sample_i, 0)
        key_ok = (sample_i >= 0) & (ts_ok[at] if len(ts_ok) else False)
        key = np.where(key_ok, sample_ts[at] if len(sample_ts) else 0, 0)
        inst_tokens = self.tokens("instance")
        firsts = self.col("instance", "first_annotation_token", _S)
        lasts = self.col("instance", "last_annotation_token", _S)
        ends = [(i, "instance", t, "first_annotation_token", firsts[i], "last_annotation_token", lasts[i])
                for i, t in enumerate(inst_tokens)]
        self._check_chain(table, inst_i, key, key_ok, lambda g: f"instance {inst_tokens[g]}", ends)
        count = np.bincount(inst_i[inst_i >= 0], minlength=len(inst_tokens))
        nbr, ok = self.ints("instance", "nbr_annotations")
        for i in np.flatnonzero(ok & (nbr != count)):
            self.add("instance", inst_tokens[i], "nbr_annotations",
                     f"is {nbr[i]} but the instance has {count[i]} annotations", "count")

    def _check_sample_data_lists(self) -> None:
        table = "sample_data"
        cols = self._sample_data_columns()
        tokens = self.tokens(table)
        chan_names = cols["channel_names"]
        n_ch = max(len(chan_names), 1)
        ts, ok = self.ints(table, "timestamp")
        known = (cols["scene"] >= 0) & (cols["channel"] >= 0)
        group = np.where(known, cols["scene"] * n_ch + cols["channel"], -1)
        scene_names = self.col("scene", "name", _S, default="?")
        order = self._check_chain(table, group, ts, ok,
                                  lambda g: f"scene {scene_names[g // n_ch]} channel {chan_names[g % n_ch]}")
        is_kf, kf_known = self.bools(table, "is_key_frame")
        self._check_key_frames(cols, is_kf, kf_known, ts, ok, tokens)
        self._check_sweep_samples(cols, order, group, is_kf, kf_known, ts, tokens)
        self._check_unique_timestamps(cols, ts, ok, tokens)

    def _check_key_frames(self, cols: dict, is_kf: np.ndarray, kf_known: np.ndarray, ts: np.ndarray,
                          ts_ok: np.ndarray, tokens: list[str]) -> None:
        """Each sample gets exactly one key frame per channel its scene records, LIDAR_TOP included."""
        chan_names = list(cols["channel_names"])
        n_ch, n_sample = max(len(chan_names), 1), len(self.recs["sample"])
        sample_tokens = self.tokens("sample")
        sample_i, chan_i = cols["sample"], cols["channel"]
        kf = is_kf & (sample_i >= 0) & (chan_i >= 0)
        count = np.bincount(sample_i[kf] * n_ch + chan_i[kf], minlength=n_sample * n_ch)
        count = count.reshape(n_sample, n_ch)
        for s, c in zip(*np.nonzero(count > 1)):
            self.add("sample", sample_tokens[s], "data", f"{count[s, c]} key-frame sample_data for channel "
                     f"{chan_names[c]} (the devkit keeps the last)", "key_frame")
        # a sample with a row of unknown channel or key-frame flag cannot be judged incomplete
        unsure = np.zeros(n_sample, dtype=bool)
        unsure[sample_i[(sample_i >= 0) & ((chan_i < 0) | ~kf_known)]] = True
        scene_of = cols["scene_of_sample"]
        n_scene = len(self.recs["scene"])
        scene_row = np.where(scene_of >= 0, scene_of, n_scene)  # extra row: samples of unknown scene
        scene_has = np.zeros((n_scene + 1, n_ch), dtype=bool)
        np.logical_or.at(scene_has, scene_row, count > 0)
        missing = scene_has[scene_row] & (count == 0) & ~unsure[:, None] & (scene_of >= 0)[:, None]
        for s, c in zip(*np.nonzero(missing)):
            self.add("sample", sample_tokens[s], "data", f"no key-frame sample_data for channel "
                     f"{chan_names[c]}, which its scene records", "key_frame")
        if "LIDAR_TOP" not in chan_names:
            if n_sample and len(tokens) and "sensor" in self.usable:
                self.add("sensor", "", "channel", f"no LIDAR_TOP sample_data at all {LIDAR_NEEDED}",
                         "key_frame")
            return
        lidar = chan_names.index("LIDAR_TOP")
        for s in np.flatnonzero((count[:, lidar] == 0) & ~missing[:, lidar] & ~unsure):
            self.add("sample", sample_tokens[s], "data", f"no LIDAR_TOP key frame {LIDAR_NEEDED}",
                     "key_frame")
        sample_ts, s_ok = self.ints("sample", "timestamp")
        rows = np.flatnonzero(kf & (chan_i == lidar) & ts_ok)
        s_of = sample_i[rows]
        differs = s_ok[s_of] & (sample_ts[s_of] != ts[rows])
        for r, s in zip(rows[differs], s_of[differs]):
            self.add("sample", sample_tokens[s], "timestamp", f"{sample_ts[s]} differs from that of its "
                     f"LIDAR_TOP key frame {tokens[r]} ({ts[r]})", "key_frame")

    def _check_sweep_samples(self, cols: dict, order: np.ndarray, group: np.ndarray, is_kf: np.ndarray,
                             kf_known: np.ndarray, ts: np.ndarray, tokens: list[str]) -> None:
        """A sweep belongs to the sample that follows it: the sample of its channel's next key frame, or
        the first sample of its scene at or after its timestamp (either reading of the format is fine;
        past the end, the last one)."""
        if not len(order):
            return
        g, kf, n = group[order], is_kf[order], len(order)
        pos = np.arange(n)
        nxt = np.minimum.accumulate(np.where(kf, pos, n)[::-1])[::-1]
        prv = np.maximum.accumulate(np.where(kf, pos, -1))
        nxt_ok = (nxt < n) & (g[np.minimum(nxt, n - 1)] == g)
        prv_ok = (prv >= 0) & (g[np.maximum(prv, 0)] == g)
        ref = np.where(nxt_ok, nxt, np.where(prv_ok, prv, -1))
        sample_i = cols["sample"]
        expected = np.where(ref >= 0, sample_i[order[np.maximum(ref, 0)]], -1)
        unsure = np.isin(g, np.unique(group[~kf_known]))
        suspects = np.flatnonzero(~kf & ~unsure & (expected >= 0) & (sample_i[order] != expected))
        if not len(suspects):
            return
        by_time = self._following_samples(cols, cols["scene"][order[suspects]], ts[order[suspects]])
        sample_tokens = self.tokens("sample")
        for p, alt in zip(suspects, by_time):
            r = order[p]
            if alt == sample_i[r]:
                continue
            which = "next" if nxt_ok[p] else "last"
            by_time = sample_tokens[alt] if alt >= 0 else "none"
            self.add("sample_data", tokens[r], "sample_token", f"sweep points at sample "
                     f"{sample_tokens[sample_i[r]]} but the {which} key frame of its channel "
                     f"({tokens[order[ref[p]]]}) belongs to sample {sample_tokens[expected[p]]} and the "
                     f"first sample at or after its timestamp is {by_time}", "sweep_sample")

    def _following_samples(self, cols: dict, scenes: np.ndarray, ts: np.ndarray) -> np.ndarray:
        """Per (scene, timestamp): the scene's first sample at or after it, else its last (-1: none)."""
        scene_of = cols["scene_of_sample"]
        sample_ts, ok = self.ints("sample", "timestamp")
        out = np.full(len(ts), -1, dtype=np.int64)
        for sc in np.unique(scenes):
            rows = np.flatnonzero((scene_of == sc) & ok)
            if len(rows):
                rows = rows[np.argsort(sample_ts[rows], kind="stable")]
                at = scenes == sc
                out[at] = rows[np.minimum(np.searchsorted(sample_ts[rows], ts[at]), len(rows) - 1)]
        return out

    def _check_unique_timestamps(self, cols: dict, ts: np.ndarray, ok: np.ndarray, tokens: list[str]) -> None:
        """No two sample_data of one channel in one log share a timestamp (across its scenes too)."""
        rows = np.flatnonzero(ok & (cols["log"] >= 0) & (cols["channel"] >= 0))
        rows = rows[np.lexsort((ts[rows], cols["channel"][rows], cols["log"][rows]))]
        log, ch, scene, t = cols["log"][rows], cols["channel"][rows], cols["scene"][rows], ts[rows]
        dup = (log[1:] == log[:-1]) & (ch[1:] == ch[:-1]) & (t[1:] == t[:-1]) & (scene[1:] != scene[:-1])
        for p in np.flatnonzero(dup):  # same-scene duplicates are reported by the linked-list check
            self.add("sample_data", tokens[rows[p + 1]], "timestamp", f"timestamp {t[p + 1]} of channel "
                     f"{cols['channel_names'][ch[p]]} is also used by {tokens[rows[p]]} in another scene of "
                     "the same log", "timestamp_order")


def _link_message(name: str, i: int, j: int, e: int, back: np.ndarray, group: np.ndarray, key: np.ndarray,
                  valid: np.ndarray, tokens: list[str], describe: Callable[[int], str],
                  later: bool) -> str | None:
    """Why record ``i``'s ``name`` link is ``j``, not the expected ``e``: one clause per failure mode."""
    if j == -1:
        return f"is empty but {tokens[e]} {'follows' if later else 'precedes'} it in {describe(group[i])}"
    if not valid[j]:
        return None  # the target cannot be placed; its own problem is reported
    if group[j] != group[i]:
        return f"{tokens[j]} belongs to {describe(group[j])}, not {describe(group[i])}"
    if (key[j] <= key[i]) if later else (key[j] >= key[i]):
        return (f"{tokens[j]} is not {'later' if later else 'earlier'} (timestamp {key[j]} "
                f"{'<=' if later else '>='} {key[i]}): cycle or out-of-order list")
    if back[j] != i:
        other = "prev" if name == "next" else "next"
        have = tokens[back[j]] if back[j] >= 0 else ""
        return f"prev/next not symmetric: {name} is {tokens[j]} but its {other} is {have!r}"
    if e >= 0:
        return f"is {tokens[j]} but {tokens[e]} lies between them in time"
    return f"is {tokens[j]} but the record is the {'last' if later else 'first'} of {describe(group[i])}"
