"""``nuav2 devkit-hook install|uninstall|status``: let every Python process of this environment open nuAV2
maps with the unmodified devkit, without ``import nuav2`` (an opt-in ``.pth`` start-up line)."""

from __future__ import annotations

import argparse
import json
import sys

from nuav2.cli_types import path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "devkit-hook", help="install the devkit's nuAV2 map registration at Python start-up (.pth)",
        description="install: write a .pth into site-packages so that unmodified nuScenes scripts in this "
                    "environment open nuAV2 map locations without `import nuav2` (it loads only the "
                    "standalone devkit_hook file, about 8 ms, and patches the devkit lazily when it is "
                    "imported); "
                    "uninstall: remove it; status: say whether it is there.")
    p.add_argument("action", choices=("install", "uninstall", "status"))
    p.add_argument("--site-dir", type=path, default=None,
                   help="directory to write the .pth into (default: this environment's site-packages)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import UsageError
    from nuav2.devkit_pth import default_site_dir, install, status, uninstall

    site_dir = args.site_dir or default_site_dir()
    if not site_dir.is_dir():
        raise UsageError(f"--site-dir {site_dir}: not a directory")
    try:
        if args.action == "install":
            out = {"installed": str(install(site_dir))}
        elif args.action == "uninstall":
            removed = uninstall(site_dir)
            out = {"removed": str(removed) if removed else None}
        else:
            out = {**status(site_dir), "site_dir": str(site_dir)}
    except OSError as e:
        raise UsageError(f"--site-dir {site_dir}: cannot {args.action} there ({e.strerror or e})") from e
    print(json.dumps(out))
    if args.action == "status" and out["installed"] and not out["current"]:
        print(f"nuav2 devkit-hook: {out['installed']} is not this installation's hook (left by another "
              "checkout?): run `nuav2 devkit-hook install` again", file=sys.stderr)
        return 1
    return 0
