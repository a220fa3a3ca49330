"""Every ``nuav2 ...`` command the README and docs/ print parses with the real CLI parser.

A renamed or removed flag, a value outside a flag's range or choices, or a command that no longer
exists makes the docs lie to the reader who copies them; this catches it without running anything.
Placeholders are filled in: ``[--flag X]`` optional groups are kept (without brackets), ``a|b``
alternatives take the first, ``<...>`` becomes a word, and an ALL-CAPS value after a flag (``N``,
``HZ``) becomes ``1``.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from nuav2.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*$")


def documented_commands() -> list[tuple[str, str]]:
    """(file:line, command) for each line in a fenced block that starts with ``nuav2 <command> `` (not an
    error message such as ``nuav2 convert: ...``); ``\\`` continuations joined, ``#`` comments cut."""
    found = []
    for path in DOCS:
        in_block, pending, start = False, "", 0
        for i, raw in enumerate(path.read_text().splitlines(), 1):
            if raw.startswith("```"):
                in_block, pending = not in_block, ""
                continue
            line = raw.split(" #")[0].rstrip()
            if not in_block:
                continue
            if pending:
                pending += " " + line.strip().rstrip("\\")
            elif re.match(r"^nuav2 [a-z-]+( |$)", line.strip()):
                pending, start = line.strip().rstrip("\\"), i
            else:
                continue
            if not line.endswith("\\"):
                found.append((f"{path.name}:{start}", pending))
                pending = ""
    return found


def argv_of(command: str) -> list[str]:
    while re.search(r"\[[^\[\]]*\]", command):
        command = re.sub(r"\[([^\[\]]*)\]", r"\1", command)
    out: list[str] = []
    for tok in shlex.split(command)[1:]:
        if tok in ("...", "…"):
            continue
        tok = re.sub(r"<[^>]*>", "X", tok.split("|")[0])
        if out and out[-1].startswith("--") and PLACEHOLDER.match(tok):
            tok = "1"
        out.append(tok)
    return out


COMMANDS = documented_commands()


def test_the_docs_print_commands():
    assert len(COMMANDS) > 40  # the scan finds them (a broken scan would pass every case vacuously)


@pytest.mark.parametrize("where, command", COMMANDS, ids=[w for w, _ in COMMANDS])
def test_a_documented_command_parses(where: str, command: str):
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv_of(command))
    except SystemExit as e:
        assert not e.code, f"{where}: {command}\n{err.getvalue().strip()}"


CITED_PATH = re.compile(r"`((?:nuav2|tests|docs|converters|rig_specs|\.ci)/[\w./-]*)`")


def test_every_repository_path_the_docs_cite_exists():
    """A module, test or file named in backticks (``nuav2/warp/harmonise.py``, ``tests/...``) exists."""
    cited, missing = 0, []
    for path in DOCS:
        for i, line in enumerate(path.read_text().splitlines(), 1):
            for m in CITED_PATH.finditer(line):
                cited += 1
                if not (ROOT / m.group(1).rstrip("/.")).exists():
                    missing.append(f"{path.name}:{i}: {m.group(1)}")
    assert cited > 100 and not missing, missing
