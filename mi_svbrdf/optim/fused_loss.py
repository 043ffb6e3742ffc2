"""The optimisation's re-rendering loss on the texel path as one fused Dr.Jit kernel.

:func:`mi_svbrdf.optim.loop.residual` renders every photo in one kernel
(:mod:`mi_svbrdf.core.render_drjit`), then measures the renders' distance to the target intervals
``[lo, hi]`` with about ten PyTorch operations over ``(N, 3, H, W)`` tensors, each with its
autograd record. Here the render, the interval residual (log-L1 or L2, exactly as
:func:`~mi_svbrdf.optim.loop.residual`) and the sum over photos and channels run in the
same kernel; since a texel's loss depends only on that texel's ten map values, its ten
derivatives are computed with the value (forward-mode cost, one pass, as
``render_drjit``'s fused rendering loss), so the backward pass is a multiply.

The kernel is called without ``dr.wrap``: the fit's constant inputs (bounds, lights, cameras, sizes) are
converted to Dr.Jit arrays once per objective (one per fit run; again after :meth:`FusedObjective.update` or on
another device), the variables cross as nine views of one tensor (DLPack, no copy) and the value with the gradient
come back as one array (the nine derivatives in the variables' layout, then each texel's share of the value,
written in the last launch); the launches are recorded once per size and replayed (``dr.freeze``). The total
variation reads its neighbours' maps from one small launch before the photos' launches instead of mapping each
neighbour's variables again.

What a launch costs is its arithmetic per texel and photo, so: each photo's light and camera are read as one-value
arrays (a scalar load per vector of texels, not a gather per lane); each photo's derivatives are taken right after
its value, with respect to the ten map channels, and carried to the variables once per launch
(:func:`_maps_gradient`), so the kernel does not keep every photo's intermediate values for one backward pass
after all of them; the log-L1 residual takes one logarithm, not two (:func:`_log_l1`).

Extra (ambient) lights of a photo are added to its flash in the kernel, as
:class:`~mi_svbrdf.optim.forward.TexelForward` renders them: point lights without the
distance falloff or a cone. Only for rectified captures with the Dr.Jit backend;
:meth:`TexelForward.fused_objective <mi_svbrdf.optim.forward.TexelForward.fused_objective>`
returns None otherwise.
"""
from __future__ import annotations

from types import ModuleType
from typing import Any

import drjit as dr
import torch

from mi_svbrdf.core.device import check_jit_device, jit_types_for, jit_types_of, to_jit
from mi_svbrdf.core.render import point
from mi_svbrdf.core.render_drjit import (CFG_STRIDE, Flags, _frozen, _grid, _groups, _texel_radiance, abs_log_ratio,
                                         channel_major, grid_sizes, pack_configurations, row_fields)
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


def _tv_term(T: ModuleType, m: list, neighbours: list, sizes: tuple, wx, wy):
    """This texel's share of ``tv_weight * total_variation(maps)``, scaled to the per-texel sum.

    Value: the differences to the right and lower neighbours (each pair once). Gradient: the
    differences to all four neighbours, whose maps (``neighbours``: the ten channels of every texel,
    evaluated before, without gradients) are held constant -- exactly this texel's partial
    derivatives of the total variation, so the per-texel gradient stays exact.
    """
    hw, w_u = sizes[0], sizes[1]
    idx = dr.arange(T.UInt32, dr.width(m[0]))
    i = idx // w_u
    j = idx - i * w_u
    value, grad_part = T.Float(0.0), T.Float(0.0)
    sides = ((idx + 1, j + 1 < w_u, wx, True), (idx - 1, j > 0, wx, False),
             (idx + w_u, idx + w_u < hw, wy, True), (idx - w_u, i > 0, wy, False))
    for nb_idx, mask, weight, counted in sides:
        diff = T.Float(0.0)
        for a, c in zip(m, neighbours):
            diff += dr.abs(a - dr.gather(T.Float, c, nb_idx, mask))
        diff = dr.select(mask, diff * weight, 0.0)
        grad_part += diff
        if counted:
            value += dr.detach(diff)
    return value + grad_part - dr.detach(grad_part)


def _log_l1(r, target, eps):
    """``|log(max(r, 0) + eps) - log(target + eps)|`` (``target`` constant) with one logarithm
    (:func:`~mi_svbrdf.core.render_drjit.abs_log_ratio`)."""
    return abs_log_ratio(dr.maximum(r, 0.0) + eps, target + eps)


def _display(x):  # noqa: ANN001, ANN202
    """``l2_display``'s encoding, as :func:`mi_svbrdf.optim.loop._display`."""
    return dr.power(dr.clip(x, DISPLAY_EPS, 1.0), 1.0 / GAMMA)


