"""``mi-svbrdf rectify``: frame detection, ordering, orientation, EXIF, --corners, pose, bad input, symmetric frames.

Photos are synthetic real-world photos (:mod:`mi_svbrdf.data.frame_photos`: Mitsuba, a procedural
material in an A4 paper frame on a table, flash at the camera, random poses, 8-bit sRGB with
noise) with known corners and cameras. ``benchmarks/bench_rectify.py`` prints the full figures.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from mi_svbrdf.cli import capture as capture_cli
from mi_svbrdf.cli import optimize as optimize_cli
from mi_svbrdf.cli import rectify as rectify_cli
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.core.metrics import eval_lights, rerender_rmse
from mi_svbrdf.data import procedural
from mi_svbrdf.data.frame_photos import (
    FramePose,
    ideal_captures,
    project,
    render_frame_photo,
    sample_pose,
    save_photo,
)
from mi_svbrdf.data.photo_setups import simulate
from mi_svbrdf.geometry.frame import (
    DEFAULT_FRAME,
    ORIENTED_BY_FRAME,
    ORIENTED_BY_PHOTO,
    PLANE_CORNERS,
    FrameSpec,
    order_clockwise,
    orient_by_photo,
)
from mi_svbrdf.geometry.homography import plane_homography, warp_to_plane
from mi_svbrdf.geometry.poses import camera_pose, focal_35mm_of, focal_px, fov_of_focal_35mm, intrinsics
from mi_svbrdf.geometry.rectify import RectifyOptions, rectify_photos
from mi_svbrdf.io.calibrated_photos import (
    capture_from_simulator,
    load_capture,
    save_capture,
)
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.photos import orient
from mi_svbrdf.optim import OptimizeConfig, optimize
from tests.conftest import export_tiny_net

W, H, SIZE = 480, 360, 64
#: A plain square frame: the default window with 30 mm of paper on every side (no widest margin).
SYMMETRIC = FrameSpec((210.0, 210.0), (150.0, 150.0), (30.0, 30.0))
#: The rolls (degrees about the optical axis) of the symmetric frame's photos: the photo's up near +y.
ROLLS = (10.0, -12.0)


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list, torch.Tensor]:
    """Two framed photos (PNG with EXIF focal length) of one material, and their ground truth."""
    folder = tmp_path_factory.mktemp("photos")
    maps = procedural.generate("leather", 2, SIZE)[None]
    rng = np.random.default_rng(7)
    photos = []
    for k in range(2):
        pose = sample_pose(rng, width=W, height=H, integer_focal_35mm=True)
        photo = render_frame_photo(maps, pose, seed=k, spp=8)
        save_photo(folder / f"p{k}.png", photo.image, focal_35mm=focal_35mm_of(pose.fov_deg, W, H))
        photos.append(photo)
    return folder, photos, maps


def _pose_with_roll(roll_deg: float, frame: FrameSpec) -> FramePose:
    """A camera 20 degrees south of the vertical, image up along +y of the plane turned by ``roll_deg``, at the
    nearest distance (0.1 steps) that shows the whole sheet; its FOV has a whole 35 mm focal length (EXIF)."""
    tilt, roll = math.radians(20.0), math.radians(roll_deg)
    direction = np.array([0.0, -math.sin(tilt), math.cos(tilt)])
    fwd = -direction
    base = np.array([0.0, 1.0, 0.0]) - fwd * fwd[1]
    base /= np.linalg.norm(base)
    up = math.cos(roll) * base + math.sin(roll) * np.cross(fwd, base)
    x0, x1, y0, y1 = frame.sheet_plane()
    sheet = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    for d in np.arange(2.0, 30.0, 0.1):
        pose = FramePose(tuple(d * direction), (0.0, 0.0, 0.0), tuple(up), fov_of_focal_35mm(28.0, W, H), W, H)
        uv = project(pose, sheet)
        if (uv.min(axis=0) > [0.05 * W, 0.05 * H]).all() and (uv.max(axis=0) < [0.95 * W, 0.95 * H]).all():
            return pose
    raise AssertionError("no distance shows the whole sheet")


@pytest.fixture(scope="module")
def symmetric(tmp_path_factory: pytest.TempPathFactory, scene) -> tuple[Path, list]:
    """Photos of the scene's material in a plain square frame, turned by :data:`ROLLS`, and their ground truth."""
    folder = tmp_path_factory.mktemp("symmetric")
    _, _, maps = scene
    photos = []
    for k, roll in enumerate(ROLLS):
        pose = _pose_with_roll(roll, SYMMETRIC)
        photo = render_frame_photo(maps, pose, frame=SYMMETRIC, seed=10 + k, spp=8)
        save_photo(folder / f"s{k}.png", photo.image, focal_35mm=focal_35mm_of(pose.fov_deg, W, H))
        photos.append(photo)
    return folder, photos


