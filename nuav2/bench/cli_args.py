"""What the bench commands and the demo share on the command line: the exact command (every report
carries it, so a reader can rerun it) and list-valued flags (``--preset easy,hard``, ``--seconds 2,15``)."""

from __future__ import annotations

import shlex
import sys


def command_line(argv: list[str] | None = None) -> str:
    """``nuav2 ...`` as invoked (the program path replaced by ``nuav2``), shell-quoted."""
    args = sys.argv[1:] if argv is None else argv
    return shlex.join(["nuav2", *args])


def parse_floats(text: str, flag: str) -> tuple[float, ...]:
    """``"2,15"`` -> (2.0, 15.0); anything else is an error naming ``flag``."""
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        values = ()
    if not values or any(not v > 0 for v in values):
        raise ValueError(f"{flag}: expected comma-separated numbers > 0, got {text!r}")
    return values


def parse_ints(text: str, flag: str) -> tuple[int, ...]:
    """``"0,1,2"`` -> (0, 1, 2); anything else is an error naming ``flag``."""
    try:
        values = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        values = ()
    if not values:
        raise ValueError(f"{flag}: expected comma-separated integers, got {text!r}")
    return values


def parse_presets(text: str, flag: str = "--preset") -> list[str]:
    """``"easy,hard"`` or ``"all"`` -> synthetic realism presets in the given order; unknown names are an
    error naming ``flag``."""
    from nuav2.synth import PRESETS

    names = list(PRESETS) if text.strip() == "all" else [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in names if p not in PRESETS]
    if bad or not names:
        raise ValueError(f"{flag}: unknown preset(s) {bad or [text]}; known: {', '.join(PRESETS)} (or all)")
    return list(dict.fromkeys(names))
