"""``mi-svbrdf scan``: photos of the tag print to a material in one command (rectify, optimize, export, view into
sub-folders each owned by its step), and one ``index.html`` whose every relative link and picture exists."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np
import pytest

from mi_svbrdf import cli
from mi_svbrdf.cli.common import OWNER_FILE

#: A small run: 64 px rectified views, a few seconds of fit.
SMALL = ["--size", "64", "--budget-s", "4", "--no-progress"]


def local_links(page: Path) -> list[str]:
    """The relative ``href`` and ``src`` targets of ``page`` (no scheme, no absolute path), decoded."""
    found = re.findall(r'(?:href|src)="([^"]*)"', page.read_text(encoding="utf-8"))
    return [unquote(t) for t in found if not urlparse(t).scheme and not t.startswith(("/", "#"))]


def owner(folder: Path) -> str:
    return json.loads((folder / OWNER_FILE).read_text())["command"]


@pytest.fixture(scope="module")
def scanned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, str]:
    """``mi-svbrdf scan example --frame tags`` run once, small (photos of 640 x 480: tests/test_scan_examples.py
    checks the phone-sized ones): (its folder, exit code, stderr)."""
    import io
    from contextlib import redirect_stderr

    from mi_svbrdf.data import scan_examples

    out = tmp_path_factory.mktemp("scan") / "out"
    err = io.StringIO()
    with redirect_stderr(err), pytest.MonkeyPatch.context() as patch:
        patch.setattr(scan_examples, "PHOTO_SIZE", (640, 480))
        code = cli.main(["scan", "example", "--frame", "tags", "-o", str(out), *SMALL])
    return out, code, err.getvalue()


def test_scan_writes_every_step_and_an_index_whose_links_exist(scanned: tuple[Path, int, str]) -> None:
    out, code, err = scanned
    assert code == 0, err[-3000:]
    steps = [line for line in err.splitlines() if line.startswith("mi-svbrdf scan: step ")]
    assert [line.split(": ")[2].split()[1] for line in steps] == ["rectify", "optimize", "export", "view"], steps
    # each step's folder is that command's; scan owns the whole
    assert owner(out) == "mi-svbrdf scan"
    assert {name: owner(out / name) for name in ("rectified", "fit", "export")} == {
        "rectified": "mi-svbrdf rectify", "fit": "mi-svbrdf optimize", "export": "mi-svbrdf export"}
    for rel in ("rectified/capture.json", "fit/material/normal.png", "fit/renders/000.png", "export/material.gltf",
                "view.html", "photos/000.jpg", "summary.json"):
        assert (out / rel).is_file(), rel
    summary = json.loads((out / "summary.json").read_text())
    assert [s["name"] for s in summary["steps"]] == ["rectify", "optimize", "export", "view"]
    assert all(s["exit_code"] == 0 for s in summary["steps"])
    page = out / "index.html"
    links = local_links(page)
    missing = [t for t in links if not (out / t).exists()]
    assert not missing, missing
    # the photos, the rectified views, the maps, the re-renderings and the glTF are on the page
    for rel in ("photos/000.jpg", "rectified/000.png", "rectified/overlay_000.png", "fit/material/diffuse.png",
                "fit/renders/004.png", "fit/loss.png", "export/material.gltf", "view.html"):
        assert rel in links, rel
    text = page.read_text(encoding="utf-8")
    assert "<script" not in text and "http://" not in text and "https://" not in text  # a static, offline page


def test_scan_again_replaces_its_outputs_and_keeps_the_photos(scanned: tuple[Path, int, str], tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A re-run into the same folder (the first run's photos, three of them, as the user's own) replaces its
    previous outputs: the synthetic photos and the fourth and fifth views are gone."""
    out, code, _ = scanned
    assert code == 0
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(3):
        shutil.copy(out / "rectified" / "example_photos" / f"IMG_{k:04d}.jpg", photos)
    again = tmp_path / "again"
    shutil.copytree(out, again)
    assert cli.main(["scan", str(photos), "--frame", "tags", "--frame-size", "180", "-o", str(again), *SMALL]) == 0
    captured = capsys.readouterr()
    assert "replacing the previous results" in captured.err
    assert not (again / "rectified" / "example_photos").exists()
    assert not (again / "rectified" / "004.png").exists() and not (again / "fit" / "renders" / "004.png").exists()
    assert (again / "fit" / "renders" / "002.png").is_file()
    missing = [t for t in local_links(again / "index.html") if not (again / t).exists()]
    assert not missing, missing