def _photo_term(T: ModuleType, ch: list, data: tuple, static: tuple, k: int, x, y):
    """Photo ``k``'s per-texel residual, summed over its channels, of the maps ``ch``."""
    lo, hi, fields, _, eps, extra_fields, _, _, _ = data
    flags, kind, extra_of, extra_flags, _, _ = static
    rgb = _texel_radiance(T, ch, fields[k], None, x, y, flags)
    for row in extra_of[k]:  # this photo's ambient lights
        rgb += _texel_radiance(T, ch, extra_fields[row], None, x, y, extra_flags)
    total = None
    for c, r in enumerate((rgb.x, rgb.y, rgb.z)):
        target = dr.detach(dr.minimum(dr.maximum(r, lo[3 * k + c]), hi[3 * k + c]))
        if kind == "log_l1":
            term = _log_l1(r, target, eps)
        elif kind == "l2_display":
            term = dr.square(_display(r) - _display(target))
        else:
            term = dr.square(r - target)
        total = term if total is None else total + term
    return total


def _maps_gradient(v: list, maps: list, grads: list) -> list:
    """The nine variables' derivatives from the ten map channels' (``grads``): the chain rule of
    :func:`_maps_of` written out (the normal's normalisation, ``(g - n (n . g')) / |u|`` for ``u = (v0, v1, 1)``,
    and the sigmoids' ``exp(-z) s^2``), as reverse-mode differentiation of :func:`_maps_of` computes it."""
    inv = maps[2]
    k = inv * inv * inv * (grads[0] * v[0] + grads[1] * v[1] + grads[2])
    out = [inv * grads[0] - v[0] * k, inv * grads[1] - v[1] * k]
    for c in range(7):
        s = maps[3 + c]
        out.append(grads[3 + c] * (s * s) * dr.exp(-v[2 + c]))
    return out


def _group_terms(T: ModuleType, variables: list, data: tuple, static: tuple, ks: tuple[int, ...],
                 neighbours: list, need_grad: bool) -> tuple:
    """The objective's per-texel sum over the photos ``ks`` (and the TV and the prior's terms, once, with the first
    group), and with ``need_grad`` its nine per-texel derivatives (else an empty list).

    The derivatives are taken term by term, each photo's right after its value, with respect to the ten map
    channels (the chain rule to the variables once, :func:`_maps_gradient`): the kernel then computes a photo's
    derivatives while its values are at hand, instead of keeping every photo's intermediate values for a backward
    pass after all of them."""
    sizes, tv, quadratic = data[3], data[6], data[8]
    with_tv, prior_terms = static[4], static[5]
    _, x, y = _grid(T, variables[0], sizes)
    v = [dr.detach(c) for c in variables]
    maps = _maps_of(v)
    ch = [dr.detach(c) for c in maps]
    if need_grad:
        dr.enable_grad(ch)
    total = None

    def add(term) -> None:  # noqa: ANN001
        nonlocal total
        if need_grad:
            dr.backward(term)
        value = dr.detach(term)
        total = value if total is None else total + value

    for k in ks:
        add(_photo_term(T, ch, data, static, k, x, y))
    if ks[0] == 0 and with_tv:  # the TV once, with the first group
        add(_tv_term(T, ch, neighbours, sizes, tv[0], tv[1]))
    grads = _maps_gradient(v, maps, [dr.grad(c) for c in ch]) if need_grad else []
    if ks[0] == 0 and any(prior_terms):  # and the prior's quadratic terms, of the variables
        q = [dr.detach(c) for c in variables]
        if need_grad:
            dr.enable_grad(q)
        add(_quadratic_term(q, quadratic, prior_terms))
        if need_grad:
            grads = [g + dr.grad(c) for g, c in zip(grads, q)]
    return total, grads


def _quadratic_term(v: list, quadratic: tuple, terms: tuple[bool, bool, bool]):
    """This texel's share of :class:`~mi_svbrdf.optim.loop.Prior`'s pull and chroma term, scaled to the per-texel
    sum: ``sum_c w_c (v_c - anchor_c)^2`` and ``chroma x texel factor x sum_c (s_c - mean s)^2``, with the
    weights (opaque) already multiplied by the objective's count over the prior's."""
    anchor, weights, chroma, texel = quadratic
    pull, grey, per_texel = terms
    total = 0.0
    if pull:
        for c in range(9):
            total += weights[c] * dr.square(v[c] - anchor[c])
    if grey:
        mean = (v[6] + v[7] + v[8]) * (1.0 / 3.0)
        dev = dr.square(v[6] - mean) + dr.square(v[7] - mean) + dr.square(v[8] - mean)
        total += (chroma * texel if per_texel else chroma) * dev
    return total


