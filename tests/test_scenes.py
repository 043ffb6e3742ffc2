"""Tests of the bundled XML scenes and the scene helpers (``mi_svbrdf.scenes``, the repository's scenes/)."""
from __future__ import annotations

import importlib.util
import math
import re

import mitsuba as mi
import numpy as np
import pytest
import torch

import mi_svbrdf  # noqa: F401  (selects a variant and registers the plugins)
from mi_svbrdf import scenes as S
from mi_svbrdf.core import maps as M

#: Mitsuba objects made in these tests are bound to the active variant: the CPU's (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("cpu_scene_variant")

EXPECTED_SCENES = {"flash_capture", "multiview_capture", "ambient_capture", "relight"}


def _render(scene: mi.Scene, spp: int | None = None, seed: int = 0) -> np.ndarray:
    return np.array(mi.render(scene, spp=spp or 0, seed=seed), dtype=np.float64)


def _write_exr(path, array: np.ndarray) -> str:
    mi.Bitmap(np.array(array, dtype=np.float32, order="C", copy=True)).write(str(path))
    return str(path)


def _constant_textures(tmp_path, size: int, *, normal=(0.0, 0.0, 1.0), diffuse=(1.0, 1.0, 1.0),
                       roughness=1.0, specular=(0.0, 0.0, 0.0)) -> dict[str, str]:
    n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    arrays = {"normal": (n + 1) / 2, "diffuse": diffuse, "roughness": [roughness], "specular": specular}
    return {k: _write_exr(tmp_path / f"{k}.exr", np.broadcast_to(np.asarray(v, np.float32), (size, size, len(v))))
            for k, v in arrays.items()}


# --------------------------------------------------------------------------- bundled scenes
def test_scene_names_and_paths():
    names = S.scene_names()
    assert EXPECTED_SCENES <= set(names)
    for name in names:
        path = S.scene_path(name)
        assert path.is_file() and path.suffix == ".xml"
        assert S.scene_path(name + ".xml") == path
    with pytest.raises(ValueError, match="flash_capture"):
        S.scene_path("no_such_scene")


@pytest.mark.parametrize("name", S.scene_names())
def test_scene_loads_and_renders(name):
    scene = S.load_scene(name, res=24, spp=4)
    img = _render(scene)
    assert img.shape == (24, 24, 3)
    assert np.all(np.isfinite(img))
    assert img.mean() > 0.05
    assert (img > 0).mean() > 0.9


@pytest.mark.parametrize("name", S.scene_names())
def test_parameters_are_documented(name):
    """Every ``<default>`` is listed (with its default) in the comment block at the top."""
    text = S.scene_path(name).read_text()
    header = text[:text.index("-->")]
    assert text.lstrip().startswith("<!--")
    params = S.scene_parameters(name)
    assert {"res", "spp", "distribution", "normal", "diffuse", "roughness", "specular"} <= set(params)
    for key, value in params.items():
        assert re.search(rf"^\s+{re.escape(key)}: {re.escape(value)}\b", header, re.M), (name, key)
    # Every $reference in the body has a default.
    body = text[text.index("-->"):]
    assert set(re.findall(r"\$([a-z_]+)", body)) <= set(params)


def test_load_file_directly_with_params():
    """The installed XML loads with plain ``mi.load_file(path, **params)``."""
    scene = mi.load_file(str(S.scene_path("multiview_capture")), res="8", spp="1", cam_x="0.5")
    assert tuple(scene.sensors()[0].film().size()) == (8, 8)


def test_unknown_parameter_lists_valid_ones():
    with pytest.raises(ValueError) as info:
        S.load_scene("flash_capture", res=8, lihgt_x=0.3)
    msg = str(info.value)
    assert "lihgt_x" in msg and "light_x=0" in msg and "fov=50" in msg and "res=256" in msg


def test_parameter_types_are_converted(tmp_path):
    files = _constant_textures(tmp_path, 4)
    import pathlib

    scene = S.load_scene("relight", res=8, spp=1, hide_emitters=True, env_scale=0.5,
                         diffuse=pathlib.Path(files["diffuse"]))
    img = _render(scene)
    assert np.isfinite(img).all()
    with pytest.raises(TypeError, match="res"):
        S.load_scene("relight", res=[8, 8])


