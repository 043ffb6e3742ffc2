"""Failure cases (thesis ch. 3.3.3, 4.4.4, 5.2.3): procedural captures that probe where methods break.

Every case is one material photographed N times with the ``"multiview"`` capture preset
(:mod:`mi_svbrdf.data.photo_setups`; image 0 the fronto-parallel flash photo, so a single-image net
uses it) and the same photo pipeline (noise, clip, gamma 1/2.2, 8 bits). Each
:class:`Case` carries ``clean``: the same material (or its representable description) and
the same captures without the perturbation, so a report can chart how far a method degrades.

==============================  ==================================================================
``saturated_highlight``         a (calibrated) flash 8x the preset's intensity: the highlight clips
                                (clean: the preset's intensity)
``dark_material``               diffuse albedo scaled to max 0.05 (clean: the original albedo)
``near_mirror``                 roughness remapped to [0.02, 0.05] (clean: the original roughness)
``clear_coat_print``            a printed diffuse pattern independent of the relief under a glossy
                                clear coat (clean: the print replaced by its mean colour)
``anisotropic_brushed_metal``   brushed metal rendered through Mitsuba with ``svbrdf_aniso``,
                                ``r_u = 1.8 r``, ``r_v = r / 1.8`` (``r`` the metal's roughness);
                                ``maps`` hold ``r = sqrt(r_u r_v)``, the isotropic maps the case is
                                derived from (clean: those maps, ``r_u = r_v = r``, same renderer)
``cast_shadows``                studs of a height field rendered as real geometry (a Mitsuba mesh)
                                under the flash: cast shadows and parallax; ``maps`` hold the height
                                field's normals at texel centres (clean: those maps on the flat plane)
``non_uniform_ambient``         a rectangular area light beside the sample, unknown to the methods:
                                light that varies across the sample (clean: without it)
``jpeg``                        the 8-bit photos JPEG-compressed at quality 50 by Pillow
``noisy``                       sensor noise of std 0.05 before the photo pipeline (preset ~0.005)
``wrong_gamma``                 the sRGB-encoded photo values passed as if linear
==============================  ==================================================================

Texel-path cases render with :func:`mi_svbrdf.data.photo_setups.render_captures`. The three Mitsuba cases
use :func:`mitsuba_radiance`: a rectified camera identical to the texel path (one ray per texel,
from the camera position through the texel centre on z = 0, so a flat plane gives the texel
renderer's values), Mitsuba's ray intersection (real geometry), the plugin's ``eval``, shadow
rays to the flash and the ambient lights, and ``spp`` emitter samples of scene emitters.
"""
from __future__ import annotations

import dataclasses
import io
import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
import torch
from PIL import Image

from mi_svbrdf import plugins, scenes
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import gamma_decode, gamma_encode
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import Captures, photograph, render_captures, sample_captures
from mi_svbrdf.variant import scene_variant

#: Capture preset of every case.
PRESET = "multiview"
#: Samples per texel of scene emitters (the area light of ``non_uniform_ambient``).
SPP = 8


@dataclass
class Case:
    """One failure case: ground-truth maps, its photos and their calibration."""

    name: str  #: a key of :data:`CASES`
    description: str  #: what it probes
    maps: torch.Tensor  #: (1, 10, H, W) ground truth (our model's best description; see the module docstring)
    inputs: torch.Tensor  #: (1, N, 3, H, W) linear photos after the photo pipeline (what methods receive)
    captures: Captures  #: their exact calibration (B = 1)
    clean: Case | None = None  #: the same material and captures without the perturbation


# ----------------------------------------------------------------------------- Mitsuba path
def _bitmap(array: torch.Tensor) -> dict:
    """A raw nearest-lookup bitmap texture of a ``(C, H, W)`` map, row 0 at y = +1."""
    data = np.ascontiguousarray(array.detach().float().permute(1, 2, 0).numpy())
    return {"type": "bitmap", "bitmap": mi.Bitmap(data), "raw": True, "filter_type": "nearest",
            "wrap_mode": "clamp", "to_uv": scenes.flip_v()}


def aniso_bsdf(maps: torch.Tensor, roughness_u: torch.Tensor, roughness_v: torch.Tensor) -> dict:
    """An ``svbrdf_aniso`` dict of ``maps`` (1, 10, H, W) with roughness maps ``(1, 1, H, W)`` each."""
    plugins.register()
    bsdf = scenes.material_bsdf(maps, filter_type="nearest")
    del bsdf["roughness"]
    bsdf.update(type="svbrdf_aniso", roughness_u=_bitmap(roughness_u[0]), roughness_v=_bitmap(roughness_v[0]))
    return bsdf


