"""The README's Python example runs, and the CLI's first job works end to end."""
from __future__ import annotations

import argparse
import json
import pathlib
import re
import subprocess
import sys

import numpy as np

from mi_svbrdf import cli
from mi_svbrdf.io import material_io
from mi_svbrdf.io.image_io import read_image

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_readme_python_example_runs(tmp_path, monkeypatch):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no python example"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert namespace["img"].shape == (1, 2, 3, 128, 128)
    assert abs(float(namespace["a"]) - float(namespace["b"])) < 1e-5 * float(namespace["b"])
    assert (tmp_path / "out/tiles/material.json").is_file()


def test_readme_training_data_example_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    assert len(blocks) >= 2, "README has no training-data example"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(blocks[1], "README.md", "exec"), namespace)
    assert namespace["wood"].shape == (10, 128, 128)
    assert namespace["maps"].shape == (10, 64, 64)
    assert namespace["batch"].maps.shape == (4, 10, 64, 64)


def test_cli_render_writes_outputs(tmp_path, capsys):
    out = tmp_path / "render"
    assert cli.main(["render", "--size", "32", "--spp", "16", "--param", "filter_type=nearest", "--out", str(out)]) == 0
    for name in ("maps.png", "render.exr", "render.png", "texel.png", "summary.json", "material/material.json"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    losses = summary["rendering_loss_trivial_estimate"]
    assert losses["mitsuba"] > 0 and abs(losses["mitsuba"] - losses["torch"]) < 1e-4 * losses["torch"]
    # The Mitsuba render of the flash scene and the texel path agree (antialiasing aside).
    assert summary["texel_vs_mitsuba_mean_abs_diff"] < 0.03 * summary["mean_radiance"]
    image, _ = read_image(out / "render.exr")
    assert image.shape == (32, 32, 3) and np.isfinite(image).all() and image.mean() > 0.01
    maps = material_io.read_material(out / "material")
    assert maps.shape == (1, 10, 32, 32)
    assert not list(out.glob(".*tmp*")), "a temporary file was left behind"


def test_cli_errors_and_help(tmp_path, capsys):
    assert cli.main(["render", "--material", "example:nope", "--out", str(tmp_path)]) == 2
    assert "expected one of" in capsys.readouterr().err
    assert cli.main([]) == 2
    # the ``mi-svbrdf`` entry point (pyproject's project.scripts) in a fresh process
    entry = "from mi_svbrdf.cli import main; raise SystemExit(main())"
    res = subprocess.run([sys.executable, "-c", entry, "render", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "summary.json" in res.stdout and "--material" in res.stdout


def test_readme_first_command_captures_the_example_with_bundled_weights(tmp_path):
    """The README's first set-up command: `mi-svbrdf capture example -o out/capture`."""
    from mi_svbrdf.nets import weights as pretrained

    text = (ROOT / "README.md").read_text()
    first = re.search(r"```bash\n(?:#.*\n)*bash \.ci/setup\.sh && (?:\. \.venv/bin/activate && )?(mi-svbrdf [^\n]+)", text).group(1)
    args = first.split()[1:]
    assert args[:2] == ["capture", "example"], first
    assert "single" in pretrained.available(), "the bundled single-image weights are missing"
    out = tmp_path / "capture"
    assert cli.main(args[:-1] + [str(out)]) == 0
    maps = material_io.read_material(out)
    assert maps.shape == (1, 10, 256, 256) and bool(maps.isfinite().all())
    for name in ("contact_sheet.png", "relit.gif", "summary.json"):
        assert (out / name).is_file(), name


def _leaf_commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """``(command words, parser)`` of every runnable subcommand (``materials make``, ``optimize`` ...)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for name, child in subs[0].choices.items():
        yield from _leaf_commands(child, prefix + (name,))


#: Subcommands that write no files (none at present): exempt from the output-option convention.
WRITES_NOTHING: set[tuple[str, ...]] = set()
#: A file name with an extension, as a command's help lists its outputs (``summary.json``, ``log.csv`` ...).
OUTPUT_FILE = re.compile(r"\b[\w<>-]+\.(?:json|csv|png|exr|gif|pt|md|html|gltf|bin|xml|py)\b")


def test_every_command_that_writes_files_takes_out_and_lists_its_outputs():
    commands = [(words, p) for words, p in _leaf_commands(cli.build_parser()) if words not in WRITES_NOTHING]
    assert {w[0] for w, _ in commands} >= {"render", "optimize", "train", "capture"}
    problems = []
    for words, p in commands:
        options = [set(a.option_strings) for a in p._actions]
        if not any({"-o", "--out"} <= o for o in options):
            problems.append(f"mi-svbrdf {' '.join(words)}: expected one option -o/--out, got {sorted(set().union(*options))}")
        text = p.format_help()
        files = set(OUTPUT_FILE.findall(text))
        if not files or (len(files) < 2 and words != ("view",)):  # view writes one page
            problems.append(f"mi-svbrdf {' '.join(words)} --help: expected the files it writes, got {sorted(files)}")
    assert not problems, "\n".join(problems)
