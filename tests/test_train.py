"""Training: exact resume, warm start, validation, bundled-weight files, DDP on gloo."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from mi_svbrdf.nets import weights as pretrained
from mi_svbrdf.nets.network import build_network, network_config
from mi_svbrdf.nets.train import TrainConfig, learning_rate, load_config, train, warm_start

TINY_NET = {"encoder_features": [8, 16, 16], "last_features": 8, "resolution": 32}


def _cfg(tmp: Path, **kw: object) -> TrainConfig:
    base = {"name": "run", "out": str(tmp), "net": TINY_NET, "batch_size": 2, "sizes": [[0, 32]], "steps": 4,
            "warmup": 2, "validate_every": 0, "log_every": 1, "checkpoint_every_s": 1e9, "bf16": False,
            "simulator": {"preset": "single_flash", "pool_size": 4}}
    return TrainConfig.from_dict({**base, **kw})


def test_resume_continues_exactly(tmp_path: Path) -> None:
    straight = train(_cfg(tmp_path / "a"), progress=False)
    # the same run, interrupted after 2 steps (as a checkpoint on Ctrl-C would leave it), then resumed
    train(_cfg(tmp_path / "b", steps=2), progress=False)
    state = torch.load(tmp_path / "b" / "run" / "checkpoint.pt", weights_only=False)
    assert state["step"] == 2
    resumed = train(_cfg(tmp_path / "b"), resume=True, progress=False)
    a = torch.load(straight / "checkpoint.pt", weights_only=False)
    b = torch.load(resumed / "checkpoint.pt", weights_only=False)
    assert a["step"] == b["step"] == 4
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert [r["loss"] for r in a["log"]] == pytest.approx([r["loss"] for r in b["log"]], rel=1e-6)
    assert (straight / "log.csv").is_file() and (straight / "curve.png").is_file()


def test_resume_refuses_another_architecture(tmp_path: Path) -> None:
    train(_cfg(tmp_path, steps=1), progress=False)
    with pytest.raises(ValueError, match="trained with"):
        train(_cfg(tmp_path, net={**TINY_NET, "last_features": 4}), resume=True, progress=False)


def test_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown keys"):
        TrainConfig.from_dict({"stpes": 3})
    with pytest.raises(ValueError, match="recipe"):
        load_config(str(tmp_path / "missing.json"))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json"):
        load_config(str(bad))
    with pytest.raises(ValueError, match="sizes"):
        _cfg(tmp_path, sizes=[[5, 32]])


def test_learning_rate_schedule(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, steps=100, warmup=10, lr=1e-3, min_lr_factor=0.1)
    assert learning_rate(cfg, 0) == pytest.approx(1e-4)
    assert learning_rate(cfg, 9) == pytest.approx(1e-3)
    assert learning_rate(cfg, 100) == pytest.approx(1e-4)
    lrs = [learning_rate(cfg, s) for s in range(10, 101)]
    assert all(x >= y for x, y in zip(lrs, lrs[1:]))


def test_warm_start_single_into_multi(tmp_path: Path) -> None:
    single = build_network(network_config("compact", "single", **TINY_NET))
    torch.save({"model": single.state_dict()}, tmp_path / "s.pt")
    multi = build_network(network_config("compact", "multi", **TINY_NET))
    copied = warm_start(multi, tmp_path / "s.pt")
    assert copied == len([k for k in single.state_dict() if k.startswith("trunk.")])
    w_s, w_m = single.trunk.encoder[0].conv.weight, multi.trunk.encoder[0].conv.weight
    assert torch.equal(w_m[:, :3], w_s) and not w_m[:, 3:].any()  # coordinate channels start at zero


def test_a_run_continuing_the_bundled_net_adds_to_its_steps_and_history(tmp_path: Path) -> None:
    """init "bundled:KIND" of the run's own kind (a new machine resumes from the bundled weights): the bundled
    entry's steps, hours and validation come first; another init (or another kind's) starts from zero."""
    bundled = pretrained.read_manifest().get("single")
    if bundled is None:
        pytest.skip("no bundled single-image net")
    run = train(_cfg(tmp_path, steps=2, validate_every=2, val_materials=2, val_size=32), progress=False)
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    for init, continued in (("bundled:single", True), ("bundled:multi", False), (None, False)):
        state["config"]["init"] = init
        torch.save(state, tmp_path / "c.pt")
        entry = pretrained.export_weights(tmp_path / "c.pt", folder=tmp_path / "w")
        offset = bundled["steps"] if continued else 0
        assert entry["steps"] == offset + 2
        assert entry["validation"][-1]["step"] == offset + 2
        if continued:
            assert entry["validation"][:len(bundled["validation"])] == bundled["validation"]
            assert entry["continues"]["sha256"] == bundled["sha256"] and entry["continues"]["steps"] == offset
            assert entry["training_hours"] >= bundled["training_hours"]
        else:
            assert "continues" not in entry and len(entry["validation"]) == 1


def test_validation_logs_held_out_metrics(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    run = train(_cfg(tmp_path, steps=2, validate_every=2, val_materials=2, val_size=32), progress=False)
    log = torch.load(run / "checkpoint.pt", weights_only=False)["log"]
    val = [r for r in log if "val_rmse_normal" in r]
    assert len(val) == 1 and 0 < val[0]["val_rmse_render"] < 1


def test_bundled_weights_round_trip_and_checksum(tmp_path: Path) -> None:
    run = train(_cfg(tmp_path, steps=1), progress=False)
    entry = pretrained.export_weights(run / "checkpoint.pt", accuracy={"rmse_normal": 0.1}, folder=tmp_path / "w",
                                      foreign_accuracy={"rmse_normal": 0.2}, note="resumed with lr 1e-4")
    assert entry["steps"] == 1 and entry["accuracy"] == {"rmse_normal": 0.1}
    assert entry["foreign_accuracy"] == {"rmse_normal": 0.2}
    assert pretrained.read_manifest(tmp_path / "w")["single"]["note"] == "resumed with lr 1e-4"
    assert (tmp_path / "w" / entry["curve"]).stat().st_size > 1000  # the training curve beside the weights
    net = pretrained.load_network("single", folder=tmp_path / "w")
    state = torch.load(run / "checkpoint.pt", weights_only=False)["model"]
    for k, v in net.state_dict().items():
        assert torch.allclose(v, state[k].half().float()), k
    with pytest.raises(ValueError, match="expected a network with config"):
        pretrained.load_network("single", folder=tmp_path / "w",
                                expected=network_config("compact", "single", **{**TINY_NET, "last_features": 4}))
    with pytest.raises(ValueError, match="bundled networks"):
        pretrained.load_network("multi", folder=tmp_path / "w")
    path = tmp_path / "w" / entry["file"]
    path.write_bytes(path.read_bytes()[:-8] + b"corrupt!")
    with pytest.raises(ValueError, match="checksum mismatch"):
        pretrained.load_network("single", folder=tmp_path / "w")


def test_bundled_manifest_is_consistent() -> None:
    """Every bundled network loads (checksum verified), is < 20 MB and records its accuracy."""
    manifest = pretrained.read_manifest()
    if not manifest:
        pytest.skip("no bundled weights in this checkout")
    for kind, entry in manifest.items():
        assert (pretrained.WEIGHTS_DIR / entry["file"]).stat().st_size < 20e6
        assert entry["net_config"]["kind"] == kind and entry["steps"] > 0 and entry["accuracy"]
        if entry.get("curve"):
            assert (pretrained.WEIGHTS_DIR / entry["curve"]).is_file()
        pretrained.load_network(kind)


def test_torchrun_ddp_gloo_two_processes(tmp_path: Path) -> None:
    config = tmp_path / "ddp.json"
    cfg = _cfg(tmp_path, steps=2)
    import dataclasses

    config.write_text(json.dumps(dataclasses.asdict(cfg)))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                          "-m", "mi_svbrdf.cli.train", "train", str(config), "--no-progress"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    assert state["step"] == 2 and all(torch.isfinite(v).all() for v in state["model"].values())


def test_warm_start_from_bundled_weights(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run = train(_cfg(tmp_path, steps=1), progress=False)
    pretrained.export_weights(run / "checkpoint.pt", folder=tmp_path / "w")
    monkeypatch.setattr(pretrained, "WEIGHTS_DIR", tmp_path / "w")
    multi = build_network(network_config("compact", "multi", **TINY_NET))
    assert warm_start(multi, "bundled:single") > 0
    single = pretrained.load_network("single", folder=tmp_path / "w")
    assert torch.equal(multi.trunk.encoder[1].conv.weight, single.trunk.encoder[1].conv.weight)


def test_warm_start_from_a_bundled_net_of_the_same_kind_copies_every_tensor(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A bundled file is a bare state dict: its kind comes from the manifest, so a multi-image net
    warm-started from the bundled multi-image net gets its fuse layers and head too (they were left random)."""
    from conftest import export_tiny_net

    export_tiny_net(tmp_path, "multi", 32)
    monkeypatch.setattr(pretrained, "WEIGHTS_DIR", tmp_path)
    bundled = pretrained.load_network("multi", folder=tmp_path)
    fresh = build_network(bundled.config)
    assert warm_start(fresh, "bundled:multi") == len(fresh.state_dict())
    x = torch.rand(1, 2, 3, 32, 32)
    assert torch.allclose(fresh.eval()(x), bundled(x), atol=1e-6)
    # a bare state dict on disk is read the same way (its kind from its keys)
    torch.save(bundled.state_dict(), tmp_path / "bare.pt")
    again = build_network(bundled.config)
    assert warm_start(again, tmp_path / "bare.pt") == len(again.state_dict())


