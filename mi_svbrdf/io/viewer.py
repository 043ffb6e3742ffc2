"""A self-contained HTML page that draws a material with WebGL2 under a movable point light.

:func:`viewer_html` embeds the four maps (8-bit PNG, base64 data URIs: no network, no other
file) and a fragment shader (``mi_svbrdf/io/templates/viewer.frag.glsl``) that evaluates exactly the
model of :mod:`mi_svbrdf.core.render` (docs/conventions.md) with the material's microfacet
distribution (``distribution``: a material folder's ``material.json``, see
:func:`~mi_svbrdf.io.material_io.read_distribution`): GGX D with the separable Smith-Schlick G
of k = alpha/2, or Beckmann D with k = alpha sqrt(2/pi) (as :func:`mi_svbrdf.core.brdf_torch.eval_brdf`),
every denominator floored at 1e-3, the authors' Fresnel ``2^((-5.55473 c - 6.98316) c)``, diffuse
``d (1 - s) / pi``, alpha = r^2 with r clipped to [1e-3, 1], and the radiance of a point light with fall-off::

    L = f * pi * I * c(n . wl) / |P_L - P|^2          (distance_falloff=True, no cone, no wl.z division)

What the page shows, and how :func:`mi_svbrdf.core.render` reproduces it:

- **Geometry.** One canvas pixel per texel (row i, column j), the texel at the conventions' plane
  position x = -1 + (2j + 1)/W, y = 1 - (2i + 1)/H, z = 0 (+y up, i.e. the top row is y > 0).
  The image is the rectified sample (orthographic from above), but the direction towards the
  viewer at each texel points at a **camera position** ``view`` (default (0, 0, 2.75), the
  authors' camera): ``core.render(maps, light, view, distance_falloff=True, distribution=...)``
  with ``view`` ``(B, K, 3)`` positions. The canvas is drawn at W x H pixels (CSS-scaled for display only).
- **Light.** A point light at ``light`` (default (0, 0, 2)) with intensity I (default 4: unit
  irradiance at the centre from the default height), times ``2^exposure`` (exposure in stops).
  Dragging on the canvas moves the light over the plane (its height stays; the height slider
  or the mouse wheel changes it).
- **Maps** are embedded as 8-bit PNG exactly as :func:`mi_svbrdf.io.material_io.write_material`
  stores them: normals as (n + 1)/2 (decoded 2v - 1, renormalised, zero -> (0, 0, 1)), albedos
  **sRGB-encoded** (decoded in the shader with the IEC 61966-2-1 curve, as colour-science does),
  roughness linear. :func:`embedded_maps` returns the maps the page really sees (after this
  8-bit round trip); render those to compare with a screenshot.
- **Display.** The project's display encoding, :func:`mi_svbrdf.core.metrics.display`:
  ``clip(x, 0, 1)^(1/2.2)``, written to an 8-bit canvas. ``show=normal|diffuse|roughness|specular``
  shows a map's stored PNG values instead (normals (n+1)/2, albedos sRGB).

The URL fragment sets the state (missing keys keep the page's defaults), and the page keeps it
up to date as you drag: ``page.html#light=0.3,0.2,2&exposure=0&show=render``. Keys: ``light``
and ``view`` (x,y,z), ``intensity`` (I or r,g,b), ``exposure`` (stops), ``show``
(:data:`SHOW`), ``scale`` (CSS pixels per texel; default: an integer fitting ~512 px) and ``ui=0``
(hide the controls: only the canvas, at the top left and 1:1 unless ``scale`` is given, as the
browser test screenshots it).

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.core.maps import constant_maps
    >>> page = viewer_html(constant_maps(1, 4, 4, diffuse=0.5))
    >>> "http://" in page or "https://" in page, page.count("data:image/png;base64,")
    (False, 4)
"""
from __future__ import annotations

