"""A texel window of a rectified capture (:meth:`CaptureSpec.window`) renders exactly the crop of the whole capture."""
from __future__ import annotations

import pytest
import torch

from mi_svbrdf.data.procedural import generate
from mi_svbrdf.io.calibrated_photos import CaptureSpec, window_texels
from mi_svbrdf.optim.forward import TexelForward


def _spec() -> CaptureSpec:
    """Three photos: a flash at the lens, a flash with a cone off the lens with an ambient light, an oblique view."""
    def image(k: int, camera: list[float], light: dict, extra: list[dict] | None = None) -> dict:
        d = {"file": f"{k}.png", "encoding": "linear_exr", "rectified": True,
             "camera": {"position": camera, "fov_deg": 50}, "light": light}
        if extra:
            d["extra_lights"] = extra
        return d

    return CaptureSpec.from_dict({"version": 1, "images": [
        image(0, [0.1, -0.2, 2.4], {"position": [0.1, -0.2, 2.4], "intensity": [6.0, 5.5, 5.0], "cone": None}),
        image(1, [1.2, 0.4, 1.9], {"position": [1.3, 0.5, 1.8], "intensity": [4.0, 4.0, 4.2],
                                   "cone": {"target": [0.2, 0.1, 0.0], "exponent": 6.0}},
              [{"position": [-3.0, 2.0, 6.0], "intensity": [0.05, 0.06, 0.07]}]),
        image(2, [-1.5, -1.0, 1.2], {"position": [-1.4, -1.1, 1.3], "intensity": [3.0, 3.0, 3.0], "cone": None}),
    ]})


@pytest.mark.parametrize("backend", ["torch", "mitsuba"])
@pytest.mark.parametrize("window, size, step", [((5, 9, 16, 16), (40, 40), 1), ((0, 0, 40, 40), (40, 40), 1),
                                                ((24, 24, 16, 16), (40, 40), 1), ((3, 6, 12, 16), (30, 40), 1),
                                                ((0, 0, 40, 40), (40, 40), 2), ((4, 8, 24, 24), (40, 40), 3),
                                                ((3, 6, 12, 16), (30, 40), 4)])
def test_a_window_renders_the_crop_of_the_whole(backend: str, window: tuple[int, int, int, int],
                                                size: tuple[int, int], step: int) -> None:
    """A window, and every ``step``-th texel of it, renders exactly those texels of the whole capture's renders."""
    spec = _spec()
    maps = generate("tiles", 3, max(size))[None][..., :size[0], :size[1]].contiguous()
    whole = TexelForward(spec, size, backend)(maps)
    crop = window_texels(maps, *window, step).contiguous()
    part = TexelForward(spec.window(*window, size, step), tuple(crop.shape[-2:]), backend)(crop)
    expected = window_texels(whole, *window, step)
    assert part.shape == expected.shape
    assert float((part - expected).abs().max()) <= 1e-5 * float(expected.abs().max()) + 1e-7


def test_the_window_s_irradiance_is_the_crop_of_the_whole() -> None:
    """The optimiser's start divides a photo by the flat irradiance: the window's is the crop of the whole's."""
    spec = _spec()
    whole = TexelForward(spec, (32, 32), "torch").irradiance()
    part = TexelForward(spec.window(8, 16, 16, 16, (32, 32)), (16, 16), "torch").irradiance()
    assert torch.allclose(part, whole[..., 8:24, 16:32], rtol=1e-5, atol=1e-8)


def test_a_window_outside_the_photos_or_of_another_aspect_is_refused() -> None:
    spec = _spec()
    with pytest.raises(ValueError, match="inside the 32x32 photos"):
        spec.window(20, 0, 16, 16, (32, 32))
    with pytest.raises(ValueError, match="aspect 32:32"):
        spec.window(0, 0, 8, 16, (32, 32))
    with pytest.raises(ValueError, match="step: expected an int >= 1 dividing the window's 12x12"):
        spec.window(0, 0, 12, 12, (32, 32), step=5)
    flat = CaptureSpec.from_dict({"version": 1, "images": [dict(spec.to_dict()["images"][0], rectified=False)]})
    with pytest.raises(ValueError, match="rectified photos"):
        flat.window(0, 0, 8, 8, (16, 16))
