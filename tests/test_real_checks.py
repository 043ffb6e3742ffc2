"""The real-style checks (``mi_svbrdf.eval.studies.real_checks``): the leak metric, the panels, the report section."""
from __future__ import annotations

import argparse
import json
import math
import types
from pathlib import Path

import pytest
import torch
from PIL import Image

from mi_svbrdf.cli import evaluate as eval_cli
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.metrics import METRIC_KEYS
from mi_svbrdf.eval.studies import real_checks as rc
from mi_svbrdf.eval import report
from tests.conftest import export_tiny_net

RES = 64  # the tiny nets' resolution
SIZE = 32  # the checks' maps and photos


def _disk(size: int, radius: float) -> torch.Tensor:
    """``(1, size, size)`` bool disk at the centre."""
    c = torch.arange(size) - (size - 1) / 2
    return (c[None, :] ** 2 + c[:, None] ** 2 <= radius ** 2)[None]


def _grey(values: torch.Tensor) -> torch.Tensor:
    """``(1, H, W)`` values -> ``(1, 3, H, W)`` grey diffuse (luminance = the value)."""
    return values[:, None].expand(-1, 3, -1, -1).clone()


def test_leak_hand_computed_and_the_halo_is_left_out() -> None:
    mask = _disk(32, 5.0)
    near = torch.nn.functional.max_pool2d(mask.float()[:, None], 3, stride=1, padding=1)[:, 0] > 0  # r = 1
    diffuse = torch.where(mask, 0.6, 0.2)
    diffuse = torch.where(near & ~mask, 0.9, diffuse)  # the 1-pixel halo: in neither region
    leak = rc.highlight_leak(_grey(diffuse), mask, halo=1)
    assert leak.dtype == torch.float64 and float(leak[0]) == pytest.approx(3.0, rel=1e-6)
    assert float(rc.highlight_leak(_grey(diffuse), mask, halo=0)[0]) != pytest.approx(3.0)  # halo counted outside
    assert rc.halo_radius(32) == 1 and rc.halo_radius(128) == 4 and rc.halo_radius(256) == 8
    # luminance weights: a pure green map has luminance 0.7152 x its value
    green = torch.zeros(1, 3, 32, 32)
    green[:, 1] = torch.where(mask, 0.6, 0.2)
    assert float(rc.highlight_leak(green, mask, halo=1)[0]) == pytest.approx(3.0)


def test_pasted_highlight_leaks_and_the_truth_gives_its_own_ratio() -> None:
    """A textured true diffuse; the truth itself (and any global scale of it) gives the truth's ratio, the
    truth with the photo's highlight pasted in gives a larger one."""
    gen = torch.Generator().manual_seed(0)
    truth = 0.1 + 0.4 * torch.rand(2, 3, 64, 64, generator=gen)
    mask = torch.cat([_disk(64, 8.0), _disk(64, 12.0)])
    ratio = rc.highlight_leak(truth, mask)
    assert torch.isfinite(ratio).all() and ((ratio - 1.0).abs() < 0.1).all()  # uniform noise: about 1
    assert torch.allclose(rc.highlight_leak(truth * 0.7, mask), ratio)
    highlight = torch.exp(-((torch.arange(64) - 31.5) ** 2)[None, :] / 200 - ((torch.arange(64) - 31.5) ** 2)[:, None]
                          / 200)
    baked = (truth + 0.6 * highlight).clamp(0, 1)
    leak = rc.highlight_leak(baked, mask)
    assert (leak > 1.5 * ratio).all() and (leak > 1.0).all()
    # the relative leak of the method is what the report reads
    assert rc.verdict(float((leak / ratio).mean())) == "bakes the highlight into diffuse"
    assert rc.verdict(1.0) == "keeps the highlight out of diffuse"
    assert rc.verdict(0.5) == "darkens the highlight in diffuse"
    assert "could not be measured" in rc.verdict(math.nan)


