"""Material bank: deterministic files, a complete index, the class filter and the CLI."""
from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import pytest
import torch

from mi_svbrdf.cli import materials as materials_cli
from mi_svbrdf.cli.common import OWNER_FILE
from mi_svbrdf.data import augment, bank, procedural
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.material_sets import MaterialSet

SIZE = 32
LINEAR_8BIT = 0.5 / 255 + 1e-6


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by relative path, with its bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_bytes(tmp_path: Path) -> None:
    a = bank.make_bank(tmp_path / "a", 4, size=SIZE, seed=3, mix_fraction=0.5, progress=False)
    bank.make_bank(tmp_path / "b", 4, size=SIZE, seed=3, mix_fraction=0.5, progress=False)
    bank.make_bank(tmp_path / "c", 4, size=SIZE, seed=4, mix_fraction=0.5, progress=False)
    fa, fb, fc = files(tmp_path / "a"), files(tmp_path / "b"), files(tmp_path / "c")
    assert len(fa) == 4 + 3 and fa == fb  # 4 strips, index.json, index.csv, contact_sheet.png
    assert fa["index.json"] != fc["index.json"]
    strips_a = [v for k, v in sorted(fa.items()) if k.startswith("0")]
    strips_c = [v for k, v in sorted(fc.items()) if k.startswith("0")]
    assert all(x != y for x, y in zip(strips_a, strips_c))
    assert a.materials_per_second > 0 and a.contact_sheet == tmp_path / "a" / "contact_sheet.png"


def test_index_records_everything_needed_to_rebuild(tmp_path: Path) -> None:
    result = bank.make_bank(tmp_path, 6, size=SIZE, seed=1, mix_fraction=0.5, progress=False)
    index = json.loads((tmp_path / "index.json").read_text())
    assert index == json.loads(json.dumps(result.index))
    assert index["seed"] == 1 and index["count"] == 6 and index["classes"] == list(procedural.CLASSES)
    materials = index["materials"]
    assert [m["file"][:7] for m in materials] == [f"{i:06d}_" for i in range(6)]
    assert any(m["mix_alpha"] is not None for m in materials) and any(m["mix_alpha"] is None for m in materials)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing may be skipped
        loaded = MaterialSet(tmp_path, size=SIZE)
    assert [name for name, _ in (loaded[i] for i in range(6))] == [m["file"] for m in materials]
    for i, m in enumerate(materials):
        assert m["file"] == bank.file_name(i, m["classes"], "strip")
        assert len(m["classes"]) == len(m["parameters"]) == len(m["seeds"]) == (1 if m["mix_alpha"] is None else 2)
        for name, params in zip(m["classes"], m["parameters"]):
            assert procedural.validate_parameters(name, params) == params
        if m["mix_alpha"] is not None:
            assert 0.1 <= m["mix_alpha"] <= 0.9
        rot = m["rotation"]
        assert -torch.pi <= rot["angle"] <= torch.pi and rot["generated_size"] == 46
        # The record alone rebuilds the stored maps (up to 8-bit storage), without the bank's code.
        parts = [procedural.generate(name, s, rot["generated_size"], **p)[None]
                 for name, p, s in zip(m["classes"], m["parameters"], m["seeds"])]
        rebuilt = parts[0] if m["mix_alpha"] is None else augment.mix(parts[0], parts[1], m["mix_alpha"])
        rebuilt = augment.transform_maps(rebuilt, rot["angle"], rot["scale"], rot["translation"], SIZE)[0]
        stored = loaded[i][1]
        assert (rebuilt[3:] - stored[3:]).abs().max() <= LINEAR_8BIT, m["file"]
        assert (rebuilt[:3] - stored[:3]).abs().max() < 0.01
    csv_lines = (tmp_path / "index.csv").read_text().splitlines()
    assert len(csv_lines) == 7 and csv_lines[0].startswith("file,class,class_b,seed")
    assert csv_lines[1].startswith(materials[0]["file"] + ",")


def test_recipe_options() -> None:
    plain = bank.recipe(7, 2, ["wood", "metal"], SIZE, mix_fraction=0.0, rotation="none")
    always = bank.recipe(7, 2, ["wood", "metal"], SIZE, mix_fraction=1.0, rotation="quarter")
    assert plain["mix_alpha"] is None and plain["rotation"] is None and len(plain["classes"]) == 1
    assert always["mix_alpha"] is not None and len(always["classes"]) == 2
    assert always["classes"][0] == plain["classes"][0] and always["parameters"][0] == plain["parameters"][0]
    assert always["rotation"]["angle"] in [k * torch.pi / 2 for k in range(4)]
    at_defaults = bank.recipe(7, 2, ["tiles"], SIZE, spread=0.0)
    assert at_defaults["parameters"][0] == procedural.validate_parameters("tiles", {})


def test_cli_class_filter_folder_format_and_stale_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bank"
    argv = ["materials", "make", "--count", "4", "--size", str(SIZE), "--out", str(out), "--classes", "wood,metal",
            "--format", "folder", "--seed", "5", "--mix-fraction", "0.5", "--quiet"]
    assert materials_cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "wrote 4 materials" in printed and "materials/s" in printed and "contact_sheet.png" in printed
    index = json.loads((out / "index.json").read_text())
    assert {c for m in index["materials"] for c in m["classes"]} <= {"wood", "metal"}
    assert index["classes"] == ["wood", "metal"] and index["file_format"] == "folder"
    assert all((out / m["file"] / "material.json").is_file() for m in index["materials"])
    # no temporary files left (the one hidden file records the command that wrote the folder)
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [OWNER_FILE]
    sheet, _ = read_image(out / "contact_sheet.png")
    assert sheet.shape[2] == 3 and sheet.shape[1] > 4 * 5 * bank.THUMB and sheet.std() > 0.05
    loaded = MaterialSet(out, size=SIZE)
    assert len(loaded) == 4 and loaded[3][1].shape == (10, SIZE, SIZE)
    # A smaller bank in the same folder removes what the old index listed and the new one does not.
    assert materials_cli.main(argv[:3] + ["2"] + argv[4:]) == 0
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == [m["file"] for m in index["materials"][:2]]
    # Errors: exit code 2 and a message naming the argument.
    assert materials_cli.main(["materials", "make", "--count", "2", "--out", str(out), "--classes", "marble"]) == 2
    assert "classes: expected names among" in capsys.readouterr().err
    assert materials_cli.main(["materials"]) == 2


def test_add_parser_wires_a_materials_command() -> None:
    parser = argparse.ArgumentParser(prog="mi-svbrdf")
    materials_cli.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["materials", "make", "--count", "3", "--out", "x"])
    assert args.func is materials_cli.cmd_make and args.count == 3 and args.size == 256 and args.format == "strip"
    assert args.classes is None and args.mix_fraction == 0.3 and args.rotation == "any"


def test_workers_give_the_same_bank(tmp_path: Path) -> None:
    bank.make_bank(tmp_path / "one", 3, size=SIZE, seed=2, progress=False, sheet=0)
    bank.make_bank(tmp_path / "two", 3, size=SIZE, seed=2, workers=2, progress=False, sheet=0)
    assert files(tmp_path / "one") == files(tmp_path / "two")
