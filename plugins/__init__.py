"""Mitsuba plugins of mi_svbrdf, installed as ``mi_svbrdf.plugins``.

``register()`` registers every BSDF for the current Mitsuba variant; call it through
:func:`mi_svbrdf.variant.ensure_variant`, which also picks a variant when none is set.
"""
from __future__ import annotations

import mitsuba as mi

_registered: set[str] = set()


def register() -> None:
    """Register ``svbrdf_ggx``, ``svbrdf_beckmann`` and ``svbrdf_aniso`` for the current variant (idempotent)."""
    variant = mi.variant()
    if variant is None:
        raise RuntimeError("mi_svbrdf.plugins.register(): no Mitsuba variant is set; "
                           "call mi_svbrdf.ensure_variant() first")
    if variant in _registered:
        return
    from .svbrdf_aniso import AnisoSVBRDF  # imported late: they need a variant
    from .svbrdf_bsdf import SVBRDF

    mi.register_bsdf("svbrdf_ggx", lambda props: SVBRDF(props, distribution="ggx"))
    mi.register_bsdf("svbrdf_beckmann", lambda props: SVBRDF(props, distribution="beckmann"))
    mi.register_bsdf("svbrdf_aniso", lambda props: AnisoSVBRDF(props))
    _registered.add(variant)
