"""Honest progress and reports: the evaluation's estimate from measured rows, the reduced run's caveat, the
optimisation benchmark's targets, and ``train --no-progress`` and its last line."""
from __future__ import annotations

import importlib.util
import json
import math
import re
import types
from pathlib import Path

import pytest
import torch

from mi_svbrdf.cli import train as train_cli
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.eval import report, runner
from mi_svbrdf.nets import train as training

ROOT = Path(__file__).resolve().parent.parent
TINY_NET = {"encoder_features": [8, 16, 16], "last_features": 8, "resolution": 32}
#: What a tqdm bar writes (its rate or its bar).
BAR = re.compile(r"it/s|s/it|\d+%\|")


def _data(size: int) -> types.SimpleNamespace:
    """A stand-in dataset: the estimate reads only the photos' height."""
    return types.SimpleNamespace(inputs=torch.empty(0, 1, 3, size, size))


# ----------------------------------------------------------------------------- evaluate: the estimate
def test_the_first_row_of_each_setting_is_timed_first() -> None:
    held, case = _data(64), _data(128)
    t1, t3, o3 = runner.Job("trivial", 1, None), runner.Job("trivial", 3, None), runner.Job("optimize", 3, 4.0)
    todo = [(t1, held, 0), (t1, held, 1), (t3, held, 0), (o3, held, 0), (o3, held, 1), (t1, case, 0), (t1, case, 1)]
    timed, rest = runner.timing_rows_first(todo)
    assert timed == [(t1, held, 0), (t3, held, 0), (o3, held, 0), (t1, case, 0)]  # one per (job, size)
    assert rest == [(t1, held, 1), (o3, held, 1), (t1, case, 1)]


def test_estimate_from_measured_rows_hand_computed() -> None:
    config = runner.EvalConfig(size=64, materials=4, n_images=(1, 3), budgets=(4.0,), refine_budgets=(4.0,),
                               stability_materials=2, stability_trials=1)
    measured = {("trivial", 1, None, 64): 0.1, ("optimize", 1, 4.0, 64): 2.0, ("optimize", 5, 4.0, 64): 3.0}
    held, case = _data(64), _data(128)
    rest = [(runner.Job("trivial", 1, None), held, 1)] * 3 + [(runner.Job("optimize", 4, 4.0), held, 1)] * 2 \
        + [(runner.Job("trivial", 1, None), case, 0)]
    stab = [runner.Job("trivial", 3, None), runner.Job("optimize", 3, 4.0)]
    est = runner.measured_estimate(rest, measured, stab, config, real_checks=True)
    # trivial 3 x 0.1; optimize N=4 takes the nearest N's (5: 3.0 s) twice; the 128^2 case row 4 x 0.1
    assert est.rows == pytest.approx(0.3 + 6.0 + 0.4)
    assert est.worst_rows == pytest.approx(0.3 + 2 * 6.0 + 0.4)  # a fit may run to 1.5 x its 4 s budget
    # stability: 2 materials x (4 + 1 trials) calls of trivial (0.1 s) and of optimize at N=3 (nearest: 1 and 5,
    # equally near; the faster one is taken)
    assert est.stability == pytest.approx(10 * 0.1 + 10 * 2.0)
    assert est.total == pytest.approx(est.rows + est.stability + runner.REAL_CHECKS_S + runner.REPORT_S)
    # a method timed at no size or budget of the job: the a-priori figure (estimate_seconds)
    refine = runner.Job("refine", 3, 4.0)
    assert runner.row_seconds(measured, refine, 64, config) == runner.estimate_seconds([refine], 1, config)[0]
    # the uncalibrated refinement untimed: its budget x 1.05 plus the row overhead (1.5 s at 256^2, / 16 at 64^2)
    uncal = runner.Job("uncalibrated", 3, 4.0)
    assert runner.row_seconds(measured, uncal, 64, config) == pytest.approx(4.2 + 1.5 / 16)
    # timed at N = 1: the nearest N's time, like every method; its stability calls priced the same way
    timed = {**measured, ("uncalibrated", 1, 4.0, 64): 5.0}
    assert runner.row_seconds(timed, uncal, 64, config) == 5.0
    est = runner.measured_estimate([(uncal, held, 1)], timed, [uncal], config, real_checks=False)
    assert est.rows == 5.0 and est.worst_rows == 6.0 and est.stability == pytest.approx(10 * 5.0)


