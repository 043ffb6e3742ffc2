"""Benchmark (the proof of ``mi-svbrdf rectify --frame tags``): the print -> photos -> rectify -> optimize.

1. The print: ``mi-svbrdf frame tags`` (:func:`mi_svbrdf.geometry.sheets.write_sheets`); its A4
   sheet drawn at 300 dpi must show all 16 tags with the ring's outer edges ``S`` apart.
2. ``--photos`` Mitsuba photos of a procedural material under that print
   (:func:`mi_svbrdf.data.tag_photos.render_tag_photo`: random cameras 15-40 degrees from the
   vertical, any azimuth, roll within 30 degrees, FOV 60 degrees, flash at the camera), 8-bit
   sRGB with noise, saved without EXIF: the camera is calibrated from the tags.
3. ``rectify --frame tags`` (the library call): camera position error in % of the distance
   (target: every camera within 1 %), the calibrated focal length and principal point against
   the truth (target: within 2 %), tags used and reprojection error per photo; the window's edges
   against its inside (the mean of the 2 outermost texel rows and columns over that of the next 4,
   per photo: target within 5 % of 1, no paper in the edge texels) and the texels repeated there.
4. ``optimize`` (same config, same seed) on the rectified capture and on the "ideally
   rectified" one: the capture simulator's texel renders of the same maps from the true
   cameras and flashes; the held-out re-rendering RMSE of each fit against the ground truth
   and their ratio (target: rectified <= 1.25 x ideal).

Run: ``python benchmarks/bench_tags.py`` (``--quick``: 4 photos of 640x480, 64^2, short fits).
"""
from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

import mi_svbrdf  # noqa: F401  (variant, plugins)
from mi_svbrdf.core.metrics import eval_lights, rerender_rmse
from mi_svbrdf.data import procedural
from mi_svbrdf.data.frame_photos import FramePhoto, FramePose, ideal_captures, save_photo
from mi_svbrdf.data.photo_setups import simulate
from mi_svbrdf.data.tag_photos import render_tag_photo, sample_camera
from mi_svbrdf.geometry.poses import focal_px_of_fov
from mi_svbrdf.geometry.rectify import RectifyOptions
from mi_svbrdf.geometry.sheets import sheet_figure, write_sheets
from mi_svbrdf.geometry.tag_rectify import rectify_tag_photos
from mi_svbrdf.io.atomic import dumps_json
from mi_svbrdf.geometry.tags import TagSheet, detect_tags
from mi_svbrdf.io.calibrated_photos import capture_from_simulator, load_capture, save_capture
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.material_io import srgb_decode
from mi_svbrdf.optim import OptimizeConfig, optimize

#: The print's ring size S (mm) and the photos' field of view (degrees across the long side).
SHEET_MM, FOV = 180.0, 60.0
NOISE = 0.004


def check_print(folder: Path) -> float:
    """Write the sheets; the A4 sheet at 300 dpi: the measured S in mm (every tag must be found)."""
    write_sheets("tags", folder, SHEET_MM)
    dpi = 300
    sheet_figure("tags", "a4", SHEET_MM).savefig(folder / "a4_300dpi.png", dpi=dpi)
    det = detect_tags(cv2.imread(str(folder / "a4_300dpi.png"), cv2.IMREAD_GRAYSCALE))
    if det.ids.tolist() != list(range(16)):
        raise SystemExit(f"the printed sheet shows tags {det.ids.tolist()}, expected 0..15")
    return float((det.corners[..., 0].max() - det.corners[..., 0].min()) / dpi * 25.4)


def ideal(cameras: list, width: int, height: int) -> list[FramePhoto]:
    """The true cameras and flashes as :class:`FramePhoto` ground truth (for :func:`ideal_captures`)."""
    out = []
    for cam in cameras:
        c = tuple(float(v) for v in cam.position)
        pose = FramePose(c, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), FOV, width, height)
        out.append(FramePhoto(np.zeros((1, 1, 3), np.uint8), np.zeros((4, 2)), pose, c, float(np.dot(c, c)), NOISE))
    return out


def edge_ratio(path: Path) -> float:
    """A rectified photo's 2 outermost texel rows and columns over the next 4 (linear means): 1 with no paper."""
    grey = srgb_decode(read_image(path)[0]).mean(axis=2)
    s = grey.shape[0]
    edge = np.zeros((s, s), bool)
    edge[:2], edge[-2:], edge[:, :2], edge[:, -2:] = True, True, True, True
    ring = np.zeros((s, s), bool)
    ring[:6], ring[-6:], ring[:, :6], ring[:, -6:] = True, True, True, True
    ring &= ~edge
    return float(grey[edge].mean() / grey[ring].mean())


def fit_error(capture_json: Path, gt: torch.Tensor, cfg: OptimizeConfig) -> float:
    """Held-out re-rendering RMSE of an optimize run on a capture file."""
    spec, images, valid = load_capture(capture_json)
    torch.manual_seed(0)
    return float(rerender_rmse(optimize(spec, images, valid, config=cfg).maps, gt, eval_lights())[0])


