"""The optimisation's re-rendering loss on the texel path as one fused Dr.Jit kernel.

:func:`mi_svbrdf.optim.loop.residual` renders every photo in one kernel
(:mod:`mi_svbrdf.core.render_drjit`), then measures the renders' distance to the target intervals
``[lo, hi]`` with about ten PyTorch operations over ``(N, 3, H, W)`` tensors, each with its
autograd record. Here the render, the interval residual (log-L1 or L2, exactly as
:func:`~mi_svbrdf.optim.loop.residual`) and the sum over photos and channels run in the
same kernel; since a texel's loss depends only on that texel's ten map values, its ten
derivatives are computed with the value (forward-mode cost, one pass, as
``render_drjit``'s fused rendering loss), so the backward pass is a multiply.

Extra (ambient) lights of a photo are added to its flash in the kernel, as
:class:`~mi_svbrdf.optim.forward.TexelForward` renders them: point lights without the
distance falloff or a cone. Only for rectified captures with the Dr.Jit backend;
:meth:`TexelForward.fused_objective <mi_svbrdf.optim.forward.TexelForward.fused_objective>`
returns None otherwise.
"""
from __future__ import annotations

from types import ModuleType

import drjit as dr
import torch

from mi_svbrdf.core.device import check_jit_device, jit_types_of
from mi_svbrdf.core.render import point
from mi_svbrdf.core.render_drjit import (CFG_STRIDE, Flags, _grid, _texel_radiance, grid_sizes, pack_configurations,
                                         reduce_terms)
from mi_svbrdf.core.colour import GAMMA
from mi_svbrdf.plugins.model import DISTRIBUTIONS

#: The log-L1 epsilon, as :data:`mi_svbrdf.optim.loop.LOG_EPS`.
LOG_EPS = 0.01
#: The re-rendering errors (the home of :data:`mi_svbrdf.optim.loop.LOSSES`; the loop's docstring defines them).
LOSSES = ("log_l1", "l2", "l2_display")
#: Smallest value ``l2_display`` encodes (the power's slope is finite there).
DISPLAY_EPS = 1e-4


def _sigmoid(z):
    return dr.rcp(1.0 + dr.exp(-z))


def _maps_of(v: list) -> list:
    """Nine unconstrained variables -> the ten map channels (:func:`~mi_svbrdf.optim.params.to_maps`)."""
    inv = dr.rsqrt(v[0] * v[0] + v[1] * v[1] + 1.0)
    return [v[0] * inv, v[1] * inv, inv] + [_sigmoid(z) for z in v[2:]]


def _tv_term(T: ModuleType, v: list, m: list, sizes: tuple, wx, wy):
    """This texel's share of ``tv_weight * total_variation(maps)``, scaled to the per-texel sum.

    Value: the differences to the right and lower neighbours (each pair once). Gradient: the
    differences to all four neighbours, whose maps are held constant -- exactly this texel's
    partial derivatives of the total variation, so the per-texel gradient stays exact.
    """
    hw, w_u = sizes[0], sizes[1]
    idx = dr.arange(T.UInt32, dr.width(v[0]))
    i = idx // w_u
    j = idx - i * w_u
    value, grad_part = T.Float(0.0), T.Float(0.0)
    neighbours = ((idx + 1, j + 1 < w_u, wx, True), (idx - 1, j > 0, wx, False),
                  (idx + w_u, idx + w_u < hw, wy, True), (idx - w_u, i > 0, wy, False))
    for nb_idx, mask, weight, counted in neighbours:
        nb = _maps_of([dr.gather(T.Float, dr.detach(c), nb_idx, mask) for c in v])
        diff = T.Float(0.0)
        for a, b in zip(m, nb):
            diff += dr.abs(a - b)
        diff = dr.select(mask, diff * weight, 0.0)
        grad_part += diff
        if counted:
            value += dr.detach(diff)
    return value + grad_part - dr.detach(grad_part)


def _display(x):  # noqa: ANN001, ANN202
    """``l2_display``'s encoding, as :func:`mi_svbrdf.optim.loop._display`."""
    return dr.power(dr.clip(x, DISPLAY_EPS, 1.0), 1.0 / GAMMA)