def _rectify(paths: list[Path], out: Path, **kw: object) -> list:
    corners = kw.pop("corners_file", None)
    return rectify_photos(paths, out, RectifyOptions(size=SIZE, **kw), corners_file=corners)


def _pixels(path: Path) -> np.ndarray:
    return read_image(path)[0]


# --- pure functions ------------------------------------------------------------------------


def test_order_and_homography_and_warp() -> None:
    pts = np.array([[10.0, 90.0], [90.0, 10.0], [10.0, 10.0], [90.0, 90.0]])
    assert order_clockwise(pts).tolist() == [[10, 10], [90, 10], [90, 90], [10, 90]]
    assert order_clockwise(pts[::-1]).tolist() == order_clockwise(pts).tolist()
    assert orient_by_photo(pts).tolist() == order_clockwise(pts).tolist()  # an upright square stays as it is
    hom = plane_homography(order_clockwise(pts))
    img = hom @ np.c_[PLANE_CORNERS, np.ones(4)].T
    assert np.allclose((img[:2] / img[2]).T, order_clockwise(pts))
    # A linear ramp along x warps to texel centres x = -1 + (2j + 1)/S (OpenCV pixel centres).
    ramp = np.tile(np.arange(100, dtype=np.float32), (100, 1))[..., None]
    out = warp_to_plane(ramp, hom, 8, supersample=2)[..., 0]
    x = -1.0 + (2 * np.arange(8) + 1) / 8.0
    assert np.allclose(out[3], 10.0 + (x + 1.0) * 40.0, atol=1e-3)


def test_orientation_by_the_photo_keeps_the_image_up() -> None:
    """Turned up to 40 degrees either way, in any order: the side nearest the photo's bottom edge is the bottom."""
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])  # TL, TR, BR, BL (image y down)
    for deg in (-40.0, -12.0, 0.0, 7.0, 40.0):
        a = math.radians(deg)
        turned = 50.0 * square @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]]) + [200.0, 150.0]
        for order in ([0, 1, 2, 3], [2, 0, 3, 1], [3, 2, 1, 0]):
            assert np.allclose(orient_by_photo(turned[order]), turned), (deg, order)
    # Turned by more than 45 degrees, another side is nearest the bottom: the corners follow the photo.
    a = math.radians(60.0)
    turned = 50.0 * square @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
    assert np.allclose(orient_by_photo(turned), np.roll(turned, 1, axis=0))
    assert SYMMETRIC.symmetric and not DEFAULT_FRAME.symmetric


def test_pose_of_a_projected_frame_and_fov_sources() -> None:
    pose = sample_pose(np.random.default_rng(3), width=W, height=H)
    corners = project(pose, np.c_[PLANE_CORNERS, np.zeros(4)])
    f, _, _ = focal_px((H, W), pose.fov_deg, None)
    got = camera_pose(corners, intrinsics((H, W), f))
    assert np.allclose(got.position, pose.camera, rtol=1e-5, atol=1e-5) and got.reprojection_px < 1e-6
    f35 = focal_35mm_of(pose.fov_deg, W, H)
    assert focal_px((H, W), None, f35)[1] == pytest.approx(pose.fov_deg)
    with pytest.raises(ValueError, match="expected --fov or an EXIF 35 mm-equivalent focal length"):
        focal_px((H, W), None, None)


# --- the proof on small photos --------------------------------------------------------------


