"""``nuav2 eval PRED.json``: chamfer AP of MapTR-format predictions against GT built from the map."""

from __future__ import annotations

import argparse
import json
import logging

from nuav2.cli_types import number, positive_float

log = logging.getLogger(__name__)


# --split default: the first that holds scenes, among the splits of the database's own release
# (nuav2.maptr.subsets.release_splits: a v1.0-mini database skips trainval's val, as the devkit does).
DEFAULT_SPLITS = ("geo_val", "av2_val", "val", "mini_val", "all")
MINI_DEFAULT_SPLITS = ("geo_val", "av2_val", "mini_val", "val", "all")
DEFAULT_PATCH_M = (60.0, 30.0)  # MapTR's GT patch: forward, right
# Flags that choose the map GT; a GT file fixes its samples and vectors itself.
MAP_GT_FLAGS = (("dataroot", "--dataroot"), ("version", "--version"), ("split", "--split"),
                ("patch", "--patch"))
# Points per line for the chamfer distance: MapTR uses 100; beyond 1000 only the run time grows.
N_RESAMPLE_RANGE = (2, 1000)


def format_table(result: dict) -> str:
    """A small text table: AP per class and threshold, and the two mAP conventions."""
    thr = list(result["ap"][result["classes"][0]])
    lines = [
        f"{'class':<14}{'gts':>8}{'preds':>8}" + "".join(f"{'AP@' + t:>10}" for t in thr) + f"{'mean':>10}"
    ]
    for c in result["classes"]:
        aps = "".join(f"{result['ap'][c][t]:>10.4f}" for t in thr)
        lines.append(
            f"{c:<14}{result['num_gts'][c]:>8}{result['num_preds'][c]:>8}{aps}"
            f"{result['class_mean_ap'][c]:>10.4f}"
        )
    lines.append(
        f"{'mAP (GT classes)':<30}" + "".join(f"{result['map_per_threshold'][t]:>10.4f}" for t in thr)
    )
    classes = result["classes"]
    lines.append(f"mAP (headline) over {len(classes)} classes ({', '.join(classes)}): {result['mAP']:.4f}")
    if result.get("classes_left_out"):
        lines.append(f"left out (no prediction in the result file): {', '.join(result['classes_left_out'])}")
    return "\n".join(lines)


def default_split_order(version: str) -> tuple[str, ...]:
    """DEFAULT_SPLITS, with mini_val before val for a ``*-mini`` version (the devkit's and MapTR's
    evaluation split of v1.0-mini)."""
    return MINI_DEFAULT_SPLITS if version.endswith("-mini") else DEFAULT_SPLITS


def resolve_split(dataroot: str, version: str, split: str | None) -> str:
    """``split``, or the default (the first of :func:`default_split_order` that holds scenes among the
    release's splits); an unknown split, or one without scenes, is a UsageError."""
    from nuav2.cli import UsageError, require_database
    from nuav2.maptr.subsets import release_splits
    from nuav2.splits import available_splits

    require_database(dataroot, version)
    present = available_splits(dataroot, version)
    if split is None:
        own = release_splits(dataroot, version)
        order = default_split_order(version)
        split = next((s for s in order if own.get(s)), None)
        if split is None:
            raise UsageError(f"--split: none of the default splits {list(order)} holds scenes in {dataroot}/"
                             f"{version}; splits present: {', '.join(sorted(present)) or 'none'}")
        log.info("evaluating split %s (give --split to choose another)", split)
    elif split not in present:
        raise UsageError(f"--split {split}: not a split of {dataroot}/{version}; splits present: "
                         f"{', '.join(sorted(present)) or 'none'}")
    elif not present[split]:
        raise UsageError(f"--split {split}: holds no scenes in {dataroot}/{version}; splits "
                         f"with scenes: {', '.join(sorted(s for s in present if present[s])) or 'none'}")
    return split


