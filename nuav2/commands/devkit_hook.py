"""``nuav2 devkit-hook install|uninstall|status``: let every Python process of this environment open nuAV2
maps with the unmodified devkit, without ``import nuav2`` (an opt-in ``.pth`` start-up line)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "devkit-hook", help="install the devkit's nuAV2 map registration at Python start-up (.pth)",
        description="install: write a .pth into site-packages so that unmodified nuScenes scripts in this "
                    "environment open nuAV2 map locations without `import nuav2` (it loads only the "
                    "standalone devkit_hook file, ~15 ms, and patches the devkit lazily when it is "
                    "imported); "
                    "uninstall: remove it; status: say whether it is there.")
    p.add_argument("action", choices=("install", "uninstall", "status"))
    p.add_argument("--site-dir", type=Path, default=None,
                   help="directory to write the .pth into (default: this environment's site-packages)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import UsageError
    from nuav2.devkit_pth import default_site_dir, install, installed, uninstall

    site_dir = args.site_dir or default_site_dir()
    if not site_dir.is_dir():
        raise UsageError(f"--site-dir {site_dir}: not a directory")
    if args.action == "install":
        out = {"installed": str(install(site_dir))}
    elif args.action == "uninstall":
        removed = uninstall(site_dir)
        out = {"removed": str(removed) if removed else None}
    else:
        found = installed(site_dir)
        out = {"installed": str(found) if found else None, "site_dir": str(site_dir)}
    print(json.dumps(out))
    return 0