def heightfield_mesh(height: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], size: int, bsdf: dict) -> mi.Mesh:
    """A mesh of ``z = height(x, y)`` over [-1, 1]^2, vertices on a ``(size + 1)^2`` grid, uv as the rectangle's.

    Made under the CPU's variant (:func:`~mi_svbrdf.variant.scene_variant`): Mitsuba's objects are bound to the
    variant active when they are made, so use the mesh under it too (:func:`mitsuba_radiance` enters it).
    """
    with scene_variant("cpu"):
        return _heightfield_mesh(height, size, bsdf)


def _heightfield_mesh(height: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], size: int, bsdf: dict) -> mi.Mesh:
    lin = torch.linspace(-1.0, 1.0, size + 1)
    y, x = torch.meshgrid(-lin, lin, indexing="ij")
    x, y = x.requires_grad_(), y.requires_grad_()
    z = height(x, y)
    gx, gy = torch.autograd.grad(z.sum(), (x, y))
    normal = torch.stack([-gx, -gy, torch.ones_like(gx)], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    pos = torch.stack([x, y, z], -1).detach().reshape(-1, 3)
    uv = torch.stack([(x + 1) / 2, (y + 1) / 2], -1).detach().reshape(-1, 2)
    idx = torch.arange((size + 1) ** 2).view(size + 1, size + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = torch.cat([torch.stack([a, c, b], -1).reshape(-1, 3), torch.stack([b, c, d], -1).reshape(-1, 3)])
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh("heightfield", pos.shape[0], faces.shape[0], props=props, has_vertex_normals=True,
                   has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(pos.numpy().ravel())
    params["faces"] = mi.UInt32(faces.numpy().astype(np.uint32).ravel())
    params["vertex_texcoords"] = mi.Float(uv.numpy().ravel())
    params["vertex_normals"] = mi.Float(normal.detach().reshape(-1).numpy())
    params.update()
    return mesh


def mitsuba_radiance(shape: dict | mi.Mesh, captures: Captures, size: int, *, emitters: Sequence[dict] = (),
                     spp: int = SPP, seed: int = 0) -> torch.Tensor:
    """Linear radiance ``(1, N, 3, size, size)`` of a Mitsuba shape under ``captures`` (rectified, see module doc).

    Args:
        shape: a shape dict with its BSDF (e.g. a ``rectangle``) or a loaded mesh.
        captures: B = 1 captures; the flash (point, ``pi I / d^2``, cone) and the ambient lights
            (``pi I``, no fall-off) are evaluated with shadow rays.
        size: texels per side.
        emitters: extra Mitsuba emitter dicts, sampled ``spp`` times per texel.
        spp: emitter samples per texel (only used with ``emitters``).
        seed: seed of those samples.

    Renders under the CPU's variant (:func:`~mi_svbrdf.variant.scene_variant`; a loaded ``shape`` must be of it).
    """
    with scene_variant("cpu"):
        return _mitsuba_radiance(shape, captures, size, emitters=emitters, spp=spp, seed=seed)


def _mitsuba_radiance(shape: dict | mi.Mesh, captures: Captures, size: int, *, emitters: Sequence[dict],
                      spp: int, seed: int) -> torch.Tensor:
    scene = mi.load_dict({"type": "scene", "shape": shape, **{f"emitter_{k}": e for k, e in enumerate(emitters)}})
    if captures.batch_size != 1:
        raise ValueError(f"captures: expected B = 1, got {captures.batch_size}")
    centres = -1.0 + (2.0 * np.arange(size) + 1.0) / size
    px = np.tile(centres, size)
    py = np.repeat(-centres, size)
    ctx = mi.BSDFContext()
    out = []
    for k in range(captures.n_images):
        cam = captures.view[0, k].tolist()
        target = mi.Point3f(mi.Float(px), mi.Float(py), mi.Float(np.zeros_like(px)))
        origin = dr.opaque(mi.Point3f, cam)  # opaque: one kernel for every image, not one per constant
        ray = mi.Ray3f(origin, dr.normalize(target - origin))
        si = scene.ray_intersect(ray)
        bsdf, valid = si.bsdf(), si.is_valid()
        total = mi.Color3f(0.0)

        def point_light(position: list[float], intensity: list[float], falloff: bool,
                        cone: tuple[list[float], float] | None = None) -> mi.Color3f:
            position, intensity = dr.opaque(mi.Point3f, position), dr.opaque(mi.Color3f, intensity)
            to_light = position - si.p
            dist2 = dr.squared_norm(to_light)
            wl = dr.normalize(to_light)
            value = bsdf.eval(ctx, si, si.to_local(wl), valid)
            visible = ~scene.ray_test(si.spawn_ray_to(position), valid)
            scale = mi.Float(math.pi) * (dr.rcp(dist2) if falloff else 1.0)
            if cone is not None:
                axis = dr.normalize(position - dr.opaque(mi.Point3f, cone[0]))
                scale = scale * dr.power(dr.maximum(dr.dot(wl, axis), 0.0), dr.opaque(mi.Float, cone[1]))
            return dr.select(valid & visible, value * intensity * scale, 0.0)

        if captures.flash:
            cone = (captures.cone_target[0, k].tolist(), float(captures.cone_exponent[0, k])) if captures.cone else None
            total += point_light(captures.light[0, k].tolist(), captures.intensity[0, k].tolist(), True, cone)
        for a in range(captures.ambient_light.shape[1]):
            total += point_light(captures.ambient_light[0, a].tolist(), captures.ambient_intensity[0, a].tolist(),
                                 False)
        if emitters:
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(seed * 1000 + k, size * size)
            extra = mi.Color3f(0.0)
            for _ in range(spp):
                ds, weight = scene.sample_emitter_direction(si, sampler.next_2d(), True, valid)
                extra += dr.select(valid, bsdf.eval(ctx, si, si.to_local(ds.d), valid) * weight, 0.0)
                dr.eval(extra)  # one small kernel per sample rather than one huge one
            total += extra / spp
        rgb = np.asarray(total, dtype=np.float32).reshape(3, size, size)  # Color3f -> (3, texels)
        out.append(torch.from_numpy(np.ascontiguousarray(rgb)))
    return torch.stack(out)[None]


def plane(bsdf: dict) -> dict:
    """The default [-1, 1]^2 rectangle with ``bsdf``."""
    return {"type": "rectangle", "bsdf": bsdf}


# ----------------------------------------------------------------------------- helpers
def _generator(name: str, seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(zlib.crc32(name.encode()) + 7919 * seed)


def _material(kind: str, seed: int, size: int, **params: float) -> torch.Tensor:
    return procedural.generate(kind, seed=seed, size=size, **params)[None]


def _photos(name: str, maps: torch.Tensor, captures: Captures, seed: int) -> torch.Tensor:
    """Texel-path photos, noise drawn from the case's own generator (the same for case and clean)."""
    return photograph(render_captures(maps, captures, backend="torch"), captures, _generator(name + "/photo", seed))


def _pair(name: str, description: str, maps: torch.Tensor, captures: Captures, seed: int, *,
          clean_maps: torch.Tensor | None = None, clean_captures: Captures | None = None) -> Case:
    """Case and clean case rendered on the texel path (maps or captures differ)."""
    clean_maps = maps if clean_maps is None else clean_maps
    clean_captures = captures if clean_captures is None else clean_captures
    clean = Case(name, f"{name} without the perturbation", clean_maps, _photos(name, clean_maps, clean_captures, seed),
                 clean_captures)
    return Case(name, description, maps, _photos(name, maps, captures, seed), captures, clean)


def _with_maps(maps: torch.Tensor, **parts: torch.Tensor) -> torch.Tensor:
    out = maps.clone()
    for key, value in parts.items():
        out[:, M.SLICES[key]] = value
    return out


# ----------------------------------------------------------------------------- the cases
def _saturated_highlight(size: int, n: int, seed: int, cap: Captures) -> Case:
    maps = _material("plastic", seed, size, roughness=0.15)
    strong = dataclasses.replace(cap, intensity=cap.intensity * 8.0)
    return _pair("saturated_highlight", "flash 8x the preset's (calibrated): the highlight clips",
                 maps, strong, seed, clean_captures=cap)


def _dark_material(size: int, n: int, seed: int, cap: Captures) -> Case:
    clean = _material("leather", seed, size, value=0.8)  # a light leather; the case darkens it
    d = M.diffuse(clean)
    dark = _with_maps(clean, diffuse=d * (0.05 / d.amax().clamp_min(1e-6)), specular=M.specular(clean).clamp_max(0.05))
    return _pair("dark_material", "diffuse albedo <= 0.05: little signal above the noise", dark, cap, seed,
                 clean_maps=clean)


def _near_mirror(size: int, n: int, seed: int, cap: Captures) -> Case:
    clean = _material("plastic", seed, size)
    r = M.roughness(clean)
    r = 0.02 + 0.03 * (r - r.amin()) / (r.amax() - r.amin()).clamp_min(1e-6)
    return _pair("near_mirror", "roughness in [0.02, 0.05]: a highlight a few texels wide",
                 _with_maps(clean, roughness=r),
                 cap, seed, clean_maps=clean)


def _clear_coat_print(size: int, n: int, seed: int, cap: Captures) -> Case:
    relief = _material("leather", seed, size)
    print_ = M.diffuse(_material("paint", seed + 1, size))
    coat = torch.tensor([0.05, 0.07, 0.06]).view(1, 3, 1, 1).expand(1, 3, size, size)
    maps = _with_maps(relief, diffuse=print_, roughness=torch.full((1, 1, size, size), 0.15), specular=coat)
    flat = _with_maps(maps, diffuse=print_.mean(dim=(2, 3), keepdim=True).expand_as(print_))
    return _pair("clear_coat_print", "a printed pattern independent of the relief under a coloured clear coat",
                 maps, cap, seed, clean_maps=flat)


def _mitsuba_pair(name: str, description: str, shape: dict | mi.Mesh, clean_shape: dict | mi.Mesh, maps: torch.Tensor,
                  cap: Captures, size: int, seed: int, emitters: Sequence[dict] = (),
                  clean_emitters: Sequence[dict] = ()) -> Case:
    """Case and clean case rendered by :func:`mitsuba_radiance` (the same noise draw for both)."""
    photo_gen = _generator(name + "/photo", seed)
    clean_gen = _generator(name + "/photo", seed)
    rad = mitsuba_radiance(shape, cap, size, emitters=list(emitters), seed=seed)
    rad_clean = mitsuba_radiance(clean_shape, cap, size, emitters=list(clean_emitters), seed=seed)
    clean = Case(name, f"{name} without the perturbation", maps, photograph(rad_clean, cap, clean_gen), cap)
    return Case(name, description, maps, photograph(rad, cap, photo_gen), cap, clean)


def _anisotropic_brushed_metal(size: int, n: int, seed: int, cap: Captures) -> Case:
    maps = _material("metal", seed, size, brushed=1.0, angle=0.0)
    r = M.roughness(maps).clamp(0.1, 0.55)
    maps = _with_maps(maps, roughness=r)
    aniso = plane(aniso_bsdf(maps, (1.8 * r).clamp_max(1.0), r / 1.8))
    iso = plane(aniso_bsdf(maps, r, r))
    return _mitsuba_pair("anisotropic_brushed_metal", "anisotropic GGX (r_u = 1.8 r, r_v = r / 1.8): not our model",
                         aniso, iso, maps, cap, size, seed)


def studs(x: torch.Tensor, y: torch.Tensor, cells: int = 4, radius: float = 0.16, height: float = 0.12) -> torch.Tensor:
    """Rounded studs on a ``cells`` x ``cells`` grid over [-1, 1]^2 (steep sides: cast shadows)."""
    pitch = 2.0 / cells
    dx = torch.remainder(x + 1.0, pitch) - pitch / 2
    dy = torch.remainder(y + 1.0, pitch) - pitch / 2
    r = (dx * dx + dy * dy + 1e-8).sqrt()
    return height * torch.sigmoid((radius - r) * 40.0)


def _cast_shadows(size: int, n: int, seed: int, cap: Captures) -> Case:
    base = _material("plastic", seed, size, relief=0.0)
    centres = -1.0 + (2.0 * torch.arange(size) + 1.0) / size
    y, x = torch.meshgrid(-centres, centres, indexing="ij")
    x, y = x.requires_grad_(), y.requires_grad_()
    gx, gy = torch.autograd.grad(studs(x, y).sum(), (x, y))
    normal = torch.stack([-gx, -gy, torch.ones_like(gx)])[None]
    maps = _with_maps(base, normal=normal / normal.norm(dim=1, keepdim=True))
    flat_normals = _with_maps(maps, normal=torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, size, size))
    mesh = heightfield_mesh(studs, size, scenes.material_bsdf(flat_normals, filter_type="nearest"))
    flat = plane(scenes.material_bsdf(maps, filter_type="nearest"))
    return _mitsuba_pair("cast_shadows", "studs of height 0.12 as real geometry: cast shadows, parallax",
                         mesh, flat, maps, cap, size, seed)


def _non_uniform_ambient(size: int, n: int, seed: int, cap: Captures) -> Case:
    maps = _material("stone", seed, size)
    shape = plane(scenes.material_bsdf(maps, filter_type="nearest"))
    lamp = {"type": "rectangle",
            "to_world": mi.ScalarTransform4f().look_at(origin=[-1.7, 0.0, 0.7], target=[0.0, 0.0, 0.0], up=[0, 0, 1])
            @ mi.ScalarTransform4f().scale([0.5, 1.0, 1.0]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [9.0, 8.0, 6.5]}}}
    return _mitsuba_pair("non_uniform_ambient", "a warm area light beside the sample: light varying across it",
                         shape, shape, maps, cap, size, seed, emitters=[lamp])


def _jpeg(size: int, n: int, seed: int, cap: Captures) -> Case:
    clean = _pair("jpeg", "", _material("wood", seed, size), cap, seed).clean
    out = []
    for photo in clean.inputs[0]:
        enc = (gamma_encode(photo) * 255.0).round().to(torch.uint8).permute(1, 2, 0).numpy()
        buf = io.BytesIO()
        Image.fromarray(enc).save(buf, format="JPEG", quality=50)
        dec = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"), dtype=np.float32) / 255.0
        out.append(gamma_decode(torch.from_numpy(dec).permute(2, 0, 1)))
    return Case("jpeg", "photos JPEG-compressed at quality 50 (Pillow)", clean.maps, torch.stack(out)[None], cap, clean)


def _noisy(size: int, n: int, seed: int, cap: Captures) -> Case:
    loud = dataclasses.replace(cap, noise_std=torch.full_like(cap.noise_std, 0.05))
    return _pair("noisy", "sensor noise of std 0.05 (the preset's ~0.005)", _material("tiles", seed, size), loud, seed,
                 clean_captures=cap)


def _wrong_gamma(size: int, n: int, seed: int, cap: Captures) -> Case:
    clean = _pair("wrong_gamma", "", _material("fabric", seed, size), cap, seed).clean
    return Case("wrong_gamma", "sRGB-encoded photo values declared linear", clean.maps,
                gamma_encode(clean.inputs), cap, clean)


#: Case generators by name: ``f(size, n_images, seed, captures) -> Case``.
CASES: dict[str, Callable[..., Case]] = {
    "saturated_highlight": _saturated_highlight,
    "dark_material": _dark_material,
    "near_mirror": _near_mirror,
    "clear_coat_print": _clear_coat_print,
    "anisotropic_brushed_metal": _anisotropic_brushed_metal,
    "cast_shadows": _cast_shadows,
    "non_uniform_ambient": _non_uniform_ambient,
    "jpeg": _jpeg,
    "noisy": _noisy,
    "wrong_gamma": _wrong_gamma,
}


def make_case(name: str, size: int = 256, n_images: int = 5, seed: int = 0) -> Case:
    """Generate failure case ``name`` (a key of :data:`CASES`) with its ``clean`` twin.

    Args:
        name: the case.
        size: texels per side (>= 8).
        n_images: N photos (image 0 fronto-parallel).
        seed: material, capture and noise seed.

    Returns:
        :class:`Case` with ``maps (1, 10, size, size)``, ``inputs (1, N, 3, size, size)`` in [0, 1].
    """
    if name not in CASES:
        raise ValueError(f"name: expected one of {sorted(CASES)}, got {name!r}")
    if not (isinstance(size, int) and size >= 8):
        raise ValueError(f"size: expected an int >= 8, got {size!r}")
    if not (isinstance(n_images, int) and n_images >= 1):
        raise ValueError(f"n_images: expected an int >= 1, got {n_images!r}")
    captures = sample_captures(1, n_images, PRESET, _generator(name + "/captures", seed))
    with scene_variant("cpu"):  # the cases' Mitsuba scenes are bound to a variant; their outputs are CPU tensors
        return CASES[name](size, n_images, seed, captures)


def clean_case(name: str, size: int = 256, n_images: int = 5, seed: int = 0) -> Case:
    """The unperturbed twin of :func:`make_case` ``(name, ...)`` (its ``clean``; its own ``clean`` is None)."""
    case = make_case(name, size, n_images, seed)
    assert case.clean is not None
    return case.clean