def test_cli_out_is_the_run_folder(tmp_path: Path) -> None:
    from mi_svbrdf.cli.train import main

    config = tmp_path / "tiny.json"
    config.write_text(json.dumps({k: v for k, v in _cfg(tmp_path / "ignored", steps=1).__dict__.items()}))
    assert main(["train", str(config), "-o", str(tmp_path / "my_run"), "--no-progress"]) == 0
    for name in ("config.json", "checkpoint.pt", "log.csv", "curve.png"):
        assert (tmp_path / "my_run" / name).is_file(), name
    saved = json.loads((tmp_path / "my_run" / "config.json").read_text())
    assert saved["name"] == "my_run" and saved["out"] == str(tmp_path)
    assert not (tmp_path / "ignored").exists() and not list((tmp_path / "my_run").glob(".*tmp*"))


@pytest.mark.parametrize("kind", ["multi", "single"])
def test_bundle_records_a_bundled_nets_foreign_accuracy(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        kind: str) -> None:
    """``python -m mi_svbrdf.cli.bundle KIND --record-foreign``: the manifest entry gains the foreign figures (the
    net alone and its symmetry ensemble), the weights and their checksum stay."""
    from conftest import export_tiny_net

    from mi_svbrdf.cli.bundle import main as bundle_main

    export_tiny_net(tmp_path, kind, 32)
    before = pretrained.read_manifest(tmp_path)[kind]
    assert bundle_main([kind, "--record-foreign", "--materials", "1", "--size", "32", "-o", str(tmp_path)]) == 0
    after = pretrained.read_manifest(tmp_path)[kind]
    assert after["sha256"] == before["sha256"] and after["foreign_accuracy"]["set"]["set"] == "foreign"
    key = "N=10" if kind == "multi" else "single"
    assert {key, f"{key}, 8 symmetries", f"baseline {key}"} <= set(after["foreign_accuracy"])
    text = capsys.readouterr().out
    assert "generalisation, 8 symmetries" in text
    assert ("foreign render falls with N" in text) == (kind == "multi")
    with pytest.raises(SystemExit):
        bundle_main(["nope", "--record-foreign", "-o", str(tmp_path)])


