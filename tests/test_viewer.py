"""``mi-svbrdf view``: the self-contained WebGL2 page, checked in a real browser against the texel renderer.

The browser tests load the page in headless Chromium (Debian's ``chromium``, which ``.ci/setup.sh --tests``
installs) with the light in the URL fragment and ``ui=0`` (the bare canvas at 1:1, one pixel per
texel), take a screenshot and compare it, texel for texel, with :func:`mi_svbrdf.core.render` of
the same light, camera and microfacet model (point light with fall-off, shading towards the camera
position; each case once with GGX and once with Beckmann, the page's ``distribution``),
displayed as the project displays renders (:func:`mi_svbrdf.core.metrics.display`: clip, then
gamma 1/2.2) and rounded to 8 bits. Thresholds, in 8-bit display levels:

- against the texel renderer on the maps the page embeds (:func:`mi_svbrdf.io.viewer.embedded_maps`,
  the 8-bit round trip of the maps): mean |difference| < 0.1 and max <= 2 (only float rounding in
  the shader and the 8-bit output rounding remain; measured: bit-exact on the GGX cases here and on
  tiles with Beckmann, 5e-5 mean and max 1 on metal_plate with Beckmann; 7e-5 mean and max 1 on
  metal_plate at 256² with GGX);
- against the texel renderer on the original float maps: mean < 2 (adds the 8-bit quantisation
  of the embedded maps, mostly the roughness of glossy texels; measured 0.35 and 0.61 with GGX,
  0.37 and 0.65 with Beckmann).

Without chromium (or without WebGL2 in it) the browser tests are skipped with the reason.
"""
from __future__ import annotations

import base64
import io
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mi_svbrdf.cli import capture as capture_cli
from mi_svbrdf.cli import optimize as optimize_cli
from mi_svbrdf.cli import view as view_cli
from mi_svbrdf.core.maps import MAP_NAMES
from mi_svbrdf.core.metrics import display
from mi_svbrdf.core.render import render
from mi_svbrdf.data.examples import example_material
from mi_svbrdf.io import viewer
from mi_svbrdf.io.material_io import read_material, write_material

#: Mean |screenshot - texel renderer| (8-bit display levels) on the maps the page embeds.
MEAN_TOL_EMBEDDED = 0.1
#: Largest per-value difference allowed on the embedded maps.
MAX_TOL_EMBEDDED = 2
#: Mean |screenshot - texel renderer| on the original float maps (adds the 8-bit map quantisation).
MEAN_TOL_FLOAT = 2.0

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run", "--force-device-scale-factor=1", "--hide-scrollbars")

#: Browser window (W, H) of the screenshots: the canvas sits at its top left (``ui=0``), the rest is cropped.
WINDOW = (512, 512)

PROBE_PAGE = """<!DOCTYPE html><html><body style="margin:0;background:#000">
<canvas id="c" width="16" height="16" style="display:block"></canvas><script>
const gl = document.getElementById("c").getContext("webgl2");
if (gl) { gl.clearColor(0.2, 0.4, 0.6, 1.0); gl.clear(gl.COLOR_BUFFER_BIT); }
</script></body></html>"""


def _chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


def screenshot(browser: str, url: str, out: Path, size: tuple[int, int], profile: Path) -> np.ndarray:
    """Screenshot ``url`` in a ``size`` (W, H) window of headless Chromium: ``(H, W, 3)`` uint8.

    Keep ``size`` at least 500 px wide: Chromium widens narrower headless windows to 500 px and
    then shows less than the requested height (a 128 x 128 window showed 41 rows of the page).

    Raises:
        RuntimeError: no screenshot was written (with Chromium's exit code and last stderr lines).
    """
    args = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
            f"--screenshot={out}", url]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
    if not out.is_file():
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"chromium wrote no screenshot (exit code {proc.returncode}): {tail}")
    with Image.open(out) as image:
        return np.asarray(image.convert("RGB"))