def test_detected_corners_and_cameras_match_ground_truth(scene, tmp_path: Path) -> None:
    folder, photos, _ = scene
    results = _rectify(sorted(folder.glob("p*.png")), tmp_path)
    assert all(r.ok for r in results), [r.error for r in results]
    err = [np.linalg.norm(np.asarray(r.entry["corners_px"]) - p.corners, axis=1) for r, p in zip(results, photos)]
    assert np.median(np.concatenate(err)) < 1.0
    for r, p in zip(results, photos):
        true = np.asarray(p.pose.camera)
        window = np.asarray(r.entry["camera_position"]) * r.entry["window_covered"]  # in the window's half-widths
        assert np.linalg.norm(window - true) < 0.03 * np.linalg.norm(true)
        assert r.entry["fov_source"].startswith("EXIF")
    report = json.loads((tmp_path / "rectify.json").read_text())
    entry = report["photos"][0]
    for key in ("corners_px", "homography_plane_to_px", "reprojection_error_px", "found_by", "camera_position"):
        assert key in entry
    assert all(p["orientation"] == ORIENTED_BY_FRAME for p in report["photos"]) and report["notes"] == []
    spec, images, _ = load_capture(tmp_path / "capture.json")
    assert spec.n_images == 2 and all(im.rectified and im.light.cone is None for im in spec.images)
    assert images.shape == (2, 3, SIZE, SIZE)
    for name in ("000.png", "001.png", "overlay_000.png", "overlay_001.png"):
        assert (tmp_path / name).is_file()
    assert not list(tmp_path.glob(".*tmp*"))


def test_corners_file_in_any_order_gives_the_same_output(scene, tmp_path: Path) -> None:
    folder, photos, _ = scene
    path = folder / "p0.png"
    truth = photos[0].corners
    outs = []
    for k, order in enumerate(([0, 1, 2, 3], [2, 1, 0, 3], [1, 2, 3, 0], [3, 0, 2, 1])):
        table = tmp_path / f"c{k}.json"
        table.write_text(json.dumps({"p0.png": truth[order].tolist()}))
        res = _rectify([path], tmp_path / f"o{k}", corners_file=table)[0]
        assert res.ok, res.error
        assert res.entry["found_by"].startswith("--corners")
        assert np.allclose(res.entry["corners_px"], truth, atol=1e-3)
        outs.append(_pixels(tmp_path / f"o{k}" / "000.png"))
    assert all(np.array_equal(outs[0], o) for o in outs[1:])
    assert _rectify([path], tmp_path / "det")[0].ok
    assert np.abs(_pixels(tmp_path / "det" / "000.png") - outs[0]).mean() < 0.01


def test_rotated_photo_and_exif_rotation_give_the_same_sample(scene, tmp_path: Path) -> None:
    folder, photos, _ = scene
    upright = photos[1].image
    f35 = focal_35mm_of(photos[1].pose.fov_deg, W, H)
    # The same pixels turned 90 degrees (a camera held sideways, no EXIF)...
    save_photo(tmp_path / "turned.png", np.ascontiguousarray(np.rot90(upright, 1)), focal_35mm=f35)
    # ...and stored turned with EXIF orientation 6, which turns them back upright.
    stored = np.ascontiguousarray(np.rot90(upright, 1))
    assert np.array_equal(orient(stored, 6), upright)
    save_photo(tmp_path / "exif6.jpg", stored, focal_35mm=f35, orientation=6)
    save_photo(tmp_path / "plain.jpg", upright, focal_35mm=f35)
    res = _rectify([folder / "p1.png", tmp_path / "turned.png", tmp_path / "exif6.jpg", tmp_path / "plain.jpg"],
                   tmp_path / "out")
    assert all(r.ok for r in res), [r.error for r in res]
    out = [_pixels(tmp_path / "out" / f"{k:03d}.png") for k in range(4)]
    assert np.abs(out[1] - out[0]).mean() < 0.01  # the same sample, +y up
    assert res[2].entry["conversions"] == ["EXIF orientation 6 applied"]
    assert np.allclose(res[2].entry["corners_px"], res[3].entry["corners_px"], atol=0.3)
    assert np.abs(out[2] - out[3]).mean() < 5e-3  # JPEG blocks of turned pixels differ slightly
    # Upright corners equal the ground truth; the camera is the same whatever the rotation.
    assert np.median(np.linalg.norm(np.asarray(res[2].entry["corners_px"]) - photos[1].corners, axis=1)) < 1.0
    assert np.allclose(res[1].entry["camera_position"], res[0].entry["camera_position"], rtol=0.01, atol=0.02)