def _objective_driver(static: tuple, k_count: int, need_grad: bool, size: tuple[int, int], channels: list,
                      data) -> object:
    """The objective of the variables ``channels`` (nine arrays of ``size``'s texels) in one array, each texel's
    share of it divided by the objective's count: with ``need_grad``, ``10 * H * W`` values, the nine derivatives
    channel after channel (the variables' layout) then the shares; else the ``H * W`` shares.

    Each texel's objective depends only on that texel's nine variables (and on its neighbours' maps, held
    constant: :func:`_tv_term`), so its derivatives are computed with its value, one launch per group of
    photos, and written into the one output in the last launch: a single array crosses back to PyTorch.

    A texel whose variables are not all finite has a NaN share (``s - s`` added, ``s`` their sum: 0 for finite
    values), so the objective is finite only where the variables are (:attr:`FusedObjective.checks_finite`).
    """
    T = jit_types_of(channels[0])
    sizes, scale = data[3], data[7]
    variables = list(channels)
    neighbours = []
    if static[4]:  # the TV reads its neighbours' maps: evaluated once, before the groups
        neighbours = _maps_of(variables)
        dr.eval(neighbours)
    total, local = None, []
    groups = _groups(k_count)
    for g, ks in enumerate(groups):
        value, grads = _group_terms(T, variables, data, static, ks, neighbours, need_grad)
        if need_grad:
            grads = [dr.detach(d) for d in grads]
            local = grads if not local else [a + d for a, d in zip(local, grads)]
        total = value if total is None else total + value
        if g + 1 < len(groups):
            dr.eval(total, local)
    check = variables[0]
    for c in variables[1:]:
        check = check + c
    total = total + (check - check)
    if not need_grad:
        out = total * scale
    else:
        out = channel_major(T, [dr.detach(d) * scale for d in local] + [total * scale], sizes[0])
    dr.eval(out)
    return out


