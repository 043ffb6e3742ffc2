"""Procedural SVBRDFs: the thesis's nine material classes, generated on the fly (no download).

Each class is a vectorised generator of a seed and named parameters, each parameter with a
documented range and default (:data:`CLASSES`). A generator builds a height field (normals
come from its gradient), colour fields and per-region roughness and specular, and returns the
canonical ``(10, H, W)`` maps (:mod:`mi_svbrdf.core.maps`). Metals have coloured specular and
diffuse below 0.05; dielectrics a grey specular in [0.02, 0.08]. ``paint`` and ``plastic``
decorrelate albedo and relief by construction (``MaterialClass.decorrelated``).

Determinism: the result depends only on (class, seed, size, parameters); a batch equals its
elements generated one by one, bit for bit (each element has its own random generator).

Examples:
    >>> import torch
    >>> from mi_svbrdf.data import procedural as P
    >>> sorted(P.CLASSES)[:3], P.CLASSES["tiles"].params["tile_count"].default
    (['fabric', 'ground', 'leather'], 4.0)
    >>> m = P.generate("tiles", seed=1, size=64, tile_count=6)
    >>> tuple(m.shape), bool(torch.equal(m, P.generate_batch("tiles", [0, 1], 64, [{}, {"tile_count": 6}])[1]))
    ((10, 64, 64), True)
    >>> p = P.sample_parameters("wood", torch.Generator().manual_seed(0), spread=0.5)
    >>> P.validate_parameters("wood", p) == p
    True
"""
from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence

import torch

from mi_svbrdf.data.procedural import fabric, ground, leather, metal, paint, plastic, stone, tiles, wood
from mi_svbrdf.data.procedural.spec import MaterialClass, Param, check_class, sample, validate
from mi_svbrdf.data.procedural.surface import Builder, finish, make_context

__all__ = ["CLASSES", "MaterialClass", "Param", "generate", "generate_batch", "generate_surface",
           "sample_parameters", "validate_parameters"]

_MODULES = (paint, plastic, leather, metal, wood, fabric, stone, tiles, ground)
#: The material classes by name: paint, plastic, leather, metal, wood, fabric, stone, tiles, ground.
CLASSES: dict[str, MaterialClass] = {m.CLASS.name: m.CLASS for m in _MODULES}
_BUILDERS: dict[str, Builder] = {m.CLASS.name: m.build for m in _MODULES}
for _cls in CLASSES.values():
    check_class(_cls)

#: Materials generated together at most (bounds the working memory, ~30 MB per material at 256²).
CHUNK = 8
_MASK64 = (1 << 64) - 1


def _class(name: str) -> MaterialClass:
    if name not in CLASSES:
        raise ValueError(f"name: expected one of {sorted(CLASSES)}, got {name!r}")
    return CLASSES[name]


def validate_parameters(name: str, params: Mapping[str, float] | None) -> dict[str, float]:
    """Complete and check the parameters of class ``name``.

    Args:
        name: a key of :data:`CLASSES`.
        params: parameter values (a subset; missing ones take their defaults), or None.

    Returns:
        Every parameter of the class, as floats (integer parameters hold whole numbers).

    Raises:
        ValueError: unknown class or parameter, a value outside its range (the message names
            the parameter and its valid range) or a non-integer value of an integer parameter.
    """
    return validate(_class(name), params)


def sample_parameters(name: str, generator: torch.Generator, spread: float = 1.0) -> dict[str, float]:
    """Random valid parameters of class ``name`` (the thesis's parameter perturbation, ch. 3.2).

    Each parameter moves from its default towards an independent uniform draw over its range
    by the fraction ``spread``: 0 gives the defaults, 1 a uniform draw over the whole range
    (integers: uniform over the whole numbers, then rounded). One draw per parameter is made
    whatever ``spread`` is, so the generator advances the same way.

    Args:
        name: a key of :data:`CLASSES`.
        generator: the random source.
        spread: in [0, 1].
    """
    return sample(_class(name), generator, spread)