def test_evaluate_logs_the_estimate_and_the_time_taken(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    config = runner.quick_config(size=32, materials=2, n_images=(1, 2), methods=("trivial",), sets=("heldout",),
                                 real_checks=False, stability_materials=1)
    lines: list[str] = []
    rows = runner.run_evaluation(config, tmp_path / "report", progress=False, log=lines.append)
    assert len(rows) == 4
    text = "\n".join(lines)
    assert "4 rows to run (0 already done); timing the first row of each of the 2 method settings" in text
    estimate = re.search(r"estimated (\d+\.\d) min left, from this run's timed rows at 32\^2 \(trivial [\d.]+ s", text)
    assert estimate, text
    assert "2 rows" in text and "stability table" in text and re.search(r"took \d+\.\d min \(estimated", text)


# ----------------------------------------------------------------------------- evaluate: the reduced run's caveat
def _rows(values: dict[tuple[str, int, float | None], list[float]], stop: str = "converged") -> list[dict]:
    return [{"dataset": "heldout", "material": m, "method": method, "n": n, "budget_s": budget, "rmse_render": v,
             "stop_reason": stop if budget is not None else ""}
            for (method, n, budget), vs in values.items() for m, v in enumerate(vs)]


def test_reduced_run_says_what_it_can_and_cannot_show() -> None:
    rows = _rows({("trivial", 1, None): [0.10, 0.20, 0.30, 0.40], ("single", 1, None): [0.11, 0.21, 0.31, 0.41],
                  ("multi", 1, None): [0.13, 0.17, 0.35, 0.36], ("refine", 1, 4.0): [0.12, 0.18, 0.33, 0.37]},
                 stop="budget")
    md = "\n".join(report.small_run_section(rows, size=128))
    assert "## What this run can and cannot show" in md
    assert "4 held-out materials (full run: 16), 128^2 (full run: 256^2), optimiser budgets up to 4 s" in md
    # single is worse than trivial on every material by 0.01: resolved; multi vs trivial is not
    assert "| single N=1 − trivial N=1 | 4 | +0.0100 | 0.0000 | single N=1 worse |" in md
    assert re.search(r"\| multi N=1 − trivial N=1 \| 4 \| \+0\.0\d+ \| [\d.]+ \| within noise \|", md)
    assert "| refine 4s N=1 − multi N=1 |" in md and "4 of 4 optimiser and refinement fits stopped on their budget" in md
    assert "2 of 3 comparisons are within noise" in md


def test_reduced_run_compares_the_uncalibrated_refinement_with_the_net_and_the_calibrated_one() -> None:
    rows = _rows({("multi", 1, None): [0.13, 0.17, 0.35, 0.36], ("refine", 1, 4.0): [0.12, 0.18, 0.33, 0.37]},
                 stop="converged")
    # 3 of its 4 fits stopped on the budget; one kept the net's maps (its flash photo unusable)
    rows += [dict(r, stop_reason=stop) for r, stop in zip(
        _rows({("uncalibrated", 1, 4.0): [0.125, 0.185, 0.335, 0.375]}), ("budget", "budget", "budget", "unfitted"))]
    rows += _rows({("uncalibrated", 1, 8.0): [0.13, 0.17, 0.35, 0.36]}, stop="budget")  # no refine at 8 s
    pairs = {(p["a"], p["b"]): p for p in report.paired_differences(rows)}
    assert set(pairs) == {("refine 4s N=1", "multi N=1"), ("uncalibrated 4s N=1", "multi N=1"),
                          ("uncalibrated 4s N=1", "refine 4s N=1"), ("uncalibrated 8s N=1", "multi N=1")}
    # against the net: -0.005, +0.015, -0.015, +0.015; against the calibrated refinement: +0.005 on each material
    assert pairs[("uncalibrated 4s N=1", "multi N=1")]["diff"] == pytest.approx(0.0025)
    assert not pairs[("uncalibrated 4s N=1", "multi N=1")]["resolved"]
    calibrated = pairs[("uncalibrated 4s N=1", "refine 4s N=1")]
    assert calibrated["diff"] == pytest.approx(0.005) and calibrated["se"] == pytest.approx(0.0, abs=1e-12)
    assert pairs[("uncalibrated 8s N=1", "multi N=1")]["diff"] == pytest.approx(0.0, abs=1e-12)
    md = "\n".join(report.small_run_section(rows, size=128))
    assert "| uncalibrated 4s N=1 − refine 4s N=1 | 4 | +0.0050 | 0.0000 | uncalibrated 4s N=1 worse |" in md
    assert "| uncalibrated 4s N=1 − multi N=1 | 4 | +0.0025 |" in md
    assert ("7 of 12 optimiser and refinement fits (the uncalibrated refinement's: 7 of 8) stopped on their budget"
            in md)
    assert "optimiser budgets up to 8 s (full run: up to 30 s)" in md


def test_full_size_run_has_no_caveat_and_one_material_cannot_tell() -> None:
    full = _rows({("trivial", 1, None): [0.1 + 0.01 * m for m in range(16)],
                  ("optimize", 1, 30.0): [0.1] * 16})
    assert report.small_run_section(full, size=256) == []
    one = report.paired_differences(_rows({("trivial", 1, None): [0.1], ("single", 1, None): [0.2]}))
    assert len(one) == 1 and math.isnan(one[0]["se"]) and not one[0]["resolved"]
    md = "\n".join(report.small_run_section(_rows({("trivial", 1, None): [0.1], ("single", 1, None): [0.2]}), 64))
    assert "cannot tell (one material)" in md and "within noise at this size" not in md


# ----------------------------------------------------------------------------- bench_optimize: the targets
def _bench() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location("bench_optimize", ROOT / "benchmarks" / "bench_optimize.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _bench_rows(size: int, n_cmp: int, speedup: float, stop: str, seconds: float) -> list[dict]:
    sweep = [{"path": "texel", "n": 10, "material": name, "seconds": seconds, "stop_reason": stop}
             for name in ("stone", "tiles")]
    return sweep + [{"path": "mitsuba_cmp", "n": n_cmp, "size": size, "texel_speedup": speedup}]


def test_bench_optimize_judges_targets_only_where_the_run_can() -> None:
    bench = _bench()
    quick = bench.target_lines(_bench_rows(64, 3, 3.0, "iterations", 2.0), 64, 60.0, 400, 30)
    assert len(quick) == 2 and all("not judged by this run" in line for line in quick), quick
    assert not any("NOT MET" in line for line in quick)
    assert "64^2, at most 400 steps per fit" in quick[0] and "measured 3.0x" in quick[1]
    full = bench.target_lines(_bench_rows(256, 10, 12.0, "converged", 20.0), 256, 60.0, 3000, 100)
    assert full[0].endswith("MET (stone 20.0 s converged, tiles 20.0 s converged)") and "NOT" not in full[0]
    assert full[1].endswith(": MET (12.0x)")
    slow = bench.target_lines(_bench_rows(256, 10, 5.0, "budget", 60.0), 256, 60.0, 3000, 100)
    assert all("NOT MET" in line for line in slow), slow


def test_bench_optimize_says_where_it_writes() -> None:
    text = (ROOT / "benchmarks" / "bench_optimize.py").read_text()
    assert 'print(f"bench_optimize: writing bench_optimize.csv and bench_optimize.png to {args.out} (--out)"' in text
    assert 'default=Path("/tmp/bench_optimize")' in text


# ----------------------------------------------------------------------------- train: --no-progress, the last line
def _config_file(tmp_path: Path, **kw: object) -> str:
    cfg = {"net": TINY_NET, "batch_size": 2, "sizes": [[0, 32]], "steps": 2, "warmup": 1, "validate_every": 2,
           "val_materials": 2, "val_size": 32, "log_every": 1, "checkpoint_every_s": 1e9, "bf16": False,
           "threads": 1, "simulator": {"preset": "single_flash", "pool_size": 4}, **kw}
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(cfg))
    return str(path)


def test_train_no_progress_shows_no_bar_and_ends_with_what_it_did(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))  # the validation set is built: its bar too
    threads = torch.get_num_threads()
    run = tmp_path / "runs" / "tiny"
    try:
        assert standalone(train_cli.add_parser, ["train", _config_file(tmp_path), "-o", str(run), "--no-progress"]) == 0
        out, err = capsys.readouterr()
        assert not BAR.search(out + err) and "held-out set" not in err, err
        assert out.strip().splitlines()[-1] == (f"train: stopped at step 2 of 2 (2 steps this run): all steps done; "
                                                f"checkpoint {run / 'checkpoint.pt'}")
        # resumed with more steps but no time: stops at once, on the time limit, and says how to continue
        code = standalone(train_cli.add_parser, ["train", _config_file(tmp_path), "-o", str(run), "--resume",
                                                 "--set", "steps=3", "--max-minutes", "0", "--no-progress"])
        assert code == 0
        last = capsys.readouterr().out.strip().splitlines()[-1]
        assert last == (f"train: stopped at step 2 of 3 (0 steps this run, resumed from step 2): time limit (0 min) "
                        f"reached; checkpoint {run / 'checkpoint.pt'}; continue with --resume")
    finally:
        torch.set_num_threads(threads)