def test_capture_geometry_defaults():
    """flash_capture: 50 deg at 1/tan(25 deg) and light intensity pi z^2 (centre radiance = albedo)."""
    p = S.scene_parameters("flash_capture")
    z = 1.0 / math.tan(math.radians(25.0))
    assert float(p["fov"]) == 50.0 and S.CAPTURE_FOV == 50.0
    assert float(p["cam_z"]) == pytest.approx(z, abs=1e-6) == S.CAPTURE_DISTANCE
    assert float(p["light_z"]) == float(p["cam_z"])
    assert float(p["light_x"]) == 0.0 and float(p["light_y"]) == 0.0
    assert float(p["light_intensity"]) == pytest.approx(math.pi * z * z, rel=1e-5)
    mv = S.scene_parameters("multiview_capture")
    for key in ("fov", "cam_z", "light_z", "light_intensity"):
        assert mv[key] == p[key]


def test_flash_capture_radiometry_and_orientation(tmp_path):
    """White Lambertian: the centre pixel has radiance 1; a row/column-coded map lands upright."""
    res = 15
    files = _constant_textures(tmp_path, res)
    img = _render(S.load_scene("flash_capture", res=res, spp=64, **files))
    assert img[res // 2, res // 2] == pytest.approx([1.0] * 3, rel=0.01)
    # Brightest at the centre (light at the camera), symmetric up to pixel-jitter noise.
    assert img[..., 0].argmax() == (res // 2) * res + res // 2
    np.testing.assert_allclose(img, img[::-1, ::-1], rtol=0.03)

    # Row-coded red, column-coded green, constant blue: the ratios are independent of lighting.
    size = 8
    files = _constant_textures(tmp_path, 1)
    files["diffuse"] = _write_exr(tmp_path / "coded.exr", _coded_diffuse(size, size))
    img = _render(S.load_scene("flash_capture", res=size, spp=4, filter_type="nearest", **files))
    rows, cols = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    np.testing.assert_allclose(img[..., 0] / img[..., 2], 2 * (rows + 1) / (size + 1), rtol=2e-3)
    np.testing.assert_allclose(img[..., 1] / img[..., 2], 2 * (cols + 1) / (size + 1), rtol=2e-3)


def _coded_diffuse(h: int, w: int) -> np.ndarray:
    """``(h, w, 3)``: red (i + 1)/(h + 1), green (j + 1)/(w + 1), blue 0.5."""
    i, j = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    return np.stack([(i + 1) / (h + 1), (j + 1) / (w + 1), np.full((h, w), 0.5)], axis=-1)


def test_light_and_camera_parameters_take_effect(tmp_path):
    files = _constant_textures(tmp_path, 4, diffuse=(0.5, 0.5, 0.5), roughness=0.5, specular=(0.04,) * 3)
    right = _render(S.load_scene("multiview_capture", res=16, spp=4, light_x=1.0, **files))
    left = _render(S.load_scene("multiview_capture", res=16, spp=4, light_x=-1.0, **files))
    assert right[:, 8:].mean() > 1.2 * right[:, :8].mean()
    np.testing.assert_allclose(right, left[:, ::-1], rtol=0.05, atol=1e-4)
    up = _render(S.load_scene("flash_capture", res=16, spp=4, light_y=1.0, **files))
    assert up[:8].mean() > 1.2 * up[8:].mean()      # row 0 is the top (y = +1)
    # The default camera sees only the plane; a camera moved aside also sees the black background.
    assert (_render(S.load_scene("multiview_capture", res=16, spp=4, **files)) > 0).all()
    moved = _render(S.load_scene("multiview_capture", res=16, spp=4, cam_x=2.0, cam_z=1.0, **files))
    assert 0.05 < (moved.max(axis=-1) == 0).mean() < 0.95


def test_environment_orientation():
    """The bundled sky: the sun is at 40 deg elevation towards (+x, +y); the ground is dim."""
    gen = _generate_assets_module()
    scene = S.load_scene("ambient_capture", res=8, spp=1)
    env = scene.environment()
    assert env is not None

    def radiance(direction) -> float:
        si = mi.SurfaceInteraction3f()
        si.wi = -mi.Vector3f(*direction)          # wi points away from the emitter
        return float(np.array(env.eval(si)).mean())

    sun = gen.SUN_DIRECTION
    assert radiance(sun) > 20.0
    assert radiance((-sun[0], -sun[1], sun[2])) < 2.0
    assert radiance((0, 0, 1)) > radiance((0, 0, -1)) * 3
    rotated = S.load_scene("ambient_capture", res=8, spp=1, env_rotation=180).environment()
    si = mi.SurfaceInteraction3f()
    si.wi = -mi.Vector3f(-sun[0], -sun[1], sun[2])
    assert float(np.array(rotated.eval(si)).mean()) > 20.0


def test_distribution_parameter():
    scene = S.load_scene("flash_capture", res=8, spp=1, distribution="beckmann")
    bsdfs = [s.bsdf() for s in scene.shapes()]
    assert "distribution = beckmann" in str(bsdfs[0])
    assert "distribution = ggx" in str(S.load_scene("flash_capture", res=8, spp=1).shapes()[0].bsdf())


def _generate_assets_module():
    path = S.scene_path("flash_capture").parent / "generate_assets.py"
    spec = importlib.util.spec_from_file_location("_mi_svbrdf_generate_assets", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bundled_assets_are_small_and_reproducible():
    gen = _generate_assets_module()
    root = S.scene_path("flash_capture").parent
    for rel in gen.assets():
        assert (root / rel).stat().st_size < 100_000, rel
    assert gen.check(root) == []
    # Stored normals are unit vectors once decoded.
    n = np.array(mi.Bitmap(str(root / "textures" / "normal.exr"))) * 2 - 1
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)


# --------------------------------------------------------------------------- helpers from tensors
def _directional(direction, irradiance: float = math.pi) -> dict:
    return {"type": "directional", "direction": [float(x) for x in direction],
            "irradiance": {"type": "rgb", "value": irradiance}}


def test_material_bsdf_dict():
    m = M.constant_maps(1, 4, 6, normal=(0.2, 0.0, 1.0), roughness=0.3)
    d = S.material_bsdf(m)
    assert d["type"] == "svbrdf_ggx"
    assert set(d) == {"type", "normal", "diffuse", "roughness", "specular"}
    for key in ("normal", "diffuse", "roughness", "specular"):
        assert d[key]["type"] == "bitmap" and d[key]["raw"] is True
    normal = np.array(d["normal"]["bitmap"])
    assert normal.shape == (4, 6, 3)
    np.testing.assert_allclose(normal[0, 0], (M.normal(m)[0, :, 0, 0].numpy() + 1) / 2, rtol=1e-6)
    assert np.array(d["roughness"]["bitmap"]).shape[-1] == 1 or np.array(d["roughness"]["bitmap"]).ndim == 2
    assert S.material_bsdf(m[0], distribution="beckmann", filter_type="nearest")["type"] == "svbrdf_beckmann"
    bsdf = mi.load_dict(d)
    assert "distribution = ggx" in str(bsdf)


def test_material_bsdf_errors():
    m = M.constant_maps(1, 4, 4)
    with pytest.raises(ValueError, match="distribution"):
        S.material_bsdf(m, distribution="phong")
    with pytest.raises(ValueError, match="filter_type"):
        S.material_bsdf(m, filter_type="cubic")
    with pytest.raises(ValueError, match="batch"):
        S.material_bsdf(M.constant_maps(2, 4, 4))
    with pytest.raises(ValueError, match="10"):
        S.material_bsdf(torch.zeros(1, 9, 4, 4))


def _coded_maps(h: int, w: int) -> torch.Tensor:
    m = M.constant_maps(1, h, w, specular=0.0, roughness=1.0)
    m[0, 3:6] = torch.from_numpy(_coded_diffuse(h, w)).permute(2, 0, 1).float()
    return m


def test_plane_scene_texel_orientation():
    """Texel (row i, column j) lands at x = -1 + (2j+1)/W, y = 1 - (2i+1)/H and on pixel (i, j)."""
    h, w = 6, 8
    scene = S.plane_scene(_coded_maps(h, w), sensor=S.capture_sensor(8), emitter=_directional((0, 0, -1)))
    i, j = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    xs = (-1 + (2 * j + 1) / w).flatten().astype(np.float32)
    ys = (1 - (2 * i + 1) / h).flatten().astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(mi.Float(xs), mi.Float(ys), 1.0), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    # The shading frame (= tangent space of the normal map) is world (+X, +Y, +Z).
    np.testing.assert_allclose(np.array(si.sh_frame.s).T, np.tile([1, 0, 0], (h * w, 1)), atol=1e-6)
    np.testing.assert_allclose(np.array(si.sh_frame.t).T, np.tile([0, 1, 0], (h * w, 1)), atol=1e-6)
    np.testing.assert_allclose(np.array(si.sh_frame.n).T, np.tile([0, 0, 1], (h * w, 1)), atol=1e-6)
    # Lambertian with s = 0 (the specular term is ~1e-4 of it): f(+z, +z) * pi = d.
    si.wi = mi.Vector3f(0, 0, 1)
    value = np.array(si.bsdf().eval(mi.BSDFContext(), si, mi.Vector3f(0, 0, 1))).T * math.pi
    np.testing.assert_allclose(value[:, 0], ((i + 1) / (h + 1)).flatten(), rtol=1e-3)
    np.testing.assert_allclose(value[:, 1], ((j + 1) / (w + 1)).flatten(), rtol=1e-3)
    # Rendering: pixel (i, j) of the square capture camera shows texel (i, j); irradiance pi -> L = d.
    size = 8
    square = S.plane_scene(_coded_maps(size, size), sensor=S.capture_sensor(size, spp=16),
                           emitter=_directional((0, 0, -1)))
    img = _render(square)
    np.testing.assert_allclose(img, _coded_diffuse(size, size), rtol=2e-3)


@pytest.mark.parametrize("axis", [0, 1])
def test_plane_scene_normal_orientation(axis):
    """A normal tilted towards +x (+y) equals the world normal: it brightens under a light at +x (+y)."""
    size = 8
    tilt = math.radians(30)
    n_pos, n_neg = [0.0, 0.0, math.cos(tilt)], [0.0, 0.0, math.cos(tilt)]
    n_pos[axis], n_neg[axis] = math.sin(tilt), -math.sin(tilt)
    m = M.constant_maps(1, size, size, specular=0.0, roughness=1.0, diffuse=0.5)
    normals = torch.tensor(n_neg).view(3, 1, 1).repeat(1, size, size)
    if axis == 0:
        normals[:, :, size // 2:] = torch.tensor(n_pos).view(3, 1, 1)   # right half tilts to +x
    else:
        normals[:, : size // 2, :] = torch.tensor(n_pos).view(3, 1, 1)  # top half (row 0 = y+) tilts to +y
    m[0, 0:3] = normals
    elev = math.radians(45)
    towards_light = [0.0, 0.0, math.sin(elev)]
    towards_light[axis] = math.cos(elev)
    scene = S.plane_scene(m, sensor=S.capture_sensor(size, spp=16),
                          emitter=_directional([-c for c in towards_light]))
    img = _render(scene)[..., 0]
    lit = img[:, size // 2:] if axis == 0 else img[: size // 2, :]
    dim = img[:, : size // 2] if axis == 0 else img[size // 2:, :]
    cos_lit, cos_dim = math.cos(elev - tilt), math.cos(elev + tilt)
    # Lambertian 0.5/pi * pi * cos (the s = 0 specular term is ~1e-4 of it)
    np.testing.assert_allclose(lit, 0.5 * cos_lit, rtol=5e-3)
    np.testing.assert_allclose(dim, 0.5 * cos_dim, rtol=5e-3)


def test_plane_scene_emitter_list_and_integrator():
    m = M.constant_maps(1, 4, 4, roughness=0.6)
    a, b = _directional((0.3, 0, -1)), _directional((-0.3, 0, -1))
    sensor = S.capture_sensor(8, spp=64)
    both = S.plane_scene(m, sensor=sensor, emitter=[a, b])
    keys = set(mi.traverse(both).keys())
    assert {"emitter_0.irradiance.value", "emitter_1.irradiance.value"} <= keys
    assert {"material.normal.data", "material.diffuse.data", "material.roughness.data",
            "material.specular.data"} <= keys
    img_both = _render(both)
    img_a = _render(S.plane_scene(m, sensor=sensor, emitter=a))
    img_b = _render(S.plane_scene(m, sensor=sensor, emitter=b))
    # `direct` picks one of the two emitters per sample: equal in expectation only.
    assert img_both.mean() == pytest.approx((img_a + img_b).mean(), rel=0.01)
    np.testing.assert_allclose(img_both, img_a + img_b, rtol=0.15)
    path = S.plane_scene(m, sensor=sensor, emitter=a, integrator={"type": "path", "max_depth": 2},
                         filter_type="bilinear", distribution="beckmann")
    assert np.isfinite(_render(path)).all()
    with pytest.raises(ValueError, match="emitter"):
        S.plane_scene(m, sensor=sensor, emitter=[])
    with pytest.raises(TypeError, match="sensor"):
        S.plane_scene(m, sensor=None, emitter=a)


def test_capture_sensor_covers_plane():
    """Corner pixels of the default capture sensor see texels right at the plane's corners."""
    s = mi.load_dict(S.capture_sensor(4))
    ray, _ = s.sample_ray(0.0, 0.5, mi.Point2f([0.5 / 4, 3.5 / 4], [0.5 / 4, 3.5 / 4]), mi.Point2f(0.5, 0.5))
    t = -np.array(ray.o.z) / np.array(ray.d.z)
    hit = np.array(ray.o).T + t[:, None] * np.array(ray.d).T
    np.testing.assert_allclose(hit[:, :2], [[-0.75, 0.75], [0.75, -0.75]], atol=1e-5)
    with pytest.raises(ValueError, match="fov"):
        S.capture_sensor(4, fov=180)