import base64
import html
import io
import os
import re
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from mi_svbrdf.core.maps import MAP_NAMES, SLICES
from mi_svbrdf.plugins.model import DISTRIBUTIONS
from mi_svbrdf.io.atomic import dumps_json, write_text
from mi_svbrdf.io.material_io import (
    decode_normal,
    encode_normal,
    read_distribution,
    read_material,
    single_material,
    srgb_decode,
    srgb_encode,
)

__all__ = [
    "DEFAULT_INTENSITY",
    "DEFAULT_LIGHT",
    "DEFAULT_VIEW",
    "auto_exposure",
    "page_title",
    "PAGE_NAME",
    "SHOW",
    "TEMPLATES",
    "embedded_maps",
    "fill_template",
    "fragment",
    "map_codes",
    "read_template",
    "view_material",
    "viewer_html",
    "write_viewer",
]

#: What the page can show: the rendering, or one map as stored (``show=`` in the URL fragment).
SHOW = ("render", "normal", "diffuse", "roughness", "specular")
#: Default light position (half sample widths above the plane's centre).
DEFAULT_LIGHT = (0.0, 0.0, 2.0)
#: Default camera position (the authors' camera, as :func:`mi_svbrdf.cli.capture.relit_frames`).
DEFAULT_VIEW = (0.0, 0.0, 2.75)
#: Default light intensity I: unit irradiance at the centre at normal incidence from the default light.
DEFAULT_INTENSITY = 4.0
#: The display value the brightest texels reach at the default exposure (:func:`auto_exposure`), and their share.
AUTO_WHITE, AUTO_QUANTILE = 0.9, 0.99
#: File name the commands that write maps (``capture``, ``optimize``) give the page.
PAGE_NAME = "view.html"
#: Albedo maps, stored sRGB-encoded in the page.
_SRGB_MAPS = ("diffuse", "specular")
#: Package data of :mod:`mi_svbrdf.io` the exporters fill in (``mi_svbrdf/io/templates/``): the page,
#: its shaders (the fragment shader is the package's model, term for term, as :func:`mi_svbrdf.core.brdf_torch.eval_brdf`)
#: and the Blender script of :func:`mi_svbrdf.io.export.export_blender`.
TEMPLATES = ("viewer.html", "viewer.vert.glsl", "viewer.frag.glsl", "blender_material.py.in")
#: A template's placeholders: ``__NAME__`` (upper case, so Python's ``__file__`` is none).
_PLACEHOLDER = re.compile(r"__[A-Z][A-Z0-9_]*__")


def read_template(name: str) -> str:
    """The text of the template ``name`` (one of :data:`TEMPLATES`), read with :mod:`importlib.resources`."""
    if name not in TEMPLATES:
        raise ValueError(f"name: expected one of {TEMPLATES}, got {name!r}")
    return resources.files(__package__).joinpath("templates", name).read_text(encoding="utf-8")


def fill_template(name: str, values: Mapping[str, str]) -> str:
    """The template ``name`` with each placeholder ``__KEY__`` replaced by ``values[KEY]``.

    Raises:
        ValueError: a key of ``values`` is not a placeholder of the template, or a placeholder has no value.
    """
    text = read_template(name)
    wanted = {m[2:-2] for m in _PLACEHOLDER.findall(text)}
    if set(values) != wanted:
        raise ValueError(f"values: expected the placeholders of {name} {sorted(wanted)}, got {sorted(values)}")
    return _PLACEHOLDER.sub(lambda m: values[m.group(0)[2:-2]], text)


def map_codes(maps: torch.Tensor) -> dict[str, np.ndarray]:
    """The 8-bit code values the page embeds: ``{map name: (H, W, 3) uint8}`` (roughness ``(H, W)``).

    Normals (n + 1)/2, albedos sRGB-encoded (colour-science), roughness linear; values clipped
    to [0, 1] and rounded to the nearest code, as :func:`~mi_svbrdf.io.material_io.write_material` does.

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
    """
    data = single_material(maps)
    codes = {}
    for name in MAP_NAMES:
        values = data[:, :, SLICES[name]]
        if name == "normal":
            values = encode_normal(values)
        elif name in _SRGB_MAPS:
            values = srgb_encode(values)
        codes[name] = np.rint(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)
    codes["roughness"] = codes["roughness"][:, :, 0]
    return codes


