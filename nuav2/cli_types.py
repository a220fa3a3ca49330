"""argparse ``type=`` checks shared by every command: a bad value is refused while parsing,
before any work, with argparse's "argument --flag: ..." naming the flag.

``number(kind, lo=..., hi=...)`` accepts finite values only (``nan`` and ``inf`` are refused
even without bounds); bounds are inclusive unless ``lo_open`` / ``hi_open``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def number(kind: type = float, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, hi_open: bool = False) -> Callable[[str], float]:
    """A parser of one finite ``kind`` (int or float) within [lo, hi] (open ends if asked)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            raise argparse.ArgumentTypeError(f"must be {'>' if lo_open else '>='} {lo:g}, got {text}")
        if hi is not None and (value >= hi if hi_open else value > hi):
            raise argparse.ArgumentTypeError(f"must be {'<' if hi_open else '<='} {hi:g}, got {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


positive_int = number(int, lo=1)
non_negative_int = number(int, lo=0)
positive_float = number(float, lo=0, lo_open=True)
non_negative_float = number(float, lo=0)
finite_float = number(float)


def path(text: str):
    """A path argument: ``Path("")`` is ``.``, so an empty one (an unset shell variable) would
    silently mean the current folder; it is refused instead."""
    from pathlib import Path

    if not text:
        raise argparse.ArgumentTypeError("empty path")
    return Path(text)


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the command and the flag (as every other
    error of the CLI is), pointing at ``--help`` instead of printing the usage block."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {' '.join(message.split())} (see '{self.prog} --help')\n")