# MapTR's classes (its v1 configs and MapTRv2's 3-class ones); MapTRv2's centerline is the optional fourth.
ALWAYS_SCORED = ("divider", "ped_crossing", "boundary")


def choose_classes(
    preds: dict, classes: list[str] | None, pred_path: str, gt_classes: frozenset[str] = frozenset()
) -> tuple[list[str], list[str]]:
    """(classes to evaluate, classes left out): ``--classes`` if given, else MapTR's three classes, each
    scored AP 0 when the file never predicts it (MapTR averages its configured classes, so a model that
    lost a class must not score higher than MapTR would score it), plus ``centerline`` when the file
    predicts it (a 3-class MapTRv2 result file is scored on its three classes, as MapTR does).
    ``gt_classes``: the classes a GT file holds, so a class of its own is not called one without GT."""
    from nuav2.evaluate import MAP_CLASSES
    from nuav2.evaluate.chamfer_ap import predicted_classes

    if classes:
        return list(classes), []
    found, missing, unknown = predicted_classes(preds, MAP_CLASSES)
    own = [c for c in unknown if c in gt_classes]
    if own:
        log.warning("%s: class(es) %s are not MapTR classes: left out of the default mAP (--classes "
                    "scores them)", pred_path, own)
    if len(own) < len(unknown):
        log.warning("%s: predicted class(es) %s have no GT class and are ignored", pred_path,
                    [c for c in unknown if c not in own])
    zero = [c for c in missing if c in ALWAYS_SCORED]
    if zero:
        log.warning("%s: no prediction of class(es) %s: scored AP 0, as MapTR does", pred_path, zero)
    left_out = [c for c in missing if c not in ALWAYS_SCORED]
    if left_out:
        log.warning("%s: no prediction of class(es) %s: left out of the mAP, as a 3-class MapTR model is "
                    "scored (--classes includes them, as AP 0)", pred_path, left_out)
    return [c for c in MAP_CLASSES if c not in left_out], left_out


def check_classes(classes: list[str] | None, known: list[str], source: str) -> None:
    """Refuse a ``--classes`` name outside the vocabulary (a typo would score a silent AP 0)."""
    from nuav2.cli import UsageError
    from nuav2.cli_inputs import refuse_repeats

    if not classes:
        return
    unknown = sorted(set(classes) - set(known))
    if unknown:
        raise UsageError(f"--classes: unknown class(es) {', '.join(unknown)}; the classes of {source} are: "
                         f"{', '.join(known)}")
    refuse_repeats("--classes", classes)


def gt_file_classes(gts: dict, preds: dict) -> list[str]:
    """The class vocabulary when the GT is a file: the map classes plus any the file or the
    predictions name (a GT file of another MapTR variant may have its own)."""
    from nuav2.evaluate import MAP_CLASSES

    seen = {vec[0] for vectors in (*gts.values(), *preds.values()) for vec in vectors}
    return [*MAP_CLASSES, *sorted(seen - set(MAP_CLASSES))]


def map_gt(args: argparse.Namespace) -> tuple[dict, str]:
    """(GT vectors, source description) from the database's map, for the chosen split."""
    from nuav2.cli_inputs import diagnosed_tables
    from nuav2.maptr.vectorize import gt_vectors_for_split  # the map GT; never a cached file

    split = resolve_split(args.dataroot, args.version, args.split)
    with diagnosed_tables(args.dataroot, args.version):
        gts = gt_vectors_for_split(args.dataroot, args.version, split,
                                   patch=tuple(args.patch or DEFAULT_PATCH_M))
    return gts, f"{args.dataroot} {args.version} split {split} (from the map)"