# --- a symmetric frame: oriented by the photos, with a note ----------------------------------


def test_symmetric_frame_is_oriented_by_each_photo_with_a_note(symmetric, tmp_path: Path, capsys) -> None:
    folder, photos = symmetric
    # The first photo again, turned a quarter (a camera held sideways): its own bottom side is another one.
    save_photo(tmp_path / "turned.png", np.ascontiguousarray(np.rot90(photos[0].image, 1)),
               focal_35mm=focal_35mm_of(photos[0].pose.fov_deg, W, H))
    out = tmp_path / "out"
    paths = [folder / "s0.png", folder / "s1.png", tmp_path / "turned.png"]
    assert rectify_cli.main([*map(str, paths), "-o", str(out), "--size", str(SIZE)]) == 0
    report = json.loads((out / "rectify.json").read_text())
    assert [p["status"] for p in report["photos"]] == ["ok"] * 3
    assert all(p["orientation"] == ORIENTED_BY_PHOTO for p in report["photos"])
    note = "the orientation of 3 photos was taken from the photos, not the frame"
    assert len(report["notes"]) == 1 and report["notes"][0].startswith(note)
    assert f"mi-svbrdf rectify: note: {note}" in capsys.readouterr().err
    # Turned by a small angle, the photo's up is +y: the corners in the true order, the true camera.
    for entry, photo in zip(report["photos"][:2], photos):
        assert np.median(np.linalg.norm(np.asarray(entry["corners_px"]) - photo.corners, axis=1)) < 1.0
        true = np.asarray(photo.pose.camera)
        window = np.asarray(entry["camera_position"]) * entry["window_covered"]  # in the window's half-widths
        assert np.linalg.norm(window - true) < 0.03 * np.linalg.norm(true)
    # The turned photo's rectified image is the upright one's turned the same way (its left side at the bottom).
    upright, turned = _pixels(out / "000.png"), _pixels(out / "002.png")
    assert np.abs(turned - np.rot90(upright, 1)).mean() < 0.01 < np.abs(turned - upright).mean()
    spec, _, _ = load_capture(out / "capture.json")
    assert spec.n_images == 3


def test_a_set_with_a_widest_margin_is_oriented_by_it_alone(scene, symmetric, tmp_path: Path) -> None:
    """One rule per set: a photo that shows the frame's widest margin orients the set; one that does not fails."""
    folder, _, _ = scene
    sym_folder, _ = symmetric
    results = _rectify([folder / "p0.png", sym_folder / "s0.png"], tmp_path)
    assert results[0].ok and results[0].entry["orientation"] == ORIENTED_BY_FRAME
    assert not results[1].ok and "no margin of the frame is clearly the widest" in results[1].error
    assert "1 other photo of the set shows the frame's widest margin" in results[1].error
    assert not (tmp_path / "001.png").exists() and (tmp_path / "overlay_001.png").is_file()
    assert json.loads((tmp_path / "rectify.json").read_text())["notes"] == []
    # Alone, the same symmetric photo is oriented by itself.
    alone = _rectify([sym_folder / "s0.png"], tmp_path / "alone")[0]
    assert alone.ok and alone.entry["orientation"] == ORIENTED_BY_PHOTO


# --- bad input -------------------------------------------------------------------------------


