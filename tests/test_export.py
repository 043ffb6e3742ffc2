"""Exports (``mi-svbrdf export``): the glTF BRDF, glTF validity, the Blender script, the Mitsuba scene.

Each format for GGX and for Beckmann materials (``distribution``). Real tools where the set-up
installed them (``bash .ci/setup.sh --tests``; skipped with the reason where absent):

- glTF: the Khronos glTF validator (npm's ``gltf-validator`` in ``.tools/``, another folder with
  ``MI_SVBRDF_TOOLS``) validates the written model, its buffer and its images: no error, no warning.
- Blender: the exported script is run by Blender itself (PyPI's ``bpy`` 4.5 in ``.venv-blender``,
  another venv with ``MI_SVBRDF_BLENDER_VENV``) and rendered with Cycles under a point light
  (``tests/blender_render.py``), then compared with our texel renderer (tolerances at the test).
  The script is also executed against a stand-in ``bpy`` (a ``MagicMock`` recording the images it
  loads and the colour spaces it sets) to cover its Blender 3.x branches, and its texture table is
  checked against the files on disk.
"""
from __future__ import annotations

import ast
import json
import math
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path
from unittest import mock

import mitsuba as mi
import numpy as np
import pygltflib
import pytest
import torch
import torch.nn.functional as F
from pygltflib.validator import validate

import mi_svbrdf as ms
from mi_svbrdf.cli import export as cli_export
from mi_svbrdf.core import brdf_gltf
from mi_svbrdf.core import maps as M
from mi_svbrdf.data.examples import example_material
from mi_svbrdf.io import export as E
from mi_svbrdf.io import material_io
from mi_svbrdf.io.image_io import read_image
from tests.conftest import random_maps

ROOT = Path(__file__).resolve().parent.parent


# ------------------------------------------------------------------------ the glTF BRDF
def _gltf_scalar(n_l: float, n_v: float, n_h: float, v_h: float, base: float, metallic: float, r: float,
                 spec_color: float, spec: float) -> float:
    """The glTF BRDF for one channel, written out from the spec (grey colours: max_rgb = the value)."""
    a = r * r
    a2 = a * a
    d = a2 / (math.pi * (n_h ** 2 * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (n_l * math.sqrt(n_v ** 2 * (1 - a2) + a2) + n_v * math.sqrt(n_l ** 2 * (1 - a2) + a2))
    w = (1 - v_h) ** 5
    f0 = min(0.04 * spec_color, 1.0) * spec
    fd = f0 + (spec - f0) * w
    dielectric = fd * vis * d + (1 - fd) * base / math.pi
    metal = (base + (1 - base) * w) * vis * d
    return (1 - metallic) * dielectric + metallic * metal


def test_gltf_brdf_normal_incidence_hand_value():
    # n = l = v = z, r = 0.5: alpha = 0.25, D = 1/(pi alpha^2) = 16/pi, Vis = 1/4, F = f0 = 0.04 * 2.
    up = torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1)
    one = torch.ones(1, 1, 1)
    f = brdf_gltf.eval_brdf(up, up, up, torch.full((3, 1, 1), 0.5), 0 * one, 0.5 * one,
                            torch.tensor([2.0, 1.0, 0.5]).view(3, 1, 1), one)
    f0 = torch.tensor([0.08, 0.04, 0.02])
    expected = f0 * (16 / math.pi) / 4 + (1 - 0.08) * 0.5 / math.pi
    assert torch.allclose(f.flatten(), expected, rtol=1e-6)


@pytest.mark.parametrize("metallic", [0.0, 0.3, 1.0])
def test_gltf_brdf_oblique_hand_value(metallic):
    n = torch.tensor([0.0, 0.0, 1.0])
    wl = torch.tensor([math.sin(1.0), 0.0, math.cos(1.0)])
    wv = torch.tensor([-math.sin(0.4) * 0.6, math.sin(0.4) * 0.8, math.cos(0.4)])
    h = (wl + wv) / (wl + wv).norm()
    f = brdf_gltf.eval_brdf(n.view(3, 1, 1), wl.view(3, 1, 1), wv.view(3, 1, 1), torch.full((3, 1, 1), 0.3),
                            torch.full((1, 1, 1), metallic), torch.full((1, 1, 1), 0.6),
                            torch.full((3, 1, 1), 1.5), torch.full((1, 1, 1), 0.9))
    want = _gltf_scalar(float(wl[2]), float(wv[2]), float(h[2]), float(wv @ h), 0.3, metallic, 0.6, 1.5, 0.9)
    assert torch.allclose(f.flatten(), torch.full((3,), want), rtol=1e-5)


def test_conversion_matches_ours_at_normal_incidence_and_beats_naive():
    maps = random_maps(1, 4, 4, seed=3, max_tilt=0.0, rough_range=(0.2, 1.0))  # r > 0.2: no 1e-3 floor
    maps[:, M.SLICES["specular"]] = 0.2 + 0.8 * maps[:, M.SLICES["specular"]]  # F residue < 0.1 %
    # flash at the texel: light = view straight above -> v.h = 1, both Fresnels = s, Vis = G/4.
    material = brdf_gltf.from_svbrdf(maps)
    up = torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1)
    n = M.normal(maps)
    ours = ms.core.brdf_torch.eval_brdf(n, up, up, M.diffuse(maps), M.specular(maps),
                                        M.roughness(maps).clamp(1e-3, 1), include_diffuse=False)
    theirs = brdf_gltf.eval_brdf(n, up, up, torch.zeros_like(material.base_color), material.metallic,
                                 material.roughness, material.specular_color, material.specular)
    # specular lobes: equal up to ours' 2^-12.5 Fresnel residue and 1e-3 floors
    assert torch.allclose(theirs, ours, rtol=2e-3, atol=1e-4)
    example = example_material("metal_plate", size=64)
    matched = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, "matched"))["rmse_display"]
    naive = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, "naive"))["rmse_display"]
    assert matched < naive and matched < 0.02


