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


def _figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """The figures the optimize module saves, kept instead of written."""
    from mi_svbrdf.cli import optimize as optimize_module

    figures: list = []
    monkeypatch.setattr(optimize_module, "save_figure", lambda fig, path, dpi=90: figures.append(fig))
    return figures


def _legend(ax: object) -> list[str]:
    """The legend's entries of ``ax``, each on one line."""
    return [" ".join(t.get_text().split()) for t in ax.get_legend().get_texts()]


def _bottoming_out(eligible_from: int, length: int, still_improving: bool) -> dict:
    """The chosen candidate of a selection like the bundled capture's: its three fold curves (scored every 10
    steps from 70 to 260) bottom out at 100 steps, then rise a little; the schedule decays until ``eligible_from``,
    and ``length`` is the length chosen."""
    curves = {str(k): [[n, base + (0.004 if n < 100 else 0.0) + 0.00001 * max(n - 100, 0)] for n in range(70, 261, 10)]
              for k, base in ((0, 0.013), (2, 0.015), (5, 0.023))}
    mean = sum(c[-1][1] for c in curves.values()) / len(curves)
    return {"name": "uniform", "mean": mean, "eliminated": False, "length": length, "se": None,
            "still_improving": still_improving, "eligible_from": eligible_from,
            "fold_errors": {k: mean for k in curves}, "fold_seconds": {k: 1.0 for k in curves}, "fold_curves": curves}


def _selection(row: dict) -> types.SimpleNamespace:
    sel = {"mode": "auto", "candidates": [row], "choice": row["name"], "best": row["name"], "folds": [0, 2, 5],
           "why": "uniform: the lowest mean held-out error", "fold_size": [48, 48],
           "runs": [[row["name"], int(k)] for k in row["fold_curves"]]}
    return types.SimpleNamespace(selection=sel, uncertainty=None, choice=row["name"])


def test_the_selection_chart_says_why_the_length_is_after_the_lowest_point(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Fold curves that bottom out at 100 steps while the schedule decays until 266: the band is labelled, the
    length is said to be the only one scored after the decay (not "still improving"), and the lowest point inside
    the band is named, lower than the chosen length's."""
    from mi_svbrdf.cli.optimize import write_selection

    figures = _figures(monkeypatch)
    row = _bottoming_out(266, 266, True)  # the fold fits ended before any length they may end at was scored
    write_selection(tmp_path, _selection(row), None, [f"{k:03d}.png" for k in range(6)])
    ax1, ax2 = figures[-1].axes
    legend = _legend(ax2)
    assert any(t.startswith("before step 266: the learning rate is still decaying") for t in legend), legend
    chosen = next(t for t in legend if t.startswith("its length, 266 steps"))
    assert "the only length scored after the schedule decayed" in chosen and "still" not in chosen, chosen
    lowest = next(t for t in legend if t.startswith("lowest before the schedule decayed"))
    assert "at 100 steps" in lowest and "lower, but a fit never ends there" in lowest, lowest
    assert "mean over the folds: the length is chosen on it" in legend
    ladder = " ".join(t.get_text() for t in ax1.texts)
    assert "still improving" not in ladder and "266 steps (only length after the schedule)" in ladder, ladder
    # Lengths scored after the decay, the last the best: "still falling", and the band's lowest said as it is.
    row = _bottoming_out(200, 260, True)
    write_selection(tmp_path, _selection(row), None, None)
    legend = _legend(figures[-1].axes[1])
    chosen = next(t for t in legend if t.startswith("its length, 260 steps"))
    assert "the lowest error after the schedule decayed" in chosen and "still falling" in chosen, chosen


def test_the_loss_chart_names_the_length_chosen_not_a_lowest_error(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """An early stop whose left-out photo's error rises the whole time: the dot at the length chosen (the first
    after the schedule) is not called the lowest error; the lowest, inside the labelled band, is named."""
    from mi_svbrdf.cli.optimize import write_loss_figure

    figures = _figures(monkeypatch)
    curve = [[0.01 * n, n, 0.0435 + 0.0057 * (1 - math.exp(-n / 40))] for n in range(10, 311, 10)]
    result = types.SimpleNamespace(history=[(0.0, 1, 0.1), (3.0, 300, 0.05)], phases=[("fit", 0)], steps=300,
                                   seconds=3.0, recoveries=0,
                                   held_out={"curve": curve, "eligible_from": 300, "photos": [2], "best_length": 300,
                                             "best": curve[29][2], "then": "refit"})
    write_loss_figure(tmp_path / "loss.png", result, None, [f"{k:03d}.png" for k in range(6)])
    legend = _legend(figures[-1].axes[1])
    assert not any("its lowest error" in t for t in legend), legend
    chosen = next(t for t in legend if t.startswith("the length chosen, 300 steps"))
    assert "after the schedule decayed" in chosen and "every photo then fitted that long" in chosen, chosen
    assert any(t.startswith("before step 300: the learning rate is still decaying") for t in legend), legend
    lowest = next(t for t in legend if t.startswith("lowest before the schedule decayed"))
    assert f"{curve[0][2]:.4f} at 10 steps" in lowest, lowest


def test_an_uncertainty_scale_says_its_top_is_the_percentile_rounded_up(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """The top of the scale is the 99th percentile rounded up, so fewer than 1 % of texels lie above it: the
    title gives the percentile's value and the share above, measured, and never calls the top the percentile."""
    from mi_svbrdf.cli.optimize import write_uncertainty_figure
    from mi_svbrdf.io.figures import robust_top

    figures = _figures(monkeypatch)
    spread = np.random.default_rng(0).gamma(2.0, 0.7, size=(32, 32))
    top = robust_top(spread, 99.0)
    write_uncertainty_figure(tmp_path / "normal_deg.png", "normal_deg", spread, top)
    title = " ".join(figures[-1].axes[0].get_title().split())
    above = float((spread > top).mean())
    assert above < 0.01
    assert (f"scale 0 to {top:g}°, its top the 99th percentile ({np.percentile(spread, 99):.3g}°) rounded up: "
            f"{above:.1%} of texels above it") in title, title


def test_the_scan_page_and_the_terminal_name_one_measure_alike(tmp_path: Path) -> None:
    """scan's page gives the fit's error against the photos by the name and figure optimize prints, and the stop
    reason in words."""
    import json

    from mi_svbrdf.cli.optimize import RMSE_NAME, STOP_WORDS, rmse_words
    from mi_svbrdf.cli.scan import index_html

    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "summary.json").write_text(json.dumps({"steps": 819, "seconds": 33.2, "stop_reason": "held-out",
                                                               "rerender_rmse": 0.0037, "selection": {}}))
    page = index_html(tmp_path, {"title": "scan", "frame": "tags"}, {})
    assert f"{RMSE_NAME} 0.0037" in page and rmse_words(0.0037) == f"{RMSE_NAME} 0.0037"
    assert f"({STOP_WORDS['held-out']})" in page and "(held-out)" not in page
