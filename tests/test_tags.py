"""``rectify --frame tags`` and ``frame``: the AprilTag print, its detection, the calibration, poses, the sheets.

Photos are ray-cast in numpy / OpenCV (:func:`mi_svbrdf.data.tag_photos.project_photo`) through known
cameras (focal length, off-centre principal point, radial distortion) with noise, JPEG, blur, a
hidden tag, a photo stored sideways with an EXIF orientation, and the tags 3 mm above the sample;
``rectify example --frame tags`` renders with Mitsuba.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from mi_svbrdf.cli import frame as frame_cli
from mi_svbrdf.cli import rectify as rectify_cli
from mi_svbrdf.cli.rectify_tags import EXAMPLE_SHEET_MM, example_cameras
from mi_svbrdf.data.frame_photos import save_photo
from mi_svbrdf.data.tag_photos import look_at, project_photo, smooth_texture
from mi_svbrdf.geometry.rectify import RectifyOptions
from mi_svbrdf.geometry.sheets import PAPERS, sheet_figure, tag_layout
from mi_svbrdf.geometry.tag_rectify import _read, _warp, clear_limits, rectify_tag_photos
from mi_svbrdf.geometry.tags import (
    DICTIONARY,
    Intrinsics,
    TagPose,
    TagSheet,
    calibrate,
    detect_tags,
    sheet_image,
    tag_centres,
    tag_corners_units,
    visible_reach,
)
from mi_svbrdf.io.calibrated_photos import load_capture
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode

W, H, SIZE = 640, 480, 96
#: The true camera: focal length, principal point (off the centre), radial distortion.
FOCAL, PRINCIPAL, DISTORTION = 560.0, (331.0, 233.0), (-0.06, 0.02, 0.0, 0.0, 0.0)
#: The print: S = 180 mm, the tags 3 mm above the sample.
SHEET = TagSheet(180.0, depth_mm=3.0)
#: (tilt from the vertical, azimuth, roll, distance) of the photos, degrees and capture units.
POSES = ((25.0, 10.0, 5.0, 4.6), (35.0, 100.0, -20.0, 4.4), (20.0, 200.0, 15.0, 4.8), (38.0, 280.0, 0.0, 4.3),
         (30.0, 150.0, -10.0, 4.5), (28.0, 320.0, 25.0, 4.7))
#: How each photo is degraded / stored: name -> (photo index, kind).
TEXTURE = smooth_texture(256, 3)


def _camera(tilt: float, azimuth: float, roll: float, distance: float):
    t, a = math.radians(tilt), math.radians(azimuth)
    position = distance * np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    return look_at(position, focal=FOCAL, size=(W, H), roll_deg=roll, principal=PRINCIPAL, distortion=DISTORTION)


def _hide_tag(image: np.ndarray, camera, tag_id: int) -> np.ndarray:
    """A grey blob over one tag (a finger, glare)."""
    corners = camera.project(SHEET.object_points([tag_id]).reshape(-1, 3))
    out = image.copy()
    cv2.fillConvexPoly(out, np.round(corners.mean(axis=0) + 1.3 * (corners - corners.mean(axis=0))).astype(np.int32),
                       (200, 200, 200))
    return out


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], list]:
    """Six photos of the print (no EXIF focal length) and their true cameras."""
    folder = tmp_path_factory.mktemp("tags")
    cameras = [_camera(*p) for p in POSES]
    paths = []
    for k, cam in enumerate(cameras):
        image = project_photo(cam, TEXTURE, depth=SHEET.depth, supersample=2, seed=k, blur_px=1.2 if k == 2 else 0.0)
        if k == 1:
            image = _hide_tag(image, cam, 6)
        if k == 4:  # a phone held sideways: the sensor's pixels stored with EXIF orientation 6
            path = folder / f"p{k}.jpg"
            save_photo(path, image, orientation=6)
        elif k in (0, 3):
            path = folder / f"p{k}.jpg"
            cv2.imwrite(str(path), image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
        else:
            path = folder / f"p{k}.png"
            save_photo(path, image)
        paths.append(path)
    return paths, cameras


# --- the print ---------------------------------------------------------------------------------


def test_every_tag_of_the_sheet_is_where_and_how_the_field_prints_it() -> None:
    """IDs clockwise from the top left; each tag turned by 180 degrees: OpenCV's first corner at its bottom right."""
    img, origin, ppu = sheet_image(6, 2.0)
    corners, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY)).detectMarkers(img)
    ids = ids.reshape(-1)
    assert sorted(ids.tolist()) == list(range(16))
    centres_px = np.stack([origin + tag_centres()[:, 0] * ppu - 0.5, origin - tag_centres()[:, 1] * ppu - 0.5], -1)
    for tag_id, quad in zip(ids, corners):
        quad = quad.reshape(4, 2)
        centre = quad.mean(axis=0)
        assert np.abs(centre - centres_px[tag_id]).max() < 1.0, tag_id
        first = quad[0] - centre
        assert first[0] > 0 and first[1] > 0, (tag_id, quad)  # bottom right in the image (y down)
    # The ring's order: top row left to right, right column down, bottom row right to left, left column up.
    c = tag_centres()
    assert c[:5, 1].tolist() == [8.0] * 5 and np.all(np.diff(c[:5, 0]) > 0)
    assert c[5:8, 0].tolist() == [8.0] * 3 and np.all(np.diff(c[4:9, 1]) < 0)
    assert c[8:13, 1].tolist() == [-8.0] * 5 and np.all(np.diff(c[8:13, 0]) < 0)
    assert c[13:, 0].tolist() == [-8.0] * 3 and np.all(np.diff(c[12:, 1]) > 0)
    # Our detector (edge-refined corners) returns every corner in OpenCV's order at its true place.
    det = detect_tags(img)
    expected = tag_corners_units(det.ids)
    px = np.stack([origin + expected[..., 0] * ppu - 0.5, origin - expected[..., 1] * ppu - 0.5], axis=-1)
    assert det.ids.tolist() == list(range(16)) and np.abs(det.corners - px).max() < 0.2