def test_mask_and_degenerate_cases() -> None:
    photo = torch.full((1, 3, 8, 8), 0.5)
    photo[0, 0, 2, 3] = 1.0  # one clipped channel is clipped
    photo[0, :, 5, 5] = 254.5 / 255  # bright, not clipped
    mask = rc.highlight_mask(photo)
    assert mask.shape == (1, 8, 8) and mask.sum() == 1 and mask[0, 2, 3]
    diffuse = torch.full((1, 3, 8, 8), 0.3)
    assert math.isnan(float(rc.highlight_leak(diffuse, torch.zeros(1, 8, 8, dtype=torch.bool))[0]))  # no highlight
    assert math.isnan(float(rc.highlight_leak(diffuse, torch.ones(1, 8, 8, dtype=torch.bool))[0]))  # no outside
    assert math.isnan(float(rc.highlight_leak(diffuse * 0, mask)[0]))  # black outside
    with pytest.raises(ValueError, match="diffuse"):
        rc.highlight_leak(diffuse[:, :1], mask)
    with pytest.raises(ValueError, match="mask"):
        rc.highlight_leak(diffuse, mask.float())
    with pytest.raises(ValueError, match="halo"):
        rc.highlight_leak(diffuse, mask, halo=-1)
    with pytest.raises(ValueError, match="photo"):
        rc.highlight_mask(photo[0])


def test_highlight_photos_are_deterministic_and_clip() -> None:
    maps, photos, captures = rc.highlight_photos(SIZE)
    maps2, photos2, _ = rc.highlight_photos(SIZE)
    assert torch.equal(maps, maps2) and torch.equal(photos, photos2)
    assert maps.shape == (len(rc.GLOSSY), 10, SIZE, SIZE) and photos.shape == (len(rc.GLOSSY), 1, 3, SIZE, SIZE)
    clipped = rc.highlight_mask(photos[:, 0]).float().mean(dim=(1, 2))
    assert ((clipped > 0) & (clipped < 0.3)).all(), clipped  # a highlight, not a blown-out photo
    assert (M.roughness(maps).flatten(1).median(dim=1).values < 0.35).all()  # glossy
    assert captures.ambient_light.shape[1] == 0  # the flash alone: the metering's scaling is exact


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory, one_torch_thread: None) -> types.SimpleNamespace:
    """Tiny random nets (both, and single alone) and one run of the checks with each folder."""
    root = tmp_path_factory.mktemp("real_checks")
    both, single = root / "both", root / "single"
    for folder, kinds in ((both, ("single", "multi")), (single, ("single",))):
        folder.mkdir()
        for kind in kinds:
            export_tiny_net(folder, kind, RES)
    out_both, out_single = root / "out_both", root / "out_single"
    result = rc.real_checks(out_both, weights_dir=both, size=SIZE, progress=False)
    result_single = rc.real_checks(out_single, weights_dir=single, size=SIZE, progress=False)
    return types.SimpleNamespace(root=root, out=out_both, result=result, out_single=out_single,
                                 result_single=result_single)


def test_panels_and_json_are_written(env: types.SimpleNamespace) -> None:
    for name in (rc.EXAMPLES_PNG, rc.HIGHLIGHTS_PNG):
        path = env.out / name
        assert path.is_file() and path.stat().st_size > 1000
        with Image.open(path) as im:
            assert im.size[0] > 4 * SIZE and im.size[1] > 2 * SIZE
    saved = json.loads((env.out / rc.JSON_NAME).read_text())
    assert saved == env.result
    assert env.result["nets"] == ["single", "multi"] and env.result["notes"] == []
    rows = {(r["method"], r["n"]) for r in env.result["examples"]}
    assert rows == {("single", 1), ("multi", 1), ("trivial", 1), ("multi", 3), ("trivial", 3)}
    for r in env.result["examples"]:
        assert all(0 <= r[k] < 1 for k, _ in rc.EXAMPLE_METRICS if k in METRIC_KEYS)
    assert [m["name"] for m in env.result["highlight"]] == [g.name for g in rc.GLOSSY]
    for m in env.result["highlight"]:
        assert set(m["leak"]) == {"truth", "single", "multi", "trivial"} and m["clipped_percent"] > 0
        assert m["relative"]["single"] == pytest.approx(m["leak"]["single"] / m["leak"]["truth"])
    # the trivial baseline is the photo as diffuse: the clipped highlight is in it
    assert env.result["mean_relative"]["trivial"] > rc.BAKED


def test_example_truth_is_the_bundled_photos_material(env: types.SimpleNamespace) -> None:
    """The regenerated example material photographs to the bundled PNG (8-bit sRGB vs the simulator's 2.2)."""
    from mi_svbrdf.data.example_photos import render_examples
    from mi_svbrdf.nets.inference import load_inputs

    photo = render_examples(which=("flash",))["example_flash.png"]
    png, _ = load_inputs(rc.EXAMPLE_FLASH)
    assert (png[0, 0] - photo).abs().max() < 0.01


