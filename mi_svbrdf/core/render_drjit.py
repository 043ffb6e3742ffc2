"""The ``"mitsuba"`` backend of the texel renderer and of the rendering loss.

The per-texel radiance calls the plugin's BRDF (``mi_svbrdf.plugins.model.eval_brdf``)
inside a function wrapped with ``dr.wrap(source="torch", target="drjit")``: PyTorch tensors
go in, Dr.Jit traces one fused kernel, and gradients flow back to the maps.

Kernel layout. The ten map channels are passed as ten contiguous ``(B*H*W,)`` arrays, so a
texel's data is read without gathers and, in reverse mode, each channel's gradient is written
without scatters. One kernel evaluates one configuration over the ``B*H*W`` texels, reading
its light/view/intensity/cone by a small gather from a packed ``(B*K, 16)`` table; it is
launched K times with an opaque configuration index (and its adjoint likewise, accumulating
the gradients). Sizes (B, H, W), K, eps and the configuration values all enter as *opaque*
values, so a new batch size, K or configuration reuses the compiled kernels: only the flags
select a kernel, and the kernel stays small enough to compile in a fraction of a second.
:func:`render_sum` (the ambient renderer's sum over many lights) accumulates the groups' outputs
launch by launch instead of keeping them, so its memory is O(B*H*W) whatever K.

Frozen launches. The launches of a call are recorded once with ``dr.freeze`` and replayed by later calls of the same
kind (the same flags, K and gradient need) whatever their batch size, resolution and configuration values, which are
all Dr.Jit inputs: a call costs its kernels and the PyTorch/Dr.Jit hand-over, not the Python tracing of the BRDF
(about 5 ms a call on a CPU, more on a GPU). See the frozen drivers below.

The fused loss goes further: a texel's loss depends only on that texel's maps, so its ten
derivatives are computed in the same kernel as its value (forward-mode cost, one pass) and the
adjoint is a single multiply by the incoming gradient. The target is rendered in the same launches, without
derivatives. It is called without ``dr.wrap`` (:class:`_LogL1`): the channels cross to Dr.Jit as views of one
tensor (DLPack, no copy) and the backward pass is a PyTorch multiply, so a small call costs its launches, not the
wrapper's conversions.

Devices: ``dr.wrap`` (and :func:`mi_svbrdf.core.device.to_jit`, for the loss) hands the kernels Dr.Jit arrays on
the tensors' device (CPU tensors: LLVM, CUDA tensors: CUDA) and the kernels make every array of their own with the types of that backend
(:func:`mi_svbrdf.core.device.jit_types_of`), so the active Mitsuba variant plays no part: the same
call works on CPU and CUDA tensors whichever variant is set, and never switches it. The outputs are
on the inputs' device.
"""
from __future__ import annotations

from dataclasses import dataclass

from types import ModuleType
from typing import Any

import drjit as dr
import torch

from mi_svbrdf.core.device import check_jit_device, jit_types_for, jit_types_of, to_jit
from mi_svbrdf.plugins import model

#: Floats per packed configuration row: light xyzw, view xyzw, intensity rgb, cone target xyz, exponent, pad.
CFG_STRIDE = 16


@dataclass(frozen=True)
class Flags:
    """Compile-time switches of a kernel (each combination is one kernel)."""

    distance_falloff: bool
    light_z_division: bool
    cone: bool
    include_diffuse: bool
    normalize_normals: bool
    distribution: str


def pack_configurations(light: torch.Tensor, view: torch.Tensor, intensity: torch.Tensor,
                        cone_target: torch.Tensor | None, cone_exponent: torch.Tensor | None) -> torch.Tensor:
    """Pack per-configuration data into a flat float32 ``(B*K*16,)`` table."""
    b, k = light.shape[:2]
    table = torch.zeros(b, k, CFG_STRIDE, dtype=torch.float32, device=light.device)
    table[..., 0:4] = light
    table[..., 4:8] = view
    table[..., 8:11] = intensity
    if cone_target is not None:
        table[..., 11:14] = cone_target
        table[..., 14] = cone_exponent
    return table.reshape(-1).detach()


