"""First-hour behaviour of the command line: re-runs replace their own outputs, a folder belongs to the
command that wrote it, -o naming a file is one line before any work, Ctrl-C says one line, export and
render print one line, calibrate records the maps' BRDF model."""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from mi_svbrdf import cli
from mi_svbrdf.cli import common
from mi_svbrdf.core import brdf_measured as BM
from mi_svbrdf.core import maps as M
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io import material_io
from mi_svbrdf.io import measured as MS
from mi_svbrdf.io.atomic import clear_owned
from mi_svbrdf.io.calibrated_photos import capture_from_simulator, save_capture
from mi_svbrdf.eval import measured_comparison as C
from tests.conftest import export_tiny_net
from tests.test_cli_readme import _leaf_commands


def synthetic_capture(folder: Path, size: int, n: int) -> Path:
    """A calibrated capture of ``n`` photos of a procedural material (as tests/test_optimize.py makes)."""
    gt = procedural.generate("tiles", 1, size)[None]
    cfg = capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=4.0)
    cap = sample_captures(1, n, cfg, torch.Generator().manual_seed(0))
    spec, images = capture_from_simulator(cap.images(slice(0, n)), 0, render_captures(gt, cap, backend="torch"))
    save_capture(folder / "capture.json", spec, images)
    return folder / "capture.json"


