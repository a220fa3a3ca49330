"""Command-line entry point: argument parsing only; each command calls one library function.

Errors: whatever a command raises on bad input becomes one line on stderr, ``nuav2 <command>:
<what is wrong>`` naming the file or flag, and exit code 2; ``nuav2 -v <command> ...`` shows the
traceback too. Commands raise :class:`UsageError` for a bad argument they detect themselves.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import pkgutil
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

import nuav2.commands
from nuav2.cli_types import OneLineParser

log = logging.getLogger(__name__)
_GROUPS: dict[str, argparse._SubParsersAction] = {}
_TOP: argparse._SubParsersAction | None = None
EXIT_BAD_INPUT = 2
# Exceptions that mean "the input is wrong" (their message says what and where); anything else is
# reported the same way but flagged as an internal error.
INPUT_ERRORS = (OSError, ValueError, LookupError, AssertionError, UnicodeError)


class UsageError(ValueError):
    """A command-line argument is wrong; the message names the flag or path."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``docker stop``, a batch scheduler): unwound like Ctrl-C, so every
    half-written file is removed on the way out, instead of the process dying where it stands."""


# When the handler ran: code between it and main (Ray's wait) may re-raise a plain Ctrl-C.
_TERMINATED: list[float] = []


# A second SIGTERM this soon after the first must not cut the cleanup short; a later one raises
# again, so a Terminated that third-party code swallowed (a bare ``except:``) is not the last word.
TERMINATE_GRACE_S = 10.0


def _raise_terminated(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    now = time.monotonic()
    if _TERMINATED and now - _TERMINATED[-1] < TERMINATE_GRACE_S:
        return
    _TERMINATED.append(now)
    raise Terminated()


def require_database(dataroot: str | Path, version: str | None) -> str:
    """The table folder to read: ``version`` (None: the only one in DATAROOT, :func:`resolve_version`)
    when it holds nuScenes tables, else a UsageError naming ``--version`` / DATAROOT and what exists."""
    version = resolve_version(dataroot, version)
    root = Path(dataroot)
    if not root.is_dir():
        raise UsageError(f"{root}: dataroot not found")
    folder = root / version
    if not (folder / "scene.json").is_file():
        raise UsageError(f"--version {version}: {folder} holds no nuScenes tables "
                         f"(versions in {root}: {', '.join(versions_in(root)) or 'none'})")
    return version


def resolve_version(dataroot: str | Path, version: str | None) -> str:
    """``--version`` as given, else the only table folder under DATAROOT (the common case: one
    conversion per dataroot); none or several is a UsageError that lists what is there."""
    if version is not None:
        return version
    root = Path(dataroot)
    if not root.is_dir():
        raise UsageError(f"{root}: dataroot not found")
    found = versions_in(root)
    if len(found) != 1:
        what = f"several ({', '.join(found)})" if found else "none (no folder with a scene.json)"
        raise UsageError(f"--version: give the table folder; {root} holds {what}")
    log.info("--version %s (the only table folder in %s)", found[0], root)
    return found[0]


def versions_in(root: Path) -> list[str]:
    """The table folders (holding a scene.json) directly under a dataroot, for error messages."""
    return sorted(p.name for p in root.iterdir() if (p / "scene.json").is_file())


def describe_error(e: BaseException) -> str:
    """One line saying what went wrong, naming the file where the exception knows it."""
    if isinstance(e, OSError) and e.filename is not None:
        where = f"{e.filename}" + (f" -> {e.filename2}" if e.filename2 is not None else "")
        msg = f"{where}: {e.strerror or e}"
    elif isinstance(e, KeyError):
        msg = f"not found: {e.args[0]!r}" if e.args else "KeyError"
    elif isinstance(e, INPUT_ERRORS):
        msg = str(e) or type(e).__name__
    else:
        msg = f"internal error: {type(e).__name__}: {e} (rerun as 'nuav2 -v ...' for the traceback)"
    return " ".join(msg.split())


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
    parser = OneLineParser(
        prog="nuav2", description="Argoverse 2 -> nuScenes databases, re-rendered into any camera rig.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    _TOP = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for mod in sorted(pkgutil.iter_modules(nuav2.commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"nuav2.commands.{mod.name}").register(_TOP)
    return parser


def _log_above_progress_bars():
    """On a terminal, log lines are printed above the tqdm bars instead of onto the bar's line."""
    from nuav2.progress import stderr_is_tty

    if not stderr_is_tty():
        return contextlib.nullcontext()
    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm()


def _leaf_parser(args: argparse.Namespace) -> argparse.ArgumentParser:
    """The sub-command's own parser (``nuav2 bench loader``), so its errors name it, not ``nuav2``."""
    assert _TOP is not None
    leaf = _TOP.choices[args.command]
    kind = getattr(args, f"{args.command}_cmd", None)
    if args.command in _GROUPS and kind is not None:
        leaf = _GROUPS[args.command].choices[kind]
    return leaf


def _stopped() -> int:
    """Say how the run was stopped (Ctrl-C or SIGTERM) and return the shell's code for it."""
    if _TERMINATED:  # set by the SIGTERM handler, whatever KeyboardInterrupt reached us
        print("terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    print("interrupted", file=sys.stderr)
    return 130


def _raised_by_interrupt(e: BaseException) -> bool:
    """An error raised while a Ctrl-C unwound: numba's dispatcher, for one, turns a KeyboardInterrupt
    caught in compiled code into "SystemError: CPUDispatcher(...) returned a result with an
    exception set", which would read as an internal error."""
    seen: set[int] = set()
    cause: BaseException | None = e
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # argparse would blame the top-level parser; the sub-command owns the flags
        _leaf_parser(args).error(f"unrecognized arguments: {' '.join(unknown)}")
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    in_main_thread = threading.current_thread() is threading.main_thread()  # signal.signal's rule
    _TERMINATED.clear()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main_thread else None
    try:
        with _log_above_progress_bars():
            code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not as "Exception ignored" at exit
        return code
    except KeyboardInterrupt:
        return _stopped()
    except BrokenPipeError:  # stdout closed early (`nuav2 ... | head`): stop quietly, as Unix tools do
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except Exception as e:  # noqa: BLE001 - the one place errors become a message and an exit code
        if _raised_by_interrupt(e):
            return _stopped()
        if args.verbose:
            traceback.print_exc()
        print(f"nuav2 {args.command}: {describe_error(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