def row_fields(T: ModuleType, table, rows: int) -> list[list]:
    """The rows of a packed configuration table (:func:`pack_configurations`, a Dr.Jit array) as evaluated
    one-value arrays, ``rows`` lists of :data:`CFG_STRIDE` values: a kernel reads such a value once per
    vector of texels (a scalar load), where a gather from the table at a per-texel index reads it per lane."""
    fields = [[dr.gather(T.Float, table, T.UInt32(r * CFG_STRIDE + o)) for o in range(CFG_STRIDE)]
              for r in range(rows)]
    dr.eval(fields)
    return fields


def _texel_radiance(T: ModuleType, ch: list, cfg, cfg_index, x, y, flags: Flags):
    """Radiance (``T.Array3f``) of every texel under one configuration (arrays of size B*H*W).

    ``T`` is the Dr.Jit module of the inputs' backend (:func:`~mi_svbrdf.core.device.jit_types_of`). ``cfg``: the
    packed table, read at ``cfg_index`` (per texel); or, with ``cfg_index`` None, the configuration's row as
    one-value arrays (:func:`row_fields`: one configuration for every texel).
    """
    def field(offset: int):
        if cfg_index is None:
            return cfg[offset]
        return dr.gather(T.Float, cfg, cfg_index * CFG_STRIDE + offset)

    n = T.Array3f(ch[0], ch[1], ch[2])
    if flags.normalize_normals:
        n = model.safe_normalize(n)
    diffuse = T.Array3f(ch[3], ch[4], ch[5])
    rough = model.clamp_roughness(ch[6])
    spec = T.Array3f(ch[7], ch[8], ch[9])

    light = T.Array3f(field(0), field(1), field(2))
    light_w = field(3)
    view = T.Array3f(field(4), field(5), field(6))
    view_w = field(7)
    pos = T.Array3f(x, y, 0.0)
    wl = light - light_w * pos
    wv = view - view_w * pos

    f = model.eval_brdf(n, wl, wv, diffuse, spec, rough, flags.distribution, flags.include_diffuse)
    wl_unit = model.safe_normalize(wl)
    scale = dr.pi * dr.maximum(dr.dot(n, wl_unit), 0.0)
    if flags.distance_falloff:
        scale *= light_w / dr.maximum(dr.squared_norm(wl), 1e-12) + (1.0 - light_w)
    if flags.light_z_division:
        scale /= dr.maximum(wl_unit.z, model.EPS_DENOM)
    if flags.cone:
        axis = model.safe_normalize(light - T.Array3f(field(11), field(12), field(13)))
        scale *= dr.power(dr.maximum(dr.dot(wl_unit, axis), 1e-12), field(14))
    intensity = T.Array3f(field(8), field(9), field(10))
    return f * intensity * scale


def grid_sizes(T: ModuleType, height: int, width: int) -> tuple:
    """The opaque size values :func:`_grid` reads: ``(H*W, W, 2/W, 2/H)`` (made outside the frozen functions, so
    a new size is a new input, not a new recording)."""
    return (dr.opaque(T.UInt32, height * width), dr.opaque(T.UInt32, width),
            dr.opaque(T.Float, 2.0 / width), dr.opaque(T.Float, 2.0 / height))


def _grid(T: ModuleType, texels, sizes: tuple) -> tuple:
    """Batch index (``T.UInt32``) and texel-centre coordinates (``T.Float``) of each texel of ``texels`` (an
    array of B*H*W values; only its width is read) for :func:`grid_sizes` ``sizes``."""
    hw, w_u, inv_w, inv_h = sizes
    idx = dr.arange(T.UInt32, dr.width(texels))
    b = idx // hw
    p = idx - b * hw
    i = p // w_u
    j = p - i * w_u
    x = (T.Float(j) + 0.5) * inv_w - 1.0
    y = 1.0 - (T.Float(i) + 0.5) * inv_h
    return b, x, y