def test_a_non_finite_gradient_skips_the_step_and_leaves_the_weights(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from mi_svbrdf.nets import train as T
    cfg = _cfg(tmp_path)
    net = build_network(cfg.net_config)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    batch = T.make_simulator(cfg, 32).batch(0)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    # finite loss (1), NaN gradient: d sqrt(0 x) / dx = 0 * inf
    monkeypatch.setattr(T, "training_loss", lambda cfg, pred, maps, gen: torch.sqrt(pred * 0.0).sum() + 1.0)
    with pytest.warns(RuntimeWarning, match="non-finite gradient"):
        loss, _ = T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "checkpoint.pt")
    assert loss == 1.0
    for k, v in net.state_dict().items():
        assert torch.equal(v, before[k]), k
    monkeypatch.undo()  # a finite gradient updates them
    T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "checkpoint.pt")
    assert any(not torch.equal(v, before[k]) for k, v in net.state_dict().items())


def test_step_time_breakdown_in_the_log_and_the_summary(tmp_path: Path) -> None:
    """Every log row holds the mean ms of the simulator and each phase of a step; the run ends with a line
    adding them up (the docstring's example too)."""
    import doctest

    from mi_svbrdf.nets import train as T

    lines: list[str] = []
    run = train(_cfg(tmp_path, steps=3), progress=False, report=lines.append)
    log = torch.load(run / "checkpoint.pt", weights_only=False)["log"]
    phases = ("simulator", *T.STEP_PHASES)
    for row in log:
        assert all(row[f"ms_{k}"] > 0 for k in phases), row
    assert lines[0].startswith("train: a step on cpu (mean of 3 timed steps): simulator ")
    assert all(f"{k} " in lines[0] for k in phases) and lines[0].endswith("steps/s")
    assert doctest.run_docstring_examples(T.breakdown_line, {"torch": torch, "breakdown_line": T.breakdown_line},
                                          optionflags=doctest.ELLIPSIS) is None


