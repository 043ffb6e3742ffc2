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


def _python_blocks(path: pathlib.Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def _run_block(block: str, name: str, tmp_path: pathlib.Path, monkeypatch) -> dict:
    """Run a documented Python block as a user would, from a folder that is not the clone's (its files found through
    the package, as the user's are: no path rewritten)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    namespace: dict = {}
    exec(compile(block, name, "exec"), namespace)
    return namespace


def test_readme_python_example_runs(tmp_path, monkeypatch):
    blocks = _python_blocks(ROOT / "README.md")
    assert blocks, "README has no python example"
    assert len(blocks[0].strip().splitlines()) <= 15, "the README's Python example is longer than 15 lines"
    namespace = _run_block(blocks[0], "README.md", tmp_path, monkeypatch)
    assert namespace["img"].shape == (1, 1, 3, 128, 128) and namespace["maps"].shape == (1, 10, 256, 256)
    assert (tmp_path / "out/predicted/material.json").is_file()


def test_python_api_guide_example_runs(tmp_path, monkeypatch):
    namespace = _run_block(_python_blocks(ROOT / "docs/guides/python-api.md")[0], "python-api.md", tmp_path, monkeypatch)
    assert namespace["img"].shape == (1, 2, 3, 128, 128)
    a, b = float(namespace["a"].detach()), float(namespace["b"].detach())
    assert abs(a - b) < 1e-5 * b
    assert (tmp_path / "out/tiles/material.json").is_file()


def test_training_data_guide_example_runs(tmp_path, monkeypatch):
    blocks = _python_blocks(ROOT / "docs/guides/training-data.md")
    assert blocks, "the training-data guide has no example"
    namespace = _run_block(blocks[0], "training-data.md", tmp_path, monkeypatch)
    assert namespace["wood"].shape == (10, 128, 128)
    assert namespace["maps"].shape == (10, 64, 64)
    assert namespace["batch"].maps.shape == (4, 10, 64, 64)


def _documents() -> list[pathlib.Path]:
    """The README and every guide and reference page in docs/."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_every_documented_command_parses():
    """Every ``mi-svbrdf ...`` line of a bash block in the README and docs/ is a command the CLI accepts."""
    parser = cli.build_parser()
    problems, count = [], 0
    for doc in _documents():
        for block in re.findall(r"```bash\n(.*?)```", doc.read_text(), flags=re.S):
            for line in block.replace("\\\n", " ").splitlines():
                for part in re.split(r"&&|;", line.split("#", 1)[0]):
                    words = part.split()
                    if not words or words[0] != "mi-svbrdf":
                        continue
                    count += 1
                    try:
                        parser.parse_args(words[1:])
                    except SystemExit:
                        problems.append(f"{doc.relative_to(ROOT)}: {part.strip()}")
    assert count >= 20, count
    assert not problems, "\n".join(problems)


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
OUTPUT_FILE = re.compile(r"\b[\w<>-]+\.(?:json|csv|png|exr|gif|pt|md|html|gltf|bin|xml|py|pdf)\b")


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


def test_results_page_is_what_its_script_generates(tmp_path):
    """docs/results.md is generated from the weights' manifest and docs/benchmarks/: never hand-edited figures."""
    out = tmp_path / "results.md"
    res = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "make_results.py"), "--out", str(out)],
                         capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    assert out.read_text() == (ROOT / "docs" / "results.md").read_text(), \
        "docs/results.md is stale: run python benchmarks/make_results.py"
