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
    assert err.startswith("nuav2 convert av2: the following arguments are required: out")
