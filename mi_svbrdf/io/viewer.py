"""A self-contained HTML page that draws a material with WebGL2 under a movable point light.

:func:`viewer_html` embeds the four maps (8-bit PNG, base64 data URIs: no network, no other
file) and a fragment shader that evaluates exactly the model of :mod:`mi_svbrdf.core.render`
(docs/conventions.md): GGX D and the separable G with k = alpha/2, every denominator floored
at 1e-3, the authors' Fresnel ``2^((-5.55473 c - 6.98316) c)``, diffuse ``d (1 - s) / pi``,
alpha = r^2 with r clipped to [1e-3, 1], and the radiance of a point light with fall-off::

    L = f * pi * I * c(n . wl) / |P_L - P|^2          (distance_falloff=True, no cone, no wl.z division)

What the page shows, and how :func:`mi_svbrdf.core.render` reproduces it:

- **Geometry.** One canvas pixel per texel (row i, column j), the texel at the conventions' plane
  position x = -1 + (2j + 1)/W, y = 1 - (2i + 1)/H, z = 0 (+y up, i.e. the top row is y > 0).
  The image is the rectified sample (orthographic from above), but the direction towards the
  viewer at each texel points at a **camera position** ``view`` (default (0, 0, 2.75), the
  authors' camera): ``core.render(maps, light, view, distance_falloff=True)`` with ``view``
  ``(B, K, 3)`` positions. The canvas is drawn at W x H pixels (CSS-scaled for display only).
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
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from mi_svbrdf.core.maps import MAP_NAMES, SLICES
from mi_svbrdf.io.atomic import write_text
from mi_svbrdf.io.material_io import (
    decode_normal,
    encode_normal,
    read_material,
    single_material,
    srgb_decode,
    srgb_encode,
)

__all__ = [
    "DEFAULT_INTENSITY",
    "DEFAULT_LIGHT",
    "DEFAULT_VIEW",
    "PAGE_NAME",
    "SHOW",
    "embedded_maps",
    "fragment",
    "map_codes",
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
#: File name the commands that write maps (``capture``, ``optimize``) give the page.
PAGE_NAME = "view.html"
#: Albedo maps, stored sRGB-encoded in the page.
_SRGB_MAPS = ("diffuse", "specular")


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


def viewer_html(maps: torch.Tensor, *, title: str = "material", light: Sequence[float] = DEFAULT_LIGHT,
                view: Sequence[float] = DEFAULT_VIEW, intensity: float | Sequence[float] = DEFAULT_INTENSITY,
                exposure: float = 0.0, show: str = "render") -> str:
    """The self-contained viewer page of one material (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        title: page title (shown, escaped).
        light: default light position (x, y, z), z > 0; the URL fragment overrides it.
        view: default camera position (x, y, z), z > 0.
        intensity: default light intensity I (scalar or RGB).
        exposure: default exposure in stops (radiance times ``2^exposure``).
        show: default view, one of :data:`SHOW`.

    Returns:
        The HTML text (UTF-8): four PNG data URIs, an inline script and style, no external reference.
    """
    settings = _settings(light, view, intensity, exposure, show)
    codes = map_codes(maps)
    height, width = codes["roughness"].shape
    images = "\n".join(f'<img id="map-{name}" alt="" hidden src="{_png_data_uri(codes[name])}">'
                       for name in MAP_NAMES)
    config = {"width": width, "height": height, "defaults": settings, "show": list(SHOW)}
    radios = "\n".join(f'<label><input type="radio" name="show" value="{name}"> {name}</label>' for name in SHOW)
    replacements = {"__TITLE__": html.escape(title), "__IMAGES__": images, "__RADIOS__": radios,
                    "__CONFIG__": json.dumps(config).replace("</", "<\\/"),
                    "__VERTEX__": _VERTEX_SHADER, "__FRAGMENT__": _FRAGMENT_SHADER}
    page = _PAGE
    for key, value in replacements.items():
        page = page.replace(key, value)
    return page


def write_viewer(path: str | os.PathLike, maps: torch.Tensor, **options: object) -> Path:
    """Write :func:`viewer_html` of ``maps`` to ``path`` atomically (its folder must exist); returns the path.

    Args:
        path: target ``.html`` file.
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        **options: keyword arguments of :func:`viewer_html` (``title``, ``light``, ``view``,
            ``intensity``, ``exposure``, ``show``).
    """
    path = Path(path)
    write_text(path, viewer_html(maps, **options))  # type: ignore[arg-type]
    return path


def view_material(folder: str | os.PathLike, out: str | os.PathLike, **options: object) -> Path:
    """Read a material folder (:func:`~mi_svbrdf.io.material_io.read_material`) and write its viewer page to ``out``."""
    maps = read_material(folder)
    options.setdefault("title", Path(folder).resolve().name)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    return write_viewer(out, maps, **options)


# The shaders. The fragment shader is the package's model (docs/conventions.md), term for term (brdf_torch.eval_brdf).
_VERTEX_SHADER = """#version 300 es
void main() {  // one triangle covering the viewport
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}"""

_FRAGMENT_SHADER = """#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D uNormal, uDiffuse, uRoughness, uSpecular;  // 8-bit codes / 255, fetched per texel
uniform vec3 uLight;      // point light position
uniform vec3 uView;       // camera position (direction to the viewer per texel)
uniform vec3 uIntensity;  // I * 2^exposure
uniform int uShow;        // 0 render, 1 normal, 2 diffuse, 3 roughness, 4 specular
out vec4 outColor;
const float PI = 3.14159265358979;
const float EPS = 1e-3;   // every denominator's floor

vec3 srgbDecode(vec3 v) {  // IEC 61966-2-1, as colour-science's cctf_decoding
  return mix(pow((v + 0.055) / 1.055, vec3(2.4)), v / 12.92, vec3(lessThanEqual(v, vec3(0.04045))));
}
vec3 unit(vec3 v) { return v * inversesqrt(max(dot(v, v), 1e-12)); }

void main() {
  ivec2 size = textureSize(uRoughness, 0);
  int j = int(gl_FragCoord.x);
  int i = size.y - 1 - int(gl_FragCoord.y);  // canvas row i = texel row i (top row first)
  ivec2 t = ivec2(j, i);
  vec3 nCode = texelFetch(uNormal, t, 0).rgb;
  vec3 dCode = texelFetch(uDiffuse, t, 0).rgb;
  float rCode = texelFetch(uRoughness, t, 0).r;
  vec3 sCode = texelFetch(uSpecular, t, 0).rgb;
  if (uShow == 1) { outColor = vec4(nCode, 1.0); return; }
  if (uShow == 2) { outColor = vec4(dCode, 1.0); return; }
  if (uShow == 3) { outColor = vec4(vec3(rCode), 1.0); return; }
  if (uShow == 4) { outColor = vec4(sCode, 1.0); return; }

  vec3 n = nCode * 2.0 - 1.0;
  float len = length(n);
  n = len > 1e-6 ? n / len : vec3(0.0, 0.0, 1.0);
  n = unit(n);
  vec3 d = srgbDecode(dCode);
  vec3 s = srgbDecode(sCode);
  float r = clamp(rCode, 1e-3, 1.0);
  // texel centre on the [-1, 1]^2 plane, +y up
  vec3 p = vec3(-1.0 + (2.0 * float(j) + 1.0) / float(size.x), 1.0 - (2.0 * float(i) + 1.0) / float(size.y), 0.0);
  vec3 toLight = uLight - p;
  vec3 wl = unit(toLight);
  vec3 wv = unit(uView - p);
  vec3 h = unit(wl + wv);
  float nh = max(dot(n, h), 0.0), nl = max(dot(n, wl), 0.0), nv = max(dot(n, wv), 0.0), vh = max(dot(wv, h), 0.0);
  float alpha = r * r;
  float a2 = alpha * alpha;
  float base = max(nh * nh * (a2 - 1.0) + 1.0, EPS);
  float D = a2 / (PI * base * base);                                  // GGX
  float k = alpha / 2.0;
  float G = 1.0 / max(nl * (1.0 - k) + k, EPS) / max(nv * (1.0 - k) + k, EPS);
  vec3 F = s + (1.0 - s) * exp2((-5.55473 * vh - 6.98316) * vh);     // the authors' Fresnel
  vec3 f = F * G * D / 4.0 + d * (1.0 - s) / PI;
  vec3 radiance = f * PI * uIntensity * nl / max(dot(toLight, toLight), 1e-12);
  outColor = vec4(pow(clamp(radiance, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);  // core.metrics.display
}"""

_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__TITLE__ - mi_svbrdf viewer</title>
<style>
  html, body { margin: 0; background: #000; color: #ddd; font: 13px sans-serif; }
  #view { display: flex; flex-wrap: wrap; align-items: flex-start; }
  canvas { display: block; image-rendering: pixelated; cursor: crosshair; touch-action: none; }
  #panel { padding: 8px 12px; width: 340px; }
  #panel label { display: block; margin: 4px 0; }
  #panel .show label { display: inline-block; margin-right: 4px; }
  #panel input[type=range] { width: 150px; vertical-align: middle; }
  #panel .note { color: #999; font-size: 12px; }
  #error { color: #f66; padding: 8px; }
  #error:empty { display: none; }
  body.bare #panel { display: none; }
  body.bare { overflow: hidden; }
</style>
</head>
<body>
<div id="view">
<canvas id="canvas"></canvas>
<div id="panel">
  <h3>__TITLE__</h3>
  <div class="show">
__RADIOS__
  </div>
  <label>exposure <input id="exposure" type="range" min="-6" max="6" step="0.1"> <span id="exposure-value"></span> stops</label>
  <label>light height <input id="height" type="range" min="0.1" max="6" step="0.05"> <span id="height-value"></span></label>
  <div>light <span id="light-value"></span></div>
  <p class="note">Drag on the image to move the point light over the sample (the wheel changes its height).
  The sample spans [-1, 1]&sup2; (+y up); the camera looks from <span id="view-value"></span>.
  GGX model and display (clip, then gamma 1/2.2) as mi_svbrdf's texel renderer.</p>
</div>
</div>
<div id="error"></div>
__IMAGES__
<script id="vertex-shader" type="x-shader/x-vertex">__VERTEX__</script>
<script id="fragment-shader" type="x-shader/x-fragment">__FRAGMENT__</script>
<script>
"use strict";
const CONFIG = __CONFIG__;
const MAPS = ["normal", "diffuse", "roughness", "specular"];
const state = JSON.parse(JSON.stringify(CONFIG.defaults));
let scale = 1;
let gl = null, uniforms = {}, pending = false;

function numbers(text, counts) {  // "a,b,c" -> [a, b, c] or null
  const v = text.split(",").map(Number);
  return counts.includes(v.length) && v.every(Number.isFinite) ? v : null;
}
function readFragment() {  // the URL fragment overrides the defaults, key by key
  const params = new URLSearchParams(location.hash.slice(1));
  Object.assign(state, JSON.parse(JSON.stringify(CONFIG.defaults)));
  for (const key of ["light", "view"]) {
    const v = params.has(key) ? numbers(params.get(key), [3]) : null;
    if (v) state[key] = v;
  }
  const inten = params.has("intensity") ? numbers(params.get("intensity"), [1, 3]) : null;
  if (inten) state.intensity = inten.length === 1 ? [inten[0], inten[0], inten[0]] : inten;
  const ev = Number(params.get("exposure"));
  if (params.has("exposure") && Number.isFinite(ev)) state.exposure = ev;
  if (CONFIG.show.includes(params.get("show"))) state.show = params.get("show");
  const bare = params.get("ui") === "0";  // only the canvas, at 1:1 unless a scale is given
  const s = Number(params.get("scale"));
  scale = params.has("scale") && s > 0 ? s : bare ? 1 : Math.max(1, Math.floor(512 / Math.max(CONFIG.width, CONFIG.height)));
  document.body.classList.toggle("bare", bare);
}
function writeFragment() {  // keep the URL in step with the state (shareable, reproducible)
  const params = new URLSearchParams(location.hash.slice(1));
  params.set("light", state.light.map(x => +x.toFixed(4)).join(","));
  params.set("exposure", String(+state.exposure.toFixed(2)));
  params.set("show", state.show);
  history.replaceState(null, "", "#" + params.toString().replace(/%2C/g, ","));
}
function syncControls() {
  const canvas = document.getElementById("canvas");
  canvas.style.width = (CONFIG.width * scale) + "px";
  canvas.style.height = (CONFIG.height * scale) + "px";
  document.getElementById("exposure").value = state.exposure;
  document.getElementById("exposure-value").textContent = state.exposure.toFixed(1);
  document.getElementById("height").value = state.light[2];
  document.getElementById("height-value").textContent = state.light[2].toFixed(2);
  document.getElementById("light-value").textContent = "(" + state.light.map(x => x.toFixed(2)).join(", ") + ")";
  document.getElementById("view-value").textContent = "(" + state.view.map(x => x.toFixed(2)).join(", ") + ")";
  for (const r of document.querySelectorAll("input[name=show]")) r.checked = r.value === state.show;
}
function compile(type, id) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, document.getElementById(id).textContent);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(id + ": " + gl.getShaderInfoLog(shader));
  return shader;
}
function setup() {
  const canvas = document.getElementById("canvas");
  canvas.width = CONFIG.width;
  canvas.height = CONFIG.height;
  gl = canvas.getContext("webgl2", {alpha: false, antialias: false, depth: false, preserveDrawingBuffer: true});
  if (!gl) throw new Error("this browser has no WebGL2");
  const program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER, "vertex-shader"));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, "fragment-shader"));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  gl.useProgram(program);
  gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);  // the codes as stored, no colour management
  gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
  MAPS.forEach((name, unit) => {
    gl.activeTexture(gl.TEXTURE0 + unit);
    gl.bindTexture(gl.TEXTURE_2D, gl.createTexture());
    for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, document.getElementById("map-" + name));
    const uniformName = "u" + name[0].toUpperCase() + name.slice(1);
    gl.uniform1i(gl.getUniformLocation(program, uniformName), unit);
  });
  for (const name of ["uLight", "uView", "uIntensity", "uShow"]) uniforms[name] = gl.getUniformLocation(program, name);
}
function draw() {
  pending = false;
  const gain = Math.pow(2, state.exposure);
  gl.viewport(0, 0, CONFIG.width, CONFIG.height);
  gl.uniform3fv(uniforms.uLight, state.light);
  gl.uniform3fv(uniforms.uView, state.view);
  gl.uniform3fv(uniforms.uIntensity, state.intensity.map(x => x * gain));
  gl.uniform1i(uniforms.uShow, CONFIG.show.indexOf(state.show));
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  syncControls();
}
function redraw(updateUrl) {
  if (updateUrl) writeFragment();
  if (!pending) { pending = true; requestAnimationFrame(draw); }
}
function lightFromPointer(event) {  // canvas position -> plane (x, y), the light keeps its height
  const rect = event.currentTarget.getBoundingClientRect();
  const x = -1 + 2 * (event.clientX - rect.left) / rect.width;
  const y = 1 - 2 * (event.clientY - rect.top) / rect.height;
  state.light = [Math.max(-3, Math.min(3, x)), Math.max(-3, Math.min(3, y)), state.light[2]];
  redraw(true);
}
function listen() {
  const canvas = document.getElementById("canvas");
  canvas.addEventListener("pointerdown", e => { canvas.setPointerCapture(e.pointerId); lightFromPointer(e); });
  canvas.addEventListener("pointermove", e => { if (canvas.hasPointerCapture(e.pointerId)) lightFromPointer(e); });
  canvas.addEventListener("wheel", e => {
    e.preventDefault();
    state.light[2] = Math.max(0.1, Math.min(6, state.light[2] * Math.exp(-e.deltaY * 0.001)));
    redraw(true);
  }, {passive: false});
  document.getElementById("exposure").addEventListener("input", e => { state.exposure = Number(e.target.value); redraw(true); });
  document.getElementById("height").addEventListener("input", e => { state.light[2] = Number(e.target.value); redraw(true); });
  for (const r of document.querySelectorAll("input[name=show]")) {
    r.addEventListener("change", e => { state.show = e.target.value; redraw(true); });
  }
  window.addEventListener("hashchange", () => { readFragment(); redraw(false); });
}
window.addEventListener("load", () => {  // the embedded PNGs are decoded before "load"
  try {
    readFragment();
    setup();
    draw();  // synchronously: a headless screenshot taken at "load" shows the first frame
    listen();
  } catch (err) {
    document.getElementById("error").textContent = "viewer: " + err.message;
  }
});
</script>
</body>
</html>
"""