def test_sheets_are_pdfs_at_true_scale_with_the_tags_where_they_belong(tmp_path: Path, capsys) -> None:
    assert frame_cli.main(["tags", "-o", str(tmp_path / "tags")]) == 0
    assert "--frame tags --frame-size S" in capsys.readouterr().out
    for paper, (w, h) in PAPERS.items():
        data = (tmp_path / "tags" / f"sheet_{paper}.pdf").read_bytes()
        box = [float(v) for v in re.search(rb"/MediaBox\s*\[([^\]]*)\]", data).group(1).split()]
        assert box[2:] == pytest.approx([w / 25.4 * 72.0, h / 25.4 * 72.0], abs=0.01), paper
    assert (tmp_path / "tags" / "sheet.png").is_file()
    # The drawing at 400 dpi: every tag found, the ring's outer edges S = 180 mm apart, the window centred. (The
    # raster's black cells grow by about a pixel a side -- matplotlib's non-antialiased drawing, not the PDF's --,
    # which the edge-refined corners measure: 0.06 mm at 400 dpi, 0.17 mm at 200 dpi.)
    dpi = 400.0
    fig = sheet_figure("tags", "letter")
    fig.savefig(tmp_path / "hi.png", dpi=dpi)
    det = detect_tags(cv2.imread(str(tmp_path / "hi.png"), cv2.IMREAD_GRAYSCALE))
    assert det.ids.tolist() == list(range(16))
    span_mm = (det.corners[..., 0].max() - det.corners[..., 0].min()) / dpi * 25.4
    assert span_mm == pytest.approx(180.0, abs=0.3)
    layout = tag_layout("letter", 180.0)
    first = det.corners[0, 2]  # tag 0's third corner: its top left, the ring's top-left corner
    assert first / dpi * 25.4 == pytest.approx([layout.ring_mm[0], PAPERS["letter"][1] - layout.ring_mm[3]], abs=0.3)
    # The paper frame, and a size that does not fit: one line, nothing written.
    assert frame_cli.main(["a4", "-o", str(tmp_path / "a4")]) == 0
    assert (tmp_path / "a4" / "sheet_letter.pdf").is_file()
    assert frame_cli.main(["tags", "--size", "300", "-o", str(tmp_path / "big")]) == 2
    assert "expected a ring size S in (0, 194] mm to fit a4, got 300" in capsys.readouterr().err
    assert not (tmp_path / "big").exists()


# --- synthetic captures with known cameras ------------------------------------------------------