def test_markdown_names_both_nets_and_reads_the_numbers(env: types.SimpleNamespace) -> None:
    md = "\n".join(rc.real_checks_markdown(env.result))
    assert md.startswith("## Real-style checks")
    assert "**single**" in md and "**multi**" in md and "the trivial baseline" in md
    assert "| single | example_flash.png |" in md and "| multi | example_view1.png, example_view2.png" in md
    assert f"]({rc.EXAMPLES_PNG})" in md and f"]({rc.HIGHLIGHTS_PNG})" in md
    for m in env.result["highlight"]:
        assert f"| {m['name']} |" in md
    rel = env.result["mean_relative"]["multi"]
    line = next(s for s in md.splitlines() if s.startswith("- **multi**"))
    assert rc.verdict(rel) in line and f"relative leak {rel:.2f}" in line
    assert f"{env.result['mean_leak']['multi']:.2f} vs {env.result['mean_leak']['truth']:.2f} in the truth" in line
    # a different reading when the numbers say so
    baked = json.loads(json.dumps(env.result))
    baked["mean_relative"]["multi"] = 1.8
    line = next(s for s in rc.real_checks_markdown(baked) if s.startswith("- **multi**"))
    assert "bakes the highlight into diffuse" in line and "relative leak 1.80" in line


def test_one_net_only_is_skipped_and_said(env: types.SimpleNamespace) -> None:
    r = env.result_single
    assert r["nets"] == ["single"] and len(r["notes"]) == 1 and "'multi'" in r["notes"][0]
    assert {row["method"] for row in r["examples"]} == {"single", "trivial"}
    assert all(set(m["leak"]) == {"truth", "single", "trivial"} for m in r["highlight"])
    md = "\n".join(rc.real_checks_markdown(r))
    assert "**single**" in md and "**multi**" not in md and "multi skipped" in md
    assert (env.out_single / rc.EXAMPLES_PNG).stat().st_size > 1000


def test_bad_arguments_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="size"):
        rc.real_checks(tmp_path, size=8)
    with pytest.raises(ValueError, match="weights_dir"):
        rc.real_checks(tmp_path, weights_dir=tmp_path / "nonexistent", size=SIZE)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="out_dir"):
        rc.real_checks(tmp_path / "file", size=SIZE)
    with pytest.raises(ValueError, match="result"):
        rc.real_checks_markdown({"examples": []})
    with pytest.raises(ValueError, match="count"):
        rc.highlight_captures(0)


def _rows() -> list[dict[str, object]]:
    rows = []
    for ds in ("heldout", "foreign"):
        for m in range(2):
            row: dict[str, object] = {"dataset": ds, "material": m, "class": "c", "method": "trivial", "n": 1,
                                      "budget_s": None, "seconds": 1.0, "peak_mb": 1.0, "recoveries": 0}
            row.update({k: 0.1 + 0.01 * m for k in METRIC_KEYS})
            rows.append(row)
    return rows


def test_report_section_follows_generalisation(env: types.SimpleNamespace, tmp_path: Path) -> None:
    for name in (rc.JSON_NAME, rc.EXAMPLES_PNG, rc.HIGHLIGHTS_PNG):
        (tmp_path / name).write_bytes((env.out / name).read_bytes())
    files = report.write_evaluation_report(tmp_path, _rows(), reference_n=1)
    md = files["summary.md"].read_text()
    assert md.index("## Generalisation") < md.index("## Real-style checks")
    assert files["real_checks"].name == rc.JSON_NAME and files["real_highlights"].name == rc.HIGHLIGHTS_PNG
    (tmp_path / rc.JSON_NAME).unlink()  # no checks run: no section
    assert "Real-style" not in report.write_evaluation_report(tmp_path, _rows(), reference_n=1)["summary.md"].read_text()


def test_cli_switch() -> None:
    parser = argparse.ArgumentParser()
    eval_cli.add_parser(parser.add_subparsers(dest="command"))
    assert eval_cli.config_from_args(parser.parse_args(["evaluate", "--quick"])).real_checks is True
    assert eval_cli.config_from_args(parser.parse_args(["evaluate", "--quick", "--no-real-checks"])).real_checks \
        is False
