"""Bad input to every subcommand: exit code 2, one line naming the argument or file, no traceback.

Also: photos that hold no measurement (all black, all saturated) are accepted with a warning in
the output and in ``summary.json``'s notes, and a folder of photos is taken as its photos.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mi_svbrdf import cli
from mi_svbrdf.assets import EXAMPLE_CAPTURE_DIR, EXAMPLE_FLASH
from mi_svbrdf.cli.common import one_line, terminal_text
from mi_svbrdf.core.maps import constant_maps
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import write_material
from tests.conftest import export_tiny_net

TEXT = "this is a text file, not an image\n" * 20


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of bad inputs: text files named as images, an empty folder, broken capture files, tiny nets."""
    r = tmp_path_factory.mktemp("bad")
    for name in ("text.png", "text.jpg", "text.exr"):
        (r / name).write_text(TEXT)
    (r / "empty").mkdir()
    (r / "broken.json").write_text("{")
    for name, damage in {"textcap": lambda d: (d / "000.png").write_text(TEXT),
                         "greycap": lambda d: write_image(d / "000.png", np.full((128, 128), 0.5, np.float32)),
                         "deepcap": lambda d: write_image(d / "000.png", np.full((128, 128, 3), 0.5, np.float32), 16),
                         "nocap": lambda d: (d / "capture.json").unlink(),
                         "emptycap": lambda d: (d / "capture.json").write_text('{"version": 1, "images": []}')}.items():
        shutil.copytree(EXAMPLE_CAPTURE_DIR, r / name)
        damage(r / name)
    export_tiny_net(r, "single", 64)
    export_tiny_net(r, "multi", 64)
    export_tiny_net(r, "large", 32)
    shutil.copy(EXAMPLE_FLASH, r / "wall.png")
    write_material(r / "nomap", constant_maps(1, 16, 16))
    (r / "nomap" / "roughness.png").unlink()
    return r