def page_errors(browser: str, url: str, profile: Path) -> str:
    """The text of the page's error box after loading (diagnostics for a failed comparison)."""
    proc = subprocess.run([browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--dump-dom", url],
                          capture_output=True, text=True, timeout=120, check=False)
    found = re.search(r'<div id="error">(.*?)</div>', proc.stdout, flags=re.DOTALL)
    return found.group(1).strip() if found else f"(no error box in the DOM; exit code {proc.returncode})"


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Chromium's path, after it screenshotted a WebGL2 clear colour exactly; else the test is skipped."""
    binary = _chromium_binary()
    if binary is None:
        pytest.skip("headless browser test: no 'chromium' on PATH (Debian: apt-get install chromium; "
                    "bash .ci/setup.sh --tests installs it)")
    folder = tmp_path_factory.mktemp("probe")
    (folder / "probe.html").write_text(PROBE_PAGE, encoding="utf-8")
    try:
        shot = screenshot(binary, (folder / "probe.html").as_uri(), folder / "probe.png", WINDOW, folder / "profile")
    except (RuntimeError, subprocess.TimeoutExpired, OSError) as err:
        pytest.skip(f"headless browser test: {binary} cannot take a screenshot here: {err}")
    if tuple(shot[0, 0]) != (51, 102, 153):
        pytest.skip(f"headless browser test: {binary} has no working WebGL2 here (probe pixel {tuple(shot[0, 0])}, "
                    f"expected (51, 102, 153))")
    return binary


def _material(name: str, size: int, rows: int | None = None) -> torch.Tensor:
    maps = example_material(name, size=size)
    return maps[:, :, :rows].contiguous() if rows else maps  # rows < size: a non-square sample


def _texel_image(maps: torch.Tensor, light: tuple[float, ...], view: tuple[float, ...],
                 intensity: torch.Tensor, distribution: str = "ggx") -> np.ndarray:
    """The texel renderer's displayed 8-bit image (H, W, 3) of one point light and camera position."""
    with torch.no_grad():
        radiance = render(maps, torch.tensor([[light]]), torch.tensor([[view]]),
                          intensity=intensity.view(1, 1, 3), distance_falloff=True, distribution=distribution)[0, 0]
    return np.rint(display(radiance).permute(1, 2, 0).numpy() * 255.0)


CASES = {
    # material, size, rows, light, view (None: the page's default), intensity (None: default), exposure, model
    "tiles_square": ("tiles", 64, None, (0.4, -0.3, 1.2), None, None, 0.5, "ggx"),
    "metal_nonsquare_rgb_light": ("metal_plate", 96, 64, (-0.6, 0.5, 1.6), (0.3, -0.2, 2.2), (3.0, 2.5, 2.0), -0.5,
                                  "ggx"),
    "tiles_square_beckmann": ("tiles", 64, None, (0.4, -0.3, 1.2), None, None, 0.5, "beckmann"),
    "metal_nonsquare_beckmann": ("metal_plate", 96, 64, (-0.6, 0.5, 1.6), (0.3, -0.2, 2.2), (3.0, 2.5, 2.0), -0.5,
                                 "beckmann"),
}
#: Mean |screenshot - texel renderer of the other model| must exceed this (8-bit levels): the page shades
#: with the material's model, not the other one (measured: 0.96 on tiles, 34 on metal_plate).
MEAN_OTHER_MODEL_MIN = 0.5


@pytest.mark.parametrize("case", sorted(CASES))
def test_browser_screenshot_matches_texel_renderer(browser: str, tmp_path: Path, case: str) -> None:
    name, size, rows, light, view, intensity, exposure, model = CASES[case]
    maps = _material(name, size, rows)
    height, width = maps.shape[-2:]
    page = viewer.write_viewer(tmp_path / "view.html", maps, title=case, distribution=model)
    url = page.as_uri() + "#" + viewer.fragment(light, view=view, intensity=intensity, exposure=exposure, ui=False)
    shot = screenshot(browser, url, tmp_path / "shot.png", (max(width, WINDOW[0]), max(height, WINDOW[1])),
                      tmp_path / "profile")
    assert shot.shape[0] >= height and shot.shape[1] >= width, shot.shape
    shot = shot[:height, :width].astype(np.float64)  # the canvas, at the top left, one pixel per texel

    gain = torch.tensor(intensity if intensity is not None else (viewer.DEFAULT_INTENSITY,) * 3) * 2.0 ** exposure
    camera = view if view is not None else viewer.DEFAULT_VIEW
    expected = _texel_image(viewer.embedded_maps(maps), light, camera, gain, model)
    diff = np.abs(shot - expected)
    if not (diff.mean() < MEAN_TOL_EMBEDDED and diff.max() <= MAX_TOL_EMBEDDED):
        Image.fromarray(np.concatenate([shot, expected], axis=1).astype(np.uint8)).save(tmp_path / "shot_vs_texel.png")
        pytest.fail(f"{case}: screenshot vs texel renderer: mean |diff| {diff.mean():.4f} (< {MEAN_TOL_EMBEDDED}), "
                    f"max {diff.max():.0f} (<= {MAX_TOL_EMBEDDED}) 8-bit levels; page errors: "
                    f"{page_errors(browser, url, tmp_path / 'profile')}; images: {tmp_path / 'shot_vs_texel.png'}")
    assert expected.std() > 10.0, "the test image should not be flat"
    original = _texel_image(maps, light, camera, gain, model)
    assert np.abs(shot - original).mean() < MEAN_TOL_FLOAT
    other = _texel_image(viewer.embedded_maps(maps), light, camera, gain, "beckmann" if model == "ggx" else "ggx")
    assert np.abs(shot - other).mean() > MEAN_OTHER_MODEL_MIN, "the page should shade with the material's model"


def test_browser_shows_each_map_as_stored(browser: str, tmp_path: Path) -> None:
    maps = _material("tiles", 64, 40)
    page = viewer.write_viewer(tmp_path / "view.html", maps)
    codes = viewer.map_codes(maps)
    for show in ("normal", "roughness", "diffuse"):
        url = page.as_uri() + "#" + viewer.fragment(show=show, ui=False)
        shot = screenshot(browser, url, tmp_path / f"{show}.png", WINDOW, tmp_path / "profile")[:40, :64]
        stored = codes[show] if codes[show].ndim == 3 else np.repeat(codes[show][:, :, None], 3, axis=2)
        assert np.array_equal(shot, stored), f"show={show}: max diff {np.abs(shot.astype(int) - stored).max()}"


def _data_uris(page: str) -> list[str]:
    return re.findall(r'src="(data:image/png;base64,[^"]*)"', page)


def test_page_is_self_contained_with_the_maps_embedded() -> None:
    maps = _material("tiles", 32, 24)
    page = viewer.viewer_html(maps, title="<tiles>")
    assert "http://" not in page and "https://" not in page
    assert not re.search(r"<link|<iframe|@import|url\(|fetch\(|XMLHttpRequest", page)
    sources = re.findall(r'src="([^"]*)"', page)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "&lt;tiles&gt;" in page and "<tiles>" not in page
    uris = _data_uris(page)
    assert len(uris) == 4
    codes = viewer.map_codes(maps)
    for name, uri in zip(MAP_NAMES, uris):  # the PNGs are exactly the 8-bit codes, untagged (no colour chunks)
        data = base64.b64decode(uri.split(",", 1)[1])
        assert b"sRGB" not in data and b"gAMA" not in data and b"iCCP" not in data
        with Image.open(io.BytesIO(data)) as image:
            assert np.array_equal(np.asarray(image), codes[name]), name
    # The shader decodes the codes as embedded_maps does: within the 8-bit quantisation of the maps.
    decoded = viewer.embedded_maps(maps)
    assert decoded.shape == maps.shape
    assert (decoded[:, 6:7] - maps[:, 6:7]).abs().max() <= 0.5 / 255 + 1e-6  # roughness: linear codes
    assert (decoded[:, 3:6] - maps[:, 3:6]).abs().max() < 0.01  # albedos: sRGB codes, finer in the darks
    assert torch.allclose(decoded[:, :3].norm(dim=1), torch.ones(1, 24, 32), atol=1e-5)


def test_page_names_and_uses_the_folders_model(tmp_path: Path) -> None:
    maps = _material("tiles", 16)
    for model, shown in (("ggx", "GGX model"), ("beckmann", "Beckmann model")):
        write_material(tmp_path / model, maps, fmt="exr", distribution=model)
        page = viewer.view_material(tmp_path / model, tmp_path / f"{model}.html").read_text(encoding="utf-8")
        assert f'"distribution": "{model}"' in page and shown in page
    page = viewer.view_material(tmp_path / "beckmann", tmp_path / "forced.html", distribution="ggx")
    assert '"distribution": "ggx"' in page.read_text(encoding="utf-8")
    with pytest.raises(ValueError, match="^distribution: expected"):
        viewer.viewer_html(maps, distribution="phong")


def test_templates_are_package_data_read_by_importlib() -> None:
    import fnmatch

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10: the tomli backport (a dependency there)
        import tomli as tomllib

    root = Path(__file__).resolve().parent.parent
    folder = root / "mi_svbrdf" / "io" / "templates"
    assert sorted(p.name for p in folder.iterdir()) == sorted(viewer.TEMPLATES)
    patterns = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["mi_svbrdf.io"]
    for name in viewer.TEMPLATES:  # each shipped in the wheel, and read from the package
        assert any(fnmatch.fnmatch(f"templates/{name}", pattern) for pattern in patterns), name
        assert viewer.read_template(name) == (folder / name).read_text(encoding="utf-8")
    with pytest.raises(ValueError, match="^name: expected"):
        viewer.read_template("viewer.js")
    with pytest.raises(ValueError, match=r"^values: expected the placeholders of viewer.html .*'TITLE'"):
        viewer.fill_template("viewer.html", {"TITLE": "x"})
    page = viewer.viewer_html(_material("tiles", 16))
    assert not re.search(r"__[A-Z][A-Z0-9_]*__", page)  # every placeholder filled
    assert viewer.read_template("viewer.frag.glsl").rstrip("\n") in page


def test_fragment_and_bad_settings_name_the_field() -> None:
    assert viewer.fragment((0.3, 0.2, 2.0), exposure=1, show="render") == "light=0.3,0.2,2&exposure=1&show=render"
    assert viewer.fragment(intensity=2, ui=False) == "intensity=2&ui=0"
    maps = _material("tiles", 16)
    for kwargs, field in (({"light": (0, 0)}, "light"), ({"light": (0, 0, -1)}, "light"),
                          ({"view": (0, 0, 0)}, "view"), ({"show": "albedo"}, "show"),
                          ({"intensity": (1, 2)}, "intensity"), ({"exposure": float("nan")}, "exposure")):
        with pytest.raises(ValueError, match=f"^{field}: expected"):
            viewer.viewer_html(maps, **kwargs)


def test_cli_view_writes_the_page(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "material"
    write_material(folder, _material("metal_plate", 32))
    assert view_cli.main(["view", str(folder)]) == 0  # default: beside the maps
    assert (folder / viewer.PAGE_NAME).is_file()
    out = tmp_path / "pages" / "page.html"
    assert view_cli.main(["view", str(folder), "-o", str(out), "--light", "0.3,0.2,2", "--exposure", "1",
                          "--show", "normal"]) == 0
    text = capsys.readouterr().out
    assert "page.html" in text and "#light=0.3,0.2,2&exposure=1&show=normal" in text
    page = out.read_text(encoding="utf-8")
    assert len(_data_uris(page)) == 4 and '"show": "normal"' in page and '"light": [0.3, 0.2, 2.0]' in page
    codes = viewer.map_codes(read_material(folder))
    with Image.open(io.BytesIO(base64.b64decode(_data_uris(page)[1].split(",", 1)[1]))) as image:
        assert np.array_equal(np.asarray(image), codes["diffuse"])
    assert not list(out.parent.glob(".*tmp*")), "a temporary file was left behind"


def test_cli_view_out_takes_a_file_and_refuses_the_users_own(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """-o given a folder: one line saying -o takes a file (no temporary name); given the user's own file: refused
    without --force, as the folders are (mi_svbrdf.cli.common.check_folder); a page view wrote is replaced."""
    folder = tmp_path / "out"
    folder.mkdir()
    assert view_cli.main(["view", "example:tiles", "-o", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err == (f"mi-svbrdf view: error: -o/--out: expected the page's file name (-o takes a file, e.g. "
                   f"{folder / viewer.PAGE_NAME}), got the folder {folder}/\n"), err
    assert ".tmp" not in err and not list(folder.iterdir())
    mine = folder / "summary.json"
    mine.write_text('{"mine": true}')
    assert view_cli.main(["view", "example:tiles", "-o", str(mine)]) == 2
    err = capsys.readouterr().err
    assert err == (f"mi-svbrdf view: error: -o/--out: expected a new file or a page `mi-svbrdf view` wrote, got the "
                   f"existing file {mine}, which is not one (choose another file, or --force to replace it)\n"), err
    assert mine.read_text() == '{"mine": true}' and sorted(folder.iterdir()) == [mine]
    page = folder / "page.html"  # a page view wrote is replaced without --force (a re-run)
    assert view_cli.main(["view", "example:tiles", "-o", str(page), "--title", "first"]) == 0
    assert viewer.is_viewer_page(page) and view_cli.main(["view", "example:tiles", "-o", str(page)]) == 0
    assert "<title>tiles - mi_svbrdf viewer</title>" in page.read_text()
    assert view_cli.main(["view", "example:tiles", "-o", str(mine), "--force"]) == 0  # --force: replaced
    assert viewer.is_viewer_page(mine) and not list(folder.glob(".*tmp*"))
    material = tmp_path / "material"  # the default page beside the maps follows the same rule
    write_material(material, _material("tiles", 16))
    (material / viewer.PAGE_NAME).write_text("my page")
    assert view_cli.main(["view", str(material)]) == 2
    assert "-o/--out (its default): expected a new file" in capsys.readouterr().err
    assert (material / viewer.PAGE_NAME).read_text() == "my page"


def test_cli_view_help_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        view_cli.main(["view", "--help"])
    text = capsys.readouterr().out
    assert "-o/--out" in text and "view.html" in text and "#light=" in text
    assert "view.html" in capture_cli.HELP and "view.html" in optimize_cli.HELP  # the commands that write it
    assert view_cli.main(["view", str(tmp_path / "missing")]) == 2
    assert "MATERIAL: expected a material folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        view_cli.main(["view", "example:tiles", "--light", "1,2"])
    assert "--light" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_default_exposure_keeps_a_bright_sample_below_white_and_titles_name_the_folder_once() -> None:
    """A bright sample (yellow_box's fit: albedo ~0.9, glossy) saturated the page at exposure 0; the default exposure
    is now 0 or lower, so the brightest 1 % of texels stay below white under the default light. The commands' pages
    are titled by their folder and the command, not the command twice ("mi-svbrdf optimize optimize")."""
    import doctest

    from mi_svbrdf.core import maps as M

    assert doctest.testmod(viewer).failed == 0
    bright = M.constant_maps(1, 16, 16, diffuse=0.9, specular=0.3, roughness=0.3)
    dark = M.constant_maps(1, 16, 16, diffuse=0.2, specular=0.04, roughness=0.5)
    stops = viewer.auto_exposure(bright)
    assert viewer.auto_exposure(dark) == 0.0 and stops < 0 and stops * 2 == round(stops * 2)
    light = torch.tensor([[list(viewer.DEFAULT_LIGHT)]])
    view = torch.tensor([[list(viewer.DEFAULT_VIEW)]])
    image = render(bright, light, view, intensity=torch.tensor(viewer.DEFAULT_INTENSITY), distance_falloff=True)
    top = float(torch.quantile(image[0, 0].amax(0).flatten(), viewer.AUTO_QUANTILE))
    assert top > 1.0 and top * 2 ** stops <= viewer.AUTO_WHITE < top * 2 ** (stops + 0.5)
    assert f'"exposure": {stops}' in viewer.viewer_html(bright) and '"exposure": 1.0' in viewer.viewer_html(
        bright, exposure=1.0)
    assert viewer.page_title("optimize", Path("out/optimize")) == "out/optimize (mi-svbrdf optimize)"