def test_timed_step_equals_a_plain_backward(tmp_path: Path) -> None:
    """The timed step (the loss's gradient at the net's output, then the net's backward) moves the weights exactly
    as one ``loss.backward()`` through the whole graph does."""
    from mi_svbrdf.nets import train as T

    cfg = _cfg(tmp_path, grad_clip=1.0)
    cpu = torch.device("cpu")
    net, opt, _, _, _ = T._start(cfg, None, cpu, T.grad_scaler(cfg, cpu))
    ref_net, ref_opt, _, _, _ = T._start(cfg, None, cpu, T.grad_scaler(cfg, cpu))
    ref_net.load_state_dict(net.state_dict())
    batch = T.make_simulator(cfg, 32).batch(0)
    times: dict[str, float] = {}
    torch.manual_seed(7)  # the same dropout masks in both
    loss, _ = T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "c.pt", cpu, times=times)
    assert set(times) == set(T.STEP_PHASES)
    for group in ref_opt.param_groups:
        group["lr"] = T.learning_rate(cfg, 0)
    gen = torch.Generator().manual_seed(cfg.seed * 1_000_003)
    torch.manual_seed(7)
    ref_loss = T.training_loss(cfg, ref_net(batch.inputs[:, :1]).float(), batch.maps, gen)
    ref_opt.zero_grad()
    ref_loss.backward()
    torch.nn.utils.clip_grad_norm_(ref_net.parameters(), cfg.grad_clip)
    ref_opt.step()
    assert loss == pytest.approx(ref_loss.item(), rel=1e-6)
    for a, b in zip(net.parameters(), ref_net.parameters()):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)


def test_normal_weight_adds_an_l1_on_the_normals_alone() -> None:
    """TrainConfig.normal_weight adds weight x mean |normal difference| to the loss, nothing else."""
    import mi_svbrdf.nets.train as T
    from mi_svbrdf.core.maps import constant_maps

    pred, maps = constant_maps(1, 8, 8), constant_maps(1, 8, 8).clone()
    maps[:, 0] = 0.6  # the normal's x only
    base = T.TrainConfig(kind="single", render_weight=0.0, map_weight=1.0)
    extra = T.TrainConfig(kind="single", render_weight=0.0, map_weight=1.0, normal_weight=2.0)
    gen = torch.Generator().manual_seed(0)
    a = T.training_loss(base, pred, maps, gen)
    b = T.training_loss(extra, pred, maps, torch.Generator().manual_seed(0))
    assert float(b - a) == pytest.approx(2.0 * float((pred[:, :3] - maps[:, :3]).abs().mean()))
    with pytest.raises(ValueError, match="normal_weight"):
        T.TrainConfig(normal_weight=-1.0)
