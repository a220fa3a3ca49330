"""Split names, the keys this splitter writes into ``splits.json``, and the leakage radius."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

SPLITS = ("train", "val", "test")
HOLDOUT = ("val", "test")
DISCARDED = "discarded"
GEO_PREFIX = "geo_"  # names this splitter writes into splits.json
# Key prefixes of split groups in splits.json: plain, ours, and the converter's AV2 source splits.
SPLIT_PREFIXES = ("", GEO_PREFIX, "av2_")
LEAKAGE_RADIUS_M = 5.0

Positions = Mapping[str, np.ndarray]  # scene name -> (N, 2) city xy of its samples