def embedded_maps(maps: torch.Tensor) -> torch.Tensor:
    """The maps the page shades with: ``maps`` after the page's 8-bit encoding and the shader's decoding.

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.

    Returns:
        ``(1, 10, H, W)`` float32 maps: render these with :func:`mi_svbrdf.core.render` to get
        (up to float rounding) what the page draws.
    """
    codes = map_codes(maps)
    parts = []
    for name in MAP_NAMES:
        values = codes[name].astype(np.float32) / 255.0
        if name == "normal":
            values = decode_normal(values)
        elif name in _SRGB_MAPS:
            values = srgb_decode(values)
        parts.append(values.reshape(values.shape[0], values.shape[1], -1))
    return torch.from_numpy(np.concatenate(parts, axis=2)).permute(2, 0, 1)[None].contiguous()


def _png_data_uri(codes: np.ndarray) -> str:
    """``data:image/png;base64,...`` of uint8 codes (no colour chunks: the browser must not convert them)."""
    buffer = io.BytesIO()
    Image.fromarray(codes).save(buffer, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _vector(value: Sequence[float], name: str, sizes: tuple[int, ...] = (3,)) -> list[float]:
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected {' or '.join(map(str, sizes))} numbers, got {value!r}") from None
    if len(out) not in sizes or not all(np.isfinite(out)):
        raise ValueError(f"{name}: expected {' or '.join(map(str, sizes))} finite numbers, got {value!r}")
    return out


def _settings(light: Sequence[float], view: Sequence[float], intensity: float | Sequence[float],
              exposure: float, show: str) -> dict[str, object]:
    """Checked page state as JSON-ready values."""
    light_v = _vector(light, "light")
    view_v = _vector(view, "view")
    if light_v[2] <= 0.0:
        raise ValueError(f"light: expected a position above the plane (z > 0), got z = {light_v[2]}")
    if view_v[2] <= 0.0:
        raise ValueError(f"view: expected a camera above the plane (z > 0), got z = {view_v[2]}")
    inten = _vector([intensity] if np.isscalar(intensity) else intensity, "intensity", (1, 3))
    if len(inten) == 1:
        inten = inten * 3
    if min(inten) < 0.0:
        raise ValueError(f"intensity: expected values >= 0, got {intensity!r}")
    if not np.isfinite(float(exposure)):
        raise ValueError(f"exposure: expected a finite number of stops, got {exposure!r}")
    if show not in SHOW:
        raise ValueError(f"show: expected one of {SHOW}, got {show!r}")
    return {"light": light_v, "view": view_v, "intensity": inten, "exposure": float(exposure), "show": show}


def fragment(light: Sequence[float] | None = None, *, view: Sequence[float] | None = None,
             intensity: float | Sequence[float] | None = None, exposure: float | None = None,
             show: str | None = None, scale: float | None = None, ui: bool = True) -> str:
    """The URL fragment (without ``#``) that sets the page's state; None keeps the page's default.

    Examples:
        >>> fragment((0.3, 0.2, 2.0), exposure=1, show="render")
        'light=0.3,0.2,2&exposure=1&show=render'
    """
    def num(x: float) -> str:
        return f"{float(x):.9g}"

    parts = []
    if light is not None:
        parts.append("light=" + ",".join(num(v) for v in _vector(light, "light")))
    if view is not None:
        parts.append("view=" + ",".join(num(v) for v in _vector(view, "view")))
    if intensity is not None:
        values = _vector([intensity] if np.isscalar(intensity) else intensity, "intensity", (1, 3))
        parts.append("intensity=" + ",".join(num(v) for v in values))
    if exposure is not None:
        parts.append(f"exposure={num(exposure)}")
    if show is not None:
        if show not in SHOW:
            raise ValueError(f"show: expected one of {SHOW}, got {show!r}")
        parts.append(f"show={show}")
    if scale is not None:
        if not float(scale) > 0:
            raise ValueError(f"scale: expected a number > 0, got {scale!r}")
        parts.append(f"scale={num(scale)}")
    if not ui:
        parts.append("ui=0")
    return "&".join(parts)


def page_title(command: str, out: str | os.PathLike) -> str:
    """The title of the page a command writes into its folder ``out``: the folder (with its parent) and the command.

    Examples:
        >>> page_title("optimize", "out/optimize")
        'out/optimize (mi-svbrdf optimize)'
    """
    out = Path(out)
    return f"{out.parent.name}/{out.name} (mi-svbrdf {command})" if out.parent.name else \
        f"{out.name} (mi-svbrdf {command})"


def auto_exposure(maps: torch.Tensor, light: Sequence[float] = DEFAULT_LIGHT, view: Sequence[float] = DEFAULT_VIEW,
                  intensity: float | Sequence[float] = DEFAULT_INTENSITY, distribution: str = "ggx",
                  max_side: int = 256) -> float:
    """The page's default exposure in stops: 0, or lower (in half stops) so that under the default light the
    brightest texels (quantile :data:`AUTO_QUANTILE` of the brightest channel) stay below :data:`AUTO_WHITE`
    instead of saturating (a bright sample: a white paper, a glossy print). Rendered with the texel renderer,
    the page's model, on at most ``max_side`` texels a side.

    Examples:
        >>> from mi_svbrdf.core.maps import constant_maps
        >>> auto_exposure(constant_maps(1, 8, 8, diffuse=0.2)), auto_exposure(constant_maps(1, 8, 8, diffuse=0.95))
        (0.0, -0.5)
    """
    from mi_svbrdf.core.render import render

    maps = maps if maps.dim() == 4 else maps[None]
    step = max(1, -(-max(maps.shape[-2:]) // max_side))
    small = maps[..., ::step, ::step].float()
    inten = torch.as_tensor(intensity, dtype=torch.float32)
    image = render(small, torch.tensor([[list(light)]], dtype=torch.float32),
                   torch.tensor([[list(view)]], dtype=torch.float32), intensity=inten,
                   distance_falloff=True, distribution=distribution)
    top = float(torch.quantile(image[0, 0].amax(dim=0).flatten(), AUTO_QUANTILE))
    if not np.isfinite(top) or top <= AUTO_WHITE:
        return 0.0
    return -float(np.ceil(2.0 * np.log2(top / AUTO_WHITE)) / 2.0)


def viewer_html(maps: torch.Tensor, *, title: str = "material", light: Sequence[float] = DEFAULT_LIGHT,
                view: Sequence[float] = DEFAULT_VIEW, intensity: float | Sequence[float] = DEFAULT_INTENSITY,
                exposure: float | None = None, show: str = "render", distribution: str = "ggx",
                uncertainty: Mapping[str, tuple[np.ndarray, str]] | None = None) -> str:
    """The self-contained viewer page of one material (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        title: page title (shown, escaped).
        light: default light position (x, y, z), z > 0; the URL fragment overrides it.
        view: default camera position (x, y, z), z > 0.
        intensity: default light intensity I (scalar or RGB).
        exposure: default exposure in stops (radiance times ``2^exposure``); None: :func:`auto_exposure` (0, or
            lower where the sample would saturate under the default light).
        show: default view, one of :data:`SHOW`.
        distribution: the maps' microfacet model, ``"ggx"`` or ``"beckmann"`` (a material folder's
            :func:`~mi_svbrdf.io.material_io.read_distribution`); the page shades with it and names it.
        uncertainty: optional ``{name: (image (H, W, 3) in [0, 1], caption)}``, e.g. the per-texel spread of a
            fit's maps drawn with a colour scale; the page then has an "uncertainty" toggle that shows the chosen
            one in the rendering's place, with its caption (what the colours mean).

    Returns:
        The HTML text (UTF-8): four PNG data URIs, an inline script and style, no external reference.
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if exposure is None:
        _settings(light, view, intensity, 0.0, show)  # checked before they are rendered with
        exposure = auto_exposure(maps, light, view, intensity, distribution)
    settings = _settings(light, view, intensity, exposure, show)
    codes = map_codes(maps)
    height, width = codes["roughness"].shape
    images = "\n".join(f'<img id="map-{name}" alt="" hidden src="{_png_data_uri(codes[name])}">'
                       for name in MAP_NAMES)
    config = {"width": width, "height": height, "defaults": settings, "show": list(SHOW), "distribution": distribution,
              "uncertainty": {name: caption for name, (_, caption) in (uncertainty or {}).items()}}
    radios = "\n".join(f'<label><input type="radio" name="show" value="{name}"> {name}</label>' for name in SHOW)
    unc_images, unc_controls = "", ""
    if uncertainty:
        for name, (image, _) in uncertainty.items():
            if not re.fullmatch(r"[a-z_]+", name):
                raise ValueError(f"uncertainty: expected map names of lower-case letters and _, got {name!r}")
            if image.ndim != 3 or image.shape[2] != 3:
                raise ValueError(f"uncertainty[{name!r}]: expected an (H, W, 3) image, got shape {image.shape}")
        codes_u = {name: np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
                   for name, (image, _) in uncertainty.items()}
        unc_images = "\n".join(f'<img class="uncertainty" id="uncertainty-{name}" alt="uncertainty of {name}" hidden '
                               f'src="{_png_data_uri(c)}">' for name, c in codes_u.items())
        options = "".join(f'<option value="{name}">{name}</option>' for name in uncertainty)
        unc_controls = ('  <label><input type="checkbox" id="uncertainty-toggle"> uncertainty '
                        f'<select id="uncertainty-map">{options}</select></label>\n'
                        '  <div class="note" id="uncertainty-caption"></div>')
    return fill_template("viewer.html", {
        "TITLE": html.escape(title), "IMAGES": images, "RADIOS": radios,
        "UNCERTAINTY_IMAGES": unc_images, "UNCERTAINTY_CONTROLS": unc_controls,
        "MODEL": {"ggx": "GGX", "beckmann": "Beckmann"}[distribution],
        "CONFIG": dumps_json(config, indent=None).replace("</", "<\\/"),
        "VERTEX": read_template("viewer.vert.glsl").rstrip("\n"),
        "FRAGMENT": read_template("viewer.frag.glsl").rstrip("\n")})


def is_viewer_page(path: str | os.PathLike) -> bool:
    """Whether the file ``path`` is a page :func:`write_viewer` wrote (its head: the template's title line).

    Examples:
        >>> import tempfile, pathlib
        >>> mine = pathlib.Path(tempfile.mkdtemp()) / "notes.html"
        >>> _ = mine.write_text("<p>my notes</p>")
        >>> is_viewer_page(mine)
        False
    """
    try:
        with open(path, "rb") as f:
            head = f.read(1024)
    except OSError:
        return False
    return head.startswith(b"<!DOCTYPE html>") and b" - mi_svbrdf viewer</title>" in head


def write_viewer(path: str | os.PathLike, maps: torch.Tensor, **options: object) -> Path:
    """Write :func:`viewer_html` of ``maps`` to ``path`` atomically (its folder must exist); returns the path.

    Args:
        path: target ``.html`` file.
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        **options: keyword arguments of :func:`viewer_html` (``title``, ``light``, ``view``,
            ``intensity``, ``exposure``, ``show``, ``distribution``).
    """
    path = Path(path)
    write_text(path, viewer_html(maps, **options))  # type: ignore[arg-type]
    return path


def view_material(folder: str | os.PathLike, out: str | os.PathLike, **options: object) -> Path:
    """Read a material folder (:func:`~mi_svbrdf.io.material_io.read_material`) and write its viewer page to ``out``.

    The page shades with the folder's model (:func:`~mi_svbrdf.io.material_io.read_distribution`)
    unless ``options`` names a ``distribution``.
    """
    maps = read_material(folder)
    options.setdefault("title", Path(folder).resolve().name)
    options.setdefault("distribution", read_distribution(folder))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    return write_viewer(out, maps, **options)
