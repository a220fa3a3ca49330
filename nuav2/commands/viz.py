"""``nuav2 viz DATAROOT --version V --sample TOKEN --out x.png``: cameras + BEV with map vectors drawn."""

from __future__ import annotations

import argparse
from pathlib import Path

from nuav2.cli_types import number

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")  # what the picture is written as (by OpenCV)
TILE_HEIGHT_RANGE = (16, 4320)  # pixels: below, the labels do not fit; above 8K, memory explodes


def image_path(text: str) -> Path:
    """An ``--out`` path whose suffix names a supported image format (refused while parsing)."""
    path = Path(text)
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a supported image file name: it must end in {', '.join(IMAGE_SUFFIXES)}")
    return path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "viz",
        help="draw a keyframe's map GT (and MapTR predictions) into its cameras and a BEV panel",
        description="Camera images with the vectorized map projected onto the ground and a BEV panel "
        "(divider yellow, boundary red, crossing blue, centerline green).",
    )
    p.add_argument("dataroot", type=Path, help="nuScenes-format dataroot")
    p.add_argument("--version", help="table folder under DATAROOT (default: the only one there)")
    p.add_argument("--sample", required=True, help="sample token")
    p.add_argument("--out", required=True, type=image_path, help="output image (.png, .jpg or .jpeg)")
    p.add_argument("--pred", type=Path, default=None, help="MapTR-format results json to overlay")
    p.add_argument("--score-thr", type=number(float, lo=0, hi=1), default=0.4,
                   help="minimum prediction confidence drawn, in [0, 1] (default 0.4)")
    p.add_argument("--tile-height", type=number(int, *TILE_HEIGHT_RANGE), default=270,
                   help=f"height of each camera tile in pixels ({TILE_HEIGHT_RANGE[0]} to "
                        f"{TILE_HEIGHT_RANGE[1]}; default 270)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import require_database
    from nuav2.cli_inputs import diagnosed_tables, require_out_path
    from nuav2.viz import render

    require_out_path(args.out)
    args.version = require_database(args.dataroot, args.version)
    with diagnosed_tables(args.dataroot, args.version):
        out = render(
            args.dataroot, args.version, args.sample, args.out, args.pred, args.score_thr, args.tile_height
        )
    print(out)
    return 0
