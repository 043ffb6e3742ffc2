"""A non-editable wheel install registers the plugins and loads and renders every scene."""
from __future__ import annotations

import pathlib
import subprocess
import sys
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent

CHECK = r"""
import pathlib, sys
import mitsuba as mi, numpy as np
import mi_svbrdf
from mi_svbrdf import scenes
root = pathlib.Path(sys.argv[1])
assert pathlib.Path(mi_svbrdf.__file__).resolve().is_relative_to(root), mi_svbrdf.__file__
assert pathlib.Path(scenes.__file__).resolve().is_relative_to(root), scenes.__file__
import mi_svbrdf.cli, mi_svbrdf.eval.report, mi_svbrdf.data.dataset.output  # every layer imports
bsdf = mi.load_dict({"type": "svbrdf_ggx"})
assert "svbrdf" in str(bsdf).lower() or bsdf is not None
names = scenes.scene_names()
assert {"flash_capture", "multiview_capture", "ambient_capture", "relight"} <= set(names), names
for name in names:
    assert scenes.scene_path(name).resolve().is_relative_to(root)
    image = np.asarray(mi.render(scenes.load_scene(name, res=8, spp=2)))
    assert np.isfinite(image).all() and image.mean() > 0, name
print("ok", mi.variant(), names)
"""


@pytest.mark.slow
def test_wheel_install_renders_every_scene(tmp_path):
    wheel_dir = tmp_path / "wheel"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(wheel_dir), str(ROOT)], check=True, capture_output=True, text=True)
    (wheel,) = wheel_dir.glob("mi_svbrdf-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:  # a pure-Python wheel installs by unpacking
        names = zf.namelist()
        zf.extractall(site)
    for expected in ("mi_svbrdf/plugins/model.py", "mi_svbrdf/scenes/flash_capture.xml",
                     "mi_svbrdf/scenes/textures/diffuse.exr", "mi_svbrdf/assets/example_flash.png",
                     "mi_svbrdf/weights/manifest.json", "mi_svbrdf/weights/single_compact.pt.zz"):
        assert expected in names, f"{expected} missing from the wheel"
    # every module of every layer ships (a subpackage left out of pyproject's list would not)
    sources = {f"mi_svbrdf/{p.relative_to(ROOT / 'mi_svbrdf').as_posix()}" for p in (ROOT / "mi_svbrdf").rglob("*.py")}
    missing = sorted(sources - set(names))
    assert not missing, f"modules missing from the wheel: {missing}"
    env = {"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin", "HOME": str(pathlib.Path.home())}
    res = subprocess.run([sys.executable, "-c", CHECK, str(site)], cwd=tmp_path, env=env,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.startswith("ok")
