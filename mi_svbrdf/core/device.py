"""Devices: the one parser of ``--device`` and the Mitsuba variant that goes with a device.

Tensors flow on the caller's device; a command's ``--device`` (``cpu``, ``cuda``, ``cuda:N``) is
parsed here once. Dr.Jit's backend follows the tensors, never the active Mitsuba variant: ``dr.wrap``
hands a kernel LLVM arrays for CPU tensors and CUDA arrays for CUDA tensors, and the kernels build
their own arrays from :func:`jit_types_of` (the module of its inputs' arrays: ``drjit.llvm.ad`` or
``drjit.cuda.ad``). Only Mitsuba's own scene rendering needs a variant: :func:`variant_for` names the
one of a device (``llvm_ad_rgb`` / ``cuda_ad_rgb``), :func:`mi_svbrdf.variant.scene_variant` enters it.

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

import importlib
import re
from types import ModuleType

import torch

from mi_svbrdf.variant import variant_for

__all__ = ["DEVICE_HELP", "check_jit_device", "jit_types_of", "resolve_device", "variant_for"]

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


#: The Dr.Jit AD module whose arrays live on each torch device type.
_JIT_MODULES = {"cpu": "drjit.llvm.ad", "cuda": "drjit.cuda.ad"}


def jit_types_of(array: object) -> ModuleType:
    """The Dr.Jit AD module of a Dr.Jit ``array`` (its backend: ``drjit.llvm.ad`` or ``drjit.cuda.ad``).

    Kernels called through ``dr.wrap`` use it to make their own arrays on the backend of their inputs.
    """
    import drjit as dr

    backend = dr.backend_v(array)
    if backend == dr.JitBackend.CUDA:
        return importlib.import_module("drjit.cuda.ad")
    if backend == dr.JitBackend.LLVM:
        return importlib.import_module("drjit.llvm.ad")
    raise ValueError(f"array: expected a Dr.Jit array of the LLVM or CUDA backend, got {type(array).__name__}")


def check_jit_device(**tensors: torch.Tensor) -> torch.device:
    """The common device of ``tensors`` (keyword = argument name), one Dr.Jit has a backend for.

    Raises:
        ValueError: the tensors are on different devices, or on a device other than cpu or cuda.
    """
    (first, tensor), *rest = tensors.items()
    for name, other in rest:
        if other.device != tensor.device:
            raise ValueError(f"{name}: expected a tensor on {first}'s device {tensor.device}, got {other.device}")
    if tensor.device.type not in _JIT_MODULES:
        raise ValueError(f"{first}: expected tensors on cpu or cuda (Dr.Jit's LLVM and CUDA backends), "
                         f"got {tensor.device}")
    return tensor.device
