"""Mitsuba plugins of mi_svbrdf, installed as ``mi_svbrdf.plugins``.

``register()`` registers every BSDF for the current Mitsuba variant; call it through
:func:`mi_svbrdf.variant.ensure_variant`, which also picks a variant when none is set.
"""
from __future__ import annotations

import importlib

import mitsuba as mi

_registered: set[str] = set()


def bsdf_classes() -> tuple[type, type]:
    """``(SVBRDF, AnisoSVBRDF)`` defined for the current variant.

    A plugin class derives from the ``mi.BSDF`` of the variant active when its module ran, so the
    plugin modules are re-run (``importlib.reload``) when another variant is active; classes handed
    out earlier stay those of their variant (Mitsuba keeps each variant's registration).
    """
    from . import svbrdf_aniso, svbrdf_bsdf  # imported late: they need a variant

    if svbrdf_bsdf.DEFINED_FOR != mi.variant():
        importlib.reload(svbrdf_bsdf)
    if svbrdf_aniso.DEFINED_FOR != mi.variant() or svbrdf_aniso.SVBRDF is not svbrdf_bsdf.SVBRDF:
        importlib.reload(svbrdf_aniso)
    return svbrdf_bsdf.SVBRDF, svbrdf_aniso.AnisoSVBRDF


def register() -> None:
    """Register ``svbrdf_ggx``, ``svbrdf_beckmann`` and ``svbrdf_aniso`` for the current variant (idempotent)."""
    variant = mi.variant()
    if variant is None:
        raise RuntimeError("mi_svbrdf.plugins.register(): no Mitsuba variant is set; "
                           "call mi_svbrdf.ensure_variant() first")
    if variant in _registered:
        return
    svbrdf, aniso = bsdf_classes()
    mi.register_bsdf("svbrdf_ggx", lambda props, cls=svbrdf: cls(props, distribution="ggx"))
    mi.register_bsdf("svbrdf_beckmann", lambda props, cls=svbrdf: cls(props, distribution="beckmann"))
    mi.register_bsdf("svbrdf_aniso", lambda props, cls=aniso: cls(props))
    _registered.add(variant)
