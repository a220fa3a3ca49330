"""``nuav2 split DATAROOT --version V``: geo-disjoint train/val/test scenes and the leakage report."""

from __future__ import annotations

import argparse
import json
import logging
from typing import TYPE_CHECKING

from nuav2.cli_types import non_negative_float, non_negative_int, positive_float

if TYPE_CHECKING:
    from nuav2.splits import SceneTable

log = logging.getLogger(__name__)


def _warn_empty_holdout(result: dict, n_scenes: int, args: argparse.Namespace) -> None:
    """Say so when a split got no scene, with the cause the split method can have (the geo rule fills
    train first, so only val and test can end up empty there; lists and regions can leave any)."""
    empty = [k for k in ("train", "val", "test") if not result.get(k)]
    if not empty:
        return
    if args.lists:
        why = f"--lists {args.lists} gives it no scene of this database"
    elif args.regions:
        why = f"--regions {args.regions} puts no scene of this database there"
    else:
        why = (f"too few scenes for the ratios (a whole group of scenes within --min-distance "
               f"{args.min_distance:g} m must fit a holdout's share), or all of them close together; use "
               f"more logs, other --ratios, a smaller --min-distance, or --lists")
    log.warning("%s: no scene in %s (of %d scenes; %d discarded): %s", args.dataroot, " and ".join(empty),
                n_scenes, len(result.get("discarded", [])), why)


def _list_split(table: SceneTable, lists_path: str) -> tuple[dict, dict]:
    """(splits, report entry) from ``--lists``; refused when no entry names a scene of the database
    (the split would discard every scene and overwrite splits.json with nothing), while entries
    naming none are only warned about: published lists name more logs than one database holds."""
    from nuav2 import splits as sp

    lists = sp.load_lists(lists_path)
    try:
        result, unmatched = sp.list_split(table.identifiers, lists)
    except ValueError as e:  # a bad key or a scene in two splits: say which file
        raise ValueError(f"{lists_path}: {e}") from None
    if not any(result[k] for k in sp.SPLITS):
        shown = ", ".join(unmatched[:5]) + (f" and {len(unmatched) - 5} more" if len(unmatched) > 5 else "")
        raise ValueError(f"{lists_path}: no entry names a scene of this database "
                         f"(unknown: {shown or 'none; the lists are empty'}); entries are scene names, "
                         f"scene tokens, log tokens or log ids")
    if unmatched:
        log.warning("%s: %d entr(ies) name no scene of this database and are ignored: %s", lists_path,
                    len(unmatched), ", ".join(unmatched[:5]) + (" ..." if len(unmatched) > 5 else ""))
    return result, {"method": "lists", "lists": str(lists_path), "unmatched_entries": unmatched}


def _run(args: argparse.Namespace) -> int:
    from nuav2 import splits as sp
    from nuav2.cli import UsageError, require_database
    from nuav2.cli_inputs import diagnosed_tables

    args.version = require_database(args.dataroot, args.version)
    if args.regions and args.lists and not args.report_only:
        raise UsageError("give at most one of --regions and --lists")
    if args.straddle and not args.regions:
        raise UsageError("--straddle applies to --regions only")
    if sum(args.ratios) <= 0:
        raise UsageError(f"--ratios: at least one share must be positive, got {args.ratios}")
    with diagnosed_tables(args.dataroot, args.version):
        table = sp.read_scene_table(args.dataroot, args.version)
    scenes = sorted(table.positions)
    report: dict = {
        "dataroot": str(args.dataroot),
        "version": args.version,
        "existing": {
            name: sp.split_summary(split, table, args.radius)
            for name, split in sp.existing_splits(args.dataroot, args.version, scenes).items()
        },
    }
    if not args.report_only:
        if args.regions:
            regions, straddle = sp.load_regions(args.regions)
            result = sp.region_split(table.positions, table.city_of, regions, args.straddle or straddle)
            method = {
                "method": "regions",
                "regions": str(args.regions),
                "straddle": args.straddle or straddle,
            }
        elif args.lists:
            result, method = _list_split(table, args.lists)
        else:
            result = sp.geo_split(table.positions, table.city_of, args.ratios, args.min_distance, args.seed)
            method = {
                "method": "geo",
                "ratios": args.ratios,
                "min_distance_m": args.min_distance,
                "seed": args.seed,
            }
        _warn_empty_holdout(result, len(scenes), args)
        report["new"] = {
            **method,
            **sp.split_summary(result, table, args.radius),
            "discarded": result["discarded"],
        }
        report["written"] = str(sp.write_splits(args.dataroot, args.version, result, report))
    print(json.dumps(report, indent=1))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("split", help="geo-disjoint train/val/test splits (+ leakage report)")
    p.add_argument("dataroot", help="nuScenes-format dataroot (nuScenes, nuAV2, or both merged)")
    p.add_argument("--version", help="database version, e.g. v1.0-trainval (default: the only one in "
                                     "DATAROOT)")
    p.add_argument(
        "--ratios",
        type=non_negative_float,
        nargs=3,
        default=[0.8, 0.1, 0.1],
        metavar=("TRAIN", "VAL", "TEST"),
        help="target shares of samples (default 0.8 0.1 0.1)",
    )
    p.add_argument(
        "--min-distance",
        type=non_negative_float,
        default=50.0,
        help="no val/test sample within this many metres of a train sample (default 50)",
    )
    p.add_argument("--seed", type=non_negative_int, default=0, help="random seed (>= 0) of the geo split")
    p.add_argument("--regions", help="JSON of val/test polygons per city (Lilja et al. style)")
    p.add_argument("--straddle", choices=("drop", "train"), help="region mode: scenes crossing a boundary")
    p.add_argument("--lists", help="JSON {train, val, test: [scene names, tokens or log ids]}")
    p.add_argument("--radius", type=positive_float, default=5.0, help="leakage radius in metres (default 5)")
    p.add_argument("--report-only", action="store_true", help="only report the leakage of existing splits")
    p.set_defaults(func=_run)
