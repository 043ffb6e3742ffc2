"""The thesis dataset's strip PNG: ``input(s) | normal | diffuse | roughness | specular``.

Square panels side by side, the panel size being the image height. 2018 images hold one input,
2019 test images ten, 2019 training materials none: the number of inputs is ``width / height - 4``.
As in the authors' code, albedo panels are linear as stored (no gamma decoding), normals decode
as ``2 v - 1`` (renormalised here, a zero vector becoming ``(0, 0, 1)``; the 2018 code does not
renormalise, the 2019 renderer does), roughness is one grey value (the 3 channels are averaged)
and input panels are returned as stored (gamma handling of photos is the caller's).

Some public copies have 288-px panels that the authors' training crops to 256 at random. Here the
crop is deterministic: centred by default, or at ``offset``, the same window in every panel so
inputs and maps stay aligned.

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.core import maps as M
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "material.png"
    >>> write_strip(path, M.constant_maps(1, 8, 8), inputs=torch.zeros(1, 3, 8, 8))
    >>> inputs, maps = read_strip(path, crop=None)
    >>> tuple(inputs.shape), tuple(maps.shape)
    ((1, 3, 8, 8), (1, 10, 8, 8))
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.core.maps import MAP_NAMES, NUM_CHANNELS, SLICES
from mi_svbrdf.io.image_io import read_image, select_channels, write_image
from mi_svbrdf.io.material_io import decode_normal, encode_normal, single_material

#: Map panels after the inputs, in order.
MAP_PANELS = MAP_NAMES


def read_strip(path: str | os.PathLike, panel: int | None = None, crop: int | None = 256,
               offset: tuple[int, int] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Read a strip PNG.

    Args:
        path: strip image (8- or 16-bit RGB PNG; an opaque alpha is ignored).
        panel: expected panel size; ``None`` takes the image height.
        crop: crop every panel to ``crop x crop`` (no-op if equal to the panel); ``None`` keeps
            panels whole.
        offset: ``(top, left)`` of the crop window inside a panel; ``None`` centres it.

    Returns:
        ``(inputs, maps)``: inputs ``(N, 3, S, S)`` float32 in [0, 1] as stored (``N`` may be 0)
        and maps ``(1, 10, S, S)``, ``S`` the panel or crop size.

    Raises:
        ValueError: naming the file: not RGB, width not a multiple of the panel size, fewer than
            4 panels, crop larger than the panel or outside it.
    """
    path = Path(path)
    image, _ = read_image(path)
    image = select_channels(image, 3, path)
    height, width = image.shape[:2]
    if panel is not None and panel != height:
        raise ValueError(f"{path}: expected square panels of {panel} px (the image height), "
                         f"got height {height}")
    panel = height
    if width % panel != 0 or width // panel < len(MAP_PANELS):
        raise ValueError(f"{path}: expected a width that is a multiple (>= 4) of the panel size {panel} "
                         f"(inputs | normal | diffuse | roughness | specular), got width {width}")
    count = width // panel
    panels = image.reshape(panel, count, panel, 3).transpose(1, 0, 2, 3)  # (count, S, S, 3)
    if crop is None and offset is not None:
        raise ValueError(f"offset: expected None when crop is None, got {offset}")
    if crop is not None:
        if not 0 < crop <= panel:
            raise ValueError(f"{path}: expected crop in 1..{panel} (the panel size; "
                             f"crop=None keeps panels whole), got {crop}")
        top, left = offset if offset is not None else ((panel - crop) // 2,) * 2
        if not (0 <= top <= panel - crop and 0 <= left <= panel - crop):
            raise ValueError(f"offset: expected (top, left) in [0, {panel - crop}] for a {crop}-px crop of "
                             f"{panel}-px panels, got {offset}")
        panels = panels[:, top:top + crop, left:left + crop]
    num_inputs = count - len(MAP_PANELS)
    normal, diffuse, rough, specular = panels[num_inputs:]
    rough = rough.mean(axis=2, keepdims=True)
    maps = np.concatenate([decode_normal(normal), diffuse, rough, specular], axis=2)
    inputs = torch.from_numpy(np.ascontiguousarray(panels[:num_inputs].transpose(0, 3, 1, 2)))
    return inputs, torch.from_numpy(maps).permute(2, 0, 1).unsqueeze(0).contiguous()


def write_strip(path: str | os.PathLike, maps: torch.Tensor, inputs: torch.Tensor | None = None) -> None:
    """Write maps (and inputs) as an 8-bit strip PNG, atomically.

    Args:
        path: target ``.png`` file.
        maps: ``(1, 10, S, S)`` or ``(10, S, S)`` canonical maps (square).
        inputs: ``None``, ``(3, S, S)`` or ``(N, 3, S, S)`` images in [0, 1], written as they are.

    Values are clipped to [0, 1]; albedos are stored linear, normals as ``(n + 1) / 2``,
    roughness as 3 equal channels.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: expected a .png file name for a strip, got suffix {path.suffix!r}")
    data = single_material(maps)
    size = data.shape[0]
    if data.shape[1] != size:
        raise ValueError(f"maps: expected square maps (1, {NUM_CHANNELS}, S, S), "
                         f"got {size}x{data.shape[1]} (H x W)")
    panels = []
    if inputs is not None:
        if inputs.dim() == 3:
            inputs = inputs.unsqueeze(0)
        if inputs.dim() != 4 or tuple(inputs.shape[1:]) != (3, size, size):
            raise ValueError(f"inputs: expected shape (N, 3, {size}, {size}) like the maps, "
                             f"got {tuple(inputs.shape)}")
        if not torch.isfinite(inputs).all():
            raise ValueError("inputs: expected finite values, got NaN or Inf")
        panels += list(inputs.detach().to("cpu", torch.float32).permute(0, 2, 3, 1).numpy())
    panels += [encode_normal(data[:, :, SLICES["normal"]]), data[:, :, SLICES["diffuse"]],
               np.repeat(data[:, :, SLICES["roughness"]], 3, axis=2), data[:, :, SLICES["specular"]]]
    write_image(path, np.concatenate(panels, axis=1), bit_depth=8)