def test_train_reports_an_error_with_its_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(*args: object, **kwargs: object) -> None:
        raise FloatingPointError("step 0: the training loss is nan")

    monkeypatch.setattr(training, "_train_step", fail)
    cfg = training.load_config(_config_file(tmp_path, validate_every=0), {"out": str(tmp_path), "name": "run"})
    lines: list[str] = []
    with pytest.raises(FloatingPointError):
        training.train(cfg, progress=False, report=lines.append)
    assert lines == [(f"train: stopped at step 0 of 2 (0 steps this run): error: FloatingPointError: step 0: the "
                      f"training loss is nan; checkpoint {tmp_path / 'run' / 'checkpoint.pt'}; continue with --resume")]
    assert (tmp_path / "run" / "checkpoint.pt").is_file()


# ----------------------------------------------------------------------------- optimize: bars and phases
def _capture(n: int, size: int = 24):
    from mi_svbrdf.data import procedural
    from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
    from mi_svbrdf.io.calibrated_photos import capture_from_simulator

    gt = procedural.generate("tiles", 1, size)[None]
    cap = sample_captures(1, n, capture_config(ambient=False, noise=False), torch.Generator().manual_seed(0))
    return capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"))


def test_optimize_bars_name_each_phase_and_show_no_total_they_cannot_know(capsys: pytest.CaptureFixture[str],
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A budget (or the convergence test) ends a fit at a step no one knows: no percentage, no step total;
    each run (the starts, the validation fit, the full fit) is its own named bar."""
    from mi_svbrdf.optim import OptimizeConfig, optimize

    monkeypatch.setenv("MI_SVBRDF_PROGRESS", "1")  # pytest's captured stderr is no terminal: bars would be off
    spec, images = _capture(3)
    res = optimize(spec, images, config=OptimizeConfig(iterations=300, start_iterations=5, budget_s=30.0))
    err = capsys.readouterr().err
    assert not re.search(r"\d+%\||/300\b", err), err[-400:]
    names = [name for name, _ in res.phases]
    assert names == ["validation (2 of 3 photos) start r=0.3", "validation (2 of 3 photos) start r=0.7",
                     "validation (2 of 3 photos) fit 24x24", "all 3 photos start r=0.3", "all 3 photos start r=0.7",
                     "all 3 photos fit 24x24"]
    assert all(name in err for name in names)
    assert len(res.history) == res.steps  # both fits' steps are in the history (no recoveries here)
    starts = [i for _, i in res.phases]
    assert starts == sorted(starts) and [s for _, s, _ in res.history] == list(range(res.steps))


def test_optimize_history_and_loss_curve_keep_the_fits_apart(tmp_path: Path) -> None:
    from mi_svbrdf.cli.optimize import main as optimize_main
    from mi_svbrdf.io.calibrated_photos import save_capture

    spec, images = _capture(3, 64)
    save_capture(tmp_path / "cap" / "capture.json", spec, images)
    out = tmp_path / "fit"
    assert optimize_main(["--capture", str(tmp_path / "cap"), "-o", str(out), "--iterations", "40",
                          "--no-progress"]) == 0
    rows = (out / "history.csv").read_text().strip().splitlines()
    fits = [row.rsplit(",", 1)[1] for row in rows[1:]]
    assert rows[0] == "seconds,step,loss,fit" and fits[0].startswith("validation") and fits[-1].startswith("all 3")
    summary = json.loads((out / "summary.json").read_text())
    assert len(rows) - 1 == summary["steps"]  # every step the summary counts is a row


def test_an_interrupted_fit_closes_its_bar_before_the_message() -> None:
    from tqdm.auto import tqdm

    from mi_svbrdf.optim import OptimizeConfig, optimize

    spec, images = _capture(4)

    def interrupt(step: int, grad: torch.Tensor) -> None:
        if step == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        optimize(spec, images, config=OptimizeConfig(iterations=50, roughness_starts=(0.5,)), grad_hook=interrupt)
    assert not list(getattr(tqdm, "_instances", [])), "a bar was left open"
