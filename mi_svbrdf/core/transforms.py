"""The networks' input transform (the authors' log encoding) and its inverse.

``log_encode(x) = (log(x + 0.01) - log 0.01) / (log 1.01 - log 0.01)`` maps [0, 1] to [0, 1]
and spreads the dark range; the networks see ``2 y - 1``.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.transforms import log_encode, log_decode
    >>> x = torch.tensor([0.0, 0.25, 1.0])
    >>> log_encode(x)
    tensor([0.0000, 0.7060, 1.0000])
    >>> torch.allclose(log_decode(log_encode(x)), x, atol=1e-6)
    True
"""
from __future__ import annotations

import math

import torch

_LOG_EPS = 0.01
_SCALE = math.log(1.0 + _LOG_EPS) - math.log(_LOG_EPS)


def log_encode(x: torch.Tensor) -> torch.Tensor:
    """``(log(x + 0.01) - log 0.01) / (log 1.01 - log 0.01)``, elementwise."""
    return (torch.log(x + _LOG_EPS) - math.log(_LOG_EPS)) / _SCALE


def log_decode(y: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`log_encode`: ``exp(y (log 1.01 - log 0.01) + log 0.01) - 0.01``."""
    return torch.exp(y * _SCALE + math.log(_LOG_EPS)) - _LOG_EPS


def network_input(x: torch.Tensor) -> torch.Tensor:
    """Linear image in [0, 1] -> the networks' input ``2 log_encode(x) - 1`` in [-1, 1]."""
    return 2.0 * log_encode(x) - 1.0


def network_input_inverse(z: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`network_input`."""
    return log_decode((z + 1.0) * 0.5)
