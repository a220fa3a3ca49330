"""``nuav2 convert av2 SRC OUT --mode native``: an AV2 split (or one log) -> a nuScenes dataroot."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from nuav2.cli import group
from nuav2.cli_types import number, path
from nuav2.conversion_modes import MODES

log = logging.getLogger(__name__)
# Versions whose devkit split names (create_splits_scenes: train/val/test, mini_*) are nuScenes'
# own scene lists: stock converters and load_gt select scenes by them, and find none of ours.
_NUSCENES_VERSIONS = ("v1.0-trainval", "v1.0-test", "v1.0-mini")

# Flags that only some modes use: given in another mode they are an error, not silently ignored.
_TARGET_RIG_MODES = ("warp", "render", "truth")
_MODE_FLAGS = {"rig": ("--rig", _TARGET_RIG_MODES), "scale": ("--scale", _TARGET_RIG_MODES),
               "recon_preset": ("--recon-preset", ("render",)),
               "min_confidence": ("--min-confidence", ("render",)),
               "device": ("--device", ("render",)),
               "image_link": ("--image-link", ("native",))}


def refuse_other_mode_flags(args: argparse.Namespace, offered: tuple[str, ...] = MODES) -> None:
    """A flag that ``args.mode`` does not use (``--rig`` with native, ...) is a UsageError, not ignored;
    ``convert`` and ``demo`` share it (a flag the command lacks counts as not given; ``offered``: the
    command's own modes, the only ones the message names)."""
    from nuav2.cli import UsageError

    for name, (flag, modes) in _MODE_FLAGS.items():
        if getattr(args, name, None) is not None and args.mode not in modes:
            named = " and ".join(m for m in modes if m in offered)
            raise UsageError(f"{flag} applies to --mode {named} only, not --mode {args.mode}")


def _options(args: argparse.Namespace):  # -> nuav2.convert.ConvertOptions (imported lazily)
    from nuav2.convert import ConvertOptions

    refuse_other_mode_flags(args)
    given = {name: getattr(args, name) for name in _MODE_FLAGS if getattr(args, name) is not None}
    return ConvertOptions(mode=args.mode, version=args.version, keyframe_hz=args.keyframe_hz,
                          workers=args.workers,
                          calibration_dir=args.calibration, require_cameras=not args.allow_missing_cameras,
                          show_progress=not args.no_progress, executor=args.executor,
                          ray_address=args.ray_address, cpus_per_task=args.cpus_per_task,
                          memory_per_task_gb=args.memory_per_task, gpus_per_task=args.gpus_per_task,
                          max_retries=args.max_retries, **given)


def _run(args: argparse.Namespace) -> int:
    from nuav2.convert import REPORT_FILE, convert_av2

    options = _options(args)
    if options.version in _NUSCENES_VERSIONS:
        log.warning("--version %s: the devkit's train/val/test/mini splits of that version are nuScenes' own "
                    "scene lists (used by MapTR's and mmdet3d's stock converters and load_gt); none of these "
                    "scenes is in them. Select scenes by this database's splits.json keys (av2_train, "
                    "eval_set='av2_val', `nuav2 infos`, `nuav2 split`)", options.version)
    report = convert_av2(args.src, args.out, options)
    summary = {"dataroot": report.dataroot, "version": report.version, "converted": len(report.converted),
               "resumed": len(report.resumed), "merged_earlier": len(report.merged_earlier),
               "failed": len(report.failed),
               "samples": report.table_counts.get("sample", 0), "report": str(Path(args.out) / REPORT_FILE)}
    print(json.dumps(summary, ensure_ascii=False))
    for f in report.failed:
        print(f"failed: {f['log_dir']}: {f['error']}", file=sys.stderr)
    return 1 if report.failed else 0


def _add_executor_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("executor", "where the logs run (see docs/cluster.md)")
    g.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local processes (default) or one Ray task per log (needs nuav2[ray])")
    g.add_argument("--ray-address", default=None,
                   help="Ray cluster to use (e.g. auto, HOST:6379, ray://HOST:10001); default: RAY_ADDRESS, "
                        "else a local Ray instance")
    g.add_argument("--cpus-per-task", type=float, default=None,
                   help="Ray: CPUs per log (default: 1 native/warp, 2 render)")
    g.add_argument("--memory-per-task", type=float, default=None, metavar="GIB",
                   help="Ray: memory reserved per log in GiB (default: 2 native, 4 warp, 8 render; 0: none)")
    g.add_argument("--gpus-per-task", type=float, default=None,
                   help="Ray: GPUs per log (default: 1 in render mode when the cluster has GPUs, else 0)")
    g.add_argument("--max-retries", type=int, default=2,
                   help="retries of a log whose worker process or node died (default: %(default)s); a log "
                        "that fails on its own input is reported, not retried")


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("convert", "convert a source dataset into a nuScenes database")
    p = sub.add_parser("av2", help="Argoverse 2 sensor logs -> nuScenes database",
                       description="Convert an AV2 split directory (or one log) into a nuScenes dataroot "
                                   "OUT/<version>/*.json + samples/ + sweeps/ + maps/. Exit code 1 when "
                                   "some logs failed (listed in OUT/convert_report.json; the others are "
                                   "written), 2 when nothing could be converted.")
    p.add_argument("src", type=path, metavar="SRC",
                   help="AV2 split dir, sensor/ dir, dataset root, or one log dir")
    p.add_argument("out", type=path, metavar="OUT", help="output nuScenes dataroot")
    p.add_argument("--mode", choices=MODES, default="native",
                   help="native: keep AV2's own cameras and images (the paper's AV2 baseline); "
                        "warp: fast depth-warp of the source images into the target rig; "
                        "render: Gaussian-splat reconstruction rendered in the target rig (nuAV2); "
                        "truth: a synthetic log's world rendered exactly in the target rig (the oracle)")
    p.add_argument("--rig", default=None,
                   help="warp/render/truth: target rig, a name in rig_specs/ or a spec path "
                        "(default: nuscenes)")
    p.add_argument("--scale", type=float, default=None,
                   help="warp/render/truth: target image resolution factor, e.g. 0.25 (default: 1)")
    p.add_argument("--min-confidence", type=number(float, lo=0.0, hi=1.0), default=None,
                   help="render: leave out sample times where a target camera's confidence is below this "
                        "(default: 0)")
    p.add_argument("--recon-preset", default=None,
                   help="render: reconstruction budget preset (default: default; see docs/reconstruction.md)")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], default=None,
                   help="render: where the reconstruction trains and renders; auto (default): a CUDA GPU "
                        "with gsplat when there is one (on Ray: the GPU the task was given), else the CPU")
    p.add_argument("--version", default="v1.0-nuav2", help="table directory name (default: %(default)s)")
    p.add_argument("--keyframe-hz", type=float, default=None,
                   help="sample rate; default every LiDAR sweep (10 Hz); 2 gives nuScenes-like samples")
    p.add_argument("--workers", type=int, default=1,
                   help="parallel processes, one log each (with --executor ray and no address: the slots "
                        "of the local Ray instance); in warp mode a worker with two cores to itself renders "
                        "two images at once")
    _add_executor_args(p)
    p.add_argument("--image-link", choices=["copy", "hardlink", "symlink"], default=None,
                   help="native: how the source images reach OUT (default: copy)")
    p.add_argument("--calibration", type=path, default=None,
                   help="calibration dir (egovehicle_SE3_sensor + intrinsics) for logs that ship none")
    p.add_argument("--allow-missing-cameras", action="store_true",
                   help="convert logs without (all) camera images instead of reporting them as failed")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