def _element_seed(name: str, seed: int) -> int:
    """The generator seed of (class, seed): distinct classes give unrelated materials."""
    return (seed * 0x9E3779B97F4A7C15 + zlib.crc32(name.encode())) & _MASK64


def _check_request(name: str, seeds: Sequence[int], size: int,
                   params: Sequence[Mapping[str, float] | None] | None) -> list[dict[str, float]]:
    cls = _class(name)
    if isinstance(size, bool) or not isinstance(size, int) or size < 8:
        raise ValueError(f"size: expected an integer >= 8, got {size!r}")
    if isinstance(seeds, (str, bytes)) or not isinstance(seeds, Sequence) or len(seeds) == 0:
        raise ValueError(f"seeds: expected a non-empty sequence of integers, got {seeds!r}")
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < 2**63:
            raise ValueError(f"seeds: expected integers in [0, 2^63), got {s!r}")
    if params is None:
        params = [None] * len(seeds)
    if isinstance(params, Mapping) or len(params) != len(seeds):
        raise ValueError(f"params: expected a sequence of {len(seeds)} dicts (one per seed), got {params!r}")
    return [validate(cls, p) for p in params]


def generate_surface(name: str, seeds: Sequence[int], size: int = 256,
                     params: Sequence[Mapping[str, float] | None] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Materials and the height fields their normals come from.

    Args:
        name, seeds, size, params: as :func:`generate_batch`.

    Returns:
        ``(maps, height)``: maps ``(B, 10, size, size)`` as :func:`generate_batch`, and height
        ``(B, 1, size + 2, size + 2)`` in plane units (the sample is 2 units wide) on the map's
        texel grid plus one texel on each side. The normal of texel (i, j) is
        ``normalize(-dh/dx, -dh/dy, 1)`` with central differences of ``height[i + 1, j + 1]``'s
        neighbours over the spacing ``2 / size`` (x right, y up, row 0 at the top).
    """
    values = _check_request(name, seeds, size, params)
    build = _BUILDERS[name]
    maps, heights = [], []
    for start in range(0, len(seeds), CHUNK):
        chunk = list(range(start, min(start + CHUNK, len(seeds))))
        gens = [torch.Generator().manual_seed(_element_seed(name, seeds[i])) for i in chunk]
        p = {k: torch.tensor([values[i][k] for i in chunk], dtype=torch.float32).view(-1, 1, 1, 1)
             for k in CLASSES[name].params}
        surface = build(make_context(gens, size, p))
        maps.append(finish(surface, size, CLASSES[name].ranges))
        heights.append(surface.height.expand(len(chunk), 1, -1, -1))
    return torch.cat(maps), torch.cat(heights).contiguous()


def generate_batch(name: str, seeds: Sequence[int], size: int = 256,
                   params: Sequence[Mapping[str, float] | None] | None = None) -> torch.Tensor:
    """Generate B materials of one class at once.

    Args:
        name: a key of :data:`CLASSES`.
        seeds: B integers in [0, 2^63).
        size: resolution (>= 8).
        params: B parameter dicts (partial; defaults fill in), or None for all defaults.

    Returns:
        ``(B, 10, size, size)`` float32 maps; element i equals
        ``generate(name, seeds[i], size, **params[i])`` exactly.
    """
    return generate_surface(name, seeds, size, params)[0]


def generate(name: str, seed: int, size: int = 256, **params: float) -> torch.Tensor:
    """Generate one material ``(10, size, size)``, deterministic in (name, seed, size, params).

    Args:
        name: a key of :data:`CLASSES`.
        seed: integer in [0, 2^63).
        size: resolution (>= 8).
        **params: parameter values (see ``CLASSES[name].params``); missing ones take defaults.
    """
    return generate_batch(name, [seed], size, [params])[0]
