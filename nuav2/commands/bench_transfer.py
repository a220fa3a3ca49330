"""``nuav2 bench transfer --out DIR``: the MapGS paper's Tables 1 and 2 rerun on synthetic worlds."""

from __future__ import annotations

import argparse
import json
import shlex
import sys

from nuav2.cli import UsageError, group
from nuav2.cli_types import non_negative_int, path, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = group("bench", "benchmarks").add_parser(
        "transfer",
        help="does nuAV2 close the camera-rig gap? train a small mapping model on AV2 / nuAV2 / oracle "
        "data of synthetic worlds and score it with nuav2 eval on held-out worlds in the target rig",
        description="Generates geo-disjoint train and test worlds, converts the train worlds natively, "
        "by warp, by render and exactly (truth) into the target rig, trains one model per training set and "
        "seed, fine-tunes on fractions of the oracle set from scratch and from nuAV2, and writes "
        "transfer.json, transfer.md, curves.png and pred_vs_gt_*.png under --out. Rerunning with "
        "the same --out resumes (finished worlds, conversions and runs are reused). See "
        "docs/transfer.md.",
    )
    p.add_argument("--out", type=path, required=True, help="output folder (reused on a rerun)")
    size = p.add_mutually_exclusive_group()
    size.add_argument(
        "--quick", action="store_true", help="a smaller version (measured time in docs/transfer.md)"
    )
    size.add_argument(
        "--smoke", action="store_true", help="plumbing check: two tiny worlds, a few steps (CI)"
    )
    p.add_argument("--preset", default=None, help="synthetic realism preset (default: medium)")
    p.add_argument("--seeds", type=non_negative_int, nargs="+", default=None,
                   help="training seeds, each >= 0 (default: 0 1)")
    p.add_argument("--steps", type=positive_int, default=None, help="training steps per Table 1 run, >= 1")
    p.add_argument("--finetune-steps", type=positive_int, default=None,
                   help="training steps per Table 2 run, >= 1")
    p.add_argument("--train-worlds", type=positive_int, default=None, help="training worlds, >= 1")
    p.add_argument("--test-worlds", type=positive_int, default=None, help="test worlds, >= 1")
    p.add_argument("--recon-preset", choices=["default", "fast"], default=None,
                   help="render mode's reconstruction preset (default: fast)")
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="training runs at once, >= 1, each in its own process with one torch thread (default: 2)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip curves.png and the viz pictures")
    p.add_argument("--json", action="store_true", help="print the result JSON instead of the tables")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.transfer import run_transfer
    from nuav2.bench.transfer_config import TransferConfig
    from nuav2.bench.transfer_report import format_tables

    size = "smoke" if args.smoke else "quick" if args.quick else "full"
    overrides = {
        k: v
        for k, v in {
            "preset": args.preset,
            "seeds": tuple(args.seeds) if args.seeds else None,
            "steps": args.steps,
            "finetune_steps": args.finetune_steps,
            "train_worlds": args.train_worlds,
            "test_worlds": args.test_worlds,
            "recon_preset": args.recon_preset,
            "workers": args.workers,
        }.items()
        if v is not None
    }
    try:
        cfg = TransferConfig.for_size(size, **overrides)
    except ValueError as e:
        raise UsageError(str(e)) from e
    command = "nuav2 " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["bench"] else ""
    result = run_transfer(
        cfg,
        args.out,
        command=command or f"nuav2 bench transfer --out {args.out}",
        figures=not args.no_figures,
    )
    print(json.dumps(result) if args.json else format_tables(result))
    return 0