#: Configurations evaluated per kernel launch. Larger groups read the maps (and, in reverse
#: mode, update the gradient accumulators) fewer times, which is what the kernels are bound
#: by on a CPU; smaller groups compile faster (the first call). 3 balances the two for the
#: loss's K = 9 (see benchmarks/bench_loss.py).
CONFIGS_PER_KERNEL = 3
#: Recordings a frozen driver keeps (one per term, flag combination, K and gradient need); the oldest is dropped.
FROZEN_LIMIT = 64


def _groups(size_or_count: int, k_count: int | None = None) -> list[tuple[int, ...]]:
    """The configurations of each launch: ``_groups(K)`` in groups of :data:`CONFIGS_PER_KERNEL`, ``_groups(n, K)``
    in groups of n."""
    size, k_count = (CONFIGS_PER_KERNEL, size_or_count) if k_count is None else (size_or_count, k_count)
    return [tuple(range(g, min(g + size, k_count))) for g in range(0, k_count, size)]


# --- The frozen drivers ------------------------------------------------------------------------------------------
# A *term* is a module-level function ``term(T, ch, data, static, ks) -> list of arrays``: the arrays of the
# configurations ``ks`` for the ten channel arrays ``ch`` (``data``: a PyTree of Dr.Jit arrays; ``static``: hashable
# Python values; Python ints ``ks`` only used through opaque values or to pick among same-sized arrays). The drivers
# below run a term over the groups of K configurations, one kernel launch per group, inside ``dr.freeze``: the first
# call for a (term, static, K, gradient need) records the launches, later calls replay them without tracing Python,
# whatever the batch size, resolution and configuration values (all Dr.Jit inputs). That removes the per-call floor
# of tracing, which dominates small calls (and GPU calls at any size).
#
# Python values never enter a frozen function as arguments: Dr.Jit 1.5 left some of them out of the recording's key
# (a tuple of bools or a dataclass before a ``need_grad`` flag: the call that needed gradients replayed the recording
# made without them, and returned none). :func:`_frozen` instead keeps one frozen function per driver and Python
# values, whose only arguments are Dr.Jit arrays (tests/test_frozen.py).


_FROZEN: dict[tuple, object] = {}


def _frozen(driver, *statics: object):
    """The frozen function of ``driver`` with its Python arguments ``statics`` fixed (hashable; the arrays follow)."""
    key = (driver, *statics)
    fn = _FROZEN.get(key)
    if fn is None:
        if len(_FROZEN) >= FROZEN_LIMIT:  # drop the oldest
            _FROZEN.pop(next(iter(_FROZEN)))

        def run(*arrays):  # noqa: ANN002, ANN202  (only Dr.Jit PyTrees reach the frozen function)
            return driver(*statics, *arrays)

        fn = _FROZEN[key] = dr.freeze(run, warn_after=FROZEN_LIMIT)
    return fn


def frozen_recordings() -> int:
    """How many recordings the frozen drivers made so far (a call that records traces Python and may compile)."""
    return sum(fn.n_recordings for fn in _FROZEN.values())


def channel_major(T: ModuleType, values: list, stride) -> object:
    """The arrays ``values`` (``n`` values each; ``stride``: ``n`` as an opaque value) one after the other in one
    array, written in the launch that computes them: a loop over the arrays scatters one a turn, a single side
    effect (one scatter per array would each need the array written by the one before, a launch each); no fill
    first, as every value is written. One array crosses back to PyTorch instead of one per value.

    The array is allocated at ``n``'s width when traced: a frozen function that calls this must be recorded per
    ``n`` (its key holds the size), as a replay at another width would write outside it."""
    out = dr.empty(T.Float, len(values) * dr.width(values[0]))
    idx = dr.arange(T.UInt32, dr.width(values[0]))

    def body(c):  # noqa: ANN001, ANN202
        value = values[-1]
        for k in range(len(values) - 2, -1, -1):
            value = dr.select(c == k, values[k], value)
        dr.scatter(out, value, idx + c * stride)
        return (c + 1,)

    dr.while_loop((T.UInt32(0),), lambda c: c < len(values), body)
    return out