#: (case, argv ({r}: the bad-input folder, {o}: a fresh output folder), what the error line must name,
#: a file name that must appear exactly once in it or None).
CASES = [
    ("render param not a number", "render --param light_x=abc -o {o}", ["--param light_x", "'abc'"], None),
    ("render negative spp param", "render --param spp=-3 -o {o}", ["--param spp", "integer >= 1"], None),
    ("render unknown param", "render --param bogus=1 -o {o}", ["--param bogus"], None),
    ("render param without =", "render --param light_x -o {o}", ["--param", "KEY=VALUE"], None),
    ("render out-of-range scene value", "render --param fov=500 --size 16 -o {o}", ["--scene flash_capture"], None),
    ("render missing material", "render --material {r}/nonexistent -o {o}", ["--material", "no such file"], None),
    ("render missing strip", "render --material {r}/nonexistent.png -o {o}", ["--material", "no such file"],
     "nonexistent.png"),
    ("render text strip", "render --material {r}/text.png -o {o}", ["text.png", "expected a readable PNG"], "text.png"),
    ("render unknown example", "render --material example:nope -o {o}", ["--material", "example:tiles"], None),
    ("render unknown scene", "render --scene nope -o {o}", ["--scene"], None),
    ("render missing xml", "render --scene {r}/none.xml -o {o}", ["--scene", "no such file"], None),
    ("render spp 0", "render --spp 0 -o {o}", ["--spp", "integer >= 1"], None),
    ("render size not a number", "render --size big -o {o}", ["--size", "'big'"], None),
    ("materials count 0", "materials make --count 0 -o {o}", ["--count"], None),
    ("materials mix fraction", "materials make --count 2 --mix-fraction 1.5 -o {o}", ["--mix-fraction"], None),
    ("materials unknown class", "materials make --count 2 --classes paint,nope -o {o}", ["--classes"], None),
    ("dataset missing bank", "dataset render --materials {r}/nobank -o {o}", ["--materials", "no such folder"], None),
    ("dataset empty bank", "dataset render --materials {r}/empty -o {o}", ["materials", "empty"], None),
    ("dataset fov", "dataset render --materials {r}/empty --fov 200 -o {o}", ["--fov", "(0, 180)"], None),
    ("dataset exposure order", "dataset render --materials {r}/empty --exposure 3,1 -o {o}", ["--exposure"], None),
    ("dataset spp", "dataset render --materials {r}/empty --spp -1 -o {o}", ["--spp"], None),
    ("optimize negative budget", "optimize --capture example --budget-s -1 -o {o}", ["--budget-s", "'-1'"], None),
    ("optimize nan budget", "optimize --capture example --budget-s nan -o {o}", ["--budget-s"], None),
    ("optimize iterations", "optimize --capture example --iterations 0 -o {o}", ["--iterations"], None),
    ("optimize tv", "optimize --capture example --tv -1 -o {o}", ["--tv"], None),
    ("optimize levels", "optimize --capture example --levels 0 -o {o}", ["--levels"], None),
    ("optimize missing capture", "optimize --capture {r}/none.json -o {o}", ["none.json", "no such file"], "none.json"),
    ("optimize folder without capture", "optimize --capture {r}/nocap -o {o}", ["nocap", "capture.json"], None),
    ("optimize empty photo list", "optimize --capture {r}/emptycap -o {o}",
     ["emptycap/capture.json: capture.images", "expected a non-empty list, got []"], "capture.json"),
    ("optimize broken json", "optimize --capture {r}/broken.json -o {o}", ["broken.json", "JSON"], "broken.json"),
    ("optimize text photo", "optimize --capture {r}/textcap -o {o}", ["images[0].file", "000.png", "readable PNG"],
     "000.png"),
    ("optimize grey photo", "optimize --capture {r}/greycap -o {o}", ["images[0].file", "RGB image"], "000.png"),
    ("optimize 16-bit photo", "optimize --capture {r}/deepcap -o {o}", ["images[0].encoding", "8-bit PNG"], "000.png"),
    ("capture-file no camera", "capture-file make example -o {o}", ["--camera"], None),
    ("capture-file camera below", "capture-file make example --camera 0,0,-1 -o {o}", ["--camera", "z > 0"], None),
    ("capture-file camera count", "capture-file make example --camera 0,0,2 --camera 0,0,3 -o {o}",
     ["--camera", "one per photo"], None),
    ("capture-file fov", "capture-file make example --camera 0,0,2 --fov 0 -o {o}", ["--fov"], None),
    ("capture-file intensity", "capture-file make example --camera 0,0,2 --intensity -1 -o {o}", ["--intensity"],
     None),
    ("capture-file text photo", "capture-file make {r}/text.png --camera 0,0,2 -o {o}", ["text.png"], "text.png"),
    ("capture-file empty folder", "capture-file make {r}/empty --camera 0,0,2 -o {o}", ["PHOTO", "empty"], None),
    ("capture text png", "capture {r}/text.png --weights {r} -o {o}", ["text.png", "readable PNG"], "text.png"),
    ("capture text jpg", "capture {r}/text.jpg --weights {r} -o {o}", ["text.jpg", "expected an image file"],
     "text.jpg"),
    ("capture text exr", "capture {r}/text.exr --weights {r} -o {o}", ["text.exr", "OpenEXR"], "text.exr"),
    ("capture empty folder", "capture {r}/empty --weights {r} -o {o}", ["PHOTO", "empty"], None),
    ("capture missing photo", "capture {r}/none.jpg --weights {r} -o {o}", ["none.jpg", "no such file"], "none.jpg"),
    ("capture frames", "capture example --frames -1 --weights {r} -o {o}", ["--frames"], None),
    ("capture crop", "capture example --crop 0,0,10 --weights {r} -o {o}", ["--crop"], None),
    ("large-scale missing map", "large-scale {r}/wall.png --exemplar {r}/nomap --weights {r} -o {o}",
     ["--exemplar", "nomap", "'roughness'"], None),
    ("large-scale text photo", "large-scale {r}/text.jpg --exemplar example:tiles --weights {r} -o {o}",
     ["text.jpg", "expected an image file"], "text.jpg"),
    ("large-scale tile <= overlap", "large-scale {r}/wall.png --exemplar example:tiles --tile 32 --overlap 32 -o {o}",
     ["--overlap", "[0, --tile) = [0, 32)"], None),
    ("large-scale no exemplar", "large-scale {r}/wall.png --weights {r} -o {o}", ["--exemplar", "--no-exemplar"], None),
    ("large-scale tile 0", "large-scale {r}/wall.png --exemplar example:tiles --tile 0 -o {o}", ["--tile"], None),
    ("rectify missing photo", "rectify {r}/none.jpg -o {o}", ["none.jpg", "no such file"], "none.jpg"),
    ("rectify empty folder", "rectify {r}/empty -o {o}", ["PHOTO", "empty"], None),
    ("rectify size", "rectify example --size 0 -o {o}", ["--size"], None),
    ("rectify fov", "rectify example --fov 181 -o {o}", ["--fov"], None),
    ("rectify frame-size text", "rectify example --frame-size abc -o {o}", ["--frame-size", "'abc'"], "--frame-size"),
    ("rectify flash-offset", "rectify example --flash-offset 1,2 -o {o}", ["--flash-offset", "'1,2'"],
     "--flash-offset"),
    ("export missing material", "export {r}/nomaterial --format gltf -o {o}", ["MATERIAL", "no such file"], None),
    ("export text strip", "export {r}/text.png --format gltf -o {o}", ["text.png"], "text.png"),
    ("export format", "export example:tiles --format fbx -o {o}", ["--format"], None),
    ("view missing material", "view {r}/nomaterial -o {o}/v.html", ["MATERIAL", "no such file"], None),
    ("view light", "view example:tiles --light 1,2 -o {o}/v.html", ["--light"], None),
    ("view light below", "view example:tiles --light 0,0,-2 -o {o}/v.html", ["--light", "z > 0"], None),
    ("view intensity", "view example:tiles --intensity -1 -o {o}/v.html", ["--intensity"], None),
    ("train net not a dict", "train single --set net=abc -o {o}", ["TrainConfig.net", "'abc'"], None),
    ("train negative minutes", "train single --max-minutes -1 -o {o}", ["--max-minutes"], None),
    ("train unknown recipe", "train nope -o {o}", ["config", "'nope'"], None),
    ("evaluate materials 0", "evaluate --materials 0 -o {o}", ["--materials", "integer >= 1"], None),
    ("evaluate missing ablations", "evaluate --quick --ablations {r}/none -o {o}", ["--ablations"], None),
    ("ablations steps 0", "ablations --steps 0 -o {o}", ["--steps", "integer >= 1"], None),
    ("ablations unknown arm", "ablations --arms single/nope -o {o}", ["--arms", "single/nope"], None),
]