def _run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_json
    from nuav2.cli import UsageError, resolve_version
    from nuav2.cli_inputs import require_out_path
    from nuav2.evaluate import MAP_CLASSES
    from nuav2.evaluate.chamfer_ap import evaluate_vectors
    from nuav2.evaluate.vector_files import load_gt_file, load_predictions

    require_out_path(args.out)
    ignored = [flag for key, flag in MAP_GT_FLAGS if getattr(args, key) is not None]
    if args.gt_json and ignored:
        raise UsageError(f"--gt-json: {', '.join(ignored)} only apply to the map GT, not to a GT file; "
                         "leave them out")
    if not args.gt_json:
        if not args.dataroot:
            raise UsageError("--dataroot is required (or give --gt-json)")
        args.version = resolve_version(args.dataroot, args.version)
        check_classes(args.classes, list(MAP_CLASSES), "the map GT")
    preds = load_predictions(args.pred)
    gt_classes: frozenset[str] = frozenset()  # the map GT's classes are MAP_CLASSES
    if args.gt_json:
        gts = load_gt_file(args.gt_json)
        source = str(args.gt_json)
        check_classes(args.classes, gt_file_classes(gts, preds), f"{source} and {args.pred}")
        gt_classes = frozenset(vec[0] for vectors in gts.values() for vec in vectors)
    else:
        gts, source = map_gt(args)
    classes, left_out = choose_classes(preds, args.classes, args.pred, gt_classes)
    try:
        result = evaluate_vectors(
            gts, preds, classes=classes, thresholds=args.thresholds, n_resample=args.n_resample
        )
    except ValueError as e:
        raise ValueError(f"{args.pred} against {source}: {e}") from e
    result["classes_left_out"] = left_out
    result["gt_source"] = source
    result["predictions"] = str(args.pred)
    if result["n_samples_without_predictions"]:
        log.warning(
            "%d of %d GT samples have no predictions (they count as misses)",
            result["n_samples_without_predictions"],
            result["n_samples"],
        )
    if args.out:
        atomic_write_json(args.out, result, indent=1)
    print(json.dumps(result) if args.json else format_table(result))
    return 0


def register(subparsers) -> None:
    from nuav2.evaluate import MAP_THRESHOLDS_M

    p = subparsers.add_parser("eval", help="chamfer-distance AP / mAP of map predictions (MapTR protocol)")
    p.add_argument("pred", help="predictions: MapTR nuscmap_results.json ({'meta', 'results': [...]})")
    p.add_argument("--dataroot", help="nuScenes-format dataroot whose map gives the GT")
    p.add_argument("--version", help="database version, e.g. v1.0-trainval (default: the only one in "
                                     "--dataroot)")
    p.add_argument("--split", default=None,
                   help="split name (<version>/splits.json, else the devkit's); default: the first that "
                        f"holds scenes of {', '.join(DEFAULT_SPLITS)} (mini_val first on a *-mini version; "
                        "the devkit's lists of another nuScenes release are skipped)")
    p.add_argument(
        "--gt-json", help="evaluate against this MapTR GT file ({'GTs': [...]}) instead of the map"
    )
    p.add_argument(
        "--patch",
        type=positive_float,
        nargs=2,
        default=None,
        metavar=("FORWARD_M", "RIGHT_M"),
        help="GT patch size in the LIDAR_TOP frame (default 60 30)",
    )
    p.add_argument("--classes", nargs="+", default=None,
                   help="classes the mAP averages (default: divider, ped_crossing, boundary, each AP 0 "
                        "if never predicted, as MapTR scores them, plus centerline if the file predicts it)")
    p.add_argument("--thresholds", type=number(float, lo=0, hi=100, lo_open=True, hi_open=True), nargs="+",
                   default=list(MAP_THRESHOLDS_M), help="chamfer distance thresholds in metres, in (0, 100)")
    p.add_argument("--n-resample", type=number(int, *N_RESAMPLE_RANGE), default=100,
                   help=f"points per line for the chamfer distance ({N_RESAMPLE_RANGE[0]} to "
                        f"{N_RESAMPLE_RANGE[1]}; default 100, as MapTR)")
    p.add_argument("--out", help="also write the result JSON here (atomically)")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    p.set_defaults(func=_run)
