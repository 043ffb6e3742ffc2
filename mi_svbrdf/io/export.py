"""Export a material (our four maps) for other tools: glTF 2.0, a Blender script, a Mitsuba scene.

Every exporter writes into one output folder, each file atomically (:mod:`mi_svbrdf.io.atomic`),
``export.json`` last (format, the maps' microfacet ``distribution``, files, notes; for glTF the
measured approximation error):

``gltf`` (:func:`export_gltf`)
    ``material.gltf`` + ``material.bin`` (a 2 x 2 textured square, the [-1, 1]^2 sample plane
    at z = 0 facing +Z, with normals, tangents and texture coordinates) and ``textures/``:
    ``base_color.png`` (sRGB), ``metallic_roughness.png`` (linear; G = roughness, B = metallic
    = 0), ``normal.png`` (linear, (n + 1)/2, OpenGL +Y up as glTF requires) and
    ``specular_color.png`` (sRGB, for ``KHR_materials_specular``). glTF squares its roughness
    like us (alpha = r^2), so the roughness texture is r itself. The parameters are chosen by
    :func:`mi_svbrdf.core.brdf_gltf.from_svbrdf` (baseColor = d (1 - s) / (1 - max_rgb s),
    metallic 0, specularColor = s / 0.04; its docstring lists the approximations); the
    extension is *used*, not *required*: a viewer without it falls back to the plain
    metallic-roughness material (f0 = 0.04, fine for dielectrics, wrong for metals). The
    error of the conversion, re-rendered from the written textures under
    :func:`mi_svbrdf.core.metrics.eval_lights`, is in ``export.json`` (``approximation``).
    glTF has only GGX: a Beckmann material keeps its roughness (equal highlight peak, see
    :func:`mi_svbrdf.core.brdf_gltf.ggx_roughness`), a note says so, and ``approximation``
    adds the error of the equal-width alternative.
``blender`` (:func:`export_blender`)
    ``material_blender.py`` (run ``blender --python material_blender.py``: builds a 2 x 2
    plane with the material) and ``textures/``: ``base_color.png`` (sRGB), ``roughness.png``,
    ``normal.png``, ``specular_f0.png`` (16-bit, max_rgb s) as Non-Color data,
    ``specular_tint.png`` (sRGB, s / max_rgb s). GGX: a Principled BSDF (single-scattering GGX),
    base colour d (1 - s) / (1 - max_rgb s); Blender 4.x: IOR per texel from f0
    (f0 = ((ior - 1)/(ior + 1))^2) and Specular Tint; Blender 3.x: Specular = f0 / 0.08.
    Beckmann (Principled has no Beckmann): a Diffuse BSDF of colour d (1 - s) (the base colour
    texture) plus a Beckmann Metallic BSDF with Schlick's Fresnel of s = f0 * tint (Blender
    4.3+; older: a Beckmann Glossy BSDF of colour s, no Fresnel rise). Cycles renders of both
    match our renderer (figures at :func:`export_blender`).
``mitsuba`` (:func:`export_mitsuba`)
    ``scene.xml`` (our ``svbrdf_ggx`` plugin, ``svbrdf_beckmann`` for a Beckmann material, with
    bitmap textures, a flash capture like the
    bundled ``flash_capture`` scene: camera at (0, 0, 1/tan 25 deg) with fov 50 covering the
    plane, the flash at the camera with intensity pi cam_z^2; parameters overridable in
    ``mi.load_file``) and ``textures/{normal,diffuse,roughness,specular}.exr`` (linear; the
    normal stored as (n + 1)/2, which the plugin decodes).

Normals: ``normals="directx"`` writes the normal map with green flipped (y down) for engines
that want it. glTF and Mitsuba mandate OpenGL normals, so their model keeps referencing the
OpenGL ``normal.*`` and the DirectX map is written beside it (``normal_directx.*``); the Blender
export writes only ``normal_directx.png``, which its script flips back in the node tree.

Examples:
    >>> import tempfile, json, pathlib
    >>> from mi_svbrdf.core import maps as M
    >>> out = pathlib.Path(tempfile.mkdtemp())
    >>> info = export_material(M.constant_maps(1, 8, 8, diffuse=0.5), out, "mitsuba")
    >>> sorted(info["files"])[:2]
    ['scene.xml', 'textures/diffuse.exr']
"""
from __future__ import annotations