def abs_log_ratio(a, b):
    """``|log(a) - log(b)|`` for ``a, b > 0`` with ``b`` constant, with one logarithm: the value as ``|log(a / b)|``,
    the derivative in ``a`` written out (``sign / a``, 0 where the two are equal, as the absolute value's) instead
    of differentiating the quotient."""
    ratio = dr.log(dr.detach(a) / b)
    slope = dr.select(ratio > 0.0, 1.0, dr.select(ratio < 0.0, -1.0, 0.0)) / dr.detach(a)
    return dr.abs(ratio) + slope * (a - dr.detach(a))


def _reduce_driver(term, static: tuple, k_count: int, need_grad: bool, channels: list, data) -> tuple:
    """``(total, local)``: the sum over the groups of ``term``'s single array and, with ``need_grad``, each texel's
    ten derivatives of it (``local``; empty otherwise), computed in the same launches. (Not one output array as
    :func:`channel_major` writes: an array allocated in a frozen function keeps the size it was recorded with, and
    these functions are replayed at every batch size and resolution.)

    Each texel's output depends only on that texel's ten values, so its gradient is
    ``grad_out[t] * d out[t] / d ch[c][t]``: the per-texel derivatives are computed with the value (one pass
    instead of a forward and a later adjoint pass) and scaled in the caller's backward() (:class:`_LogL1`).
    """
    T = jit_types_of(channels[0])
    total, local = None, []
    for ks in _groups(k_count):
        ch = [dr.detach(c) for c in channels]
        if need_grad:
            dr.enable_grad(ch)
        out = term(T, ch, data, static, ks)[0]
        if need_grad:
            dr.backward(out)
            grads = [dr.grad(c) for c in ch]
            local = grads if not local else [a + g for a, g in zip(local, grads)]
        value = dr.detach(out)
        total = value if total is None else total + value
        dr.eval(total, local)
    return total, local


def _outputs_driver(term, static: tuple, k_count: int, summed: bool, channels: list, data) -> list:
    """``term``'s arrays of every group, concatenated (``summed``: added element-wise, so memory is that of one
    group's outputs whatever K)."""
    T = jit_types_of(channels[0])
    outs: list = []
    with dr.suspend_grad():
        for ks in _groups(k_count):
            out = term(T, [dr.detach(c) for c in channels], data, static, ks)
            if summed:
                outs = out if not outs else [a + o for a, o in zip(outs, out)]
            else:
                outs.extend(out)
            dr.eval(outs)
    return outs


def _adjoint_driver(term, static: tuple, k_count: int, summed: bool, channels: list, grads: list, data) -> list:
    """The ten channel gradients of ``sum(outputs * grads)`` accumulated over the groups, one launch per group
    computing all ten: plain AD through ``dr.wrap`` would evaluate each input's gradient in its own kernel (redoing
    the forward pass ten times), and packing the channels into one array would turn the adjoint into
    scatter-adds. ``grads``: the incoming gradients of the concatenated outputs, or (``summed``) of the one set of
    outputs every group adds to."""
    T = jit_types_of(channels[0])
    acc: list = []
    offset = 0
    for ks in _groups(k_count):
        ch = [dr.detach(c) for c in channels]
        dr.enable_grad(ch)
        out = term(T, ch, data, static, ks)
        g = grads if summed else grads[offset:offset + len(out)]
        offset += len(out)
        total = out[0] * dr.detach(g[0])
        for o, gi in zip(out[1:], g[1:]):
            total += o * dr.detach(gi)
        dr.backward(total)
        new = [dr.grad(c) for c in ch]
        acc = new if not acc else [a + n for a, n in zip(acc, new)]
        dr.eval(acc)
    return acc


