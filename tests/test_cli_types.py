"""Flag values are checked while parsing: finite, within bounds, one line naming the flag."""

from __future__ import annotations

import argparse

import pytest

from nuav2.cli import main
from nuav2.cli_types import number, positive_float, positive_int


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "x", "0", "-1"])
def test_positive_float_refuses_what_is_not(text):
    with pytest.raises(argparse.ArgumentTypeError):
        positive_float(text)


def test_bounds_and_kinds():
    assert positive_float("0.25") == 0.25 and positive_int("3") == 3
    with pytest.raises(argparse.ArgumentTypeError, match="not an integer"):
        positive_int("1.5")
    half_open = number(float, lo=0, hi=1, hi_open=True)
    assert half_open("0") == 0.0
    with pytest.raises(argparse.ArgumentTypeError, match="must be < 1"):
        half_open("1")


def test_a_usage_error_is_one_line_naming_the_command(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["convert", "av2", "src"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert err.startswith("nuav2 convert av2: the following arguments are required: OUT")


@pytest.mark.parametrize("argv, prog", [(["split", "db", "--val-fraction", "2"], "nuav2 split"),
                                        (["bench", "loader", "--foo"], "nuav2 bench loader"),
                                        (["convert", "av2", "a", "b", "--bar"], "nuav2 convert av2")])
def test_an_unknown_flag_is_blamed_on_the_sub_command_that_was_given_it(argv, prog, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    unknown = " ".join(a for a in argv if a.startswith("--") or a == "2")
    assert err == f"{prog}: unrecognized arguments: {unknown} (see '{prog} --help')\n"


def test_a_second_sigterm_is_ignored_during_cleanup_but_a_later_one_raises_again():
    """A swallowed Terminated (third-party bare ``except:``) must not make the process unkillable."""
    from nuav2 import cli

    cli._TERMINATED.clear()
    try:
        with pytest.raises(cli.Terminated):
            cli._raise_terminated(15, None)
        assert cli._raise_terminated(15, None) is None  # within the grace: the cleanup goes on
        cli._TERMINATED[-1] -= cli.TERMINATE_GRACE_S + 1
        with pytest.raises(cli.Terminated):
            cli._raise_terminated(15, None)
    finally:
        cli._TERMINATED.clear()
