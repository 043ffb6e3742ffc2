"""Exports at a material's own size, checked by the tools they are for, against our texel renderer.

For one material folder (a fit's ``material/``, e.g. 1024^2), each format of ``mi-svbrdf export``:

* glTF: the Khronos glTF validator (npm's ``gltf-validator`` in ``.tools``, ``bash .ci/setup.sh --tests``) reads the
  model, its buffer and its images: errors and warnings counted;
* Blender: Blender itself (PyPI's ``bpy`` in ``.venv-blender``) runs the exported script and renders it with Cycles
  (``tests/blender_render.py``: one point light, the camera seeing exactly the square, one sample at each pixel's
  centre), at the maps' size;
* Mitsuba: Mitsuba loads the exported scene and renders it under its own point light at the maps' size.

Each render is compared with the texel renderer's (:func:`mi_svbrdf.render`) under the same light and camera, in
display space (gamma 2.2, clipped): mean and 99th percentile of the absolute difference. The export's time and
files' size are recorded too. Writes ``exports.{json,md,png}`` (the renders side by side, 512 px) to ``--out``::

    python benchmarks/bench_exports.py /path/to/fit/material [--out docs/benchmarks]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

import mi_svbrdf as ms
from mi_svbrdf.io import export as E
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.figures import labelled_row
from mi_svbrdf.io.image_io import read_image, write_image
from mi_svbrdf.io.material_io import read_distribution, read_material
from mi_svbrdf.io.tables import markdown_table

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "benchmarks"
#: Blender's point light of P watts has our intensity I = P / (4 pi^2) (tests/blender_render.py).
BLENDER_WATTS_PER_INTENSITY = 4.0 * math.pi ** 2
#: The light and camera of the Blender comparison (tests/test_export.py's).
LIGHT, CAM_Z, INTENSITY = (0.4, -0.3, 1.2), 2.75, 2.0
PANEL = 512


def display(x: np.ndarray) -> np.ndarray:
    return np.clip(x, 0.0, 1.0) ** (1 / 2.2)


def ours(maps: torch.Tensor, light: tuple[float, float, float], cam_z: float, intensity: float,
         distribution: str, supersample: int = 1) -> np.ndarray:
    """The texel renderer's ``(H, W, 3)`` radiance of ``maps`` under a point light seen from ``(0, 0, cam_z)``;
    ``supersample``: each texel split into ``s x s`` (nearest) and the radiance averaged back (a pixel's footprint)."""
    fine = maps.repeat_interleave(supersample, 2).repeat_interleave(supersample, 3) if supersample > 1 else maps
    radiance = ms.render(fine, torch.tensor([[light]]), ms.point(torch.tensor([[[0.0, 0.0, cam_z]]])),
                         intensity=intensity, distance_falloff=True, distribution=distribution)[0, 0]
    if supersample > 1:
        radiance = F.avg_pool2d(radiance[None], supersample)[0]
    return radiance.permute(1, 2, 0).numpy()


def compare(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    diff = np.abs(display(image) - display(reference))
    return {"mean_display_diff": round(float(diff.mean()), 5),
            "p99_display_diff": round(float(np.quantile(diff, 0.99)), 5),
            "mean_linear_rel": round(float(np.abs(image - reference).mean() / max(reference.mean(), 1e-12)), 5)}


def size_mb(folder: Path) -> float:
    return round(sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2 ** 20, 2)


def exported(maps: torch.Tensor, out: Path, fmt: str, distribution: str) -> tuple[dict[str, Any], float]:
    t0 = time.perf_counter()
    summary = E.export_material(maps, out, fmt, distribution=distribution)
    return summary, round(time.perf_counter() - t0, 2)


def check_gltf(maps: torch.Tensor, work: Path, distribution: str) -> dict[str, Any]:
    out = work / "gltf"
    _, seconds = exported(maps, out, "gltf", distribution)
    package = Path(os.environ.get("MI_SVBRDF_TOOLS") or ROOT / ".tools") / "node_modules" / "gltf-validator"
    gltf = next(out.glob("*.gltf"))
    proc = subprocess.run(["node", str(ROOT / "tests" / "gltf_validate.js"), str(package), str(gltf)],
                          capture_output=True, text=True, timeout=600, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {gltf}: {proc.stderr[-2000:]}")
    issues = json.loads(proc.stdout)["issues"]
    return {"export_s": seconds, "files_mb": size_mb(out), "errors": issues["numErrors"],
            "warnings": issues["numWarnings"], "infos": issues["numInfos"]}


def check_blender(maps: torch.Tensor, work: Path, distribution: str, spp: int) -> tuple[dict[str, Any], np.ndarray]:
    out = work / "blender"
    _, seconds = exported(maps, out, "blender", distribution)
    python = Path(os.environ.get("MI_SVBRDF_BLENDER_VENV") or ROOT / ".venv-blender") / "bin" / "python"
    size = maps.shape[-1]
    t0 = time.perf_counter()
    proc = subprocess.run([str(python), str(ROOT / "tests" / "blender_render.py"), str(out / "material_blender.py"),
                           str(work / "cycles.exr"), "--size", str(size), "--cam-z", str(CAM_Z),
                           "--light", ",".join(map(str, LIGHT)),
                           "--power", str(INTENSITY * BLENDER_WATTS_PER_INTENSITY), "--spp", str(spp)],
                          capture_output=True, text=True, timeout=1800, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"Blender failed: {proc.stderr[-3000:]}")
    render_s = round(time.perf_counter() - t0, 1)
    image = read_image(work / "cycles.exr")[0][:, :, :3]
    reference = ours(maps, LIGHT, CAM_Z, INTENSITY, distribution)
    return {"export_s": seconds, "files_mb": size_mb(out), "render_s": render_s, "spp": spp,
            **compare(image, reference)}, image


def check_mitsuba(maps: torch.Tensor, work: Path, distribution: str, spp: int) -> tuple[dict[str, Any], np.ndarray]:
    import mitsuba as mi

    from mi_svbrdf.variant import scene_variant

    out = work / "mitsuba"
    summary, seconds = exported(maps, out, "mitsuba", distribution)
    light = (0.6, -0.3, 1.8)
    t0 = time.perf_counter()
    cwd = Path.cwd()
    os.chdir(out)  # the scene's textures resolve against its folder
    try:
        with scene_variant("cpu"):
            scene = mi.load_file(str(out / "scene.xml"), spp=str(spp), filter_type="nearest", light_x=str(light[0]),
                                 light_y=str(light[1]), light_z=str(light[2]))
            image = np.asarray(mi.render(scene, seed=1))[..., :3]
    finally:
        os.chdir(cwd)
    render_s = round(time.perf_counter() - t0, 1)
    cam_z = float(summary["parameters"]["cam_z"])
    intensity = float(summary["parameters"]["light_intensity"]) / math.pi
    reference = ours(maps, light, cam_z, intensity, distribution, supersample=4)  # Mitsuba samples the footprint
    return {"export_s": seconds, "files_mb": size_mb(out), "render_s": render_s, "spp": spp,
            **compare(image, reference)}, image


def panel(name: str, image: np.ndarray) -> tuple[str, np.ndarray]:
    small = F.interpolate(torch.from_numpy(np.ascontiguousarray(display(image))).permute(2, 0, 1)[None],
                          size=(PANEL, PANEL), mode="area")[0].permute(1, 2, 0).numpy()
    return name, (small * 255 + 0.5).astype(np.uint8)


def page(results: dict[str, Any]) -> str:
    rows = []
    for fmt, r in results["formats"].items():
        check = (f"{r['errors']} errors, {r['warnings']} warnings" if fmt == "gltf" else
                 f"rendered in {r['render_s']:g} s ({r['spp']} spp): display diff mean {r['mean_display_diff']:.4f}, "
                 f"p99 {r['p99_display_diff']:.4f}; linear {100 * r['mean_linear_rel']:.2f} % of the mean")
        rows.append([fmt, f"{r['export_s']:g}", f"{r['files_mb']:g}", check])
    size = results["size"]
    return "\n".join([
        f"# Exports at {size[0]}x{size[1]}", "",
        "Generated by `python benchmarks/bench_exports.py " + results["command"] + "`; do not edit by hand. "
        "Each format of `mi-svbrdf export`, read by the tool it is for: the Khronos glTF validator; Blender (Cycles, "
        "`tests/blender_render.py`) and Mitsuba rendering the export under a point light at the maps' size, compared "
        "with the texel renderer in display space (gamma 2.2). Machine: "
        + json.dumps(results["machine"], allow_nan=False) + ".", "",
        markdown_table(["format", "export s", "files MB", "check"], rows), "",
        "![Cycles, ours and Mitsuba](exports.png)", ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("material", type=Path, help="a material folder (e.g. optimize's material/)")
    parser.add_argument("--out", type=Path, default=DOCS)
    parser.add_argument("--spp-blender", type=int, default=4)
    parser.add_argument("--spp-mitsuba", type=int, default=16)
    args = parser.parse_args(argv)
    maps = read_material(args.material)
    distribution = read_distribution(args.material)
    results: dict[str, Any] = {"command": " ".join(sys.argv[1:] if argv is None else argv),
                               "size": list(maps.shape[-2:]), "distribution": distribution,
                               "machine": {"cpus": os.cpu_count()}, "formats": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        results["formats"]["gltf"] = check_gltf(maps, work, distribution)
        print("gltf", results["formats"]["gltf"], flush=True)
        results["formats"]["blender"], cycles = check_blender(maps, work, distribution, args.spp_blender)
        print("blender", results["formats"]["blender"], flush=True)
        results["formats"]["mitsuba"], mitsuba = check_mitsuba(maps, work, distribution, args.spp_mitsuba)
        print("mitsuba", results["formats"]["mitsuba"], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    reference = ours(maps, LIGHT, CAM_Z, INTENSITY, distribution)
    row = labelled_row([panel("Blender (Cycles)", cycles), panel("ours, same light", reference),
                        panel("Mitsuba (its own light)", mitsuba)])
    write_image(args.out / "exports.png", row.astype(np.float32) / 255.0, srgb=True)
    write_json(args.out / "exports.json", results)
    write_text(args.out / "exports.md", page(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