class _ConfigOp(dr.CustomOp):
    """Autograd of a term's outputs over K configurations (:func:`_outputs_driver` / :func:`_adjoint_driver`)."""

    def eval(self, channels, term, data, static, k_count, summed):
        self.statics = (term, static, k_count, summed)
        self.channels, self.data = [dr.detach(c) for c in channels], data
        return _frozen(_outputs_driver, *self.statics)(self.channels, data)

    def backward(self):
        grads = [dr.detach(g) for g in self.grad_out()]
        self.set_grad_in("channels", _frozen(_adjoint_driver, *self.statics)(self.channels, grads, self.data))


# --- The terms of the renderer and of the loss -------------------------------------------------------------------

def _radiance_terms(T: ModuleType, ch: list, data: tuple, static: tuple, ks: tuple[int, ...]) -> list:
    """R, G, B of each configuration of ``ks`` (``data = (cfg, sizes, K)``, ``static = (flags,)``)."""
    cfg, sizes, k_count = data
    b, x, y = _grid(T, ch[0], sizes)
    out = []
    for k in ks:
        rgb = _texel_radiance(T, ch, cfg, b * k_count + dr.opaque(T.UInt32, k), x, y, static[0])
        out.extend([rgb.x, rgb.y, rgb.z])
    return out


def _summed_radiance_terms(T: ModuleType, ch: list, data: tuple, static: tuple, ks: tuple[int, ...]) -> list:
    """R, G, B summed over the configurations of ``ks`` (as :func:`_radiance_terms`)."""
    cfg, sizes, k_count = data
    b, x, y = _grid(T, ch[0], sizes)
    total = None
    for k in ks:
        rgb = _texel_radiance(T, ch, cfg, b * k_count + dr.opaque(T.UInt32, k), x, y, static[0])
        total = rgb if total is None else total + rgb
    return [total.x, total.y, total.z]


def _log_l1_terms(T: ModuleType, ch: list, data: tuple, static: tuple, ks: tuple[int, ...]) -> list:
    """Sum over the configurations of ``ks`` and the channels of ``|log(R_t + eps) - log(R_p + eps)|``.

    The target is rendered in the same launch, without derivatives (its own flags: the target's BRDF model may
    differ from the prediction's), one logarithm per channel (:func:`abs_log_ratio`)."""
    target, cfg, sizes, k_o, eps = data
    b, x, y = _grid(T, ch[0], sizes)
    total = None
    for k in ks:
        index = b * k_o + dr.opaque(T.UInt32, k)
        # Radiance is >= 0 for valid maps; the clamp keeps invalid ones (negative albedo) finite.
        pred = _texel_radiance(T, ch, cfg, index, x, y, static[0])
        ref = _texel_radiance(T, [dr.detach(c) for c in target], cfg, index, x, y, static[1])
        for p, t in zip((pred.x, pred.y, pred.z), (ref.x, ref.y, ref.z)):
            term = abs_log_ratio(dr.maximum(p, 0.0) + eps, dr.detach(dr.maximum(t, 0.0) + eps))
            total = term if total is None else total + term
    return [total]


@dr.wrap(source="torch", target="drjit")
def _render_kernel(channels, cfg, shape, flags, summed):
    batch, k_count, height, width = shape
    T = jit_types_of(cfg.array)
    data = (cfg.array, grid_sizes(T, height, width), dr.opaque(T.UInt32, k_count))
    term = _summed_radiance_terms if summed else _radiance_terms
    outs = dr.custom(_ConfigOp, [c.array for c in channels], term, data, (flags,), k_count, summed)
    return [T.TensorXf(o) for o in outs]