def test_calibration_poses_and_texture_match_the_truth(capture, tmp_path: Path) -> None:
    """Positions within 1 % of the distance, intrinsics within 2 %, the texture aligned to a texel."""
    paths, cameras = capture
    results = rectify_tag_photos(paths, tmp_path, RectifyOptions(size=SIZE), SHEET)
    assert all(r.ok for r in results), [r.error for r in results]
    for r, cam in zip(results, cameras):
        true = cam.position
        assert np.linalg.norm(np.asarray(r.entry["camera_position"]) - true) < 0.01 * np.linalg.norm(true), r.photo
        assert r.entry["reprojection_error_px"]["tags_rms"] < 0.5
    hidden = results[1].entry
    assert 6 not in hidden["tags_found"] and len(hidden["tags_found"]) >= 12
    assert hidden["tags_used"] == hidden["tags_found"]
    assert len(results[2].entry["tags_used"]) >= 8  # the blurred photo
    assert results[4].entry["conversions"] == ["EXIF orientation 6 applied"] and results[4].entry["size_hw"] == [W, H]
    report = json.loads((tmp_path / "rectify.json").read_text())
    (cal,) = report["calibrations"]
    assert cal["size_wh"] == [W, H] and cal["photos"] == 6
    assert cal["focal_px"] == pytest.approx(FOCAL, rel=0.02)
    assert np.abs(np.subtract(cal["principal_point_px"], PRINCIPAL) / [W, H]).max() < 0.02
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [p["tags_used"] for p in summary["photos"]] == [len(r.entry["tags_used"]) for r in results]
    assert all(p["reprojection_error_px"] is not None for p in summary["photos"])
    spec, images, _ = load_capture(tmp_path / "capture.json")
    assert spec.n_images == 6 and images.shape == (6, 3, SIZE, SIZE)
    # The rectified texture: aligned with the sample's texture (the central part: the tags' depth hides an edge).
    ref = srgb_encode(cv2.resize(TEXTURE, (SIZE, SIZE), interpolation=cv2.INTER_AREA))
    crop = slice(SIZE // 5, SIZE - SIZE // 5)

    def detail(a: np.ndarray) -> np.ndarray:
        g = a.mean(axis=2).astype(np.float64)[crop, crop]
        return g - cv2.GaussianBlur(g, (0, 0), 3.0)

    for k in range(6):
        out = read_image(tmp_path / f"{k:03d}.png")[0]
        (dx, dy), response = cv2.phaseCorrelate(detail(out), detail(ref))
        assert math.hypot(dx, dy) < 0.5 and response > 0.5, (k, dx, dy, response)


def test_the_flash_offset_follows_the_upright_photo_also_when_turned_by_exif(capture, tmp_path: Path) -> None:
    """--flash-offset 10,0,0: 10 mm to the right of the lens in the upright photo (photo 4 is stored sideways)."""
    paths, cameras = capture
    results = rectify_tag_photos(paths, tmp_path, RectifyOptions(size=32, flash_offset_mm=(10.0, 0.0, 0.0)), SHEET)
    step = 10.0 / (SHEET.window_mm / 2.0)  # capture units
    for k, right in ((0, cameras[0].rotation[0]), (4, -cameras[4].rotation[1])):  # EXIF 6: the stored up is the right
        entry = results[k].entry
        offset = np.subtract(entry["light_position"], entry["camera_position"])
        assert np.allclose(offset, step * right, atol=0.01 * step), (k, offset, step * right)


def test_the_warp_follows_the_true_camera_through_distortion_and_depth(capture) -> None:
    """With the true camera, the window's texels land on the sample's: the warp's geometry, depth and distortion."""
    paths, cameras = capture
    seen, cam = _read(paths[3]), cameras[3]
    rvec, _ = cv2.Rodrigues(cam.rotation)
    pose = TagPose(rvec.reshape(3), cam.translation, tuple(cam.position), (), (), 0.0)
    linear, _, _ = _warp(seen, pose, Intrinsics(cam.matrix, cam.distortion, (W, H), "truth"), SIZE)
    ref = cv2.resize(TEXTURE, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    crop = slice(SIZE // 5, SIZE - SIZE // 5)
    ratio = linear[crop, crop] / ref[crop, crop]  # the flash's smooth shading
    assert np.std(ratio / cv2.GaussianBlur(ratio, (0, 0), 4.0)) < 0.05


def _detail(a: np.ndarray) -> np.ndarray:
    """High-passed grey of an ``(S, S, 3)`` linear image, its smooth shading divided out first."""
    g = a.mean(axis=2).astype(np.float64)
    g = g / cv2.GaussianBlur(g, (0, 0), 8.0)
    return g - cv2.GaussianBlur(g, (0, 0), 2.0)


def test_the_rectified_window_shows_the_sample_up_to_its_edges(tmp_path: Path) -> None:
    """No paper in the window's edge texels: a texture with detail up to the window's edge (cells of 2 texels), seen
    through the print 3 mm above it by tilted, distorted cameras; every rectified photo's detail correlates with the
    truth's over the whole window, edge rows and columns included, and its edges are as bright as the inside."""
    rng = np.random.default_rng(4)
    cells = rng.uniform(0.0, 1.0, (SIZE // 2, SIZE // 2, 3)).astype(np.float32)
    texture = srgb_decode(0.2 + 0.6 * cv2.resize(cells, (4 * SIZE, 4 * SIZE), interpolation=cv2.INTER_NEAREST))
    texture = np.ascontiguousarray(texture, dtype=np.float32)
    paths = []
    for k, pose in enumerate(POSES[:4]):
        paths.append(tmp_path / f"p{k}.png")
        save_photo(paths[-1], project_photo(_camera(*pose), texture, depth=SHEET.depth, supersample=2, seed=k))
    results = rectify_tag_photos(paths, tmp_path / "out", RectifyOptions(size=SIZE), SHEET)
    assert all(r.ok for r in results), [r.error for r in results]
    truth = cv2.resize(texture, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    edge = np.zeros((SIZE, SIZE), bool)
    edge[:2], edge[-2:], edge[:, :2], edge[:, -2:] = True, True, True, True
    ring = np.zeros((SIZE, SIZE), bool)
    ring[2:6, 2:-2], ring[-6:-2, 2:-2], ring[2:-2, 2:6], ring[2:-2, -6:-2] = True, True, True, True
    for r in results:
        out = srgb_decode(read_image(tmp_path / "out" / r.entry["output"])[0])
        a, b = _detail(out).ravel(), _detail(truth).ravel()
        assert np.corrcoef(a, b)[0, 1] >= 0.9, (r.photo, np.corrcoef(a, b)[0, 1])
        grey = out.mean(axis=2) / truth.mean(axis=2)  # the flash's shading
        assert grey[edge].mean() / grey[ring].mean() == pytest.approx(1.0, abs=0.05), r.photo
        # Texels within the paper's reach repeat the nearest one clear of it: a few per side.
        assert max(r.entry["texels_repeated"]) <= 4 and 0.3 < r.entry["edge_blur_px"] < 1.0, r.entry


def test_the_print_hides_a_strip_on_the_cameras_side_and_the_blur_widens_the_margin() -> None:
    cam = _camera(35.0, 0.0, 0.0, 4.5)  # tilted towards +x
    rvec, _ = cv2.Rodrigues(cam.rotation)
    pose = TagPose(rvec.reshape(3), cam.translation, tuple(cam.position), (), (), 0.0)
    intr = Intrinsics(cam.matrix, cam.distortion, (W, H), "truth")
    flat, deep = visible_reach(cam.position, 0.0), visible_reach(cam.position, SHEET.depth)
    assert flat.tolist() == [1.0, 1.0, 1.0, 1.0]
    assert deep[0] < 0.985 and deep[1] > 1.0  # hidden on the camera's side, more seen on the far side
    sharp, blurry = clear_limits(pose, intr, 0.0, 0.4), clear_limits(pose, intr, 0.0, 1.5)
    assert np.all(sharp < 1.0) and np.all(blurry < sharp)
    assert clear_limits(pose, intr, SHEET.depth, 0.4)[0] < sharp[0] - 0.015
    with pytest.raises(ValueError, match="expected above the print's tag plane"):
        visible_reach((0.0, 0.0, 0.05), 0.1)


def test_fov_and_exif_give_a_pinhole_and_too_few_tags_are_reported(capture, tmp_path: Path, capsys) -> None:
    paths, cameras = capture
    image = np.asarray(cv2.imread(str(paths[5]))[..., ::-1])
    # Only the top row of tags in view: 5 tags would do, 3 do not.
    row = cameras[5].project(SHEET.object_points([0, 1, 2]).reshape(-1, 3))
    cut = np.ascontiguousarray(image[: int(row[:, 1].max()) + 8])
    if cut.shape[0] < 200:
        cut = np.pad(cut, ((0, 200 - cut.shape[0]), (0, 0), (0, 0)), mode="edge")
    save_photo(tmp_path / "three.png", cut)
    save_photo(tmp_path / "blank.png", np.full((300, 400, 3), 90, np.uint8))
    # The left part only: the left column's tags and more, but the window cut by the border.
    left = cameras[5].project(SHEET.object_points([13, 14, 15]).reshape(-1, 3))
    save_photo(tmp_path / "half.png", np.ascontiguousarray(image[:, : int(left[:, 0].max()) + 90]))
    out = tmp_path / "out"
    fov = math.degrees(2.0 * math.atan(0.5 * W / FOCAL))
    code = rectify_cli.main([str(paths[5]), str(tmp_path / "three.png"), str(tmp_path / "blank.png"),
                             str(tmp_path / "half.png"), "-o", str(out),
                             "--frame", "tags", "--frame-size", "180", "--depth", "3", "--fov", f"{fov:.6f}",
                             "--size", "64"])
    assert code == 1
    captured = capsys.readouterr()
    assert re.search(r"p5\.png -> 000\.png: 1[0-6] of 16 tags used, reprojection \d\.\d+ px rms", captured.out)
    report = json.loads((out / "rectify.json").read_text())["photos"]
    assert report[0]["status"] == "ok" and report[0]["intrinsics_source"] == "--fov"
    true = cameras[5].position  # a pinhole for a distorted camera: close, not exact
    assert np.linalg.norm(np.asarray(report[0]["camera_position"]) - true) < 0.05 * np.linalg.norm(true)
    half = report[3]
    assert half["status"] == "error" and len(half["tags_found"]) >= 4, half
    assert "expected the whole window (the sample) in the photo" in half["error"] and (out / half["overlay"]).is_file()
    for entry, name in zip(report[1:3], ("three.png", "blank.png")):
        assert entry["status"] == "error" and name in entry["error"]
        assert "expected at least 4 of the print's 16 tags" in entry["error"]
        assert "blank.png" not in name or "got 0" in entry["error"]
        assert (out / entry["overlay"]).is_file()
    assert "got 3" in report[1]["error"] or "got 2" in report[1]["error"]
    assert not (out / "001.png").exists() and load_capture(out / "capture.json")[0].n_images == 1
    assert "three.png" in captured.err and "overlay_001.png" in captured.err
    # Two photos with an EXIF focal length: the EXIF pinhole; five: calibrated, the EXIF focal lengths beside it.
    f35 = FOCAL * math.hypot(36.0, 24.0) / math.hypot(W, H)
    upright = [k for k in range(6) if k != 4]
    for k in upright:
        save_photo(tmp_path / f"e{k}.png", np.asarray(cv2.imread(str(paths[k]))[..., ::-1]), focal_35mm=f35)
    two = rectify_tag_photos([tmp_path / "e0.png", tmp_path / "e5.png"], tmp_path / "two", RectifyOptions(size=32),
                             SHEET)
    assert all(r.ok and r.entry["intrinsics_source"].startswith("EXIF FocalLengthIn35mmFilm") for r in two)
    rectify_tag_photos([tmp_path / f"e{k}.png" for k in upright], tmp_path / "five", RectifyOptions(size=32), SHEET)
    (cal,) = json.loads((tmp_path / "five" / "rectify.json").read_text())["calibrations"]
    assert cal["source"].startswith("calibrated from the tags of 5 photos") and len(cal["exif_focal_px"]) == 5


def test_one_photo_calibration_is_noted_an_unreadable_photo_has_no_overlay_and_ctrl_c_writes_nothing(
        capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    paths, _ = capture
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(b"\xff\xd8\xff\xe0 not a JPEG")
    out = tmp_path / "one"
    argv = ["--frame", "tags", "--frame-size", "180", "--depth", "3", "--size", "32"]
    assert rectify_cli.main([str(paths[5]), str(broken), "-o", str(out), *argv]) == 1
    err = capsys.readouterr().err.splitlines()
    # One photo without an EXIF focal length: calibrated from its tags, and said so (terminal and rectify.json).
    (note,) = [line for line in err if line.startswith("mi-svbrdf rectify: note: ")]
    assert "calibrated from the tags of only 1 photo of 640x480 px" in note and "give --fov" in note
    assert json.loads((out / "rectify.json").read_text())["notes"] == [note.split("note: ", 1)[1]]
    # A photo no reader understands: its error, and no overlay named.
    (line,) = [line for line in err if "broken.jpg" in line]
    assert line.startswith("mi-svbrdf rectify: error: ") and "see" not in line and line.endswith(")"), line
    # Ctrl-C while the photos are read: nothing written, no folder, and the line says so.
    from mi_svbrdf.geometry import tag_rectify

    def stop(path: Path) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(tag_rectify, "_read", stop)
    stopped = tmp_path / "stopped"
    assert rectify_cli.main([str(paths[5]), "-o", str(stopped), *argv]) == 130
    assert capsys.readouterr().err.splitlines() == [
        f"mi-svbrdf rectify: interrupted before writing; nothing of this run was written to {stopped}/ (re-run the "
        "command)"]
    assert not stopped.exists()


def test_square_on_photos_cannot_calibrate_and_bad_options_are_named(tmp_path: Path, capsys) -> None:
    cams = [look_at((0.02 * k, 0.0, 4.5 + 0.3 * k), focal=FOCAL, size=(W, H), target=(0.02 * k, 0.0, 0.0))
            for k in range(2)]
    views = []
    for cam in cams:
        det = detect_tags(project_photo(cam, TEXTURE, supersample=1, seed=1).min(axis=2))
        views.append((TagSheet(1.0).object_points(det.ids).reshape(-1, 3), det.corners.reshape(-1, 2)))
    with pytest.raises(ValueError, match="take some photos at an angle"):
        calibrate(views, (W, H))
    photo = tmp_path / "p.png"
    save_photo(photo, np.full((300, 400, 3), 90, np.uint8))
    base = [str(photo), "-o", str(tmp_path / "o"), "--frame", "tags"]
    assert rectify_cli.main(base) == 2
    assert "--frame-size: expected the tag ring's outer size S in mm" in capsys.readouterr().err
    assert rectify_cli.main([*base, "--frame-size", "150,150"]) == 2
    assert "expected one number with --frame tags" in capsys.readouterr().err
    for option, value in (("--frame-size", "abc"), ("--flash-offset", "1,2")):  # one line, as every other error
        assert rectify_cli.main([*base, option, value]) == 2
        (line,) = capsys.readouterr().err.splitlines()
        assert line.startswith(f"mi-svbrdf rectify: error: {option}: expected ") and line.endswith(f"got {value!r}")
    assert rectify_cli.main([*base, "--frame-size", "180", "--corners", str(photo)]) == 2
    assert "--corners: expected with the paper frame only" in capsys.readouterr().err
    assert rectify_cli.main([str(photo), "-o", str(tmp_path / "o"), "--depth", "2"]) == 2
    assert "--depth: expected with --frame tags only" in capsys.readouterr().err
    with pytest.raises(ValueError, match="--frame-size: expected the tag ring's outer size S"):
        TagSheet(-1.0)
    with pytest.raises(ValueError, match="--depth: expected millimetres >= 0"):
        TagSheet(180.0, float("nan"))


# --- the Mitsuba example ------------------------------------------------------------------------


def test_rectify_example_with_tags_recovers_the_cameras(tmp_path: Path, capsys, monkeypatch) -> None:
    """``rectify example --frame tags``: Mitsuba photos, the camera calibrated from the tags, poses within 1 %
    (photos of 640 x 480: tests/test_scan_examples.py checks the phone-sized ones)."""
    from mi_svbrdf.data import scan_examples

    monkeypatch.setattr(scan_examples, "PHOTO_SIZE", (640, 480))
    out = tmp_path / "ex"
    assert rectify_cli.main(["example", "--frame", "tags", "-o", str(out), "--size", "64"]) == 0
    assert len(capsys.readouterr().out.strip().splitlines()) == 1 + len(example_cameras())
    report = json.loads((out / "rectify.json").read_text())
    assert report["frame"]["size_mm"] == EXAMPLE_SHEET_MM
    assert report["calibrations"][0]["source"].startswith("calibrated from the tags of 5 photos")
    for entry, cam in zip(report["photos"], example_cameras()):
        true = cam.position
        assert entry["status"] == "ok", entry.get("error")
        assert np.linalg.norm(np.asarray(entry["camera_position"]) - true) < 0.01 * np.linalg.norm(true)
    assert report["calibrations"][0]["focal_px"] == pytest.approx(example_cameras()[0].matrix[0, 0], rel=0.02)
    assert load_capture(out / "capture.json")[0].n_images == len(example_cameras())
