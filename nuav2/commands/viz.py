"""``nuav2 viz DATAROOT --version V --sample TOKEN --out x.png``: cameras + BEV with map vectors drawn."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "viz",
        help="draw a keyframe's map GT (and MapTR predictions) into its cameras and a BEV panel",
        description="Camera images with the vectorized map projected onto the ground and a BEV panel "
        "(divider yellow, boundary red, crossing blue, centerline green).",
    )
    p.add_argument("dataroot", type=Path, help="nuScenes-format dataroot")
    p.add_argument("--version", required=True, help="table folder under DATAROOT")
    p.add_argument("--sample", required=True, help="sample token")
    p.add_argument("--out", required=True, type=Path, help="output image (.png or .jpg)")
    p.add_argument("--pred", type=Path, default=None, help="MapTR-format results json to overlay")
    p.add_argument("--score-thr", type=float, default=0.4, help="minimum prediction confidence drawn")
    p.add_argument("--tile-height", type=int, default=270, help="height of each camera tile in pixels")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import require_database
    from nuav2.viz import render

    require_database(args.dataroot, args.version)
    out = render(
        args.dataroot, args.version, args.sample, args.out, args.pred, args.score_thr, args.tile_height
    )
    print(out)
    return 0
