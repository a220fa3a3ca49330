"""Command-line entry point: argument parsing only; each command calls one library function."""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys

import nuav2.commands

_GROUPS: dict[str, argparse._SubParsersAction] = {}
_TOP: argparse._SubParsersAction | None = None


def group(name: str, help: str) -> argparse._SubParsersAction:
    """Sub-parsers of a command group (``convert``, ``bench``), created on first use."""
    if name not in _GROUPS:
        assert _TOP is not None
        p = _TOP.add_parser(name, help=help)
        _GROUPS[name] = p.add_subparsers(dest=f"{name}_cmd", required=True, metavar="KIND")
    return _GROUPS[name]


def build_parser() -> argparse.ArgumentParser:
    global _TOP
    _GROUPS.clear()
    parser = argparse.ArgumentParser(
        prog="nuav2", description="Argoverse 2 -> nuScenes databases, re-rendered into any camera rig.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    _TOP = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for mod in sorted(pkgutil.iter_modules(nuav2.commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"nuav2.commands.{mod.name}").register(_TOP)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
