"""The ``nuav2`` command's entry point. A Ctrl-C while the CLI builds its parser (its imports:
about 0.3 s) is held until it is built, then ends the run with "interrupted" and exit 130, as one
during the work does: raised inside a library's import it showed a traceback, or numpy's
"Importing the numpy C-extensions failed" (exit 1). Libraries a command loads when it runs are
inside ``cli.main``'s own handling."""

from __future__ import annotations

import signal
import sys
import threading
from typing import NoReturn


def _load_cli_held() -> bool:
    """Import the CLI and its commands with SIGINT held; True if one arrived meanwhile. A process
    that ignores SIGINT (a background job) keeps ignoring it."""
    held: list[int] = []
    hold = (threading.current_thread() is threading.main_thread()  # signal.signal's rule
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if hold:
        signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        from nuav2 import cli

        cli.build_parser()  # the commands' register() import more (numpy, av2, pyproj)
    finally:
        if hold:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    return bool(held)


def run() -> NoReturn:
    """Run the CLI; ``cli.main`` handles interrupts once the libraries are in."""
    try:
        if _load_cli_held():
            raise KeyboardInterrupt
        from nuav2.cli import main

        code = main()
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        code = 128 + signal.SIGINT
    sys.exit(code)
