"""The check for a flash highlight left in the diffuse map (``mi_svbrdf.eval.diffuse_highlight``) and capture's
warning: it fires on a pale spot the photo did not measure, not on a pattern the photo measured elsewhere, and
capture says it in the terminal and in summary.json's notes (its measurements: docs/benchmarks/diffuse_highlight.md)."""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mi_svbrdf import cli
from mi_svbrdf.assets import EXAMPLE_FLASH
from mi_svbrdf.eval.diffuse_highlight import VISIBLE_STEP, highlight_in_diffuse
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode
from mi_svbrdf.nets.inference import load_inputs

ROOT = Path(__file__).resolve().parent.parent
S = 128


def _maps(diffuse: torch.Tensor | float) -> torch.Tensor:
    """``(1, 10, S, S)``: flat, roughness 0.3, specular 0.04, the given diffuse albedo (grey)."""
    maps = torch.zeros(1, 10, S, S)
    maps[:, 2], maps[:, 6], maps[:, 7:10] = 1.0, 0.3, 0.04
    maps[:, 3:6] = diffuse if isinstance(diffuse, float) else diffuse.expand(1, 3, S, S)
    return maps


def _disc(cx: float, cy: float, r: float) -> torch.Tensor:
    """``(S, S)`` bool disc, centre and radius in pixels."""
    ys, xs = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= r ** 2


def test_a_pale_disc_where_the_photo_is_clipped_is_a_highlight_left_in_the_diffuse_map() -> None:
    clipped = _disc(100, 30, 10)
    photo = torch.where(clipped, 1.0, 0.03).expand(3, S, S).clone()
    found = highlight_in_diffuse(photo, _maps(torch.where(clipped, 0.7, 0.02)))
    assert found.left and found.excess > VISIBLE_STEP and found.elsewhere < 0.05
    assert found.centre[0] > 0 and found.centre[1] > 0  # right of and above the centre (x right, y up)
    note = found.note(n_photos=1)
    assert note.startswith("warning: the flash's highlight is left in the diffuse map") and "top right" in note
    assert "mi-svbrdf optimize" in note and "3 or more photos" in note
    assert "3 or more photos" not in found.note(n_photos=3)  # with several photos: optimize
    assert json.dumps(found.summary())  # JSON-ready
    # the same photo, the net having kept the diffuse map dark: nothing to say
    kept = highlight_in_diffuse(photo, _maps(0.02))
    assert not kept.left and abs(kept.contrast) < 0.01 and kept.note() is None


def test_a_clipped_fleck_like_the_flecks_the_photo_measured_is_the_material() -> None:
    """White flecks on a dark fabric: the clipped one is no brighter in the diffuse map than those measured."""
    flecks = torch.zeros(S, S, dtype=torch.bool)
    for cx in range(12, S, 24):
        for cy in range(12, S, 24):
            flecks |= _disc(cx, cy, 4)
    diffuse = torch.where(flecks, 0.8, 0.03)
    photo = (diffuse * 0.9).expand(3, S, S).clone()
    photo[:, _disc(60, 60, 4)] = 1.0  # the fleck under the flash clips
    found = highlight_in_diffuse(photo, _maps(diffuse))
    assert found.contrast > 0.5 and found.elsewhere > 0.5 and not found.left


def test_nothing_to_check_without_a_clipped_spot_or_without_a_measured_place() -> None:
    none = highlight_in_diffuse(torch.full((3, S, S), 0.5), _maps(0.5))
    assert not none.left and none.contrast is None and "no clipped" in none.why
    everywhere = torch.ones(3, S, S)
    everywhere[:, :4, :4] = 0.2
    full = highlight_in_diffuse(everywhere, _maps(0.5))
    assert not full.left and "nothing measured" in full.why
    # the bundled example photo has no clipped pixel: never warned, whatever the maps
    photos, _ = load_inputs(EXAMPLE_FLASH, size=256)
    assert "no clipped" in highlight_in_diffuse(photos[0, 0], _maps(0.9)).why


@pytest.mark.parametrize("photo, maps, match", [
    (torch.zeros(1, 3, S, S), torch.zeros(1, 10, S, S), "photo: expected shape"),
    (torch.zeros(3, S, S), torch.zeros(2, 10, S, S), "one material"),
    (torch.zeros(3, S, S), torch.zeros(9, S, S), "maps: expected shape"),
    (torch.zeros(3, 32, 32), torch.zeros(10, 32, 32), "at least 64"),
])
def test_bad_shapes_are_refused_in_one_line(photo: torch.Tensor, maps: torch.Tensor, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        highlight_in_diffuse(photo, maps)


def _bench():
    spec = importlib.util.spec_from_file_location("bench_diffuse_highlight",
                                                  ROOT / "benchmarks" / "bench_diffuse_highlight.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_capture_warns_when_the_single_net_paints_the_highlight_into_the_diffuse_map(tmp_path: Path, capsys) -> None:
    """A simulated dark glossy leather of the benchmark, over-exposed: the single net (alone, for speed) leaves the
    highlight in diffuse.png; capture says so on stderr and in summary.json's notes, with what to do."""
    from mi_svbrdf.core.flash import FlashSetup, render_flash

    bench = _bench()
    photo = render_flash(bench.tufted_leather(*bench.WARNED_CASE[:3], shift=(0.1, 0.05), seed=bench.WARNED_CASE[3]),
                         FlashSetup(intensity=13.0 * bench.WARNED_CASE[4]))[0]
    path = tmp_path / "leather.png"
    write_image(path, srgb_encode(photo.permute(1, 2, 0).numpy().astype(np.float32)), 8, srgb=True)
    assert cli.main(["capture", str(path), "--symmetries", "1", "--frames", "0", "-o", str(tmp_path / "cap")]) == 0
    err = capsys.readouterr().err
    assert "mi-svbrdf capture: warning: the flash's highlight is left in the diffuse map" in err
    notes = json.loads((tmp_path / "cap" / "summary.json").read_text())["notes"]
    assert any(n.startswith("warning: the flash's highlight is left") and "mi-svbrdf optimize" in n for n in notes)
