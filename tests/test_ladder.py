"""The resolution ladder: levels from LADDER_BASE up to the photos' size, its starts on the first rung, and the
CLI's --levels auto in words and in summary.json."""
from __future__ import annotations

import json

import pytest

import mi_svbrdf.optim.fit as fit
from mi_svbrdf.cli.optimize import main as cli_main
from mi_svbrdf.optim.fit import OptimizeConfig, ladder_levels, ladder_sizes
from tests.test_optimize import synthetic
from tests.test_optimize_fused import capture


@pytest.mark.parametrize(("h", "w", "levels"), [(16, 16, 1), (256, 256, 1), (257, 257, 2), (512, 512, 2),
                                                (1024, 1024, 3), (600, 800, 3), (2048, 1536, 4), (1, 1, 1)])
def test_ladder_levels_put_the_first_rung_at_or_below_the_base(h: int, w: int, levels: int) -> None:
    assert ladder_levels(h, w) == levels
    first = ladder_sizes(h, w, levels)[0]
    assert max(first) <= fit.LADDER_BASE or levels == 1
    if levels > 1:  # the rung below would also fit: the ladder is no longer than it needs to be
        assert max(ladder_sizes(h, w, levels - 1)[0]) > fit.LADDER_BASE
    assert ladder_sizes(h, w, levels)[-1] == (h, w)


def test_ladder_levels_reject_bad_sizes() -> None:
    with pytest.raises(ValueError, match="base: expected an int >= 1, got 0"):
        ladder_levels(64, 64, base=0)
    with pytest.raises(ValueError, match="expected sizes >= 1"):
        ladder_levels(0, 0)


def test_a_ladders_starts_run_on_its_first_rung_and_each_level_is_recorded(forward_sizes: list) -> None:
    sizes = forward_sizes
    _, spec, images = capture(32, 4)
    cfg = OptimizeConfig(iterations=200, levels=3, start_iterations=5, progress=False, early_stop="off")
    res = fit.optimize(spec, images, config=cfg)
    # two roughness starts at 8x8, then the rungs 8x8, 16x16, 32x32
    assert sizes == [(8, 8), (8, 8), (16, 16), (32, 32)], sizes
    assert [lv["size"] for lv in res.levels] == [[8, 8], [16, 16], [32, 32]]
    assert sum(lv["steps"] for lv in res.levels) + 2 * 5 == res.steps
    assert all(lv["seconds"] >= 0 for lv in res.levels)


def test_cli_levels_auto_says_the_ladder(tmp_path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    import mi_svbrdf.cli.optimize as optimize_cli
    monkeypatch.setattr(optimize_cli, "ladder_levels", lambda h, w: ladder_levels(h, w, base=16))
    synthetic(tmp_path / "cap", 32, 3)
    out = tmp_path / "out"
    assert cli_main(["--capture", str(tmp_path / "cap" / "capture.json"), "-o", str(out), "--iterations", "40",
                     "--no-progress", "--select", "off"]) == 0
    ladder = json.loads((out / "summary.json").read_text())["ladder"]
    assert ladder["levels"] == 2 and ladder["asked"] == "auto" and ladder["sizes"] == [[16, 16], [32, 32]]
    assert ladder["words"] == ("fits 16x16, then 32x32, each level started from the one below "
                               "(--levels auto: 2 levels)")
    assert [run["size"] for run in ladder["runs"]][-2:] == [[16, 16], [32, 32]]
    assert f"ladder: {ladder['words']}" in capsys.readouterr().err
    again = tmp_path / "again"
    assert cli_main(["--capture", str(tmp_path / "cap" / "capture.json"), "-o", str(again), "--iterations", "20",
                     "--no-progress", "--select", "off", "--levels", "1"]) == 0
    one = json.loads((again / "summary.json").read_text())["ladder"]
    assert one["levels"] == 1 and one["asked"] == 1 and one["words"] == "fits at the photos' 32x32 (--levels 1: one level)"


def test_cli_levels_refuses_words_other_than_auto(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        cli_main(["--capture", "example", "-o", str(tmp_path / "o"), "--levels", "many"])
    assert exc.value.code == 2
    assert "--levels: expected an integer >= 1, got 'many'" in capsys.readouterr().err


@pytest.mark.parametrize(("side", "budget"), [(16, 60.0), (256, 60.0), (384, 90.0), (512, 120.0), (1024, 240.0),
                                              (4096, 240.0)])
def test_the_default_budget_grows_with_the_side_up_to_its_cap(side: int, budget: float) -> None:
    assert fit.default_budget(side, side // 2 or 1) == budget == fit.default_budget(side // 2 or 1, side)


def test_cli_says_the_default_budget_with_the_ladder(tmp_path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    import mi_svbrdf.cli.optimize as optimize_cli
    monkeypatch.setattr(optimize_cli, "ladder_levels", lambda h, w: ladder_levels(h, w, base=16))
    synthetic(tmp_path / "cap", 32, 3)
    assert cli_main(["--capture", str(tmp_path / "cap" / "capture.json"), "-o", str(tmp_path / "out"),
                     "--iterations", "10", "--no-progress", "--select", "off"]) == 0
    assert "; --budget-s 60 (the default for 32x32 photos)" in capsys.readouterr().err