def _objective_terms(T: ModuleType, v: list, data: tuple, static: tuple, ks: tuple[int, ...]) -> list:
    """The objective's per-texel sum over the photos ``ks`` (and the TV, once, with the first group)."""
    lo, hi, cfg, sizes, n_o, eps, extra_cfg, rows_o, tv = data
    flags, kind, extra_of, extra_flags, with_tv = static
    b, x, y = _grid(T, v[0], sizes)
    ch = _maps_of(v)
    total = None
    for k in ks:
        rgb = _texel_radiance(T, ch, cfg, b * n_o + dr.opaque(T.UInt32, k), x, y, flags)
        for row in extra_of[k]:  # this photo's ambient lights
            rgb += _texel_radiance(T, ch, extra_cfg, b * rows_o + dr.opaque(T.UInt32, row), x, y, extra_flags)
        for c, r in enumerate((rgb.x, rgb.y, rgb.z)):
            target = dr.detach(dr.minimum(dr.maximum(r, lo[3 * k + c]), hi[3 * k + c]))
            if kind == "log_l1":
                term = dr.abs(dr.log(dr.maximum(r, 0.0) + eps) - dr.log(target + eps))
            elif kind == "l2_display":
                term = dr.square(_display(r) - _display(target))
            else:
                term = dr.square(r - target)
            total = term if total is None else total + term
    if ks[0] == 0 and with_tv:  # the TV once, with the first group
        total += _tv_term(T, v, ch, sizes, tv[0], tv[1])
    return [total]