class _Objective(torch.autograd.Function):
    """``variables -> objective`` with the gradient the kernel computed with the value: backward() is a multiply."""

    @staticmethod
    def forward(ctx: Any, variables: torch.Tensor, objective: FusedObjective) -> torch.Tensor:  # type: ignore[override]
        value, grad = objective.evaluate(variables.detach(), ctx.needs_input_grad[0])
        if grad is not None:
            ctx.save_for_backward(grad)
        return value

    @staticmethod
    def backward(ctx: Any, out: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        (grad,) = ctx.saved_tensors  # contiguous, in the variables' layout
        return grad * out, None


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
        # The kernel reads the caller's bounds without a copy, for the whole fit (at 2048^2 a copy is 50 MB a photo,
        # twice): hand over tensors that stay as they are (target_bounds makes new ones).
        self.lo = lo.detach().float().contiguous().reshape(n * 3, h * w)
        self.hi = hi.detach().float().contiguous().reshape(n * 3, h * w)
        total = n * 3 * h * w  # the per-texel sum is divided by this; TV means are over 10 channels
        self.tv_scale = (tv_weight * total / (10 * h * (w - 1)) if w > 1 else 0.0,
                         tv_weight * total / (10 * (h - 1) * w) if h > 1 else 0.0)
        self.quadratic: tuple | None = None  # the prior's pull and chroma term (set_quadratic)
        self._jit: tuple | None = None  # the constant inputs as Dr.Jit arrays (_constants)
        self._jit_device: torch.device | None = None

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
        self._jit = None  # the tables changed: converted again at the next call

    def set_quadratic(self, anchor: torch.Tensor | None, weights: tuple[float, ...], chroma_weight: float,
                      chroma_texel: torch.Tensor | None) -> None:
        """Add the pull and chroma terms of :class:`~mi_svbrdf.optim.loop.Prior` to the objective, in the kernel:
        ``mean over texels of sum_c weights[c] (v_c - anchor_c)^2`` (``anchor`` ``(1, 9, H, W)`` or None: no
        pull; ``weights``: 9 values) plus ``chroma_weight x mean over texels of chroma_texel x`` the variance of
        the three specular variables (``chroma_texel`` ``(1, 1, H, W)`` or None: 1)."""
        n, h, w = self.shape
        for name, t, c in (("anchor", anchor, 9), ("chroma_texel", chroma_texel, 1)):
            if t is not None and tuple(t.shape) != (1, c, h, w):
                raise ValueError(f"{name}: expected shape (1, {c}, {h}, {w}), got {tuple(t.shape)}")
        if len(weights) != 9 or not chroma_weight >= 0:
            raise ValueError(f"weights, chroma_weight: expected 9 values and a weight >= 0, got {weights}, "
                             f"{chroma_weight!r}")
        dev = self.lo.device  # read without a copy, as the bounds

        def flat(t: torch.Tensor, rows: int) -> torch.Tensor:
            return t.detach().float().to(dev).contiguous().reshape(rows, -1)

        self.quadratic = (None if anchor is None else flat(anchor, 9), tuple(float(x) for x in weights),
                          float(chroma_weight), None if chroma_texel is None else flat(chroma_texel, 1).reshape(-1))
        self._jit = None

    def _constants(self, device: torch.device) -> tuple:
        """The kernel's constant inputs as Dr.Jit arrays on ``device``'s backend, converted once (again after
        :meth:`update`, or for another device): the bounds, the packed lights and cameras, the sizes and the
        loss's constants."""
        if self._jit is None or self._jit_device != device:
            n, h, w = self.shape
            T = jit_types_for(device)
            extra_cfg = self.extra[0]
            self._jit = ([to_jit(r) for r in self.lo.unbind(0)], [to_jit(r) for r in self.hi.unbind(0)],
                         row_fields(T, to_jit(self.cfg), n), grid_sizes(T, h, w), dr.opaque(T.Float, LOG_EPS),
                         row_fields(T, to_jit(extra_cfg), extra_cfg.shape[0] // CFG_STRIDE),
                         (dr.opaque(T.Float, self.tv_scale[0]), dr.opaque(T.Float, self.tv_scale[1])),
                         dr.opaque(T.Float, 1.0 / (n * 3 * h * w)), self._quadratic_constants(T))
            dr.eval(self._jit)
            self._jit_device = device
        return self._jit

    def _quadratic_constants(self, T: ModuleType) -> tuple:
        """The prior's quadratic terms as Dr.Jit inputs: the anchor's nine arrays, the nine pull weights and the
        chroma weight (opaque, times the objective's count over the prior's ``H * W``: ``3 N``), the per-texel
        factor."""
        if self.quadratic is None:
            return ([], [], None, None)
        anchor, weights, chroma, texel = self.quadratic
        per = 3 * self.shape[0]
        return ([] if anchor is None else [to_jit(r) for r in anchor.unbind(0)],
                [dr.opaque(T.Float, wc * per) for wc in weights], dr.opaque(T.Float, chroma * per / 3.0),
                None if texel is None else to_jit(texel))

    def _prior_terms(self) -> tuple[bool, bool, bool]:
        """Which quadratic terms the kernel adds: the pull, the chroma term, its per-texel factor."""
        if self.quadratic is None:
            return (False, False, False)
        anchor, _, chroma, texel = self.quadratic
        return (anchor is not None, chroma > 0, chroma > 0 and texel is not None)

    def evaluate(self, variables: torch.Tensor, need_grad: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The objective of ``variables`` ``(1, 9, H, W)`` (scalar, no autograd) and, with ``need_grad``, its
        gradient ``(1, 9, H, W)``: the variables cross to Dr.Jit as one array, and the result comes back as one."""
        n, h, w = self.shape
        data = self._constants(variables.device)
        static = (self.flags, self.kind, self.extra[1], self.extra[2], self.tv_scale[0] + self.tv_scale[1] > 0,
                  self._prior_terms())
        channels = [to_jit(c) for c in variables.reshape(9, h * w).unbind(0)]
        out = _frozen(_objective_driver, static, n, need_grad, (h, w))(channels, data).torch()
        if not need_grad:
            return out.sum(), None
        return out[9 * h * w:].sum(), out[:9 * h * w].view(1, 9, h, w)

    #: The objective is NaN where the variables are not all finite (:func:`_objective_driver`): the loop need not
    #: read the variables to test them.
    checks_finite = True

    def __call__(self, variables: torch.Tensor) -> torch.Tensor:
        """The objective of ``variables`` ``(1, 9, H, W)``; differentiable in ``variables``."""
        n, h, w = self.shape
        if variables.dim() != 4 or tuple(variables.shape) != (1, 9, h, w):
            raise ValueError(f"variables: expected shape (1, 9, {h}, {w}), got {tuple(variables.shape)}")
        check_jit_device(variables=variables, lo=self.lo, cfg=self.cfg, extra=self.extra[0])
        if torch.is_grad_enabled() and variables.requires_grad:
            return _Objective.apply(variables, self)
        return self.evaluate(variables, False)[0]