@pytest.mark.parametrize("r", [0.1, 0.3, 0.5, 0.8])
def test_ggx_roughness_rules(r):
    from mi_svbrdf.eval.studies.output_model import equivalent_roughness

    rough = torch.tensor(r)
    assert brdf_gltf.ggx_roughness(rough, "ggx", "width") == rough  # GGX: as it is, whatever the rule
    assert brdf_gltf.ggx_roughness(rough, "beckmann", "peak") == rough
    width = brdf_gltf.ggx_roughness(rough, "beckmann", "width")
    assert torch.allclose(width, equivalent_roughness(rough, "beckmann", "ggx"))  # the project's convention
    assert math.isclose(float(width), r / 0.8792, rel_tol=1e-3)
    assert brdf_gltf.ggx_roughness(torch.tensor(0.95), "beckmann", "width") == 1.0
    with pytest.raises(ValueError, match="distribution: expected"):
        brdf_gltf.ggx_roughness(rough, "phong")
    with pytest.raises(ValueError, match="rule: expected"):
        brdf_gltf.ggx_roughness(rough, "beckmann", "energy")


def test_beckmann_as_gltf_exact_peak_under_a_flash_and_the_rules_measured():
    maps = random_maps(1, 4, 4, seed=3, max_tilt=0.0, rough_range=(0.2, 1.0))
    maps[:, M.SLICES["specular"]] = 0.2 + 0.8 * maps[:, M.SLICES["specular"]]
    material = brdf_gltf.from_svbrdf(maps, distribution="beckmann")
    assert torch.equal(material.roughness, M.roughness(maps))  # rule "peak": r kept
    up = torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1)
    n = M.normal(maps)
    ours = ms.core.brdf_torch.eval_brdf(n, up, up, M.diffuse(maps), M.specular(maps), M.roughness(maps),
                                        distribution="beckmann", include_diffuse=False)
    theirs = brdf_gltf.eval_brdf(n, up, up, torch.zeros_like(material.base_color), material.metallic,
                                 material.roughness, material.specular_color, material.specular)
    assert torch.allclose(theirs, ours, rtol=2e-3, atol=1e-4)  # D(n) = 1/(pi alpha^2) in both, G/4 = Vis = 1/4
    oblique = torch.tensor([0.6, 0.0, 0.8]).view(1, 3, 1, 1)  # away from the peak the lobes differ
    off = ms.core.brdf_torch.eval_brdf(n, oblique, up, M.diffuse(maps), M.specular(maps), M.roughness(maps),
                                       distribution="beckmann", include_diffuse=False)
    off_gltf = brdf_gltf.eval_brdf(n, oblique, up, torch.zeros_like(material.base_color), material.metallic,
                                   material.roughness, material.specular_color, material.specular)
    assert ((off_gltf - off).abs() / off).max() > 0.05
    # the module docstring's figures: peak beats equal width on the examples, both far above GGX's own error
    for name, peak_want, width_want, ggx_want in (("metal_plate", 0.204, 0.251, 0.010), ("tiles", 0.028, 0.037, 0.002)):
        example = example_material(name, size=64)
        peak = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, distribution="beckmann"),
                                 distribution="beckmann")["rmse_display"]
        width = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, distribution="beckmann", rule="width"),
                                  distribution="beckmann")["rmse_display"]
        ggx = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example))["rmse_display"]
        assert np.allclose([peak, width, ggx], [peak_want, width_want, ggx_want], rtol=0, atol=1e-3), name
        assert ggx < peak < width, name
    with pytest.raises(ValueError, match="distribution: expected"):
        brdf_gltf.compare(maps, material, distribution="phong")