def test_bad_inputs_are_named_with_overlays_and_the_rest_goes_on(scene, tmp_path: Path, capsys) -> None:
    folder, photos, _ = scene
    img = photos[0].image
    f35 = focal_35mm_of(photos[0].pose.fov_deg, W, H)
    x0, y0 = photos[0].corners.min(axis=0)
    x1, y1 = photos[0].corners.max(axis=0)
    bad = {
        "noframe.png": np.ascontiguousarray(np.full_like(img, 60) + (np.arange(W) % 7).astype(np.uint8)[None, :, None]),
        "two.png": np.ascontiguousarray(np.concatenate([img, img], axis=1)),
        "cut.png": np.ascontiguousarray(img[:, : int(0.5 * (x0 + x1))]) if x0 > 20 else img[: int(0.5 * (y0 + y1))],
        "small.png": cv2.resize(img, (W // 3, H // 3), interpolation=cv2.INTER_AREA),
        "blurry.png": cv2.GaussianBlur(img, (0, 0), 7.0),
    }
    for name, pixels in bad.items():
        save_photo(tmp_path / name, pixels, focal_35mm=f35)
    save_photo(tmp_path / "nofov.png", img)
    names = ["noframe.png", "two.png", "cut.png", "small.png", "blurry.png", "nofov.png"]
    out = tmp_path / "out"
    code = standalone(rectify_cli.add_parser, ["rectify", str(folder / "p0.png"),
                                               *[str(tmp_path / n) for n in names], "-o", str(out), "--size", "64"])
    assert code == 1
    report = json.loads((out / "rectify.json").read_text())["photos"]
    assert report[0]["status"] == "ok"
    errors = {n: r["error"] for n, r in zip(names, report[1:])}
    assert all(r["status"] == "error" for r in report[1:])
    for n, e in errors.items():
        assert n in e, e
    assert "no light frame" in errors["noframe.png"]
    assert "2 candidate windows" in errors["two.png"]
    assert "cut by the image border" in errors["cut.png"]
    assert "at least 200 px" in errors["small.png"]
    assert "too blurry" in errors["blurry.png"]
    assert "expected --fov or an EXIF" in errors["nofov.png"]
    for k in range(1, len(names) + 1):
        assert (out / f"overlay_{k:03d}.png").is_file()  # the user sees why
        assert not (out / f"{k:03d}.png").exists()
    spec, _, _ = load_capture(out / "capture.json")
    assert spec.n_images == 1 and spec.images[0].file == "000.png"
    err = capsys.readouterr().err
    assert "noframe.png" in err and "blurry.png" in err


def test_cli_help_lists_outputs_and_nothing_rectified_is_exit_2(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        rectify_cli.main(["--help"])
    text = capsys.readouterr().out
    for name in ("NNN.png", "overlay_NNN.png", "rectify.json", "capture.json", "--corners", "--frame-size"):
        assert name in text
    save_photo(tmp_path / "dark.png", np.full((300, 400, 3), 40, np.uint8))
    assert rectify_cli.main([str(tmp_path / "dark.png"), "-o", str(tmp_path / "o"), "--fov", "60"]) == 2
    assert not (tmp_path / "o" / "capture.json").exists()
    capsys.readouterr()
    # A malformed --frame-size: one line, as every other error (no usage block), nothing written.
    assert rectify_cli.main([str(tmp_path / "dark.png"), "-o", str(tmp_path / "p"), "--frame-size", "1,2,3"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "mi-svbrdf rectify: error: --frame-size: expected 2 comma-separated numbers (W,H) or one (S), got '1,2,3'"]
    assert not (tmp_path / "p").exists()


@pytest.mark.slow
def test_optimize_and_capture_run_on_the_output_and_match_ideal_captures(scene, tmp_path: Path) -> None:
    """The proof's third figure on a small set: rectified vs ideally rectified fits, within 25 %."""
    folder, photos, gt = scene
    rect = tmp_path / "rect"
    assert rectify_cli.main([*map(str, sorted(folder.glob("p*.png"))), "-o", str(rect), "--size", str(SIZE)]) == 0
    assert optimize_cli.main(["--capture", str(rect / "capture.json"), "-o", str(tmp_path / "fit"),
                              "--budget-s", "2", "--iterations", "20", "--no-progress"]) == 0
    export_tiny_net(tmp_path, "single", SIZE)
    code = standalone(capture_cli.add_parser, ["capture", str(rect / "000.png"), "-o", str(tmp_path / "cap"),
                                               "--weights", str(tmp_path), "--frames", "0"])
    assert code == 0 and (tmp_path / "cap" / "normal.png").is_file()
    caps = ideal_captures(photos)
    spec, images = capture_from_simulator(caps, 0, simulate(gt, caps, torch.Generator().manual_seed(0)))
    save_capture(tmp_path / "ideal" / "capture.json", spec, images)
    cfg = OptimizeConfig(budget_s=8.0, iterations=400, progress=False)
    errs = []
    for capture in (rect / "capture.json", tmp_path / "ideal" / "capture.json"):
        s, im, valid = load_capture(capture)
        errs.append(float(rerender_rmse(optimize(s, im, valid, config=cfg).maps, gt, eval_lights())[0]))
    assert errs[0] <= 1.25 * errs[1], errs


def test_the_example_is_rectified_at_the_walk_throughs_size_without_the_frames_edge(tmp_path: Path,
                                                                                      monkeypatch) -> None:
    """`mi-svbrdf rectify example` at its default size (--size auto: what the photos resolve across the sample),
    cropped inside the window: no line at the edge of a rectified photo is brighter than the lines just
    inside it by the paper's margin (before the crop, row 0 read 115-128 against 58-66 a few rows in). Photos of
    640 x 480 (tests/test_scan_examples.py checks the phone-sized ones)."""
    from PIL import Image

    from mi_svbrdf.data import scan_examples
    from mi_svbrdf.geometry.rectify import RectifyOptions

    monkeypatch.setattr(scan_examples, "PHOTO_SIZE", (640, 480))
    out = tmp_path / "rect"
    assert rectify_cli.main(["example", "-o", str(out)]) == 0
    report = json.loads((out / "rectify.json").read_text())
    # --size auto: the 640 x 480 photos resolve 238 px across the sample (the median of 3), down to a multiple of 32
    assert RectifyOptions.size is None and report["size"] == 224 and "the photos resolve 238 px" in report["size_auto"]
    # one crop for the set: texel (i, j) is the same point of the sample in every photo
    assert len({entry["window_covered"] for entry in report["photos"]}) == 1
    for entry in report["photos"]:
        grey = np.asarray(Image.open(out / entry["output"]).convert("L"), np.float64)
        assert grey.shape == (224, 224) and 0.9 <= entry["window_covered"] < 1.0
        lines = {"top": (grey[0], grey[3:7]), "bottom": (grey[-1], grey[-7:-3]),
                 "left": (grey[:, 0], grey[:, 3:7]), "right": (grey[:, -1], grey[:, -7:-3])}
        brighter = {side: round(edge.mean() - inside.mean(), 1) for side, (edge, inside) in lines.items()}
        assert max(brighter.values()) < 4.0, (entry["output"], brighter)  # of 255; the paper's margin was 50-60


def test_size_auto_is_what_the_photos_resolve_up_to_the_artists_size() -> None:
    from mi_svbrdf.geometry.rectify import AUTO_MIN, MAX_BLUR_TEXELS, auto_size, auto_size_words, window_holds

    square = np.array([[100.0, 100.0], [1500.0, 100.0], [1500.0, 1400.0], [100.0, 1400.0]])
    assert window_holds(square, math.nan) == 1300.0  # the shortest side
    assert window_holds(square, 1.0) == 1300.0  # a sharp edge holds every pixel
    assert window_holds(square, 4.0) == pytest.approx(1300.0 * MAX_BLUR_TEXELS / 4.0)  # a blurry one fewer
    assert auto_size([1300.0, 1400.0, 900.0]) == 1024  # the median, at most 1024
    assert auto_size([700.0, 650.0, 2000.0]) == 672  # down to a multiple of 32
    assert auto_size([10.0]) == AUTO_MIN
    assert auto_size([3000.0], cap=2048) == 2048
    assert auto_size_words(1024, [1300.0, 1400.0, 900.0]) == (
        "--size auto: 1024x1024 texels (the photos resolve 1300 px across the sample, the median of 3; at most 1024)")
    with pytest.raises(ValueError, match="expected the texels of at least one photo, got none"):
        auto_size([])


def test_size_refuses_words_other_than_auto(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        rectify_cli.main(["example", "-o", str(tmp_path / "o"), "--size", "big"])
    assert "--size: expected an integer >= 16, got 'big'" in capsys.readouterr().err