class _LogL1(torch.autograd.Function):
    """The fused rendering loss's per-texel sum (:func:`_reduce_driver`) called without ``dr.wrap``: the channels
    cross as views of one tensor each (DLPack, no copy), and backward() is a PyTorch multiply by the derivatives the
    launches computed with the value."""

    @staticmethod
    def forward(ctx: Any, pred: torch.Tensor, target: torch.Tensor, cfg: torch.Tensor, k_count: int,  # type: ignore[override]
                flags: Flags, eps: float, target_flags: Flags) -> torch.Tensor:
        batch, _, height, width = pred.shape
        T = jit_types_for(pred.device)
        data = ([to_jit(c) for c in _split(target)], to_jit(cfg), grid_sizes(T, height, width),
                dr.opaque(T.UInt32, k_count), dr.opaque(T.Float, eps))
        need_grad = ctx.needs_input_grad[0]
        run = _frozen(_reduce_driver, _log_l1_terms, (flags, target_flags), k_count, need_grad)
        total, local = run([to_jit(c) for c in _split(pred)], data)
        if need_grad:  # (10, B*H*W) -> (B, 10, H, W)
            grad = torch.stack([g.torch() for g in local]).view(10, batch, height, width).transpose(0, 1)
            ctx.save_for_backward(grad)
        return total.torch().sum()

    @staticmethod
    def backward(ctx: Any, out: torch.Tensor) -> tuple:  # type: ignore[override]
        (grad,) = ctx.saved_tensors
        return (grad * out).contiguous(), None, None, None, None, None, None


def _split(maps: torch.Tensor) -> list[torch.Tensor]:
    """``(B, 10, H, W)`` -> ten contiguous ``(B*H*W,)`` float32 tensors (autograd-tracked)."""
    m = maps.to(torch.float32).transpose(0, 1).reshape(10, -1).contiguous()
    return list(m.unbind(0))


#: The common device of keyword tensors, cpu or cuda, whatever Mitsuba variant is set (one home: core.device).
check_device = check_jit_device


def render(maps: torch.Tensor, cfg: torch.Tensor, k_count: int, flags: Flags) -> torch.Tensor:
    """Render ``(B, K, 3, H, W)`` on ``maps``' device; ``cfg`` from :func:`pack_configurations`."""
    check_device(maps=maps, cfg=cfg)
    batch, _, height, width = maps.shape
    outs = _render_kernel(_split(maps), cfg, (batch, k_count, height, width), flags, False)
    img = torch.stack([o.reshape(batch, height, width) for o in outs], dim=1)
    return img.reshape(batch, k_count, 3, height, width)


def render_sum(maps: torch.Tensor, cfg: torch.Tensor, k_count: int, flags: Flags) -> torch.Tensor:
    """The sum over the K configurations of :func:`render`, ``(B, 3, H, W)``, accumulated in the kernels.

    Memory is O(B*H*W) whatever K (no ``(B, K, 3, H, W)`` tensor, also in the backward pass);
    gradients flow to ``maps`` (the ambient renderer, :mod:`mi_svbrdf.core.ambient`).
    """
    check_device(maps=maps, cfg=cfg)
    batch, _, height, width = maps.shape
    outs = _render_kernel(_split(maps), cfg, (batch, k_count, height, width), flags, True)
    return torch.stack([o.reshape(batch, height, width) for o in outs], dim=1)


def log_l1(pred: torch.Tensor, target: torch.Tensor, cfg: torch.Tensor, k_count: int,
           flags: Flags, eps: float, target_flags: Flags | None = None) -> torch.Tensor:
    """Mean over B, K, pixels and channels of ``|log(R_t + eps) - log(R_p + eps)|`` in one kernel.

    ``pred`` is rendered with ``flags``, ``target`` with ``target_flags`` (None: ``flags``), e.g. another
    ``distribution``.
    """
    check_device(pred=pred, target=target, cfg=cfg)
    batch, _, height, width = pred.shape
    total = _LogL1.apply(pred, target.detach(), cfg, k_count, flags, float(eps),
                         flags if target_flags is None else target_flags)
    return total / (batch * k_count * 3 * height * width)