#: Cases Mitsuba finds when it loads the scene, after the material it reads is written.
CHECKED_BY_MITSUBA = {"render out-of-range scene value"}


def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``mi-svbrdf ARGV`` in this process: (exit code, stdout, stderr); argparse's exit counts as a code."""
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def error_line(err: str) -> str:
    """The one ``mi-svbrdf ...: error: ...`` line of ``err``; besides it only argparse's usage is allowed."""
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if ": error: " in line]
    assert len(errors) == 1, err
    others = [line for line in lines if line not in errors]
    assert all(line.startswith(("usage: ", " ")) for line in others), err
    return errors[0]


@pytest.mark.parametrize("case, argv, names, once", CASES, ids=[c[0] for c in CASES])
def test_bad_input_exits_2_with_one_line(root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         case: str, argv: str, names: list[str], once: str | None) -> None:
    out = tmp_path / "out"
    code, _, err = run_main(argv.format(r=root, o=out).split(), capsys)
    assert code == 2, f"{case}: exit code {code}\n{err}"
    assert "Traceback" not in err and "libpng" not in err and ".cpp:" not in err, err
    line = error_line(err)
    words = argv.split()
    prog = " ".join(words[:2]) if words[0] in ("materials", "dataset", "capture-file") else words[0]
    assert line.startswith(f"mi-svbrdf {prog}: error: "), line
    for name in names:
        assert name in line, f"{case}: expected {name!r} in {line!r}"
    if once:
        assert line.count(once) == 1, f"{case}: {once} named {line.count(once)} times in {line!r}"
    if case not in CHECKED_BY_MITSUBA:
        assert not out.exists() or not any(out.iterdir()), f"{case}: files written on bad input"


def test_every_subcommand_has_bad_input_cases() -> None:
    from tests.test_cli_readme import _leaf_commands

    covered = {" ".join(c[1].split()[:2]) for c in CASES} | {c[1].split()[0] for c in CASES}
    mine = {"render", "materials make", "dataset render", "optimize", "capture-file make", "capture", "rectify",
            "export", "view", "large-scale"}
    commands = {" ".join(words) for words, _ in _leaf_commands(cli.build_parser())}
    assert mine <= commands and mine <= covered, sorted(mine - covered)


@pytest.mark.parametrize("argv, name", [
    (["-m", "mi_svbrdf.cli", "render", "--param", "spp=-3"], "--param spp"),
    (["-m", "mi_svbrdf.cli.optimize", "--capture", "example", "--budget-s", "-1", "-o", "x"], "--budget-s"),
])
def test_entry_points_in_a_fresh_process(tmp_path: Path, argv: list[str], name: str) -> None:
    # -W: `python -m mi_svbrdf.cli.X` warns that mi_svbrdf.cli (which imports X) came first
    res = subprocess.run([sys.executable, "-W", "ignore::RuntimeWarning", *argv], capture_output=True, text=True,
                         cwd=tmp_path, check=False)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and name in error_line(res.stderr)