# ------------------------------------------------------------------------ glTF
@pytest.fixture(scope="module")
def material_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("material")
    maps = random_maps(1, 16, 16, seed=5, rough_range=(0.2, 0.9), max_tilt=0.6)
    maps[:, M.SLICES["specular"]] *= 0.3  # mostly dielectric, one metal-like corner
    maps[:, M.SLICES["specular"], :4, :4] = 0.9
    material_io.write_material(folder, maps, fmt="exr")
    return folder


def test_gltf_export_is_valid_and_loads_back(material_dir, tmp_path, capsys):
    out = tmp_path / "gltf"
    assert cli_export.main(["export", str(material_dir), "--format", "gltf", "-o", str(out),
                            "--normals", "directx"]) == 0
    printed = capsys.readouterr().out
    assert "RMSE display" in printed
    maps = material_io.read_material(material_dir)

    gltf = pygltflib.GLTF2().load(str(out / "material.gltf"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "provisional function"
        validate(gltf)
    assert gltf.asset.version == "2.0"
    assert "KHR_materials_specular" in gltf.extensionsUsed and not gltf.extensionsRequired
    assert gltf.buffers[0].byteLength == (out / "material.bin").stat().st_size
    assert gltf.accessors[0].min == [-1, -1, 0] and gltf.accessors[0].max == [1, 1, 0]
    images = [out / im.uri for im in gltf.images]
    assert all(p.is_file() for p in images) and len(images) == 4
    assert all(0 <= t.source < len(images) for t in gltf.textures)

    mat = gltf.materials[0]
    pbr = mat.pbrMetallicRoughness
    assert all(0.0 <= c <= 1.0 for c in pbr.baseColorFactor)
    assert 0.0 <= pbr.metallicFactor <= 1.0 and 0.0 <= pbr.roughnessFactor <= 1.0
    ext = mat.extensions["KHR_materials_specular"]
    assert 0.0 <= ext["specularFactor"] <= 1.0
    assert all(math.isfinite(c) and c >= 0.0 for c in ext["specularColorFactor"])
    # specular colour: 0.04 * factor * texture = s (8-bit sRGB precision)
    spec_tex = material_io.srgb_decode(read_image(out / gltf.images[ext["specularColorTexture"]["index"]].uri)[0])
    s = M.specular(maps)[0].permute(1, 2, 0).numpy()
    assert np.abs(0.04 * np.asarray(ext["specularColorFactor"]) * spec_tex - s).max() < 0.02
    # roughness in G, linear; metallic (B) 0
    mr = read_image(out / gltf.images[pbr.metallicRoughnessTexture.index].uri)[0]
    assert np.abs(mr[:, :, 1] - M.roughness(maps)[0, 0].numpy()).max() <= 0.5 / 255 + 1e-6
    assert mr[:, :, 2].max() == 0.0
    # OpenGL normal map; the DirectX copy has green flipped
    normal = read_image(out / gltf.images[mat.normalTexture.index].uri)[0]
    assert np.abs(material_io.decode_normal(normal) - M.normal(maps)[0].permute(1, 2, 0).numpy()).max() < 0.02
    dx = read_image(out / "textures/normal_directx.png")[0]
    assert np.abs(dx[:, :, 1] - (1.0 - normal[:, :, 1])).max() <= 1.5 / 255
    assert np.array_equal(dx[:, :, [0, 2]], normal[:, :, [0, 2]])

    summary = json.loads((out / "export.json").read_text())
    approx = summary["approximation"]
    assert 0.0 < approx["exported"]["rmse_display"] < 0.05
    assert approx["exported"]["rmse_display"] < approx["fallback_without_extension"]["rmse_display"]
    assert len(approx["exported"]["rmse_display_per_light"]) == 9
    assert set(summary["files"]) >= {"material.gltf", "material.bin", "textures/base_color.png"}
    assert summary["distribution"] == "ggx" and "notes" not in summary and "beckmann" not in approx


def test_gltf_export_of_a_beckmann_material_says_what_it_did(material_dir, tmp_path):
    maps = material_io.read_material(material_dir)
    ggx = E.export_material(maps, tmp_path / "ggx", "gltf")
    out = tmp_path / "beckmann"
    summary = E.export_material(maps, out, "gltf", distribution="beckmann")
    assert summary == json.loads((out / "export.json").read_text())
    assert summary["distribution"] == "beckmann"
    (note,) = summary["notes"]
    assert "Beckmann" in note and "GGX" in note and f"{summary['approximation']['exported']['rmse_display']:.4f}" in note
    gltf = json.loads((out / "material.gltf").read_text())
    assert gltf["asset"]["extras"]["distribution"] == "beckmann" and "Beckmann" in gltf["asset"]["extras"]["roughness"]
    # the roughness texture is r, as for GGX (rule "peak"); only the error against our renderings changes
    for name in ("metallic_roughness.png", "base_color.png", "specular_color.png", "normal.png"):
        assert np.array_equal(read_image(out / "textures" / name)[0], read_image(tmp_path / "ggx/textures" / name)[0])
    approx = summary["approximation"]
    exported = approx["exported"]["rmse_display"]
    assert ggx["approximation"]["exported"]["rmse_display"] < exported < 0.1
    assert exported < approx["beckmann"]["equal_width_roughness"]["rmse_display"]
    assert "Beckmann" in approx["approximations"]
    with pytest.raises(ValueError, match="distribution: expected"):
        E.export_material(maps, tmp_path / "bad", "gltf", distribution="phong")


def _gltf_validator() -> Path:
    """The gltf-validator npm package (``bash .ci/setup.sh --tests`` installs it); skips the test without it or node."""
    package = Path(os.environ.get("MI_SVBRDF_TOOLS") or ROOT / ".tools") / "node_modules" / "gltf-validator"
    if shutil.which("node") is None:
        pytest.skip("Khronos glTF validator: no 'node' on PATH (Debian: apt-get install nodejs)")
    if not (package / "package.json").is_file():
        pytest.skip(f"Khronos glTF validator: no {package} (bash .ci/setup.sh --tests installs it: "
                    "npm install --prefix .tools gltf-validator)")
    return package


def _validate(package: Path, gltf: Path) -> dict:
    proc = subprocess.run(["node", str(ROOT / "tests" / "gltf_validate.js"), str(package), str(gltf)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_gltf_export_passes_the_khronos_validator(material_dir, tmp_path, distribution):
    package = _gltf_validator()
    out = tmp_path / "gltf"
    E.export_material(material_io.read_material(material_dir), out, "gltf", normals="directx",
                      distribution=distribution)
    report = _validate(package, out / "material.gltf")
    issues = report["issues"]
    assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), issues["messages"]
    loaded = {r["uri"]: r for r in report["info"]["resources"]}
    assert set(loaded) == {"material.bin", *(f"textures/{n}.png" for n in
                                               ("base_color", "metallic_roughness", "normal", "specular_color"))}
    assert all(r["image"]["width"] == 16 and r["image"]["height"] == 16 for u, r in loaded.items() if u != "material.bin")
    assert report["info"]["extensionsUsed"] == ["KHR_materials_specular"]
    # the validator reads what it is given: a buffer shorter than declared is an error
    (out / "material.bin").write_bytes((out / "material.bin").read_bytes()[:-8])
    broken = _validate(package, out / "material.gltf")["issues"]
    assert broken["numErrors"] > 0, broken


# ------------------------------------------------------------------------ Blender
def _run_blender_script(path, blender4: bool) -> tuple[dict[str, str], list[str]]:
    """Execute the script against a stand-in ``bpy``: ``{loaded image path: colour space}`` and the node kinds made.

    ``blender4=False`` stands for Blender 3.x: no "Specular IOR Level" input, no Metallic BSDF node.
    """
    bpy = mock.MagicMock()
    if not blender4:
        del bpy.types.ShaderNodeBsdfMetallic
    loaded, kinds = [], []

    def load(filepath, check_existing=False):
        image = mock.MagicMock()
        loaded.append((filepath, image))
        return image

    def new_node(kind):
        kinds.append(kind)
        node = mock.MagicMock()
        if kind == "ShaderNodeBsdfPrincipled":
            node.inputs.__contains__.return_value = blender4
        return node

    bpy.data.images.load.side_effect = load
    bpy.data.materials.new.return_value.node_tree.nodes.new.side_effect = new_node
    with mock.patch.dict(sys.modules, {"bpy": bpy}):
        code = compile(path.read_text(), str(path), "exec")
        exec(code, {"__name__": "__main__", "__file__": str(path)})  # noqa: S102 - the generated script, on a stand-in bpy
    bpy.ops.mesh.primitive_plane_add.assert_called_once()
    return {p: im.colorspace_settings.name for p, im in loaded}, kinds


@pytest.mark.parametrize(("normals", "distribution"), [("opengl", "ggx"), ("directx", "ggx"), ("directx", "beckmann")])
def test_blender_script(material_dir, tmp_path, normals, distribution):
    out = tmp_path / "blender"
    maps = material_io.read_material(material_dir)
    summary = E.export_material(maps, out, "blender", normals=normals, distribution=distribution)
    script = out / "material_blender.py"
    tree = ast.parse(script.read_text())
    table = next(ast.literal_eval(node.value) for node in tree.body
                 if isinstance(node, ast.Assign) and node.targets[0].id == "TEXTURES")
    on_disk = {p.relative_to(out).as_posix() for p in (out / "textures").iterdir()}
    assert {f for f, _ in table.values()} == on_disk  # every texture referenced, each one exists
    spaces = {k: space for k, (_, space) in table.items()}
    assert spaces == {"base_color": "sRGB", "specular_tint": "sRGB", "roughness": "Non-Color",
                      "normal": "Non-Color", "specular_f0": "Non-Color"}
    assert table["normal"][0] == ("textures/normal_directx.png" if normals == "directx" else "textures/normal.png")
    assert set(summary["files"]) == on_disk | {"material_blender.py"}
    assert summary["distribution"] == distribution and summary["shading"] == E.BLENDER_SHADING[distribution]
    for blender4 in (True, False):
        loaded, kinds = _run_blender_script(script, blender4)
        assert {(out / f).resolve(): s for f, s in table.values()} == \
            {Path(p).resolve(): s for p, s in loaded.items()}
        if distribution == "ggx":
            assert "ShaderNodeBsdfPrincipled" in kinds and "ShaderNodeBsdfDiffuse" not in kinds
        else:  # Principled has no Beckmann: Diffuse + Metallic (Blender 4.3+) or Glossy (older)
            assert "ShaderNodeBsdfPrincipled" not in kinds and "ShaderNodeBsdfDiffuse" in kinds
            assert ("ShaderNodeBsdfMetallic" if blender4 else "ShaderNodeBsdfGlossy") in kinds
    base = material_io.srgb_decode(read_image(out / "textures/base_color.png")[0])
    d, s = (M.diffuse(maps)[0].permute(1, 2, 0).numpy(), M.specular(maps)[0].permute(1, 2, 0).numpy())
    if distribution == "beckmann":  # the Diffuse BSDF's colour: our diffuse term d (1 - s)
        assert np.abs(base - d * (1 - s)).max() < 0.01
        assert "Beckmann" in summary["notes"][0]
    else:  # the Principled BSDF's: the glTF conversion's
        assert np.abs(base - np.clip(d * (1 - s) / (1 - s.max(-1, keepdims=True)), 0, 1)).max() < 0.01
        assert "notes" not in summary


#: Blender (Cycles) render of the exported script vs our texel renderer of the same maps, light and camera
#: (64 x 64 examples, point light at (0.4, -0.3, 1.2), camera at (0, 0, 2.75)), in display values
#: clip(x, 0, 1)^(1/2.2). What remains is not noise (Cycles sees a point light at the pixel centres: no
#: sampling noise with nothing else in the scene) but the models: 8-bit base colour and tint textures; for
#: GGX, the Principled BSDF's layering (diffuse under the specular layer, (1 - v.h)^5 Fresnel) against
#: our d (1 - s) and spherical-Gaussian Fresnel; for Beckmann, Cycles' exact Smith G against our
#: Smith-Schlick k = alpha sqrt(2/pi). Measured: mean 0.0016 / 0.0020 (GGX tiles / metal_plate),
#: 0.0012 / 0.0015 (Beckmann); 99th percentile 0.0076 / 0.0098 and 0.0049 / 0.0226; mean linear
#: |difference| over mean radiance 0.0065 / 0.0071 and 0.0055 / 0.0087. The other model (e.g. the
#: Beckmann export against our GGX rendering) is 0.082 (tiles) and 0.52 (metal_plate) at the 99th
#: percentile: the tolerances tell the models apart.
BLENDER_MEAN_TOL = 0.003
BLENDER_P99_TOL = 0.035
BLENDER_LINEAR_REL_TOL = 0.02
#: Blender's point light of P watts has our intensity I = P / (4 pi^2) (tests/blender_render.py).
BLENDER_WATTS_PER_INTENSITY = 4.0 * math.pi ** 2


@pytest.fixture(scope="module")
def blender_python() -> Path:
    """The Python of the bpy venv (``bash .ci/setup.sh --tests`` makes ``.venv-blender``); skips the test without it."""
    venv = Path(os.environ.get("MI_SVBRDF_BLENDER_VENV") or ROOT / ".venv-blender")
    python = venv / "bin" / "python"
    if not python.is_file():
        pytest.skip(f"Blender render test: no {venv} (bash .ci/setup.sh --tests makes it with PyPI's bpy 4.5 "
                    "for Python 3.11)")
    proc = subprocess.run([str(python), "-c", "import bpy; print(bpy.app.version_string)"],
                          capture_output=True, text=True, timeout=300, check=False)
    if proc.returncode != 0:
        pytest.skip(f"Blender render test: bpy does not import in {venv}: {proc.stderr.strip()[-300:]}")
    return python


@pytest.mark.parametrize(("name", "distribution", "normals"), [
    ("tiles", "ggx", "opengl"), ("metal_plate", "ggx", "opengl"), ("tiles", "beckmann", "opengl"),
    ("metal_plate", "beckmann", "opengl"), ("metal_plate", "beckmann", "directx")])
def test_blender_renders_the_export_like_our_renderer(blender_python, tmp_path, name, distribution, normals):
    size, light, cam_z, intensity = 64, (0.4, -0.3, 1.2), 2.75, 2.0
    maps = example_material(name, size=size)
    out = tmp_path / "blender"
    E.export_material(maps, out, "blender", distribution=distribution, normals=normals)
    proc = subprocess.run([str(blender_python), str(ROOT / "tests" / "blender_render.py"),
                           str(out / "material_blender.py"), str(tmp_path / "cycles.exr"), "--size", str(size),
                           "--cam-z", str(cam_z), "--light", ",".join(map(str, light)),
                           "--power", str(intensity * BLENDER_WATTS_PER_INTENSITY), "--spp", "4"],
                          capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0 and (tmp_path / "cycles.exr").is_file(), proc.stderr[-3000:]
    image = read_image(tmp_path / "cycles.exr")[0][:, :, :3]
    assert image.shape == (size, size, 3)

    def ours(model: str) -> np.ndarray:
        radiance = ms.render(maps, torch.tensor([[light]]), torch.tensor([[[0.0, 0.0, cam_z]]]), intensity=intensity,
                             distance_falloff=True, distribution=model)[0, 0]
        return radiance.permute(1, 2, 0).numpy()

    def display(x: np.ndarray) -> np.ndarray:
        return np.clip(x, 0.0, 1.0) ** (1 / 2.2)

    same = ours(distribution)
    diff = np.abs(display(image) - display(same))
    assert diff.mean() < BLENDER_MEAN_TOL, diff.mean()
    assert np.quantile(diff, 0.99) < BLENDER_P99_TOL, np.quantile(diff, 0.99)
    assert np.abs(image - same).mean() < BLENDER_LINEAR_REL_TOL * same.mean()
    other = ours("beckmann" if distribution == "ggx" else "ggx")
    assert np.quantile(np.abs(display(image) - display(other)), 0.99) > BLENDER_P99_TOL  # the model matters
    assert np.abs(display(image[:, ::-1]) - display(same)).mean() > 0.05  # and so does the orientation


# ------------------------------------------------------------------------ Mitsuba
SPP = 1024
SUPERSAMPLE = 8


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
@pytest.mark.usefixtures("cpu_scene_variant")  # conftest: a scene renders under the CPU's variant
def test_mitsuba_export_renders_like_the_texel_path(tmp_path, monkeypatch, distribution):
    size = 16
    maps = random_maps(1, size, size, seed=0, rough_range=(0.2, 1.0), max_tilt=0.6)
    out = tmp_path / "mitsuba"
    summary = E.export_material(maps, out, "mitsuba", normals="directx", distribution=distribution)
    assert (out / "textures/normal_directx.exr").is_file()
    assert summary["distribution"] == distribution
    assert f'type="svbrdf_{distribution}"' in (out / "scene.xml").read_text()
    monkeypatch.chdir(tmp_path)  # textures resolve against the scene's folder, not the working dir
    light = [0.6, -0.3, 1.8]
    scene = mi.load_file(str(out / "scene.xml"), spp=str(SPP), filter_type="nearest",
                         light_x=str(light[0]), light_y=str(light[1]), light_z=str(light[2]))
    image = np.asarray(mi.render(scene, seed=1))[..., :3]
    assert image.shape == (size, size, 3)

    cam_z = float(summary["parameters"]["cam_z"])
    intensity = float(summary["parameters"]["light_intensity"]) / math.pi
    fine = maps.repeat_interleave(SUPERSAMPLE, 2).repeat_interleave(SUPERSAMPLE, 3)
    texel = ms.render(fine, torch.tensor([[light]]), ms.point(torch.tensor([[[0.0, 0.0, cam_z]]])),
                      intensity=intensity, distance_falloff=True, distribution=distribution)[0, 0]
    texel = F.avg_pool2d(texel[None], SUPERSAMPLE)[0].permute(1, 2, 0).numpy()

    rel = np.abs(image - texel) / (np.abs(texel) + 1e-2 * np.abs(texel).max())
    assert rel.mean() < 3e-3
    assert np.quantile(rel, 0.99) < 2e-2
    assert abs(image.mean() - texel.mean()) < 1e-2 * texel.mean()
    assert (np.abs(image[:, ::-1] - texel) / (np.abs(texel) + 1e-2)).mean() > 0.05  # orientation matters


def test_bad_arguments(material_dir, tmp_path):
    with pytest.raises(ValueError, match="normals: expected"):
        E.export_material(material_io.read_material(material_dir), tmp_path, "gltf", normals="dx")
    with pytest.raises(ValueError, match="format: expected"):
        E.export_material(material_io.read_material(material_dir), tmp_path, "fbx")


@pytest.mark.parametrize("model", ["ggx", "beckmann"])
def test_the_commands_pass_a_material_folders_model_on(tmp_path: Path, model: str) -> None:
    """``export`` and ``view`` of a material folder use the model its ``material.json`` records."""
    import json as _json
    import re

    from mi_svbrdf import cli
    from mi_svbrdf.core.maps import constant_maps
    from mi_svbrdf.io.material_io import write_material

    folder = tmp_path / "mat"
    write_material(folder, constant_maps(1, 8, 8), fmt="png", distribution=model)
    assert cli.main(["export", str(folder), "--format", "mitsuba", "-o", str(tmp_path / "scene")]) == 0
    summary = _json.loads((tmp_path / "scene" / "export.json").read_text())
    assert summary["distribution"] == model
    assert f"svbrdf_{model}" in (tmp_path / "scene" / "scene.xml").read_text()
    assert cli.main(["view", str(folder), "-o", str(tmp_path / "view.html")]) == 0
    page = (tmp_path / "view.html").read_text()
    assert re.search(r'"distribution":\s*"' + model + '"', page), "the page's CONFIG names the model"
