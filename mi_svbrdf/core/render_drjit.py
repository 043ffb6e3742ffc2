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

The fused loss goes further: a texel's loss depends only on that texel's maps, so its ten
derivatives are computed in the same kernel as its value (forward-mode cost, one pass) and the
adjoint is a single multiply by the incoming gradient. The target's log-radiance is computed
once per configuration in its own kernel.

Devices: ``dr.wrap`` hands the kernels Dr.Jit arrays on the tensors' device (CPU tensors: LLVM,
CUDA tensors: CUDA) and the kernels make every array of their own with the types of that backend
(:func:`mi_svbrdf.core.device.jit_types_of`), so the active Mitsuba variant plays no part: the same
call works on CPU and CUDA tensors whichever variant is set, and never switches it. The outputs are
on the inputs' device.
"""
from __future__ import annotations

from dataclasses import dataclass

from types import ModuleType

import drjit as dr
import torch

from mi_svbrdf.core.device import check_jit_device, jit_types_of
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


def _texel_radiance(T: ModuleType, ch: list, cfg, cfg_index, x, y, flags: Flags):
    """Radiance (``T.Array3f``) of every texel under one configuration (arrays of size B*H*W).

    ``T`` is the Dr.Jit module of the inputs' backend (:func:`~mi_svbrdf.core.device.jit_types_of`).
    """
    def field(offset: int):
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


def _grid(T: ModuleType, batch: int, height: int, width: int) -> tuple:
    """Batch index (``T.UInt32``) and texel-centre coordinates (``T.Float``) of each of the B*H*W texels
    (sizes opaque)."""
    hw = dr.opaque(T.UInt32, height * width)
    w_u = dr.opaque(T.UInt32, width)
    inv_w = dr.opaque(T.Float, 2.0 / width)
    inv_h = dr.opaque(T.Float, 2.0 / height)
    idx = dr.arange(T.UInt32, batch * height * width)
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


def _groups(k_count: int) -> list[tuple[int, ...]]:
    return [tuple(range(g, min(g + CONFIGS_PER_KERNEL, k_count))) for g in range(0, k_count, CONFIGS_PER_KERNEL)]


class _GroupedConfigOp(dr.CustomOp):
    """Run ``fn(channels, ks)`` over groups ``ks`` of configurations, one kernel launch per group.

    ``fn`` returns the arrays of the configurations ``ks`` (Python ints that ``fn`` must only use
    through opaque values or to pick among same-sized arrays, so every full group reuses the
    kernel compiled for the first). With ``reduce=True`` it returns one array (a sum over the
    group) and the groups are summed (the fused loss); otherwise the outputs are concatenated.

    With ``reduce=True`` the per-texel derivatives are computed with the value (see
    ``_eval_reduce``) and the adjoint is a multiply. Otherwise, in reverse mode the ten channel
    gradients are accumulated over the groups, each launch computing all ten at once: plain AD through ``dr.wrap`` would evaluate each input's gradient
    in its own kernel (redoing the forward pass ten times), and packing the channels into one
    array would turn the adjoint into scatter-adds.
    """

    def eval(self, channels, fn, k_count, reduce, need_grad=False):
        self.channels, self.fn, self.k_count, self.reduce = channels, fn, k_count, reduce
        self.local_grads = None
        ch = [dr.detach(c) for c in channels]
        if reduce:
            return self._eval_reduce(ch, need_grad)
        with dr.suspend_grad():
            outs = []
            for ks in _groups(k_count):
                out = fn(ch, ks)
                dr.eval(out)
                outs.extend(out)
            return outs

    def _eval_reduce(self, ch: list, need_grad: bool):
        """Sum over the groups; with ``need_grad`` also each texel's derivatives, in the same kernels.

        Each texel's output depends only on that texel's ten values, so its gradient is
        ``grad_out[t] * d out[t] / d ch[c][t]``: the per-texel derivatives are computed with the
        value (one pass instead of a forward and a later adjoint pass) and scaled in backward().
        """
        width, float_t = dr.width(ch[0]), type(ch[0])
        total = dr.zeros(float_t, width)
        dr.make_opaque(total)
        local = None
        if need_grad:
            local = [dr.zeros(float_t, width) for _ in range(10)]
            dr.make_opaque(local)
        for ks in _groups(self.k_count):
            if not need_grad:
                with dr.suspend_grad():
                    total = total + self.fn(ch, ks)[0]
                    dr.eval(total)
                continue
            ch_g = [dr.detach(c) for c in ch]
            dr.enable_grad(ch_g)
            out = self.fn(ch_g, ks)[0]
            dr.backward(out)
            total = total + dr.detach(out)
            local = [a + dr.grad(c) for a, c in zip(local, ch_g)]
            dr.eval(total, local)
        self.local_grads = local
        return total

    def backward(self):
        grad_out = self.grad_out()
        if self.reduce:  # the per-texel derivatives were computed with the value in eval()
            g = [d * grad_out for d in self.local_grads]
            dr.eval(g)
            self.set_grad_in("channels", g)
            return
        self._adjoint(lambda offset, count: grad_out[offset:offset + count])

    def _adjoint(self, grads_of) -> None:
        """Accumulate the ten channel gradients over the groups, one launch per group computing all ten.

        ``grads_of(offset, count)`` gives the incoming gradients of a group's ``count`` outputs,
        which start at output ``offset`` (the concatenated outputs) -- or the same ones for every
        group when the groups were summed (:class:`_SummedConfigOp`).
        """
        width = dr.width(self.channels[0])
        acc = [dr.zeros(type(self.channels[0]), width) for _ in range(10)]
        dr.make_opaque(acc)
        offset = 0
        for ks in _groups(self.k_count):
            ch = [dr.detach(c) for c in self.channels]
            dr.enable_grad(ch)
            out = self.fn(ch, ks)
            grads = grads_of(offset, len(out))
            offset += len(out)
            total = out[0] * dr.detach(grads[0])
            for o, g in zip(out[1:], grads[1:]):
                total += o * dr.detach(g)
            dr.backward(total)
            acc = [a + dr.grad(c) for a, c in zip(acc, ch)]
            dr.eval(acc)
        self.set_grad_in("channels", acc)


class _SummedConfigOp(_GroupedConfigOp):
    """:class:`_GroupedConfigOp` whose groups' outputs are summed element-wise into one set of arrays.

    The sum over many configurations (the ambient renderer's lights) is accumulated launch by
    launch, so memory is that of one set of outputs whatever K; the adjoint feeds the same incoming
    gradients to every group (the derivative of a sum) and accumulates the ten channel gradients.
    """

    def eval(self, channels, fn, k_count):
        self.channels, self.fn, self.k_count, self.reduce = channels, fn, k_count, False
        self.local_grads = None
        ch = [dr.detach(c) for c in channels]
        total = None
        with dr.suspend_grad():
            for ks in _groups(k_count):
                out = fn(ch, ks)
                if total is None:  # opaque zeros: every launch is the same "total + group" kernel
                    total = [dr.opaque(type(ch[0]), 0.0, dr.width(ch[0])) for _ in out]
                total = [t + o for t, o in zip(total, out)]
                dr.eval(total)
        return total

    def backward(self):
        grad_out = self.grad_out()
        self._adjoint(lambda offset, count: grad_out)


@dr.wrap(source="torch", target="drjit")
def _render_kernel(channels, cfg, shape, flags):
    batch, k_count, height, width = shape
    T = jit_types_of(cfg.array)

    def fn(ch: list, ks: tuple[int, ...]) -> list:
        b, x, y = _grid(T, batch, height, width)
        out = []
        for k in ks:
            cfg_index = b * dr.opaque(T.UInt32, k_count) + dr.opaque(T.UInt32, k)
            rgb = _texel_radiance(T, ch, cfg.array, cfg_index, x, y, flags)
            out.extend([rgb.x, rgb.y, rgb.z])
        return out

    outs = dr.custom(_GroupedConfigOp, [c.array for c in channels], fn, k_count, False)
    return [T.TensorXf(o) for o in outs]


@dr.wrap(source="torch", target="drjit")
def _summed_render_kernel(channels, cfg, shape, flags):
    batch, k_count, height, width = shape
    T = jit_types_of(cfg.array)

    def fn(ch: list, ks: tuple[int, ...]) -> list:
        b, x, y = _grid(T, batch, height, width)
        total = None
        for k in ks:
            cfg_index = b * dr.opaque(T.UInt32, k_count) + dr.opaque(T.UInt32, k)
            rgb = _texel_radiance(T, ch, cfg.array, cfg_index, x, y, flags)
            total = rgb if total is None else total + rgb
        return [total.x, total.y, total.z]

    outs = dr.custom(_SummedConfigOp, [c.array for c in channels], fn, k_count)
    return [T.TensorXf(o) for o in outs]


@dr.wrap(source="torch", target="drjit")
def _log_l1_kernel(pred, target, cfg, shape, flags, eps, target_flags):
    batch, k_count, height, width = shape
    T = jit_types_of(cfg.array)
    ch_t = [c.array for c in target]
    eps_o = dr.opaque(T.Float, eps)

    def log_radiance(ch: list, k: int, kernel_flags: Flags):
        b, x, y = _grid(T, batch, height, width)
        cfg_index = b * dr.opaque(T.UInt32, k_count) + dr.opaque(T.UInt32, k)
        # Radiance is >= 0 for valid maps; the clamp keeps invalid ones (negative albedo) finite.
        return dr.log(dr.maximum(_texel_radiance(T, ch, cfg.array, cfg_index, x, y, kernel_flags), 0.0) + eps_o)

    # The target's log-radiance is computed once per configuration and kept, so the adjoint
    # pass only redoes the prediction's rendering. Its kernel has its own flags (the target's
    # BRDF model may differ from the prediction's).
    target_log = {}
    for ks in _groups(k_count):
        target_log.update({k: log_radiance(ch_t, k, target_flags) for k in ks})
        dr.eval([target_log[k] for k in ks])

    def fn(ch_p: list, ks: tuple[int, ...]) -> list:
        total = None
        for k in ks:
            diff = dr.abs(target_log[k] - log_radiance(ch_p, k, flags))
            term = diff.x + diff.y + diff.z
            total = term if total is None else total + term
        return [total]

    channels = [c.array for c in pred]
    need_grad = dr.grad_enabled(channels)  # (inside the op, eval() only sees detached inputs)
    return T.TensorXf(dr.custom(_GroupedConfigOp, channels, fn, k_count, True, need_grad))


def _split(maps: torch.Tensor) -> list[torch.Tensor]:
    """``(B, 10, H, W)`` -> ten contiguous ``(B*H*W,)`` float32 tensors (autograd-tracked)."""
    m = maps.to(torch.float32).transpose(0, 1).reshape(10, -1).contiguous()
    return list(m.unbind(0))


def check_device(**tensors: torch.Tensor) -> torch.device:
    """The common device of ``tensors`` (keyword = argument name): cpu or cuda, whatever Mitsuba variant is set.

    Raises:
        ValueError: the tensors are on different devices, or on one Dr.Jit has no backend for.
    """
    return check_jit_device(**tensors)


def render(maps: torch.Tensor, cfg: torch.Tensor, k_count: int, flags: Flags) -> torch.Tensor:
    """Render ``(B, K, 3, H, W)`` on ``maps``' device; ``cfg`` from :func:`pack_configurations`."""
    check_device(maps=maps, cfg=cfg)
    batch, _, height, width = maps.shape
    outs = _render_kernel(_split(maps), cfg, (batch, k_count, height, width), flags)
    img = torch.stack([o.reshape(batch, height, width) for o in outs], dim=1)
    return img.reshape(batch, k_count, 3, height, width)


def render_sum(maps: torch.Tensor, cfg: torch.Tensor, k_count: int, flags: Flags) -> torch.Tensor:
    """The sum over the K configurations of :func:`render`, ``(B, 3, H, W)``, accumulated in the kernels.

    Memory is O(B*H*W) whatever K (no ``(B, K, 3, H, W)`` tensor, also in the backward pass);
    gradients flow to ``maps`` (the ambient renderer, :mod:`mi_svbrdf.core.ambient`).
    """
    check_device(maps=maps, cfg=cfg)
    batch, _, height, width = maps.shape
    outs = _summed_render_kernel(_split(maps), cfg, (batch, k_count, height, width), flags)
    return torch.stack([o.reshape(batch, height, width) for o in outs], dim=1)


def log_l1(pred: torch.Tensor, target: torch.Tensor, cfg: torch.Tensor, k_count: int,
           flags: Flags, eps: float, target_flags: Flags | None = None) -> torch.Tensor:
    """Mean over B, K, pixels and channels of ``|log(R_t + eps) - log(R_p + eps)|`` in one kernel.

    ``pred`` is rendered with ``flags``, ``target`` with ``target_flags`` (None: ``flags``), e.g. another
    ``distribution``.
    """
    check_device(pred=pred, target=target, cfg=cfg)
    batch, _, height, width = pred.shape
    per_texel = _log_l1_kernel(_split(pred), _split(target.detach()), cfg,
                               (batch, k_count, height, width), flags, float(eps),
                               flags if target_flags is None else target_flags)
    return per_texel.sum() / (batch * k_count * 3 * height * width)