import math
import os
import struct
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core import brdf_gltf
from mi_svbrdf.core.maps import SLICES
from mi_svbrdf.plugins.model import DISTRIBUTIONS
from mi_svbrdf.io.atomic import atomic_path, write_json, write_text
from mi_svbrdf.io.image_io import read_image, write_image
from mi_svbrdf.io.material_io import (
    decode_normal,
    encode_normal,
    single_material,
    srgb_decode,
    srgb_encode,
)
from mi_svbrdf.io.viewer import fill_template

#: Export formats.
FORMATS: tuple[str, ...] = ("gltf", "blender", "mitsuba")
#: Normal-map conventions: OpenGL (+Y up, ours and glTF's) or DirectX (green flipped).
NORMAL_CONVENTIONS: tuple[str, ...] = ("opengl", "directx")
#: Name of the summary file every exporter writes last.
SUMMARY_NAME = "export.json"
#: Field of view (degrees, horizontal) of the exported Mitsuba capture camera (as ``flash_capture``).
CAPTURE_FOV = 50.0
#: Camera height at which a ``CAPTURE_FOV`` camera sees exactly the [-1, 1]^2 plane.
CAPTURE_DISTANCE = 1.0 / math.tan(math.radians(CAPTURE_FOV / 2.0))

_GL_FLOAT, _GL_UINT16 = 5126, 5123
_GL_LINEAR, _GL_LINEAR_MIPMAP_LINEAR, _GL_CLAMP = 9729, 9987, 33071


# ---------------------------------------------------------------------------------- shared
def _check(maps: torch.Tensor, out: str | os.PathLike, normals: str,
           distribution: str = "ggx") -> tuple[np.ndarray, Path]:
    if normals not in NORMAL_CONVENTIONS:
        raise ValueError(f"normals: expected one of {NORMAL_CONVENTIONS}, got {normals!r}")
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    data = single_material(maps)  # (H, W, 10), checked
    n = data[:, :, SLICES["normal"]]
    data = data.copy()
    data[:, :, SLICES["normal"]] = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    out = Path(out)
    (out / "textures").mkdir(parents=True, exist_ok=True)
    return data, out


def _normal_image(normal: np.ndarray, convention: str) -> np.ndarray:
    """``(H, W, 3)`` unit normals -> stored ``(n + 1)/2``; DirectX flips green (n_y -> -n_y)."""
    if convention == "directx":
        normal = normal * np.array([1.0, -1.0, 1.0], dtype=np.float32)
    return encode_normal(normal)


def _write_normals(out: Path, normal: np.ndarray, normals: str, suffix: str, bit_depth: int,
                   files: dict[str, str]) -> None:
    """``textures/normal.<suffix>`` (OpenGL) and, for DirectX, ``textures/normal_directx.<suffix>``."""
    write_image(out / f"textures/normal.{suffix}", _normal_image(normal, "opengl"), bit_depth)
    files[f"textures/normal.{suffix}"] = "normal map, (n + 1)/2, OpenGL (+Y up)"
    if normals == "directx":
        write_image(out / f"textures/normal_directx.{suffix}", _normal_image(normal, "directx"), bit_depth)
        files[f"textures/normal_directx.{suffix}"] = "normal map, (n + 1)/2, DirectX (green flipped)"


