"""Geo-disjoint train/val/test splits of scenes, and the leakage statistic of any split.

Why: on the standard splits most validation samples lie within a few metres of a training
sample (Lilja et al., CVPR 2024: > 80 % of nuScenes val/test within 5 m), so map models are
scored on places they memorised. Three ways to split, all per scene (``splits.json`` lists
scene names, as the devkit's custom splits and ``nuav2.maptr`` read it):

* :func:`geo_split`: scenes joined by "some sample pair closer than ``min_distance_m``" form
  connected components per city; whole components go to the split furthest below its ratio
  (or, by two other rules, where they leave the split closest to its ratios; the best of the
  three results is kept), and when val/test are still short, a spatially compact region is
  carved out of the largest train component, the train scenes touching it being *discarded*
  rather than leaking (only where that brings the split closer to its ratios).
* :func:`region_split`: hand-drawn val/test polygons per city (Lilja et al.): a scene whose
  samples all lie inside a val (test) polygon goes there, one that straddles a boundary is
  dropped (or kept in train), the rest is train.
* :func:`list_split`: published scene/log lists (e.g. Lilja's AV2 log-id lists).

Positions are true city coordinates: different cities never leak. For nuScenes the city is
``log.location`` and positions are global; for nuAV2 logs (locations ``av2-<city>-<id>``) the
global frame is the AV2 city frame minus ``city_offset`` (``nuav2.nuscenes_db.map_frame``),
read from ``<version>/nuav2_logs.json`` if present, else from the ``nuav2`` block of the
location's ``maps/expansion/<location>.json``.
"""

from nuav2.splits.database import (
    SceneTable,
    available_splits,
    existing_splits,
    read_scene_table,
    split_summary,
    write_splits,
)
from nuav2.splits.geo import geo_split, leakage, leakage_counts, scene_adjacency
from nuav2.splits.names import (
    DISCARDED,
    GEO_PREFIX,
    HOLDOUT,
    LEAKAGE_RADIUS_M,
    SPLIT_PREFIXES,
    SPLITS,
    Positions,
)
from nuav2.splits.regions import Region, list_split, load_lists, load_regions, region_split

__all__ = [
    "DISCARDED", "GEO_PREFIX", "HOLDOUT", "LEAKAGE_RADIUS_M", "SPLIT_PREFIXES", "SPLITS", "Positions",
    "Region", "SceneTable", "available_splits", "existing_splits", "geo_split", "leakage",
    "leakage_counts", "list_split", "load_lists", "load_regions", "read_scene_table",
    "region_split", "scene_adjacency", "split_summary", "write_splits",
]
