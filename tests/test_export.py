"""Exports (``mi-svbrdf export``): the glTF BRDF, glTF validity, the Blender script, the Mitsuba scene.

The Blender script cannot be run here (no Blender): it is compiled, executed against a stand-in
``bpy`` (a ``MagicMock`` recording the images it loads and the colour spaces it sets), and its
texture table is checked against the files on disk.
"""
from __future__ import annotations

import ast
import json
import math
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
from mi_svbrdf.io import export as E
from mi_svbrdf.io import material_io
from mi_svbrdf.io.image_io import read_image
from tests.conftest import random_maps


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
    example = ms.data.examples.example_material("metal_plate", size=64)
    matched = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, "matched"))["rmse_display"]
    naive = brdf_gltf.compare(example, brdf_gltf.from_svbrdf(example, "naive"))["rmse_display"]
    assert matched < naive and matched < 0.02


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


# ------------------------------------------------------------------------ Blender
def _run_blender_script(path, blender4: bool) -> dict[str, str]:
    """Execute the script against a stand-in ``bpy``; return ``{loaded image path: colour space}``."""
    bpy = mock.MagicMock()
    loaded = []

    def load(filepath, check_existing=False):
        image = mock.MagicMock()
        loaded.append((filepath, image))
        return image

    def new_node(kind):
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
    return {p: im.colorspace_settings.name for p, im in loaded}


@pytest.mark.parametrize("normals", ["opengl", "directx"])
def test_blender_script(material_dir, tmp_path, normals):
    out = tmp_path / "blender"
    summary = E.export_material(material_io.read_material(material_dir), out, "blender", normals=normals)
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
    for blender4 in (True, False):
        loaded = _run_blender_script(script, blender4)
        assert {(out / f).resolve(): s for f, s in table.values()} == \
            {Path(p).resolve(): s for p, s in loaded.items()}


# ------------------------------------------------------------------------ Mitsuba
SPP = 1024
SUPERSAMPLE = 8


def test_mitsuba_export_renders_like_the_texel_path(tmp_path, monkeypatch):
    size = 16
    maps = random_maps(1, size, size, seed=0, rough_range=(0.2, 1.0), max_tilt=0.6)
    out = tmp_path / "mitsuba"
    summary = E.export_material(maps, out, "mitsuba", normals="directx")
    assert (out / "textures/normal_directx.exr").is_file()
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
                      intensity=intensity, distance_falloff=True)[0, 0]
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
