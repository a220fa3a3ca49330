"""What the bench commands, ``synth`` and the demo share on the command line: the exact command (every
report carries it, so a reader can rerun it), the argparse types of the synthetic-log flags (the bounds
``nuav2.synth.SynthConfig`` checks, so a bad value is refused while parsing, naming the flag), and
list-valued flags (``--preset easy,hard``, ``--seconds 2,15``), checked before any work."""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Callable

from nuav2.cli_types import non_negative_int, number, positive_float

# SynthConfig's checks as argparse types: seconds must give at least one 10 Hz sweep (round(10 s) >= 1,
# so strictly more than 0.05 s), cameras a resolution factor > 0, lidar at least 8 rays per beam.
synth_seconds = number(float, lo=0.05, lo_open=True, hi=3600.0)  # an hour: real AV2 logs run 15-30 s
synth_image_scale = number(float, lo=0.0, lo_open=True, hi=8.0)  # = nuav2.synth.config.MAX_IMAGE_SCALE
lidar_azimuth_steps = number(int, lo=8)


def command_line(argv: list[str] | None = None) -> str:
    """``nuav2 ...`` as invoked (the program path replaced by ``nuav2``), shell-quoted."""
    args = sys.argv[1:] if argv is None else argv
    return shlex.join(["nuav2", *args])


def _parse_list(text: str, flag: str, item: Callable[[str], float], noun: str) -> tuple:
    """Each comma-separated entry of ``text`` through ``item`` (a ``nuav2.cli_types`` parser); an empty
    list or a bad entry is a UsageError naming ``flag`` and what is wrong."""
    from nuav2.cli import UsageError

    entries = [x.strip() for x in text.split(",") if x.strip()]
    if not entries:
        raise UsageError(f"{flag}: expected comma-separated {noun}, got {text!r}")
    try:
        return tuple(item(x) for x in entries)
    except argparse.ArgumentTypeError as e:
        raise UsageError(f"{flag}: expected comma-separated {noun}, got {text!r} ({e})") from None


def parse_floats(text: str, flag: str, item: Callable[[str], float] = positive_float) -> tuple[float, ...]:
    """``"2,15"`` -> (2.0, 15.0); each entry must pass ``item`` (default: finite and > 0), else a
    UsageError naming ``flag``."""
    return _parse_list(text, flag, item, "numbers")


def parse_ints(text: str, flag: str, item: Callable[[str], float] = non_negative_int) -> tuple[int, ...]:
    """``"0,1,2"`` -> (0, 1, 2); each entry must pass ``item`` (default: an integer >= 0, e.g. a seed),
    else a UsageError naming ``flag``."""
    return _parse_list(text, flag, item, "integers")


def parse_presets(text: str, flag: str = "--preset") -> list[str]:
    """``"easy,hard"`` or ``"all"`` -> synthetic realism presets in the given order; unknown names are an
    error naming ``flag``."""
    from nuav2.synth import PRESETS

    names = list(PRESETS) if text.strip() == "all" else [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in names if p not in PRESETS]
    if bad or not names:
        raise ValueError(f"{flag}: unknown preset(s) {bad or [text]}; known: {', '.join(PRESETS)} (or all)")
    return list(dict.fromkeys(names))


def check_rig(name_or_path: str, flag: str = "--rig") -> None:
    """Load the target rig the way ``convert`` does (built-in name or JSON path); a bad one is a
    UsageError naming ``flag``, raised before any log is synthesised."""
    from nuav2.cli import UsageError
    from nuav2.rig import RigSpecError, load_rig

    try:
        load_rig(name_or_path)
    except RigSpecError as e:
        raise UsageError(f"{flag}: {e}") from None


def require_outputs(args: argparse.Namespace) -> None:
    """Refuse an unusable ``--out`` / ``--markdown`` / ``--plot`` before a benchmark's minutes of work
    (a folder that is a file only failed at the end, after all of it)."""
    from nuav2.cli_inputs import require_out_path

    for name in ("out", "markdown", "plot"):
        require_out_path(getattr(args, name, None), f"--{name}")