def test_optimize_again_replaces_only_its_own_outputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fit"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "renders").mkdir()
    (out / "renders" / "keep.txt").write_text("mine too")
    for n in (4, 2):
        capture = synthetic_capture(tmp_path / f"cap{n}", 16, n)
        assert cli.main(["optimize", "--capture", str(capture), "-o", str(out), "--iterations", "3",
                         "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"replacing the previous results in {out}/" in err
    assert sorted(p.name for p in (out / "renders").glob("*.png")) == ["000.png", "001.png"]
    assert json.loads((out / "summary.json").read_text())["photos"] == 2
    assert (out / "notes.txt").read_text() == "mine" and (out / "renders" / "keep.txt").is_file()
    assert (out / "material" / "normal.png").is_file()


def test_clear_owned_keeps_inputs_and_unrelated_files(tmp_path: Path) -> None:
    for name in ("summary.json", "renders/000.png", "renders/001.png", "renders/photo.png", ".summary.tmp0a1b2c3d.json",
                 "other/000.png"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("x")
    removed = clear_owned(tmp_path, ["summary.json", "renders/[0-9][0-9][0-9].png"],
                          keep=[tmp_path / "renders" / "001.png"])
    assert [p.relative_to(tmp_path).as_posix() for p in removed] == [
        ".summary.tmp0a1b2c3d.json", "renders/000.png", "summary.json"]
    left = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert left == ["other/000.png", "renders/001.png", "renders/photo.png"]
    (tmp_path / "only").mkdir()
    (tmp_path / "only" / "a.png").write_text("x")
    clear_owned(tmp_path, ["only/a.png"])
    assert not (tmp_path / "only").exists()  # a folder the removal left empty goes too
    assert clear_owned(tmp_path / "missing", ["x"]) == []


#: Each command that writes a folder, with arguments it accepts (the checks of -o come before the rest).
FOLDER_COMMANDS = {
    "render": "render --size 16 --spp 1", "materials make": "materials make --count 1 --size 8",
    "dataset render": "dataset render --materials .", "optimize": "optimize --capture example --iterations 3",
    "capture-file make": "capture-file make example --camera 0,0,2", "capture-file import": "capture-file import .",
    "train": "train single", "capture": "capture example", "large-scale": "large-scale example",
    "evaluate": "evaluate --quick", "ablations": "ablations --quick", "rectify": "rectify example",
    "export": "export example:tiles --format gltf", "calibrate": "calibrate example:tiles --measured m.binary",
    "frame": "frame tags", "scan": "scan example --frame tags",
}


def _run_quietly(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_every_command_that_writes_a_folder_is_listed() -> None:
    writers = {" ".join(words) for words, p in _leaf_commands(cli.build_parser())
               if any(a.dest == "force" for a in p._actions)} - {"view"}
    assert writers and writers <= set(FOLDER_COMMANDS), sorted(writers - set(FOLDER_COMMANDS))
    view = dict((" ".join(w), p) for w, p in _leaf_commands(cli.build_parser()))["view"]
    force = next(a for a in view._actions if a.dest == "force")  # view writes one file: --force replaces that file
    assert "file" in force.help and "folder" not in force.help and not view._defaults.get("_owns")


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_out_naming_a_file_is_one_line_before_any_work(command: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "results"
    target.write_text("not a folder")
    code, out, err = _run_quietly([*FOLDER_COMMANDS[command].split(), "-o", str(target)], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err == (f"mi-svbrdf {command}: error: -o/--out: expected an output folder (a new one, or one this "
                   f"command wrote), got the existing file {target}\n")
    assert target.read_text() == "not a folder" and sorted(tmp_path.iterdir()) == [target]


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_another_commands_folder_is_refused_before_any_work(command: str, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    out.mkdir()
    (out / common.OWNER_FILE).write_text(json.dumps({"command": "mi-svbrdf elsewhere", "outputs": ["a.txt"]}))
    (out / "a.txt").write_text("its result")
    code, stdout, err = _run_quietly([*FOLDER_COMMANDS[command].split(), "-o", str(out)], capsys)
    assert code == 2 and stdout == "" and err.count("\n") == 1, err
    assert err.startswith(f"mi-svbrdf {command}: error: -o/--out: expected a new folder or one `mi-svbrdf "
                          f"{command}` wrote, got {out}/, which holds the results of `mi-svbrdf elsewhere`"), err
    assert "--force" in err and "last run" not in err
    assert sorted(p.name for p in out.iterdir()) == [common.OWNER_FILE, "a.txt"]


def _first_output_name(command: str) -> str:
    """A file name (no pattern) that ``mi-svbrdf COMMAND`` writes into its folder (its ``_owns``)."""
    parser = dict((" ".join(w), p) for w, p in _leaf_commands(cli.build_parser()))[command]
    names = [o for o in parser._defaults.get("_owns") or () if not re.search(r"[*?\[]", o)]
    assert names, f"mi-svbrdf {command}: expected the names of its outputs in _owns"
    return names[0]


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_the_users_own_files_with_output_names_are_refused_before_any_work(command: str, tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    (out / "notes").mkdir(parents=True)
    name = _first_output_name(command)
    (out / name).parent.mkdir(parents=True, exist_ok=True)
    (out / name).write_text("the user's own")
    (out / "notes" / "mine.txt").write_text("unrelated")
    code, stdout, err = _run_quietly([*FOLDER_COMMANDS[command].split(), "-o", str(out)], capsys)
    assert code == 2 and stdout == "" and err.count("\n") == 1, err
    assert err == (f"mi-svbrdf {command}: error: -o/--out: expected a new folder or one `mi-svbrdf {command}` "
                   f"wrote, got {out}/, which holds files with its output names that no mi-svbrdf command "
                   f"recorded: {name} (choose another folder, or --force to replace them)\n"), err
    assert (out / name).read_text() == "the user's own" and not (out / common.OWNER_FILE).exists()


def test_capture_refuses_the_users_normal_and_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "that_folder"
    out.mkdir()
    for name in ("normal.png", "summary.json", "photo.jpg"):
        (out / name).write_text("mine")
    code, _, err = _run_quietly(["capture", "example", "-o", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert "no mi-svbrdf command recorded: normal.png, summary.json (choose another folder" in err, err
    assert all((out / n).read_text() == "mine" for n in ("normal.png", "summary.json", "photo.jpg"))


def test_force_replaces_the_users_files_and_the_record_lists_what_was_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "export"
    out.mkdir()
    (out / "material.gltf").write_text("mine")
    (out / "notes.txt").write_text("mine")
    argv = ["export", "example:tiles", "--format", "gltf", "-o", str(out)]
    assert _run_quietly(argv, capsys)[0] == 2
    code, _, err = _run_quietly([*argv, "--force"], capsys)
    assert code == 0, err
    assert f"mi-svbrdf export: --force: replacing 1 file in {out}/ that no command recorded: material.gltf\n" in err
    assert (out / "material.gltf").read_text() != "mine" and (out / "notes.txt").read_text() == "mine"
    recorded = common.folder_owner(out)["outputs"]
    written = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()
                     and p.name not in (common.OWNER_FILE, "notes.txt"))
    assert recorded == written and "scene.xml" not in recorded, (recorded, written)
    assert _run_quietly(argv, capsys)[0] == 0  # its own folder now: no --force needed


def test_the_record_lists_what_capture_wrote(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    weights = tmp_path / "weights"
    weights.mkdir()
    export_tiny_net(weights, "single", 64)
    out = tmp_path / "capture"
    argv = ["capture", "example", "--weights", str(weights), "--frames", "0", "--symmetries", "1", "-o", str(out)]
    code, _, err = _run_quietly(argv, capsys)
    assert code == 0, err
    recorded = common.folder_owner(out)["outputs"]
    written = sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                     if p.is_file() and p.name != common.OWNER_FILE)
    assert recorded == written, (recorded, written)
    assert "diffuse.exr" not in recorded and "exr/diffuse.png" not in recorded and "exr/diffuse.exr" in recorded


def test_a_folder_belongs_to_the_command_that_wrote_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    weights = tmp_path / "weights"
    weights.mkdir()
    export_tiny_net(weights, "single", 64)
    out = tmp_path / "results"
    capture = synthetic_capture(tmp_path / "cap", 16, 2)
    fit = ["optimize", "--capture", str(capture), "-o", str(out), "--iterations", "3", "--no-progress"]
    assert _run_quietly(fit, capsys)[0] == 0
    (out / "notes.txt").write_text("mine")
    assert common.folder_owner(out)["command"] == "mi-svbrdf optimize"
    fitted = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    snap = ["capture", "example", "--weights", str(weights), "--frames", "0", "--symmetries", "1", "-o", str(out)]
    code, _, err = _run_quietly(snap, capsys)  # another command: refused, the folder untouched
    assert code == 2 and err.count("\n") == 1 and "holds the results of `mi-svbrdf optimize`" in err, err
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == fitted
    code, _, err = _run_quietly([*snap, "--force"], capsys)  # --force: optimize's results go, the user's file stays
    assert code == 0, err
    assert err == f"mi-svbrdf capture: --force: replacing the results of `mi-svbrdf optimize` in {out}/ (11 files removed)\n"
    left = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert not any(name.startswith(("material/", "renders/", "history", "loss")) for name in left), left
    assert "notes.txt" in left and "normal.png" in left and "exr/normal.exr" in left
    assert common.folder_owner(out)["command"] == "mi-svbrdf capture"
    code, _, err = _run_quietly(snap, capsys)  # the same command again: it replaces its own files
    assert code == 0 and f"mi-svbrdf capture: replacing the previous results in {out}/" in err, err
    assert (out / "notes.txt").read_text() == "mine"
    code, _, err = _run_quietly(fit, capsys)  # and optimize is now the one refused
    assert code == 2 and "holds the results of `mi-svbrdf capture`" in err, err


def test_a_failed_command_leaves_no_claim(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "dataset"
    code, _, err = _run_quietly(["dataset", "render", "--materials", str(tmp_path / "empty"), "-o", str(out)], capsys)
    assert code == 2 and not out.exists(), err


def _interrupt(args: argparse.Namespace) -> int:
    raise KeyboardInterrupt


def _interrupt_while_writing(args: argparse.Namespace) -> int:
    common.replace_outputs(args, args.out, ["summary.json"])
    raise KeyboardInterrupt


@pytest.mark.parametrize("command, func, expected", [
    ("export", _interrupt, "interrupted before writing; nothing of this run was written to {out}/"),
    ("export", _interrupt_while_writing, "interrupted while writing; the results in {out}/ are incomplete"),
    ("dataset", _interrupt, "interrupted; partial results in {out}/ (re-run the same command to resume)"),
])
def test_ctrl_c_prints_one_line_and_exits_130(command: str, func, expected: str, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    module = {"export": cli.export, "dataset": cli.dataset}[command]
    name = {"export": "cmd_export", "dataset": "cmd_render"}[command]
    monkeypatch.setattr(module, name, func)
    out = tmp_path / "out"
    argv = {"export": ["export", "example:tiles", "--format", "gltf", "-o", str(out)],
            "dataset": ["dataset", "render", "--materials", str(tmp_path), "-o", str(out)]}[command]
    assert cli.main(argv) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    prog = "mi-svbrdf export" if command == "export" else "mi-svbrdf dataset render"
    assert err.startswith(f"{prog}: ") and expected.format(out=out) in err, err


def test_export_prints_one_line_and_replaces_another_format(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "export"
    assert cli.main(["export", "example:tiles", "--format", "mitsuba", "-o", str(out)]) == 0
    assert (out / "scene.xml").is_file()
    capsys.readouterr()
    assert cli.main(["export", "example:tiles", "--format", "gltf", "-o", str(out)]) == 0
    printed = capsys.readouterr().out.strip()
    assert "\n" not in printed and str(out) in printed and "material.gltf" in printed and "{" not in printed
    assert not (out / "scene.xml").exists() and not (out / "textures" / "diffuse.exr").exists()
    assert json.loads((out / "export.json").read_text())["format"] == "gltf"


def test_render_prints_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "render"
    assert cli.main(["render", "--material", "example:metal_plate", "--size", "16", "--spp", "1", "-o", str(out)]) == 0
    printed = capsys.readouterr().out.strip()
    assert "\n" not in printed and f"wrote {out}/" in printed and "{" not in printed
    assert json.loads((out / "summary.json").read_text())["material"] == "example:metal_plate"


def test_render_says_why_texel_and_mitsuba_differ_on_a_glossy_metal(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """The texel renderer samples each pixel's centre, Mitsuba integrates its area: on the glossy metal plate at
    64 px their mean |diff| is large (0.148 at 16 spp, 0.141 at 256: not noise), but the texel image averaged
    over 4x4 points per pixel comes within a fraction of it (0.011 at 256 spp): a sampling difference, no bug."""
    out = tmp_path / "render"
    assert cli.main(["render", "--material", "example:metal_plate", "--size", "64", "--spp", "128", "-o",
                     str(out)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    point, area = summary["texel_vs_mitsuba_mean_abs_diff"], summary["texel_4x4_vs_mitsuba_mean_abs_diff"]
    assert point > 0.1 and area < point / 4, (point, area)
    assert abs(point - 0.148) < 0.03 and "samples each pixel's centre, Mitsuba its area" in printed
    assert f"{area:.4f} with the texel image over 4x4 points" in printed and "highlights above 1" in printed


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_calibrate_report_records_the_model(distribution: str, tmp_path: Path) -> None:
    maps = M.constant_maps(1, 8, 8, diffuse=(0.2, 0.3, 0.4), specular=(0.05, 0.05, 0.05), roughness=0.3)
    material_io.write_material(tmp_path / "material", maps, fmt="exr", distribution=distribution)
    samples = BM.gonio_samples(C.average_material(maps, distribution=distribution).brdf, [45.0],
                               np.arange(0.0, 86.0, 2.5), np.arange(0.0, 181.0, 10.0))
    MS.write_tabulated_csv(tmp_path / "gonio.csv", *samples)
    out = tmp_path / "calibrate"
    assert cli.main(["calibrate", str(tmp_path / "material"), "--measured", str(tmp_path / "gonio.csv"),
                     "--incidences", "45", "--no-fit", "-o", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["distribution"] == distribution
    assert f"({distribution} model)" in (out / "summary.md").read_text()


ROOT = Path(__file__).resolve().parents[1]


def test_the_optimise_guide_quotes_the_line_optimize_prints(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The guide's figures are named as the command names them: its last line, with the RMSE against the photos
    (the ground-truth figures, which the command does not print, are the re-rendering RMSE and the map RMSEs)."""
    from mi_svbrdf.cli.optimize import STOP_WORDS

    guide = (ROOT / "docs" / "guides" / "optimise.md").read_text()
    quoted = re.search(r"\(`(\d+ photo\(s\): [^`]*)`", guide).group(1)
    assert "display RMSE against the photos 0.0107" in quoted
    assert "re-rendering RMSE 0.023" in " ".join(guide.replace("**", "").split())
    # the figures, the stop reason and the folder vary; the words do not
    pattern = re.sub(r"\d+(?:\\\.\d+)?", "[0-9.]+", re.escape(quoted.replace("out/optimize/", "OUT/")))
    pattern = pattern.replace("OUT/", ".+/").replace(r"\.\.\.", ".*")
    any_stop = r"\((?:" + "|".join(map(re.escape, STOP_WORDS.values())) + r")\)"
    for words in STOP_WORDS.values():  # the stop reason quoted, in words: any other may be printed
        pattern = pattern.replace(re.escape(f"({words})"), any_stop)
    capture = synthetic_capture(tmp_path / "cap", 16, 2)
    assert cli.main(["optimize", "--capture", str(capture), "-o", str(tmp_path / "fit"), "--iterations", "3",
                     "--no-progress"]) == 0
    printed = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(pattern, printed), (pattern, printed)


def _bash_blocks(page: Path) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", page.read_text(), flags=re.S)


def test_maintainer_commands_live_on_the_maintainers_page() -> None:
    """A user's pages hold no command that rewrites the package's files (bundling into mi_svbrdf/weights/,
    --record-foreign, re-making assets): those are on docs/maintainers.md, which the capture guide links."""
    maintainer = re.compile(r"python -m mi_svbrdf\.cli\.(?:bundle|example_\w+)\b(?![^\n]*(?:-o|--out|--dry-run) )")
    user_pages = [ROOT / "README.md", *sorted((ROOT / "docs" / "guides").glob("*.md"))]
    found = [(page.name, line.strip()) for page in user_pages for block in _bash_blocks(page)
             for line in block.splitlines() if maintainer.search(line) or "--record-foreign" in line]
    assert not found, found
    page = ROOT / "docs" / "maintainers.md"
    lines = "\n".join(_bash_blocks(page))
    assert "python -m mi_svbrdf.cli.bundle multi --record-foreign" in lines and "RUN/" not in lines
    assert "](../maintainers.md)" in (ROOT / "docs" / "guides" / "capture.md").read_text()


#: The ``mi-svbrdf`` command as a new process: the console script, and ``python -m mi_svbrdf.cli``.
LAUNCHERS = {"script": [str(Path(sys.executable).with_name("mi-svbrdf"))],
             "module": [sys.executable, "-m", "mi_svbrdf.cli"]}


@pytest.mark.parametrize("launcher", sorted(LAUNCHERS))
@pytest.mark.parametrize("delay", [0.3, 1.0])
def test_ctrl_c_while_the_command_starts_is_one_line_and_exit_130(launcher: str, delay: float, tmp_path: Path) -> None:
    """Ctrl-C in the first second (the command imports torch, Mitsuba and its modules) ends it like Ctrl-C later:
    one line, exit code 130, nothing written."""
    out = tmp_path / "capture"
    process = subprocess.Popen([*LAUNCHERS[launcher], "capture", "example", "-o", str(out)], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 130 and stdout == "" and stderr.count("\n") == 1, (process.returncode, stderr)
    assert stderr in ("mi-svbrdf capture: interrupted while starting; nothing was written\n",
                      f"mi-svbrdf capture: interrupted before writing; nothing of this run was written to {out}/ "
                      "(re-run the command)\n"), stderr
    if delay < 0.5:  # torch alone takes longer to import
        assert "while starting" in stderr
    assert not out.exists()


def _imported(argv: list[str], tmp_path: Path) -> set[str]:
    """The modules ``mi-svbrdf ARGV`` (the console script) imports (``PYTHONPROFILEIMPORTTIME``)."""
    env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1"}
    res = subprocess.run([*LAUNCHERS["script"], *argv], cwd=tmp_path, env=env, capture_output=True, text=True,
                         check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    return {line.rsplit("|", 1)[1].strip() for line in res.stderr.splitlines() if line.startswith("import time:")}


def test_help_imports_no_subcommand_and_neither_torch_nor_mitsuba(tmp_path: Path) -> None:
    modules = _imported(["--help"], tmp_path)
    assert "mi_svbrdf.cli" in modules and not {"torch", "mitsuba", "drjit", "numpy"} & modules
    assert not [m for m in modules if m.startswith("mi_svbrdf.") and m not in (
        "mi_svbrdf.cli", "mi_svbrdf.cli.common", "mi_svbrdf.assets", "mi_svbrdf.io", "mi_svbrdf.io.atomic",
        "mi_svbrdf.threads")], modules
    # a subcommand imports its own modules only: export neither the networks nor the evaluation
    modules = _imported(["export", "--help"], tmp_path)
    assert "mi_svbrdf.io.export" in modules  # (importlib.import_module's own module is not timed: its imports are)
    assert not [m for m in modules if m.startswith(("mi_svbrdf.eval", "mi_svbrdf.nets", "mi_svbrdf.cli.capture",
                                                    "mi_svbrdf.cli.ablations", "mi_svbrdf.optim"))], modules


def test_the_package_still_sets_up_on_import(tmp_path: Path) -> None:
    """Outside the mi-svbrdf command, importing mi_svbrdf selects a variant and registers the plugins, as before."""
    code = ("import mitsuba as mi, mi_svbrdf; assert mi.variant() is not None; "
            "mi.load_dict({'type': 'svbrdf_ggx'}); print(mi_svbrdf.render.__module__)")
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stdout.strip() == "mi_svbrdf.core.render", res.stderr[-2000:]


def test_the_list_of_commands_is_the_commands_own() -> None:
    """``mi-svbrdf --help`` lists the subcommands without importing them: its lines are theirs."""
    sub = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert {c.dest: c.help for c in sub._choices_actions} == {name: line for name, (_, line) in cli.COMMANDS.items()}
    assert [n for n in sub.choices] == list(cli.COMMANDS)


#: A command line inside a help text: ``mi-svbrdf`` and its words, up to the end of the quote, the line or
#: the next command (``&&``, ``;``, ``|``).
_COMMAND_LINE = re.compile(r"mi-svbrdf((?: [a-z][\w-]*)+)([^`\n&;|]*)")
#: Another program's command line inside a help text (its options are not mi-svbrdf's).
_OTHER_PROGRAM = re.compile(r"\b(?:blender|python3? -m|jupyter|pip) [^`\n&;|]*")
#: An option as a help text mentions it.
_OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _options_of(parser: argparse.ArgumentParser) -> set[str]:
    return {o for a in parser._actions for o in a.option_strings}


def test_every_option_a_help_mentions_is_accepted_by_its_command() -> None:
    parsers = {w: p for w, p in _leaf_commands(cli.build_parser())}
    problems = []
    for words, parser in parsers.items():
        text = _OTHER_PROGRAM.sub("", parser.format_help())
        mentions: list[tuple[tuple[str, ...], str]] = []
        for match in _COMMAND_LINE.finditer(text):  # another command's line: its options are that command's
            named = tuple(match.group(1).split())
            other = next((w for w in parsers if named[:len(w)] == w), None)
            if other is not None:
                mentions += [(other, o) for o in _OPTION.findall(match.group(2))]
        own = _COMMAND_LINE.sub("", text)
        mentions += [(words, o) for o in _OPTION.findall(own)]
        for command, option in mentions:
            if option not in _options_of(parsers[command]):
                problems.append(f"mi-svbrdf {' '.join(words)} --help: mentions {option}, which "
                                f"`mi-svbrdf {' '.join(command)}` does not accept")
    assert not problems, "\n".join(sorted(set(problems)))


@pytest.mark.parametrize("argv", [["capture", "example", "--bogus"],
                                  ["capture-file", "import", ".", "-o", "x", "--bogus"],
                                  ["optimize", "--capture", "example", "-o", "x", "--bogus", "1"]])
def test_an_unknown_option_names_the_subcommand(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    words = " ".join(argv[:2] if argv[0] == "capture-file" else argv[:1])
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert err.startswith(f"usage: mi-svbrdf {words} ") and "usage: mi-svbrdf [-h] COMMAND" not in err, err
    assert err.rstrip("\n").endswith(f"mi-svbrdf {words}: error: unrecognized arguments: "
                                     f"{' '.join(argv[argv.index('--bogus'):])}"), err


def test_the_readmes_command_table_lists_every_command() -> None:
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"^\| `([a-z][\w -]*)` \|", readme, flags=re.MULTILINE))
    commands = {" ".join(words) for words, _ in _leaf_commands(cli.build_parser())}
    assert commands <= listed, sorted(commands - listed)


def test_no_progress_bar_when_stderr_is_no_terminal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run_quietly(["materials", "make", "--count", "2", "--size", "8", "-o", str(tmp_path / "bank")],
                                capsys)
    assert code == 0 and "\r" not in err and "%|" not in err, repr(err)

    class Terminal:
        def isatty(self) -> bool:
            return True

    args = argparse.Namespace(no_progress=False)
    common.bars_for_terminals(args, Terminal())
    assert args.no_progress is False  # a terminal keeps the bar
    common.bars_for_terminals(args, tmp_path.joinpath("log.txt").open("w"))
    assert args.no_progress is True


def test_the_residual_panels_say_what_grey_means() -> None:
    from mi_svbrdf.cli.optimize import DIFFERENCE_LEGEND, residual_panel

    photo = torch.full((3, 64, 64), 0.2)
    panel = residual_panel(photo, photo)
    rows = np.flatnonzero(np.abs(panel[:, 2 * 64:, :] - 0.5).max(axis=(1, 2)) < 0.01)  # the mid-grey difference
    band = int(rows[0])
    assert panel.shape[1] == 3 * 64 and len(rows) == 64 and panel.shape[0] > band + 64 + 12
    assert "grey" in DIFFERENCE_LEGEND and "colour cast" in DIFFERENCE_LEGEND
    assert (panel[band + 64:] > 0.9).any()  # the legend's text below the panels
    # at 512 px a panel (a 1536 px strip) the text grows with it: its band and legend lines are taller
    big = residual_panel(torch.full((3, 512, 512), 0.2), torch.full((3, 512, 512), 0.2))
    big_band = int(np.flatnonzero(np.abs(big[:, 1024:, :] - 0.5).max(axis=(1, 2)) < 0.01)[0])

    def text_rows(image: np.ndarray, rows: slice) -> int:  # how many rows of a label band hold text
        return int((image[rows] > 0.5).any(axis=(1, 2)).sum())

    assert text_rows(big, slice(0, big_band)) >= 1.7 * text_rows(panel, slice(0, band))  # 21 px text against 11


def _budget_result(rates: tuple[float, float]):
    """A fit stopped by its budget whose one run took 150 steps at ``rates[0]`` steps/s, then 150 at ``rates[1]``."""
    from mi_svbrdf.optim.fit import OptimizeResult

    history, t = [], 0.0
    for step in range(300):
        t += 1.0 / (rates[0] if step < 150 else rates[1])
        history.append((t, step + 1, 1.0))
    return OptimizeResult(torch.zeros(1, 10, 4, 4), history=history, stop_reason="budget", steps=300,
                          phases=[("fit", 0)])


def test_the_budget_note_fits_where_the_capture_came_from_and_names_load(tmp_path: Path) -> None:
    from mi_svbrdf.cli.capture_file import smaller_photos_advice
    from mi_svbrdf.optim.fit import OptimizeConfig, stop_notes

    folder = tmp_path / "imported"
    folder.mkdir()
    (folder / common.OWNER_FILE).write_text(json.dumps({"command": "mi-svbrdf capture-file import",
                                                        "outputs": ["capture.json"]}))
    advice = smaller_photos_advice(folder / "capture.json")
    assert advice == "a smaller --size in capture-file import"
    (tmp_path / "rectified").mkdir()
    (tmp_path / "rectified" / "rectify.json").write_text("{}")
    assert smaller_photos_advice(tmp_path / "rectified" / "capture.json") == "a smaller --size when rectifying"
    assert smaller_photos_advice(tmp_path / "capture.json") == ""
    cfg = OptimizeConfig(budget_s=60.0, fewer_texels=advice)
    steady, = stop_notes(_budget_result((10.0, 10.0)), cfg)
    assert "(a smaller --size in capture-file import)" in steady and "rectifying" not in steady
    assert "load on the machine" not in steady
    slowed, = stop_notes(_budget_result((10.0, 2.0)), cfg)
    assert re.search(r"steps per second fell from \d+\.\d to 2\.0 during the fit", slowed), slowed
    assert "load on the machine" in slowed
    generic, = stop_notes(_budget_result((10.0, 10.0)), OptimizeConfig(budget_s=60.0))
    assert "a smaller --size where the capture file was made" in generic


def test_bars_use_the_notebook_widget_only_where_ipywidgets_is(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    import tqdm as tqdm_package
    from tqdm.auto import tqdm as auto_tqdm

    from mi_svbrdf.core import progress

    real = importlib.util.find_spec
    def without(name: str, *a: object) -> object:
        return None if name == "ipywidgets" else real(name, *a)

    def with_widgets(name: str, *a: object) -> object:
        return object() if name == "ipywidgets" else real(name, *a)

    monkeypatch.setattr(importlib.util, "find_spec", without)
    assert progress._bar_class() is tqdm_package.tqdm  # no widget library: the text bar, no IProgress warning
    monkeypatch.setattr(importlib.util, "find_spec", with_widgets)
    assert progress._bar_class() is auto_tqdm
