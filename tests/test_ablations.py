"""The ablation study (mi_svbrdf.eval.studies.ablations): config checks, arms that differ in one setting,
verdicts on synthetic numbers, a tiny end-to-end run with resume, and the CLI's errors."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import pytest

from mi_svbrdf import cli
from mi_svbrdf.data.photo_setups import capture_config
from mi_svbrdf.eval import report
from mi_svbrdf.eval.runner import COLUMNS
from mi_svbrdf.eval.studies import ablations
from mi_svbrdf.eval.studies.ablations import (
    ARMS,
    COMPARISONS,
    AblationConfig,
    ablations_markdown,
    arm_config,
    compare,
    noise_threshold,
    quick_config,
    run_ablations,
    sentence,
    verdict,
)
from mi_svbrdf.nets.train import RECIPES, TrainConfig, train

#: The capture perturbations of CaptureConfig (ch. 4.4.1), written out here independently of the module.
PERTURBATIONS = {"intensity_jitter", "white_balance", "cone_exponent_jitter", "cone_target_jitter", "light_offset",
                 "view_offset", "fov_jitter", "ambient", "noise"}
#: What each arm must change relative to its group's baseline (flattened setting names).
EXPECTED_CHANGE = {
    "single/render+l1": set(), "single/render": {"map_weight"}, "single/l1": {"render_weight"},
    "single/no-global": {"net.global_track"}, "multi/max": set(), "multi/mean": {"net.pooling"},
    "multi/no-perturb": {f"simulator.capture.{k}" for k in PERTURBATIONS},
}


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _settings(cfg: TrainConfig) -> dict[str, Any]:
    """Every setting of a run, the net and the capture resolved to all their fields (not just overrides)."""
    sim = dict(cfg.simulator)
    capture = dataclasses.asdict(capture_config(sim["preset"], **sim.pop("capture", {})))
    data = {**dataclasses.asdict(cfg), "net": cfg.net_config.to_dict(), "simulator": {**sim, "capture": capture}}
    data.pop("name")
    return _flat(data)


def test_config_rejects_unknown_keys_bad_arms_and_bad_values() -> None:
    with pytest.raises(ValueError, match="stpes"):
        AblationConfig.from_dict({"stpes": 3})
    with pytest.raises(ValueError, match=r"AblationConfig\.arms.*single/nope"):
        AblationConfig(arms=("single/render", "single/nope"))
    with pytest.raises(ValueError, match=r"AblationConfig\.size.*multiple of 2\*\*depth = 32"):
        AblationConfig(size=48)
    with pytest.raises(ValueError, match=r"AblationConfig\.train.*map_weight"):
        AblationConfig(train={"map_weight": 0.5})
    with pytest.raises(ValueError, match="TrainConfig: unknown keys"):
        AblationConfig(train={"bogus": 1})
    with pytest.raises(ValueError, match=r"AblationConfig\.n_values"):
        AblationConfig(n_values=(0, 3))
    with pytest.raises(ValueError, match="NetConfig"):
        AblationConfig(net={**ablations.ABLATION_NET, "pooling": "median"})
    cfg = AblationConfig.from_dict({"arms": ["multi/max"], "n_values": [5, 1, 3, 3]})
    assert cfg.arms == ("multi/max",) and cfg.n_values == (1, 3, 5)


def test_each_arm_differs_from_its_baseline_only_in_the_ablated_setting() -> None:
    config = AblationConfig()
    assert set(EXPECTED_CHANGE) == set(ARMS)
    baselines = {"single": "single/render+l1", "multi": "multi/max"}
    for arm, expected in EXPECTED_CHANGE.items():
        cfg = arm_config(config, arm, Path("out"))
        base = arm_config(config, baselines[arm.split("/")[0]], Path("out"))
        a, b = _settings(cfg), _settings(base)
        changed = {k for k in set(a) | set(b) if a.get(k) != b.get(k)}
        assert changed == expected, arm
        # equal compute: steps, batch, size, seed, schedule, from scratch
        assert (cfg.steps, cfg.batch_size, cfg.sizes, cfg.seed, cfg.lr, cfg.init) == \
            (config.steps, config.batch_size, [[0, config.size]], config.seed, config.lr, None)
        assert cfg.run_dir == Path("out") / "runs" / arm
    # the baselines train with the CPU recipes' data and loss
    single, multi = arm_config(config, "single/render+l1", Path("o")), arm_config(config, "multi/max", Path("o"))
    assert single.simulator == RECIPES["single"]["simulator"] and single.map_weight == RECIPES["single"]["map_weight"]
    assert multi.simulator == RECIPES["multi"]["simulator"] and multi.map_weight == RECIPES["multi"]["map_weight"]
    assert arm_config(config, "single/render", Path("o")).map_weight == 0.0  # rendering loss only
    assert arm_config(config, "single/l1", Path("o")).render_weight == 0.0  # map L1 only


def test_verdicts_noise_and_sentences_on_synthetic_numbers() -> None:
    assert verdict(0.091, 0.102, 0.004) == "agrees"
    assert verdict(0.102, 0.091, 0.004) == "disagrees"
    assert verdict(0.091, 0.094, 0.004) == "within noise"
    assert verdict(0.094, 0.091, 0.004) == "within noise"
    assert verdict(0.091, 0.0911, math.nan) == "agrees"  # no threshold: the sign decides
    # constant paired differences: no sampling noise, the curves' spread decides
    n = noise_threshold([0.1, 0.2, 0.3, 0.4], [0.11, 0.21, 0.31, 0.41], 0.003, 0.004)
    assert n["paired_se"] == pytest.approx(0.0, abs=1e-12) and n["noise"] == pytest.approx(0.005)
    # differences 0 or 0.02 in turn: SE = std / sqrt(4) = 0.011547 / 2
    n = noise_threshold([0.1] * 4, [0.1, 0.12, 0.1, 0.12], math.nan, math.nan)
    assert n["paired_se"] == pytest.approx(0.0057735, rel=1e-4) and n["noise"] == pytest.approx(2 * 0.0057735, rel=1e-4)
    assert math.isnan(noise_threshold([0.1], [0.2], math.nan, math.nan)["noise"])
    loss = next(c for c in COMPARISONS if c.key == "loss")
    text = sentence(loss, 0.091, 0.102, 0.004, "")
    assert "0.0910 (single/render) vs 0.1020 (single/l1)" in text
    assert "the rendering loss is better than the map L1 by 11 %" in text and "agrees with the thesis" in text
    text = sentence(loss, 0.102, 0.091, 0.004, "")
    assert "the map L1 is better than the rendering loss by 11 %" in text and "disagrees with the thesis" in text
    assert "neither confirms nor contradicts" in sentence(loss, 0.091, 0.093, 0.004, "")


def _arm(render: list[float], curve: list[float]) -> dict[str, Any]:
    metrics = {k: 0.1 for k in ablations.METRIC_KEYS}
    return {"metrics": {"N=1": {**metrics, "rmse_render": sum(render) / len(render)}},
            "summary": {**metrics, "rmse_render": sum(render) / len(render)},
            "per_material": {"rmse_render": render}, "curve": [[i, v] for i, v in enumerate(curve)]}


def test_compare_decides_from_the_numbers() -> None:
    pooling = next(c for c in COMPARISONS if c.key == "pooling")
    flat = [0.2, 0.2, 0.2]
    arms = {"multi/max": _arm([0.08, 0.09, 0.10], flat), "multi/mean": _arm([0.10, 0.11, 0.12], flat)}
    c = compare(pooling, arms)
    assert c["verdict"] == "agrees" and c["deltas"]["N=1"]["rmse_render"] == pytest.approx(0.02)
    assert c["noise"] == pytest.approx(0.0) and "max pooling is better than mean pooling by 18 %" in c["sentence"]
    arms["multi/mean"] = _arm([0.07, 0.08, 0.09], flat)
    assert compare(pooling, arms)["verdict"] == "disagrees"
    arms["multi/mean"] = _arm([0.081, 0.091, 0.101], [0.2, 0.21, 0.19])  # 0.001 below the curves' spread 0.01
    assert compare(pooling, arms)["verdict"] == "within noise"


def test_tiny_run_of_two_arms_writes_results_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    config = quick_config(steps=2, arms=("single/render+l1", "single/no-global"), heldout_materials=2,
                          validate_every=1, val_materials=2)
    out = tmp_path / "abl"
    # an interrupted arm: its run folder holds a checkpoint at step 0
    interrupted = arm_config(config, "single/no-global", out)
    train(interrupted, max_seconds=0.0, progress=False)
    calls: list[tuple[str, bool]] = []

    def spy(cfg: TrainConfig, resume: bool = False, **kw: Any) -> Path:
        calls.append((cfg.name, resume))
        return train(cfg, resume=resume, **kw)

    monkeypatch.setattr(ablations, "train", spy)
    result = run_ablations(config, out, progress=False)
    assert calls == [("render+l1", True), ("no-global", True)]
    assert [a["steps"] for a in result["arms"].values()] == [2, 2]
    for name in ("ablations.json", "ablations.md", "ablations.png"):
        assert (out / name).is_file(), name
    assert (out / "ablations.png").stat().st_size > 5000 and not list(out.glob(".*tmp*"))
    saved = json.loads((out / "ablations.json").read_text())
    assert list(saved["arms"]) == list(config.arms) and len(saved["arms"]["single/render+l1"]["curve"]) == 2
    (comp,) = saved["comparisons"]
    assert comp["key"] == "global" and comp["verdict"] in ("agrees", "disagrees", "within noise")
    assert set(comp["deltas"]["N=1"]) >= {"rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular",
                                          "rmse_render"}
    md = (out / "ablations.md").read_text()
    assert comp["sentence"] in md and "(ablations.png)" in md and "| single/no-global |" in md
    assert "(abl/ablations.png)" in "\n".join(ablations_markdown(out, relative_to=tmp_path))

    # the evaluation report carries the section, with the figure path relative to the report
    report_dir = tmp_path / "report"
    report_dir.mkdir()
    rows = [{"dataset": "heldout", "material": m, "class": "paint", "method": "trivial", "n": 1, "budget_s": None,
             "seconds": 0.0, "peak_mb": 0.0, "recoveries": 0, "steps": 0, "stop_reason": "", "net": "",
             **{k: 0.1 for k in COLUMNS if k.startswith(("rmse_", "ssim_"))}} for m in range(2)]
    summary = report.write_evaluation_report(report_dir, rows, reference_n=1, ablations_dir=out)["summary.md"].read_text()
    assert "## Ablations" in summary and comp["sentence"] in summary and "(../abl/ablations.png)" in summary

    # rerun: both arms finished, nothing is retrained, the same figures
    def no_training(*args: Any, **kw: Any) -> Path:
        raise AssertionError("a finished arm was retrained")

    monkeypatch.setattr(ablations, "train", no_training)
    again = run_ablations(config, out, progress=False)
    assert again["comparisons"][0]["sentence"] == comp["sentence"]
    # a run folder of other settings is refused, naming the setting
    with pytest.raises(ValueError, match=r"single/render\+l1: .* other settings \(lr\)"):
        run_ablations(dataclasses.replace(config, lr=1e-3), out, progress=False)


def test_cli_rejects_bad_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["ablations", "-o", str(tmp_path), "--arms", "single/render,single/nope"]) == 2
    assert "single/nope" in capsys.readouterr().err
    assert cli.main(["ablations", "-o", str(tmp_path), "--set", "stpes=3"]) == 2
    assert "stpes" in capsys.readouterr().err
    assert cli.main(["ablations", "-o", str(tmp_path), "--size", "48"]) == 2
    assert "AblationConfig.size" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli.main(["ablations", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "mi-svbrdf ablations -o out/ablations" in text and "ablations.json" in text
    assert not list(tmp_path.iterdir())  # nothing written on bad options