def _hwc(t: torch.Tensor) -> np.ndarray:
    """``(1, C, H, W)`` tensor -> ``(H, W, C)`` float32 array."""
    return np.ascontiguousarray(t[0].detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def _finish(out: Path, summary: dict[str, Any]) -> dict[str, Any]:
    write_json(out / SUMMARY_NAME, summary)
    return summary


def export_material(maps: torch.Tensor, out: str | os.PathLike, fmt: str, *, normals: str = "opengl",
                    source: str | None = None, distribution: str = "ggx") -> dict[str, Any]:
    """Export ``maps`` as ``fmt`` into the folder ``out`` (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        out: output folder (created).
        fmt: one of :data:`FORMATS`.
        normals: ``"opengl"`` or ``"directx"`` (also write / use a green-flipped normal map).
        source: where the maps came from (recorded in ``export.json``).
        distribution: the maps' microfacet model, ``"ggx"`` or ``"beckmann"`` (a material
            folder's :func:`~mi_svbrdf.io.material_io.read_distribution`).

    Returns:
        The content of ``out/export.json``.
    """
    exporters = {"gltf": export_gltf, "blender": export_blender, "mitsuba": export_mitsuba}
    if fmt not in exporters:
        raise ValueError(f"format: expected one of {FORMATS}, got {fmt!r}")
    return exporters[fmt](maps, out, normals=normals, source=source, distribution=distribution)


# ---------------------------------------------------------------------------------- glTF
def _gltf_geometry() -> tuple[bytes, list[dict], list[dict]]:
    """The square's buffer, buffer views and accessors (POSITION, NORMAL, TANGENT, TEXCOORD_0, indices)."""
    xy = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
    position = [(x, y, 0.0) for x, y in xy]
    normal = [(0.0, 0.0, 1.0)] * 4
    tangent = [(1.0, 0.0, 0.0, 1.0)] * 4  # bitangent = cross(n, t) * w = +Y: OpenGL normal maps
    # glTF's uv origin is the image's top-left corner: u = (x + 1)/2, v = (1 - y)/2 puts
    # image row 0 at y = +1, as our texel convention.
    uv = [((x + 1.0) / 2.0, (1.0 - y) / 2.0) for x, y in xy]
    indices = [0, 1, 2, 0, 2, 3]  # counter-clockwise seen from +Z: front faces towards +Z
    blobs = [struct.pack(f"<{3 * 4}f", *sum(position, ())), struct.pack(f"<{3 * 4}f", *sum(normal, ())),
             struct.pack(f"<{4 * 4}f", *sum(tangent, ())), struct.pack(f"<{2 * 4}f", *sum(uv, ())),
             struct.pack("<6H", *indices)]
    specs = [("VEC3", _GL_FLOAT, 4, 34962), ("VEC3", _GL_FLOAT, 4, 34962), ("VEC4", _GL_FLOAT, 4, 34962),
             ("VEC2", _GL_FLOAT, 4, 34962), ("SCALAR", _GL_UINT16, 6, 34963)]
    buffer, views, accessors = b"", [], []
    for blob, (kind, component, count, target) in zip(blobs, specs):
        views.append({"buffer": 0, "byteOffset": len(buffer), "byteLength": len(blob), "target": target})
        accessors.append({"bufferView": len(views) - 1, "componentType": component, "count": count, "type": kind})
        buffer += blob + b"\0" * (-len(blob) % 4)
    accessors[0]["min"], accessors[0]["max"] = [-1.0, -1.0, 0.0], [1.0, 1.0, 0.0]
    return buffer, views, accessors


def _read_texture(path: Path, channels: slice) -> torch.Tensor:
    image, _ = read_image(path)
    return torch.from_numpy(np.ascontiguousarray(image[:, :, channels])).permute(2, 0, 1)[None]


def _written_gltf_material(out: Path, specular_factor: float) -> brdf_gltf.GltfMaterial:
    """The glTF parameters as a viewer reads them back from the written (8-bit) textures."""
    tex = out / "textures"
    base = torch.from_numpy(srgb_decode(read_image(tex / "base_color.png")[0][:, :, :3])).permute(2, 0, 1)[None]
    mr = _read_texture(tex / "metallic_roughness.png", slice(0, 3))
    normal = torch.from_numpy(decode_normal(read_image(tex / "normal.png")[0][:, :, :3])).permute(2, 0, 1)[None]
    spec = torch.from_numpy(srgb_decode(read_image(tex / "specular_color.png")[0][:, :, :3])).permute(2, 0, 1)[None]
    return brdf_gltf.GltfMaterial(base_color=base, metallic=mr[:, 2:3] * 0.0, roughness=mr[:, 1:2],
                                  normal=normal, specular_color=spec * specular_factor,
                                  specular=torch.ones_like(mr[:, 1:2]))


def export_gltf(maps: torch.Tensor, out: str | os.PathLike, *, normals: str = "opengl",
                source: str | None = None, distribution: str = "ggx") -> dict[str, Any]:
    """Write ``material.gltf`` (+ ``.bin``, ``textures/``) and measure the conversion's error.

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        out: output folder.
        normals: ``"opengl"`` or ``"directx"`` (adds ``textures/normal_directx.png``, unreferenced).
        source: recorded in ``export.json``.
        distribution: the maps' model. glTF's is GGX: a ``"beckmann"`` material keeps its
            roughness (:func:`mi_svbrdf.core.brdf_gltf.ggx_roughness`, rule ``"peak"``: the
            highlight's peak under a flash is exact, the lobe's shape is GGX's), which ``notes``
            says. Its error, measured like the GGX conversion's (display RMSE under
            ``eval_lights()``, 64 x 64 examples): metal_plate 0.204 (0.010 for the same maps as
            GGX), tiles 0.028 (0.002); equal half-maximum widths (r / 0.879) measured higher
            (0.251, 0.037), see :mod:`mi_svbrdf.core.brdf_gltf`.

    Returns:
        ``export.json``'s content; ``approximation`` holds the RMSE of our model's renderings
        against the glTF model's (display-encoded and linear) for the written textures, the
        unquantised ``naive`` mapping (baseColor = d) and the no-extension ``fallback``; for a
        Beckmann material also ``beckmann`` (the roughness rule and the equal-width alternative's RMSE).
    """
    data, out = _check(maps, out, normals, distribution)
    m = torch.from_numpy(data).permute(2, 0, 1)[None].contiguous()
    material = brdf_gltf.from_svbrdf(m, "matched", distribution=distribution)
    s = data[:, :, SLICES["specular"]]
    s_max = float(s.max())
    spec_factor = s_max / brdf_gltf.DIELECTRIC_F0 if s_max > 0.0 else 0.0
    spec_tex = s / s_max if s_max > 0.0 else np.zeros_like(s)
    files: dict[str, str] = {}
    tex = out / "textures"
    write_image(tex / "base_color.png", srgb_encode(_hwc(material.base_color)), 8, srgb=True)
    files["textures/base_color.png"] = "baseColorTexture, sRGB: d (1 - s) / (1 - max_rgb s), clipped"
    r = _hwc(material.roughness)[:, :, 0]
    write_image(tex / "metallic_roughness.png", np.stack([np.zeros_like(r), r, np.zeros_like(r)], -1), 8)
    files["textures/metallic_roughness.png"] = "metallicRoughnessTexture, linear: G = roughness r (alpha = r^2), B = metallic 0"
    _write_normals(out, data[:, :, SLICES["normal"]], normals, "png", 8, files)
    write_image(tex / "specular_color.png", srgb_encode(spec_tex), 8, srgb=True)
    files["textures/specular_color.png"] = "KHR_materials_specular specularColorTexture, sRGB: s / max(s)"

    buffer, views, accessors = _gltf_geometry()
    with atomic_path(out / "material.bin") as tmp:
        tmp.write_bytes(buffer)
    files["material.bin"] = "geometry: the square's positions, normals, tangents, uvs, indices"

    def texture(index: int) -> dict[str, int]:
        return {"index": index, "texCoord": 0}

    images = ["base_color.png", "metallic_roughness.png", "normal.png", "specular_color.png"]
    roughness_note = "alpha = r^2 in glTF as in mi_svbrdf: the roughness texture is r"
    if distribution == "beckmann":
        roughness_note += (" (the maps' Beckmann r, kept for GGX: equal highlight peak, GGX's lobe shape; "
                           "see export.json)")
    gltf = {
        "asset": {"version": "2.0", "generator": "mi_svbrdf export",
                  "extras": {"roughness": roughness_note, "distribution": distribution,
                             "normals": "tangent space, OpenGL (+Y up), stored (n + 1)/2",
                             "source": source or ""}},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "material_sample"}],
        "meshes": [{"name": "material_sample", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3},
            "indices": 4, "material": 0, "mode": 4}]}],
        "materials": [{
            "name": "mi_svbrdf",
            "pbrMetallicRoughness": {"baseColorTexture": texture(0), "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                     "metallicRoughnessTexture": texture(1),
                                     "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "normalTexture": {"index": 2, "texCoord": 0, "scale": 1.0},
            "doubleSided": False,
            "extensions": {"KHR_materials_specular": {
                "specularFactor": 1.0, "specularColorFactor": [spec_factor] * 3,
                "specularColorTexture": texture(3)}},
        }],
        "samplers": [{"magFilter": _GL_LINEAR, "minFilter": _GL_LINEAR_MIPMAP_LINEAR,
                      "wrapS": _GL_CLAMP, "wrapT": _GL_CLAMP}],
        "images": [{"uri": f"textures/{name}", "mimeType": "image/png"} for name in images],
        "textures": [{"sampler": 0, "source": i} for i in range(len(images))],
        "buffers": [{"uri": "material.bin", "byteLength": len(buffer)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    write_json(out / "material.gltf", gltf)
    files["material.gltf"] = "glTF 2.0 model: a 2 x 2 square (the sample plane), KHR_materials_specular"

    written = _written_gltf_material(out, spec_factor)
    exported = brdf_gltf.compare(m, written, distribution=distribution)
    naive = brdf_gltf.compare(m, brdf_gltf.from_svbrdf(m, "naive", distribution=distribution),
                              distribution=distribution)
    fallback = brdf_gltf.compare(m, brdf_gltf.fallback(written), distribution=distribution)
    approximation = {
        "lights": "mi_svbrdf.core.metrics.eval_lights(): 9 point lights with 1/d^2 fall-off, each with its "
                  "own viewer (every third flash-like), intensity d^2",
        "display_encoding": "clip(x, 0, 1)^(1/2.2) (mi_svbrdf.core.metrics.display)",
        "exported": {"rmse_display": exported["rmse_display"], "rmse_linear": exported["rmse_linear"],
                     "rmse_display_per_light": exported["rmse_display_per_light"]},
        "naive_base_color_d": {"rmse_display": naive["rmse_display"], "rmse_linear": naive["rmse_linear"]},
        "fallback_without_extension": {"rmse_display": fallback["rmse_display"],
                                       "rmse_linear": fallback["rmse_linear"]},
        "mean_display_ours": exported["mean_display"],
        "approximations": "glTF: height-correlated Smith visibility, (1 - v.h)^5 Fresnel, diffuse weighted by "
                          "1 - max_rgb(F); ours: separable Smith-Schlick G (k = alpha/2), spherical-Gaussian "
                          "Fresnel, diffuse d (1 - s)/pi; baseColor matches the diffuse at normal incidence; "
                          "8-bit textures",
    }
    summary: dict[str, Any] = {"format": "gltf", "source": source, "normals": normals, "distribution": distribution,
                               "size": [int(data.shape[0]), int(data.shape[1])],
                               "specular_color_factor": spec_factor, "files": files}
    if distribution == "beckmann":
        width = brdf_gltf.compare(m, replace(written, roughness=brdf_gltf.ggx_roughness(written.roughness, "beckmann",
                                                                                         "width")),
                                  distribution=distribution)
        approximation["approximations"] = approximation["approximations"].replace(
            "ours: separable Smith-Schlick G (k = alpha/2)",
            "ours: Beckmann D rendered as GGX D of the same r, separable Smith-Schlick G (k = alpha sqrt(2/pi))")
        approximation["beckmann"] = {
            "roughness": "glTF's GGX roughness = the Beckmann r (rule 'peak' of mi_svbrdf.core.brdf_gltf.ggx_roughness): "
                         "same alpha, same D peak 1/(pi alpha^2), the highlight's peak under a flash exact",
            "equal_width_roughness": {"roughness": "r / 0.879 (equal half-maximum width of D cos^4)",
                                      "rmse_display": width["rmse_display"], "rmse_linear": width["rmse_linear"]}}
        summary["notes"] = [
            f"Beckmann material: glTF has only GGX; the roughness is kept (equal highlight peak), so the lobe has "
            f"GGX's shape: RMSE display {exported['rmse_display']:.4f} against our Beckmann renderings "
            f"(equal-width roughness r / 0.879: {width['rmse_display']:.4f}); see approximation.beckmann"]
    summary["approximation"] = approximation
    return _finish(out, summary)


# ---------------------------------------------------------------------------------- Blender
#: Texture files of the Blender export: ``{key: (file, Blender colour space, what)}``.
BLENDER_TEXTURES: dict[str, tuple[str, str, str]] = {
    "base_color": ("textures/base_color.png", "sRGB", "Base Color: d (1 - s) / (1 - max_rgb s), clipped"),
    "roughness": ("textures/roughness.png", "Non-Color", "Roughness r (Blender also squares it)"),
    "normal": ("textures/normal.png", "Non-Color", "Normal Map (tangent space, OpenGL)"),
    "specular_f0": ("textures/specular_f0.png", "Non-Color", "f0 = max_rgb(s), 16-bit"),
    "specular_tint": ("textures/specular_tint.png", "sRGB", "Specular Tint: s / max_rgb(s)"),
}
#: What the Blender script builds for each microfacet model (``export.json``'s ``shading``).
BLENDER_SHADING: dict[str, str] = {
    "ggx": "Principled BSDF, single-scattering GGX, metallic 0, base colour d (1 - s) / (1 - max_rgb s) (the glTF "
           "export's); Blender 4.x: IOR from f0 and Specular Tint, 3.x: Specular = f0 / 0.08",
    "beckmann": "Blender's Principled BSDF has no Beckmann distribution: Diffuse BSDF (Lambert) of colour d (1 - s) "
                "plus a Metallic BSDF with the Beckmann distribution and the F82-Tint Fresnel with a white edge tint "
                "(Schlick's F of s = f0 * tint), Blender 4.3+; older Blender: a Beckmann Glossy BSDF of colour s "
                "(no Fresnel rise)",
}


def export_blender(maps: torch.Tensor, out: str | os.PathLike, *, normals: str = "opengl",
                   source: str | None = None, distribution: str = "ggx") -> dict[str, Any]:
    """Write ``material_blender.py`` and its textures (see the module docstring).

    The script's material is :data:`BLENDER_SHADING` of ``distribution``. Rendered with Blender
    4.5's Cycles under a point light and compared with :func:`mi_svbrdf.core.render` of the same
    maps, light and camera (64 x 64 examples), the mean |difference| in display values
    ``clip(x, 0, 1)^(1/2.2)`` is 0.0016 (tiles) and 0.0020 (metal_plate) for GGX, 0.0012 and
    0.0015 for Beckmann (Blender shades it with the Beckmann D itself: no roughness conversion);
    with Blender's default Multiscatter GGX instead of GGX, metal_plate's was 0.0047.

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        out: output folder.
        normals: ``"opengl"`` or ``"directx"`` (then ``textures/normal_directx.png`` replaces
            ``normal.png`` and the script flips its green channel back in the node tree).
        source: recorded in ``export.json``.
        distribution: the maps' model, ``"ggx"`` or ``"beckmann"`` (then ``base_color.png`` holds
            d (1 - s), the Diffuse BSDF's colour, and ``notes`` says how Blender shades it).

    Returns:
        ``export.json``'s content.
    """
    data, out = _check(maps, out, normals, distribution)
    m = torch.from_numpy(data).permute(2, 0, 1)[None].contiguous()
    s = data[:, :, SLICES["specular"]]
    f0 = s.max(axis=-1, keepdims=True)
    tint = np.where(f0 > 0.0, s / np.maximum(f0, 1e-12), 1.0).astype(np.float32)
    if distribution == "beckmann":  # the Diffuse BSDF's colour: our diffuse term
        base = np.clip(data[:, :, SLICES["diffuse"]] * (1.0 - np.clip(s, 0.0, 1.0)), 0.0, 1.0)
    else:
        base = _hwc(brdf_gltf.from_svbrdf(m, "matched").base_color)
    files: dict[str, str] = {}
    tex = out / "textures"
    write_image(tex / "base_color.png", srgb_encode(base), 8, srgb=True)
    write_image(tex / "roughness.png", np.clip(data[:, :, SLICES["roughness"]], 0.0, 1.0), 16)
    write_image(tex / "specular_f0.png", f0, 16)
    write_image(tex / "specular_tint.png", srgb_encode(tint), 8, srgb=True)
    textures = {k: (f, space) for k, (f, space, _) in BLENDER_TEXTURES.items()}
    if normals == "directx":  # only the map the script uses
        textures["normal"] = ("textures/normal_directx.png", "Non-Color")
    write_image(out / textures["normal"][0], _normal_image(data[:, :, SLICES["normal"]], normals), 16)
    files[textures["normal"][0]] = f"normal map, (n + 1)/2, {'DirectX (green flipped)' if normals == 'directx' else 'OpenGL (+Y up)'}"
    files.update({f: f"{what} ({space})" for f, space, what in BLENDER_TEXTURES.values() if f != "textures/normal.png"})
    if distribution == "beckmann":
        files["textures/base_color.png"] = "Diffuse BSDF Color: d (1 - s) (sRGB)"
    script_name = "material_blender.py"
    script = fill_template("blender_material.py.in", {
        "SCRIPT_NAME": script_name, "TEXTURES": repr(textures), "NORMALS": repr(normals),
        "EXPORT_DIR": repr(str(out.resolve())), "MATERIAL_NAME": repr("mi_svbrdf_material"),
        "DISTRIBUTION": repr(distribution),
        "DIRECTX_NOTE": "; the DirectX map is flipped back with a Separate/Combine Color" if normals == "directx" else ""})
    write_text(out / script_name, script)
    shader = "Diffuse + Beckmann Metallic BSDF" if distribution == "beckmann" else "Principled BSDF"
    files[script_name] = f"Blender script: blender --python material_blender.py ({shader} on a 2 x 2 plane)"
    summary: dict[str, Any] = {
        "format": "blender", "source": source, "normals": normals, "distribution": distribution,
        "size": [int(data.shape[0]), int(data.shape[1])], "files": files,
        "textures": {k: {"file": f, "colorspace": c} for k, (f, c) in textures.items()},
        "shading": BLENDER_SHADING[distribution]}
    if distribution == "beckmann":
        summary["notes"] = ["Beckmann material: Blender's Principled BSDF has only GGX, so the script builds our two "
                            "terms from a Diffuse BSDF and a Beckmann Metallic BSDF (Blender 4.3+); see shading"]
    return _finish(out, summary)


# ---------------------------------------------------------------------------------- Mitsuba
#: Parameters of the exported scene and their defaults (``mi.load_file(path, name=value)`` overrides).
def mitsuba_parameters(height: int, width: int) -> dict[str, str]:
    """The exported scene's ``$parameters`` with their defaults for a ``height x width`` material."""
    return {"width": str(width), "height": str(height), "spp": "64", "fov": repr(CAPTURE_FOV),
            "cam_z": repr(CAPTURE_DISTANCE), "light_x": "0", "light_y": "0",
            "light_z": repr(CAPTURE_DISTANCE), "light_intensity": repr(math.pi * CAPTURE_DISTANCE ** 2),
            "filter_type": "bilinear"}


def _sub(parent: ET.Element, tag: str, **attrib: str) -> ET.Element:
    return ET.SubElement(parent, tag, attrib)


def _mitsuba_xml(params: dict[str, str], textures: dict[str, str], plugin: str = "svbrdf_ggx") -> str:
    root = ET.Element("scene", {"version": "3.0.0"})
    for k, v in params.items():
        _sub(root, "default", name=k, value=v)
    integ = _sub(root, "integrator", type="direct")
    _sub(integ, "integer", name="emitter_samples", value="1")
    _sub(integ, "integer", name="bsdf_samples", value="0")
    sensor = _sub(root, "sensor", type="perspective", id="camera")
    _sub(sensor, "float", name="fov", value="$fov")
    _sub(sensor, "string", name="fov_axis", value="x")
    _sub(_sub(sensor, "transform", name="to_world"), "lookat", origin="0, 0, $cam_z", target="0, 0, 0", up="0, 1, 0")
    _sub(_sub(sensor, "sampler", type="independent"), "integer", name="sample_count", value="$spp")
    film = _sub(sensor, "film", type="hdrfilm")
    _sub(film, "integer", name="width", value="$width")
    _sub(film, "integer", name="height", value="$height")
    _sub(film, "string", name="pixel_format", value="rgb")
    _sub(film, "rfilter", type="box")
    light = _sub(root, "emitter", type="point", id="flash")
    _sub(light, "point", name="position", x="$light_x", y="$light_y", z="$light_z")
    _sub(light, "rgb", name="intensity", value="$light_intensity")
    bsdf = _sub(root, "bsdf", type=plugin, id="material")
    for name, file in textures.items():
        t = _sub(bsdf, "texture", name=name, type="bitmap")
        _sub(t, "string", name="filename", value=file)
        _sub(t, "boolean", name="raw", value="true")
        _sub(t, "string", name="filter_type", value="$filter_type")
        _sub(t, "string", name="wrap_mode", value="clamp")
        to_uv = _sub(t, "transform", name="to_uv")  # v -> 1 - v: image row 0 at y = +1
        _sub(to_uv, "scale", x="1", y="-1")
        _sub(to_uv, "translate", x="0", y="1")
    _sub(_sub(root, "shape", type="rectangle", id="plane"), "ref", id="material")
    ET.indent(root, space="    ")
    doc = ("<!--\n    Written by `mi-svbrdf export --format mitsuba`: the material on the [-1, 1]^2 plane under a\n"
           f"    flash capture (as the bundled flash_capture scene). Needs the {plugin} plugin: `import mi_svbrdf`\n"
           "    first (it registers it). Textures are linear EXR read raw; normal stores (n + 1)/2 of the\n"
           "    OpenGL normal. Pixel (i, j) of a width = height = N render sees texel (i, j) of an N x N map;\n"
           "    the light intensity pi cam_z^2 is the texel renderer's I = cam_z^2 (white Lambertian\n"
           "    texel at the centre: radiance 1). Parameters: " + ", ".join(params) + "\n"
           "    (mi.load_file(path, spp='256', light_x='0.3', filter_type='nearest', ...)).\n-->\n")
    return doc + ET.tostring(root, encoding="unicode") + "\n"


def export_mitsuba(maps: torch.Tensor, out: str | os.PathLike, *, normals: str = "opengl",
                   source: str | None = None, distribution: str = "ggx") -> dict[str, Any]:
    """Write ``scene.xml`` and its EXR textures (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        out: output folder.
        normals: ``"opengl"`` or ``"directx"`` (adds ``textures/normal_directx.exr``, unreferenced:
            the plugin decodes OpenGL normals).
        source: recorded in ``export.json``.
        distribution: the maps' model: ``"ggx"`` (plugin ``svbrdf_ggx``) or ``"beckmann"``
            (``svbrdf_beckmann``; the same model as ours, exactly).

    Returns:
        ``export.json``'s content (``parameters``: the scene's parameters and defaults).
    """
    data, out = _check(maps, out, normals, distribution)
    plugin = f"svbrdf_{distribution}"
    files: dict[str, str] = {}
    tex = out / "textures"
    _write_normals(out, data[:, :, SLICES["normal"]], normals, "exr", 32, files)
    for name in ("diffuse", "roughness", "specular"):
        write_image(tex / f"{name}.exr", np.clip(data[:, :, SLICES[name]], 0.0, 1.0), 32)
        files[f"textures/{name}.exr"] = f"{name}, linear"
    params = mitsuba_parameters(int(data.shape[0]), int(data.shape[1]))
    textures = {name: f"textures/{name}.exr" for name in ("normal", "diffuse", "roughness", "specular")}
    write_text(out / "scene.xml", _mitsuba_xml(params, textures, plugin))
    files["scene.xml"] = f"Mitsuba 3 scene ({plugin}, flash capture); import mi_svbrdf before mi.load_file"
    return _finish(out, {"format": "mitsuba", "source": source, "normals": normals, "distribution": distribution,
                         "size": [int(data.shape[0]), int(data.shape[1])], "files": files,
                         "parameters": params})
