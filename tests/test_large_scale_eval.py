"""The held-out large-scale benchmark (mi_svbrdf.eval.studies.large_scale): exact figures on constructed cases, held-out
surfaces that are deterministic and disjoint from training's draws, a falsifiable exemplar-influence check, and the
bundling of a tiny large-scale checkpoint (manifest accuracy, loaded back by ``mi-svbrdf large-scale``)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from mi_svbrdf.cli import bundle
from mi_svbrdf.cli.large_scale import load_large_net
from mi_svbrdf.core.maps import SLICES, constant_maps
from mi_svbrdf.data.parameter_split import is_held_out
from mi_svbrdf.data.large_scale import LargeScaleConfig, LargeScaleData, LargeScaleHeldOut
from mi_svbrdf.eval.studies import large_scale as L
from mi_svbrdf.eval.baseline import BASELINE_ROUGHNESS, BASELINE_SPECULAR
from mi_svbrdf.nets import weights as bundled
from mi_svbrdf.nets.network import build_network, network_config
from tests.conftest import random_maps

pytestmark = pytest.mark.usefixtures("one_thread")

#: A tiny large-scale net: tiles of 32 px, exemplars of 16 px (as tests/conftest.py's export_tiny_net).
TINY = {"encoder_features": (8, 16, 16, 16), "last_features": 8, "resolution": 32, "exemplar_features": (4, 8, 8, 8),
        "exemplar_size": 16}
#: Its "training data": 128² materials, crops 64-128 (so 32-64 px per material in a tile), 8 lights.
TINY_TRAIN = {"material_size": 128, "crop": [64, 128], "n_lights": 8}


def tiny_net(seed: int = 3) -> nn.Module:
    torch.manual_seed(seed)
    return build_network(network_config("compact", "large", **TINY)).eval()


def tiny_train() -> LargeScaleConfig:
    return L.training_data_config(network_config("compact", "large", **TINY), TINY_TRAIN)


def constructed(count: int = 2, size: int = 24) -> L.LargeSurfaces:
    """Random truth maps, photos and exemplars (no rendering): figures known in closed form."""
    g = torch.Generator().manual_seed(5)
    return L.LargeSurfaces(maps=random_maps(count, size, size, seed=1), photo=torch.rand(count, 3, size, size,
                                                                                          generator=g),
                           exemplars=random_maps(count * 2, 16, 16, seed=2).reshape(count, 2, 10, 16, 16))


def test_surface_scale_maps_training_scales_to_the_benchmark() -> None:
    compact = L.surface_scale(LargeScaleConfig(size=128, exemplar_size=64), 2048)
    assert (compact["photo_size"], compact["exemplar_cut"], compact["texels_per_pixel"]) == (512, 256, 4.0)
    assert compact["training_surface_px"] == [256, 512] and compact["exemplar_fraction"] == 64 / 512
    full = L.surface_scale(LargeScaleConfig(size=512, material_size=2048, crop=(512, 1024), exemplar_size=256), 2048)
    assert (full["photo_size"], full["exemplar_cut"]) == (2048, 256)  # the thesis's setting
    with pytest.raises(ValueError, match="photo_size: expected 8 to material_size"):
        L.surface_scale(LargeScaleConfig(size=128, exemplar_size=64), 256)
    with pytest.raises(ValueError, match="LargeBenchConfig.methods"):
        L.LargeBenchConfig(methods=("large", "nope"))
    with pytest.raises(ValueError, match="unknown keys"):
        L.LargeBenchConfig.from_dict({"surfaces": 2, "materials": 3})


def test_truth_scores_zero_and_a_constant_map_scores_its_closed_form() -> None:
    s = constructed()
    truths = list(s.maps)

    def oracle(photo: torch.Tensor, exemplars: torch.Tensor) -> torch.Tensor:
        (m,) = [i for i in range(s.count) if torch.equal(photo[0], s.photo[i])]
        return truths[m][None].clone()

    const = {"normal": (0.3, -0.2, 1.0), "diffuse": (0.2, 0.5, 0.7), "roughness": 0.35, "specular": (0.05, 0.1, 0.2)}
    methods = {"oracle": L.Method(oracle), "constant": L.Method(lambda p, e: constant_maps(1, *p.shape[-2:], **const))}
    rows, kept = L.score_methods(methods, s, keep=1, progress=False)
    assert [(r["method"], r["surface"]) for r in rows] == [("oracle", 0), ("constant", 0), ("oracle", 1),
                                                          ("constant", 1)]
    for r in (r for r in rows if r["method"] == "oracle"):
        for k in ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_render"):
            assert r[k] == pytest.approx(0.0, abs=1e-6), k
    assert torch.equal(kept["oracle"], s.maps[1:2])
    n = np.array(const["normal"]) / np.linalg.norm(const["normal"])
    c = {"normal": (n + 1) / 2, "diffuse": np.array(const["diffuse"]), "roughness": np.array([const["roughness"]]),
         "specular": np.array(const["specular"])}
    for r in (r for r in rows if r["method"] == "constant"):
        truth = s.maps[r["surface"]].double().numpy()
        for name, value in c.items():
            t = truth[SLICES[name]]
            t = (t + 1) / 2 if name == "normal" else t
            expected = math.sqrt(float(np.mean((value[:, None, None] - t) ** 2)))
            assert r[f"rmse_{name}"] == pytest.approx(expected, rel=1e-5), name
        assert r["rmse_render"] > 0.01


def test_benchmark_means_over_surfaces_the_trivial_baseline_in_closed_form() -> None:
    """The whole path (methods, scoring, means, table) on constructed surfaces with the trivial baseline, whose maps
    are known: flat normal, constant roughness and specular, the photo over the exposure level as diffuse."""
    s = constructed()
    train = tiny_train()
    level = math.sqrt(train.exposure[0] * train.exposure[1])
    bench = L.large_scale_benchmark(tiny_net(), L.LargeBenchConfig(methods=("trivial",), influence=None,
                                                                   progress=False), train=train, surfaces=s)
    got = bench.summary["methods"]["trivial"]
    truth = s.maps.double().numpy()
    diffuse = np.clip(s.photo.double().numpy() / (level * (1 - BASELINE_SPECULAR)), 0, 1)
    per = {"rmse_normal": [((truth[m, 0:3] + 1) / 2 - np.array([0.5, 0.5, 1.0])[:, None, None]) for m in range(2)],
           "rmse_diffuse": [truth[m, 3:6] - diffuse[m] for m in range(2)],
           "rmse_roughness": [truth[m, 6:7] - BASELINE_ROUGHNESS for m in range(2)],
           "rmse_specular": [truth[m, 7:10] - BASELINE_SPECULAR for m in range(2)]}
    for key, diffs in per.items():
        expected = np.mean([math.sqrt(float(np.mean(d ** 2))) for d in diffs])
        assert got[key] == pytest.approx(expected, rel=1e-5), key
    assert got["rmse_render"] == pytest.approx(np.mean([r["rmse_render"] for r in bench.rows]), rel=1e-9)
    table = L.large_scale_table(bench.summary)
    assert "| trivial (photo as diffuse) |" in table and f"{got['rmse_render']:.4f}" in table


class _StandIn(nn.Module):
    """A fully convolutional stand-in for the large-scale net: constant maps whose roughness is the exemplars' mean
    roughness (``copy=True``) or 0.5 whatever the exemplars (``copy=False``)."""

    def __init__(self, copy: bool) -> None:
        super().__init__()
        self.copy = copy
        self.weight = nn.Parameter(torch.zeros(1))  # predict_large_scale reads the device off a parameter
        self.config = SimpleNamespace(resolution=16)

    def exemplar_features(self, exemplars: torch.Tensor | None) -> list[torch.Tensor] | None:
        if exemplars is None:
            return None
        return [exemplars[:, :, SLICES["roughness"]].mean(dim=(1, 2, 3, 4)).view(-1, 1, 1, 1)]

    def forward(self, photo: torch.Tensor, exemplars: torch.Tensor | None = None, *,
                features: list[torch.Tensor] | None = None) -> torch.Tensor:
        r = float(features[0].flatten()[0]) if self.copy and features is not None else 0.5
        return constant_maps(photo.shape[0], *photo.shape[-2:], roughness=r)


def test_exemplar_influence_holds_for_a_net_that_reads_exemplars_and_fails_for_one_that_ignores_them() -> None:
    s = constructed(size=40)
    reads = L.exemplar_influence(_StandIn(copy=True), s, roughness=(0.2, 0.6), progress=False)
    assert reads["predicted"] == {"shiny": pytest.approx(0.2, abs=1e-5), "rough": pytest.approx(0.6, abs=1e-5)}
    assert reads["holds"] and reads["surfaces_holding"] == reads["surfaces"] == 2
    assert reads["truth"] == pytest.approx(float(s.maps[:, 6].double().mean()), abs=1e-4)
    ignores = L.exemplar_influence(_StandIn(copy=False), s, progress=False)
    assert not ignores["holds"] and ignores["surfaces_holding"] == 0
    assert ignores["predicted"]["shiny"] == ignores["predicted"]["rough"] == pytest.approx(0.5)
    real = L.exemplar_influence(tiny_net(), s, progress=False)  # a real (random) net: both figures, finite
    assert all(math.isfinite(v) for v in real["predicted"].values()) and len(real["per_surface"]) == 2
    with pytest.raises(ValueError, match="roughness: expected"):
        L.exemplar_influence(_StandIn(copy=True), s, roughness=(0.7, 0.2))


def test_held_out_surfaces_are_deterministic_cached_and_disjoint_from_training(tmp_path: Path) -> None:
    train = tiny_train()
    cfg = L.LargeBenchConfig(surfaces=2, material_size=128, cache_dir=str(tmp_path), progress=False)
    a = L.load_surfaces(cfg, train)
    assert tuple(a.photo.shape) == (2, 3, 64, 64) and tuple(a.exemplars.shape) == (2, 2, 10, 16, 16)
    assert a.classes == ["paint", "plastic"] and a.info["photo_size"] == 64 and a.info["exemplar_cut"] == 16
    assert len(list(tmp_path.glob("heldout_large_*.pt"))) == 1  # cached
    b = L.load_surfaces(L.LargeBenchConfig(surfaces=2, material_size=128, cache=False, progress=False), train)
    assert torch.equal(a.maps, b.maps) and torch.equal(a.photo, b.photo) and torch.equal(a.exemplars, b.exemplars)
    one = L.load_surfaces(L.LargeBenchConfig(surfaces=1, material_size=128, cache=False, progress=False), train)
    assert torch.equal(one.photo[0], a.photo[0])  # a prefix
    held = L.heldout_set(cfg, train)
    specs = [spec for d in held.info(progress=False) for spec in d["materials"]]
    assert specs and all(is_held_out(spec["class"], spec["params"]) for spec in specs)
    stream = LargeScaleData({**TINY_TRAIN, "size": 32, "exemplar_size": 16, "batch_size": 2, "classes": ("paint",
                                                                                                        "plastic")})
    drawn = [spec for i in range(2) for d in stream.batch(i).materials for spec in d["materials"]]
    assert not any(is_held_out(spec["class"], spec["params"]) for spec in drawn)
    # not the validation set's surfaces either: another seed, other materials
    validation = LargeScaleHeldOut.for_training(TINY_TRAIN, size=32, materials=2, cache=False)
    assert validation.seed != cfg.seed
    assert not {spec["seed"] for spec in specs} & {spec["seed"] for d in validation.info(progress=False)
                                                   for spec in d["materials"]}


def _tiny_checkpoint(path: Path, kind: str = "large") -> Path:
    extra = TINY if kind == "large" else {k: v for k, v in TINY.items() if not k.startswith("exemplar")}
    torch.manual_seed(4)
    cfg = network_config("compact", kind, **extra)
    log = [{"step": s, "seconds": float(s), "loss": 1.0 / (s + 1)} for s in range(4)] + [
        {"step": 3, "seconds": 3.0, "val_rmse_render": 0.3, "val_rmse_normal": 0.1}]
    torch.save({"net_config": cfg.to_dict(), "model": build_network(cfg).state_dict(), "step": 3, "seconds": 7.0,
                "config": {"preset": "compact", "kind": kind, "simulator": TINY_TRAIN if kind == "large" else {},
                           "distribution": "ggx"}, "log": log}, path)
    return path


def test_bundle_of_a_tiny_large_checkpoint_records_its_benchmark_and_loads_back(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))  # never the user's cache
    ckpt = _tiny_checkpoint(tmp_path / "checkpoint.pt")
    weights = tmp_path / "weights"
    assert bundle.main([str(ckpt), "-o", str(weights), "--materials", "1", "--material-size", "128",
                        "--report", str(tmp_path / "report")]) == 0
    out = capsys.readouterr().out
    assert "| large-scale net + exemplars |" in out and "skipped for the large-scale net" in out
    entry = bundled.read_manifest(weights)["large"]
    acc = entry["accuracy"]
    assert acc["set"]["surfaces"] == 1 and acc["set"]["photo_size"] == 64 and acc["set"]["holdout"] == "test"
    assert {"large", "no_exemplar", "trivial"} <= set(acc["methods"])
    assert all(0 < acc["methods"][k]["rmse_render"] < 1 for k in acc["methods"])
    assert acc["exemplar_influence"]["surfaces"] == 1 and acc["seam_ratio"]
    assert "foreign_accuracy" not in entry and entry["bytes"] < bundled.MAX_BYTES
    assert (weights / entry["curve"]).is_file() and entry["training"]["simulator"] == TINY_TRAIN
    for name in ("large_scale.md", "large_scale.json", "large_scale.png"):
        assert (tmp_path / "report" / name).stat().st_size > 100, name
    assert json.loads((tmp_path / "report" / "large_scale.json").read_text())["summary"]["set"]["surfaces"] == 1
    net, info = load_large_net(str(weights), torch.device("cpu"))
    state = torch.load(ckpt, weights_only=False)["model"]
    assert info["kind"] == "large" and info["steps"] == 3
    for k, v in net.state_dict().items():
        assert torch.equal(v, state[k].half().float()), k


def test_bundle_refuses_report_for_a_flash_net_and_weights_over_the_size_limit(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    single = _tiny_checkpoint(tmp_path / "single.pt", "single")
    with pytest.raises(SystemExit) as exc:
        bundle.main([str(single), "--dry-run", "--report", str(tmp_path / "r")])
    assert exc.value.code == 2 and "--report: expected a checkpoint of the large-scale net" in capsys.readouterr().err
    monkeypatch.setattr(bundled, "MAX_BYTES", 1000)
    with pytest.raises(ValueError, match="expected weights under 0 MB compressed"):
        bundled.export_weights(_tiny_checkpoint(tmp_path / "large.pt"), folder=tmp_path / "w")
    assert not list((tmp_path / "w").glob("*.pt.zz")) and not (tmp_path / "w" / bundled.MANIFEST).exists()


def test_doctests() -> None:
    import doctest

    assert doctest.testmod(L).failed == 0