def run(quick: bool, material: str, seed: int, count: int, size: int, budget: float) -> dict:
    """The whole proof; returns the figures."""
    width, height = (640, 480) if quick else (1024, 768)
    focal = focal_px_of_fov(FOV, width, height)
    gt = procedural.generate(material, seed, size)[None]
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        printed_mm = check_print(tmp / "print")
        (tmp / "photos").mkdir()
        t0 = time.perf_counter()
        cameras, paths = [], []
        for k in range(count):
            cam = sample_camera(rng, focal=focal, size=(width, height))
            path = tmp / "photos" / f"IMG_{k:04d}.jpg"
            save_photo(path, render_tag_photo(gt, cam, spp=16, noise_std=NOISE, seed=seed * 100 + k))
            cameras.append(cam)
            paths.append(path)
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        results = rectify_tag_photos(paths, tmp / "rect", RectifyOptions(size=size), TagSheet(SHEET_MM))
        t_rect = time.perf_counter() - t0
        failed = [r.error for r in results if not r.ok]
        if failed:
            raise SystemExit(f"rectify failed: {failed}")
        edges = [edge_ratio(tmp / "rect" / r.entry["output"]) for r in results]
        cam_err = [100.0 * np.linalg.norm(np.asarray(r.entry["camera_position"]) - c.position)
                   / np.linalg.norm(c.position) for r, c in zip(results, cameras)]
        cal = json.loads((tmp / "rect" / "rectify.json").read_text())["calibrations"][0]
        pp_err = np.abs(np.subtract(cal["principal_point_px"], [0.5 * (width - 1), 0.5 * (height - 1)]))
        caps = ideal_captures(ideal(cameras, width, height))
        spec, images = capture_from_simulator(caps, 0, simulate(gt, caps, torch.Generator().manual_seed(seed)))
        save_capture(tmp / "ideal" / "capture.json", spec, images)
        cfg = OptimizeConfig(budget_s=budget, iterations=2000, progress=False)
        rect_err = fit_error(tmp / "rect" / "capture.json", gt, cfg)
        ideal_err = fit_error(tmp / "ideal" / "capture.json", gt, cfg)
    return {"material": f"{material}:{seed}", "photos": count, "photo_size": [width, height], "rectified_size": size,
            "printed_S_mm_at_300dpi": round(printed_mm, 3),
            "tags_used": [len(r.entry["tags_used"]) for r in results],
            "reprojection_px": [r.entry["reprojection_error_px"]["tags_rms"] for r in results],
            "edge_over_inside": [round(v, 4) for v in edges],
            "texels_repeated_max": max(max(r.entry["texels_repeated"]) for r in results),
            "camera_error_pct_median": float(np.median(cam_err)), "camera_error_pct_max": float(np.max(cam_err)),
            "focal_error_pct": 100.0 * abs(cal["focal_px"] / focal - 1.0),
            "principal_point_error_pct": float(100.0 * np.max(pp_err / [width, height])),
            "render_s": round(t_render, 1), "rectify_s_per_photo": round(t_rect / count, 2),
            "rerender_rmse_rectified": rect_err, "rerender_rmse_ideal": ideal_err,
            "rerender_ratio": rect_err / ideal_err}


def main() -> None:
    """Print the proof's figures (JSON) and whether each target is met."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="4 photos of 640x480, 64^2, short fits")
    parser.add_argument("--material", default="leather", help="procedural class (default leather)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--photos", type=int, default=8)
    parser.add_argument("--size", type=int, default=128, help="rectified size = map size (default 128)")
    parser.add_argument("--budget-s", type=float, default=60.0)
    args = parser.parse_args()
    if args.quick:
        args.photos, args.size, args.budget_s = 4, 64, 15.0
    f = run(args.quick, args.material, args.seed, args.photos, args.size, args.budget_s)
    print(dumps_json(f))
    print(f"printed S {f['printed_S_mm_at_300dpi']:.2f} mm (target {SHEET_MM:g} +- 0.3): "
          f"{'ok' if math.isclose(f['printed_S_mm_at_300dpi'], SHEET_MM, abs_tol=0.3) else 'MISSED'}")
    print(f"camera position error max {f['camera_error_pct_max']:.2f} % (target < 1): "
          f"{'ok' if f['camera_error_pct_max'] < 1 else 'MISSED'}")
    edge = max(f["edge_over_inside"], key=lambda v: abs(v - 1.0))
    print(f"window edges over inside: worst {edge:.3f} (target within 0.05 of 1): "
          f"{'ok' if abs(edge - 1.0) < 0.05 else 'MISSED'}; up to {f['texels_repeated_max']} texels repeated per side")
    worst = max(f["focal_error_pct"], f["principal_point_error_pct"])
    print(f"intrinsics error max {worst:.2f} % (target < 2): {'ok' if worst < 2 else 'MISSED'}")
    print(f"re-rendering RMSE rectified {f['rerender_rmse_rectified']:.4f} vs ideal {f['rerender_rmse_ideal']:.4f}: "
          f"ratio {f['rerender_ratio']:.3f} (target <= 1.25): {'ok' if f['rerender_ratio'] <= 1.25 else 'MISSED'}")


if __name__ == "__main__":
    main()
