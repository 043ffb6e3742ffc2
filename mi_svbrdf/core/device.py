"""Devices: the one parser of ``--device`` and the Mitsuba variant that goes with a device.

Tensors flow on the caller's device; a command's ``--device`` (``cpu``, ``cuda``, ``cuda:N``) is
parsed here once. Dr.Jit's backend follows the device: CPU tensors go through ``llvm_ad_rgb``,
CUDA tensors through ``cuda_ad_rgb`` (:func:`variant_for`).

Examples:
    >>> resolve_device("cpu")
    device(type='cpu')
    >>> resolve_device("tpu")
    Traceback (most recent call last):
    ...
    ValueError: device: expected cpu, cuda or cuda:N, got 'tpu'
    >>> variant_for(resolve_device("cpu"))
    'llvm_ad_rgb'
"""
from __future__ import annotations

import re

import torch

__all__ = ["DEVICE_HELP", "resolve_device", "variant_for"]

#: Help text of every command's ``--device`` option.
DEVICE_HELP = "cpu, cuda or cuda:N (default: cpu)"
_PATTERN = re.compile(r"^(cpu|cuda(:\d+)?)$")


def resolve_device(spec: str | torch.device | None = None) -> torch.device:
    """``spec`` (``"cpu"``, ``"cuda"``, ``"cuda:N"``, a ``torch.device`` or None = cpu) as a usable device.

    Raises:
        ValueError: an unknown device, or CUDA asked for where no CUDA device exists (or index N
            beyond the devices present).
    """
    if spec is None:
        return torch.device("cpu")
    text = str(spec)
    if not _PATTERN.match(text):
        raise ValueError(f"device: expected cpu, cuda or cuda:N, got {text!r}")
    device = torch.device(text)
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ValueError(f"device: expected cpu (this machine has no CUDA device), got {text!r}")
        if device.index is not None and device.index >= count:
            raise ValueError(f"device: expected cuda:0 .. cuda:{count - 1}, got {text!r}")
    return device


def variant_for(device: torch.device) -> str:
    """The Mitsuba variant whose Dr.Jit backend works on tensors of ``device``."""
    return "cuda_ad_rgb" if device.type == "cuda" else "llvm_ad_rgb"
