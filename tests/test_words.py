"""What the commands say agrees with what they do: a flag refused in one line and the same way everywhere; the
figures' labels say what the picture shows (why a length was chosen, what the lowest point was); one measure of
the re-renderings' error under one name; summary.json naming the maps kept. Cheap: no fit runs here."""
from __future__ import annotations

import math
import types
from pathlib import Path

import numpy as np
import pytest

from mi_svbrdf import cli


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``mi-svbrdf ARGV`` in this process: (exit code, stderr); argparse's exit counts as a code."""
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize("argv", [["optimize", "--capture", "example", "--budget-s", "-5"],
                                  ["capture", "example", "--budget-s", "-5"],
                                  ["scan", "example", "--budget-s", "-5"]])
def test_a_bad_budget_is_one_line_and_the_same_words_everywhere(argv: list[str], tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """A value out of range is one line, no usage block, and every --budget-s refuses it with the same words."""
    code, err = _run([*argv, "-o", str(tmp_path / "o")], capsys)
    assert code == 2
    assert err.splitlines() == [f"mi-svbrdf {argv[0]}: error: argument --budget-s"
                                + ("/--budget" if argv[0] == "scan" else "")
                                + ": expected seconds >= 0 (0 or inf: no limit), got '-5'"], err
    assert not (tmp_path / "o").exists()


def test_every_budget_takes_0_and_inf_as_no_limit() -> None:
    """0 means no limit wherever --budget-s is read: capture's refinement as optimize's and scan's fit."""
    from mi_svbrdf.cli.common import budget_seconds

    parser = cli.build_parser(["optimize", "capture", "scan"])
    for words in (["optimize", "--capture", "example"], ["capture", "example"], ["scan", "example"]):
        for text, seconds in (("0", math.inf), ("inf", math.inf), ("2.5", 2.5)):
            args = parser.parse_args([*words, "-o", "x", "--budget-s", text])
            assert args.budget_s == seconds == budget_seconds(text), (words, text)


def test_a_missing_argument_keeps_the_usage(capsys: pytest.CaptureFixture[str]) -> None:
    """Only an argument's value is one line: a missing argument still shows how the command is spelled."""
    code, err = _run(["optimize", "-o", "x"], capsys)
    assert code == 2 and err.startswith("usage: mi-svbrdf optimize ") and "required: --capture" in err, err