def test_scan_refuses_a_users_folder_and_another_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before any work: the user's own index.html, or a folder optimize wrote, is refused in one line."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "index.html").write_text("my page")
    assert cli.main(["scan", "example", "--frame", "tags", "-o", str(mine)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "index.html" in err and "--force" in err, err
    assert sorted(p.name for p in mine.iterdir()) == ["index.html"] and (mine / "index.html").read_text() == "my page"
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / OWNER_FILE).write_text(json.dumps({"command": "mi-svbrdf optimize", "outputs": ["summary.json"]}))
    assert cli.main(["scan", "example", "--frame", "tags", "-o", str(theirs)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mi-svbrdf optimize" in err, err
    # a step's folder that another command wrote is refused before any work too
    step = tmp_path / "step"
    (step / "fit").mkdir(parents=True)
    (step / "fit" / OWNER_FILE).write_text(json.dumps({"command": "mi-svbrdf capture", "outputs": []}))
    (step / OWNER_FILE).write_text(json.dumps({"command": "mi-svbrdf scan", "outputs": []}))
    assert cli.main(["scan", "example", "--frame", "tags", "-o", str(step)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mi-svbrdf capture" in err, err
    assert not (step / "rectified").exists()


def test_scan_with_no_photo_rectified_stops_with_a_page_saying_why(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """--force replaces the user's own index.html; a photo without the print stops scan after rectify, in one
    error line, and the page shows the photo and why."""
    from PIL import Image

    photo = tmp_path / "blank.jpg"
    Image.fromarray(np.full((240, 320, 3), 128, np.uint8)).save(photo)
    out = tmp_path / "out"
    out.mkdir()
    (out / "index.html").write_text("my page")
    assert cli.main(["scan", str(photo), "--frame", "tags", "--frame-size", "180", "-o", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith("mi-svbrdf scan: error: rectify: expected at least one photo")
    text = (out / "index.html").read_text(encoding="utf-8")
    assert "stopped:" in text and "left out" in text and "blank.jpg" in text
    assert not (out / "fit").exists()
    missing = [t for t in local_links(out / "index.html") if not (out / t).exists()]
    assert not missing, missing


def test_scan_interrupted_says_what_the_folder_holds_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from mi_svbrdf.cli import rectify

    def stop(args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(rectify, "run_cli", stop)
    assert cli.main(["scan", "example", "--frame", "tags", "-o", str(tmp_path / "out")]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"mi-svbrdf scan: interrupted in step 1 of 4, rectify; nothing of this run is in "
                       f"{tmp_path / 'out'}/; no index.html yet (re-run the command)"), err
    assert len([line for line in err if line.startswith("mi-svbrdf scan: interrupted")]) == 1


def test_scan_help_lists_the_files_it_writes(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["scan", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    for name in ("index.html", "photos/NNN.jpg", "rectified/", "fit/", "export/", "view.html", "summary.json",
                 "--frame-size", "--budget-s", "--force"):
        assert name in text, name


def test_rectify_options_are_refused_before_scan_writes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert cli.main(["scan", "IMG_1.jpg", "--frame", "tags", "-o", str(out)]) == 2
    assert "--frame-size: expected the tag ring's outer size" in capsys.readouterr().err
    assert cli.main(["scan", "IMG_1.jpg", "--depth", "2", "-o", str(out)]) == 2
    assert "--depth: expected with --frame tags only" in capsys.readouterr().err
    assert not out.exists()


def test_the_page_shows_small_copies_of_large_pictures_and_links_the_full_ones(tmp_path: Path) -> None:
    """Maps and renders of 1024^2 fits are shown as 512 px copies under small/, each linked to its full picture."""
    from PIL import Image

    from mi_svbrdf.cli.scan import SMALL_SIDE, _Page

    (tmp_path / "fit" / "renders").mkdir(parents=True)
    Image.new("RGB", (3072, 1024), (200, 10, 10)).save(tmp_path / "fit" / "renders" / "000.png")
    Image.new("RGB", (256, 256), (10, 200, 10)).save(tmp_path / "fit" / "normal.png")
    page = _Page(tmp_path)
    big = page.figure("fit/renders/000.png", "render")
    assert 'src="small/fit_renders_000.png"' in big and 'href="fit/renders/000.png"' in big
    with Image.open(tmp_path / "small" / "fit_renders_000.png") as im:
        assert im.size == (SMALL_SIDE, round(SMALL_SIDE / 3))
        assert im.getpixel((10, 10)) == (200, 10, 10)
    small = page.figure("fit/normal.png", "normal")  # small enough: shown itself
    assert 'src="fit/normal.png"' in small and not (tmp_path / "small" / "fit_normal.png").exists()
