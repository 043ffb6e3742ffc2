"""Devices: the one parser of ``--device`` and the Mitsuba variant that goes with a device.

Tensors flow on the caller's device; a command's ``--device`` (``cpu``, ``cuda``, ``cuda:N``) is
parsed here once. Dr.Jit's backend follows the tensors, never the active Mitsuba variant: ``dr.wrap``
hands a kernel LLVM arrays for CPU tensors and CUDA arrays for CUDA tensors, and the kernels build
their own arrays from :func:`jit_types_of` (the module of its inputs' arrays: ``drjit.llvm.ad`` or
``drjit.cuda.ad``). Only Mitsuba's own scene rendering needs a variant: :func:`variant_for` names the
one of a device (``llvm_ad_rgb`` / ``cuda_ad_rgb``), :func:`mi_svbrdf.variant.scene_variant` enters it.

Code written for the CPU runs on another device inside :func:`made_on`: tensor factories make their
tensors there, and random draws from a (CPU) ``torch.Generator`` are drawn on the generator's device
and moved, so a seed gives the same numbers on every device.

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

import contextlib
import importlib
import re
from collections.abc import Iterator
from types import ModuleType

import torch
from torch.overrides import TorchFunctionMode

from mi_svbrdf.variant import variant_for

__all__ = ["DEVICE_HELP", "DEVICE_PATTERN", "check_jit_device", "jit_types_for", "jit_types_of", "made_on",
           "RELEASE_TEXELS", "release_memory",
           "resolve_device", "to_jit", "variant_for"]

#: Help text of every command's ``--device`` option.
DEVICE_HELP = "cpu, cuda or cuda:N (default: cpu)"
#: The device names every ``--device`` and ``device`` setting accepts.
DEVICE_PATTERN = re.compile(r"^(cpu|cuda(:\d+)?)$")


def resolve_device(spec: str | torch.device | None = None) -> torch.device:
    """``spec`` (``"cpu"``, ``"cuda"``, ``"cuda:N"``, a ``torch.device`` or None = cpu) as a usable device.

    Raises:
        ValueError: an unknown device, or CUDA asked for where no CUDA device exists (or index N
            beyond the devices present).
    """
    if spec is None:
        return torch.device("cpu")
    text = str(spec)
    if not DEVICE_PATTERN.match(text):
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


_JIT_TYPES: dict[str, ModuleType] = {}


def jit_types_for(device: torch.device) -> ModuleType:
    """The Dr.Jit AD module whose arrays live on ``device`` (cpu: ``drjit.llvm.ad``, cuda: ``drjit.cuda.ad``)."""
    module = _JIT_TYPES.get(device.type)
    if module is None:
        if device.type not in _JIT_MODULES:
            raise ValueError(f"device: expected cpu or cuda (Dr.Jit's LLVM and CUDA backends), got {device}")
        module = _JIT_TYPES[device.type] = importlib.import_module(_JIT_MODULES[device.type])
    return module


def to_jit(tensor: torch.Tensor) -> object:
    """``tensor`` as a flat Dr.Jit ``Float`` array of its device's backend, sharing its memory (DLPack, no copy).

    The tensor is made contiguous float32 first (a copy only where it is not), and is flattened. The array keeps
    the memory alive; writing to the tensor afterwards changes what the array reads, so hand over tensors that
    stay as they are while the array is in use.

    A CPU tensor goes through its NumPy view: Dr.Jit converts a torch tensor by calling its Python
    ``__dlpack__``, and when that raises (a Ctrl-C lands there) it clears the error and converts another way,
    losing the interrupt; NumPy's ``__dlpack__`` runs no Python code.
    """
    if tensor.dtype != torch.float32 or tensor.dim() != 1 or not tensor.is_contiguous():
        tensor = tensor.detach().to(torch.float32).contiguous().reshape(-1)
    tensor = tensor.detach()
    return jit_types_for(tensor.device).TensorXf(tensor.numpy() if tensor.device.type == "cpu" else tensor).array


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


#: Draws that take their shape (and ``device``) as arguments, and draws from input tensors.
_SHAPED_DRAWS = (torch.rand, torch.randn, torch.randint, torch.randperm)
_INPUT_DRAWS = (torch.normal, torch.bernoulli, torch.multinomial, torch.poisson)


class _GeneratorDraws(TorchFunctionMode):
    """Random draws with a ``generator`` on another device than ``device``: made on the
    generator's device, then moved to ``device`` (other calls pass through)."""

    def __init__(self, device: torch.device) -> None:
        super().__init__()
        self.device = device

    def __torch_function__(self, func, types, args=(), kwargs=None):  # noqa: ANN001, ANN204
        kwargs = kwargs or {}
        gen = kwargs.get("generator")
        if gen is None or gen.device == self.device:
            return func(*args, **kwargs)
        if func in _SHAPED_DRAWS:
            return func(*args, **{**kwargs, "device": gen.device}).to(self.device)
        if func in _INPUT_DRAWS:
            args = tuple(a.to(gen.device) if isinstance(a, torch.Tensor) else a for a in args)
            return func(*args, **kwargs).to(self.device)
        return func(*args, **kwargs)


@contextlib.contextmanager
def made_on(device: str | torch.device) -> Iterator[torch.device]:
    """Run CPU-written tensor code on ``device``: factories (``torch.zeros``, ``torch.tensor``, ...)
    make their tensors there, and draws from a generator on another device (``torch.rand(...,
    generator=g)`` with a CPU ``g``) are drawn there and moved, so the numbers do not depend on
    ``device``. On the CPU (or for ``device`` None) it changes nothing.

    Tensors that come from elsewhere (files, NumPy) stay where they are: move them with ``.to``.

    Examples:
        >>> g = torch.Generator().manual_seed(0)
        >>> with made_on("meta") as dev:
        ...     x, z = torch.rand(3, generator=g), torch.zeros(2)
        >>> dev, x.device, z.device
        (device(type='meta'), device(type='meta'), device(type='meta'))
    """
    device = torch.device("cpu") if device is None else torch.device(device)
    if device.type == "cpu":
        yield device
        return
    with device, _GeneratorDraws(device):
        yield device


#: Arrays of at least this many texels are worth handing back between a fit's phases (:func:`release_memory`): at
#: 1024^2 Dr.Jit's cache of one phase's freed blocks is a few hundred MB the next phase (another size, or a scorer's
#: renders beside the objective's) does not reuse.
RELEASE_TEXELS = 1 << 20


def release_memory(collect: bool = True) -> None:
    """Hand freed memory back to the system: Dr.Jit's cache of freed blocks (it keeps them for arrays of the same
    size, which a fit at the next level or a new set of renders never asks for) and the C heap's free pages
    (glibc's ``malloc_trim``; about 1.7 GB after a 12 MP set of renders). ``collect``: Python's garbage collection
    first (False on a hot path, e.g. every few steps of a fit: the caches only)."""
    import ctypes
    import gc

    import drjit as dr

    if collect:
        gc.collect()
    dr.flush_malloc_cache()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: the heap keeps its pages
        pass