@dr.wrap(source="torch", target="drjit")
def _objective_kernel(variables, lo, hi, cfg, shape, flags, kind, eps, tv_scale, extra):
    n_photos, height, width = shape
    extra_cfg, extra_of, extra_flags = extra  # packed extra lights, their rows per photo, their flags
    T = jit_types_of(cfg.array)
    data = ([a.array for a in lo], [a.array for a in hi], cfg.array, grid_sizes(T, height, width),
            dr.opaque(T.UInt32, n_photos), dr.opaque(T.Float, eps), extra_cfg.array,
            dr.opaque(T.UInt32, extra_cfg.shape[0] // CFG_STRIDE),
            (dr.opaque(T.Float, tv_scale[0]), dr.opaque(T.Float, tv_scale[1])))
    static = (flags, kind, extra_of, extra_flags, tv_scale[0] + tv_scale[1] > 0)
    return T.TensorXf(reduce_terms([c.array for c in variables], _objective_terms, None, data, static, n_photos))


class FusedObjective:
    """``variables (1, 9, H, W) ->`` the optimisation's objective (scalar), in one Dr.Jit pass.

    Equal to ``residual(forward(to_maps(v)), lo, hi, kind).mean() + tv_weight *
    total_variation(to_maps(v))`` (:mod:`~mi_svbrdf.optim.loop`) for a
    :class:`~mi_svbrdf.optim.forward.TexelForward`; the parameterisation (:mod:`~mi_svbrdf.optim.params`) is evaluated in the kernel too.

    Args:
        light, view, intensity: ``(1, N, 3)`` light and camera positions, light RGB intensity.
        cone_target, cone_exponent: ``(1, N, 3)`` and ``(1, N)``, or None (no cone).
        lo, hi: ``(N, 3, H, W)`` target intervals (``hi`` may be ``inf``).
        kind: ``"log_l1"``, ``"l2"`` or ``"l2_display"`` (:data:`mi_svbrdf.optim.loop.LOSSES`).
        tv_weight: weight of the total variation, >= 0.
        extra_owner: ``(A,)`` the photo each extra light belongs to (None or A = 0: none).
        extra_light, extra_view, extra_intensity: ``(1, A, 3)`` the extra lights' positions, the
            camera position of their photo, their RGB intensity.
        distribution: the BRDF model the maps are rendered with, ``"ggx"`` or ``"beckmann"``.
    """

    def __init__(self, light: torch.Tensor, view: torch.Tensor, intensity: torch.Tensor,
                 cone_target: torch.Tensor | None, cone_exponent: torch.Tensor | None,
                 lo: torch.Tensor, hi: torch.Tensor, kind: str = "log_l1", tv_weight: float = 0.0,
                 extra_owner: torch.Tensor | None = None, extra_light: torch.Tensor | None = None,
                 extra_view: torch.Tensor | None = None, extra_intensity: torch.Tensor | None = None, *,
                 distribution: str = "ggx") -> None:
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
        if kind not in LOSSES:
            raise ValueError(f"kind: expected one of {LOSSES}, got {kind!r}")
        if not tv_weight >= 0:
            raise ValueError(f"tv_weight: expected >= 0, got {tv_weight!r}")
        n, _, h, w = lo.shape
        if tuple(light.shape) != (1, n, 3) or hi.shape != lo.shape:
            raise ValueError(f"lo, hi, light: expected (N, 3, H, W) twice and (1, N, 3) with N = {n}, "
                             f"got {tuple(lo.shape)}, {tuple(hi.shape)}, {tuple(light.shape)}")
        self.kind, self.shape = kind, (n, h, w)
        self.flags = Flags(True, False, cone_target is not None, True, True, distribution)
        self.cone = (cone_target, cone_exponent)
        self.cfg = pack_configurations(point(light.float()), point(view.float()), intensity.float(),
                                       cone_target, cone_exponent)
        owner = [] if extra_owner is None else [int(k) for k in extra_owner]
        if owner and not (tuple(extra_light.shape) == tuple(extra_view.shape) == tuple(extra_intensity.shape)
                          == (1, len(owner), 3) and all(0 <= k < n for k in owner)):
            raise ValueError(f"extra_owner, extra_light, extra_view, extra_intensity: expected (A,) photo indices "
                             f"in [0, {n}) and (1, A, 3) thrice with A = {len(owner)}, got {owner}, "
                             f"{tuple(extra_light.shape)}, {tuple(extra_view.shape)}, {tuple(extra_intensity.shape)}")
        extra_cfg = (pack_configurations(point(extra_light.float()), point(extra_view.float()),
                                         extra_intensity.float(), None, None) if owner
                     else torch.zeros(CFG_STRIDE, device=lo.device))
        self.extra = (extra_cfg, tuple(tuple(a for a, o in enumerate(owner) if o == k) for k in range(n)),
                      Flags(False, False, False, True, True, distribution))
        self.lo = list(lo.detach().float().reshape(n * 3, h * w).contiguous().unbind(0))
        self.hi = list(hi.detach().float().reshape(n * 3, h * w).contiguous().unbind(0))
        total = n * 3 * h * w  # the per-texel sum is divided by this; TV means are over 10 channels
        self.tv_scale = (tv_weight * total / (10 * h * (w - 1)) if w > 1 else 0.0,
                         tv_weight * total / (10 * (h - 1) * w) if h > 1 else 0.0)

    def update(self, light: torch.Tensor, view: torch.Tensor, intensity: torch.Tensor,
               extra_view: torch.Tensor | None = None, extra_intensity: torch.Tensor | None = None) -> None:
        """New light and camera positions ``(1, N, 3)`` and intensities ``(1, N, 3)`` (self-calibration);
        with extra lights, their photos' camera positions and their intensities ``(1, A, 3)``.
        The extra lights' positions and the cone stay."""
        n = self.shape[0]
        if tuple(light.shape) != (1, n, 3) or tuple(view.shape) != (1, n, 3) or tuple(intensity.shape) != (1, n, 3):
            raise ValueError(f"light, view, intensity: expected (1, {n}, 3) each, got {tuple(light.shape)}, "
                             f"{tuple(view.shape)}, {tuple(intensity.shape)}")
        self.cfg = pack_configurations(point(light.float()), point(view.float()), intensity.float(), *self.cone)
        extra_cfg, of, flags = self.extra
        if extra_view is not None and extra_intensity is not None and extra_view.shape[1]:
            table = extra_cfg.reshape(-1, CFG_STRIDE).clone()
            table[:, 4:7] = extra_view[0].float()
            table[:, 8:11] = extra_intensity[0].float()
            self.extra = (table.reshape(-1), of, flags)

    def __call__(self, variables: torch.Tensor) -> torch.Tensor:
        """The objective of ``variables`` ``(1, 9, H, W)``; differentiable in ``variables``."""
        n, h, w = self.shape
        if variables.dim() != 4 or tuple(variables.shape) != (1, 9, h, w):
            raise ValueError(f"variables: expected shape (1, 9, {h}, {w}), got {tuple(variables.shape)}")
        check_jit_device(variables=variables, lo=self.lo[0], cfg=self.cfg, extra=self.extra[0])
        per_texel = _objective_kernel(list(variables.reshape(9, h * w).unbind(0)), self.lo, self.hi, self.cfg,
                                      self.shape, self.flags, self.kind, LOG_EPS, self.tv_scale, self.extra)
        return per_texel.sum() / (n * 3 * h * w)