@pytest.mark.parametrize("argv, said", [
    ("capture example:multi --kind single", "--kind: expected 1 photo for the single-image net, got 3 "
                                            "(use --kind multi or --kind auto)"),
    ("evaluate --methods foo --no-progress", "--methods: expected some of trivial, single, multi, optimize, refine, "
                                             "uncalibrated, got foo"),
])
def test_library_errors_are_said_in_flag_terms(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: str,
                                               said: str) -> None:
    """A library's ValueError shown by the CLI names the command's flags and values, not Python's arguments
    (``kind='multi' or None``) or tuples (``('foo',)``)."""
    code, _, err = run_main([*argv.split(), "-o", str(tmp_path / "out")], capsys)
    line = error_line(err)
    assert code == 2 and line == f"mi-svbrdf {argv.split()[0]}: error: {said}", line
    assert not re.search(r"\b[a-z_]+=|None|\('", line), line


def test_flag_terms_keep_what_is_no_option() -> None:
    import argparse

    from mi_svbrdf.cli.common import flag_terms

    p = argparse.ArgumentParser()
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--kind", default=None)
    assert flag_terms("size: expected >= 64, got 3 (or size=None)", p) == "--size: expected >= 64, got 3 (or --size 256)"
    assert flag_terms("use kind='multi' or None", p) == "use --kind multi or no --kind"
    kept = "photo.png: expected x=1 y=2 (crop), got ('a', 'b')"  # no option named x or y: left as it is
    assert flag_terms(kept, p) == kept


def test_messages_are_one_line_without_internal_tags() -> None:
    assert one_line(RuntimeError("[bitmap.cpp:1707] Fatal libpng error: bad\n more")) == "Fatal libpng error: bad more"
    assert one_line(FileNotFoundError(2, "No such file or directory", "x.png")) == "x.png: no such file or directory"
    text = terminal_text("See :func:`~mi_svbrdf.io.photos.load_photo`, :mod:`mi_svbrdf.io` and ``-o OUT`` **now**.")
    assert text == "See load_photo, mi_svbrdf.io and -o OUT now."


# --- photos that hold no measurement: accepted, with a warning and a note --------------------------

def _photo(path: Path, value: float) -> Path:
    write_image(path, np.full((96, 96, 3), value, np.float32), srgb=True)
    return path


@pytest.mark.parametrize("value, word", [(0.0, "black"), (1.0, "saturated")])
def test_capture_warns_on_black_or_white_photos(root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                value: float, word: str) -> None:
    photo = _photo(tmp_path / "flat.png", value)
    out = tmp_path / "out"
    code, _, err = run_main(["capture", str(photo), "--weights", str(root), "--frames", "0", "-o", str(out)], capsys)
    assert code == 0, err
    assert f"flat.png: 100% of the pixels are {word}" in err and "every photo is black or saturated" in err
    notes = json.loads((out / "summary.json").read_text())["notes"]
    assert any(word in n for n in notes) and any("not a measurement" in n for n in notes), notes
    # one good photo beside it: the verdict names what the maps rest on
    code, _, err = run_main(["capture", str(EXAMPLE_FLASH), str(photo), "--weights", str(root), "--frames", "0",
                             "-o", str(tmp_path / "out2")], capsys)
    assert code == 0 and "1 of 2 photos are black or saturated: the maps rest on the other 1" in err, err


def test_capture_accepts_a_folder_of_photos(root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    shutil.copy(EXAMPLE_FLASH, folder / "b.png")
    shutil.copy(EXAMPLE_FLASH, folder / "a.png")
    (folder / ".hidden.png").write_text(TEXT)
    (folder / "notes.txt").write_text("not a photo")
    code, out, err = run_main(["capture", str(folder), "--weights", str(root), "--frames", "0",
                               "-o", str(tmp_path / "out")], capsys)
    assert code == 0, err
    inputs = json.loads((tmp_path / "out" / "summary.json").read_text())["inputs"]
    assert [Path(i["path"]).name for i in inputs] == ["a.png", "b.png"] and "multi-image net on 2 photo" in out


def test_optimize_warns_when_every_photo_is_saturated(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capture = tmp_path / "white"
    shutil.copytree(EXAMPLE_CAPTURE_DIR, capture)
    for png in capture.glob("0*.png"):
        _photo(png, 1.0)
    out = tmp_path / "out"
    code, _, err = run_main(["optimize", "--capture", str(capture), "--iterations", "3", "--no-progress",
                             "-o", str(out)], capsys)
    assert code == 0, err
    assert "000.png: 100% of the pixels are saturated" in err and "the fitted maps are not a measurement" in err
    summary = json.loads((out / "summary.json").read_text())
    notes = summary["notes"]
    # one warning per photo, one that the maps are not a measurement, one that the 3-step cap cut the fit
    assert summary["saturated_fraction"] == 1.0 and len(notes) == 8, notes
    assert sum("saturated (over-exposed)" in n for n in notes) == 6 and any("step cap (3 steps)" in n for n in notes), notes
