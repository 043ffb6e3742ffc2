"""Held-out and foreign-capture accuracy of a network: the figures the bundled weights' manifest records.

Examples:
    >>> from mi_svbrdf.eval.accuracy import accuracy_table
    >>> row = {k: 0.1 for k in ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular",
    ...                         "rmse_diffuse_scaled", "rmse_specular_scaled", "rmse_render", "ssim_render")}
    >>> print(accuracy_table({"single": row}).splitlines()[2][:28])
    | single | 0.1000 | 0.1000 |
"""
from __future__ import annotations

from typing import Any

from mi_svbrdf.core.metrics import METRIC_KEYS, eval_lights
from mi_svbrdf.data.foreign import VERSION as FOREIGN_VERSION
from mi_svbrdf.data.foreign import ForeignSet
from mi_svbrdf.data.heldout import VERSION, HeldOutSet
from mi_svbrdf.eval.harness import Dataset, load_foreign, load_heldout, run_and_score
from mi_svbrdf.eval.methods import make_method
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.network import SVBRDFNet

#: Held-out photo counts reported for the multi-image net.
MULTI_COUNTS = (1, 2, 3, 5, 10)
#: The row of a fused multi-image net's table holding its single-image branch on photo 1: the N = 1 that
#: ``capture`` runs (the ``N=1`` row is then "photo 1 alone" through the fused net).
SINGLE_ROW = "single net on photo 1"
#: The thesis's Table 3.1 figures of its single-image net (a different test set; our target).
THESIS = {"rmse_render": 0.083, "rmse_normal": 0.035, "rmse_diffuse": 0.019, "rmse_specular": 0.050,
          "rmse_roughness": 0.129}


def row_name(key: str, symmetries: int = 1) -> str:
    """The accuracy table's row of the net at ``key`` (``"single"``, ``"N=10"``) run as a symmetry ensemble of
    ``symmetries`` (:mod:`mi_svbrdf.nets.ensemble`; 1: the net alone, the row is ``key``)."""
    return key if symmetries == 1 else f"{key}, {symmetries} symmetries"


def held_out_accuracy(net: SVBRDFNet, *, materials: int = 16, size: int = 256,
                      counts: tuple[int, ...] = MULTI_COUNTS, progress: bool = True,
                      symmetries: tuple[int, ...] = (1,)) -> dict[str, Any]:
    """The net's accuracy table on the fixed held-out set (:class:`mi_svbrdf.data.heldout.HeldOutSet`).

    The single-image net sees the ``single_flash`` set; the multi-image net the ``multiview`` set
    at each N of ``counts`` (the first N photos; photo 0 is the fronto-parallel flash), at the
    set's size, two materials per call. The trivial baseline
    (:func:`mi_svbrdf.eval.baseline.trivial_baseline`) is measured on the same photos twice:
    with the exact captures (``"baseline ..."``: it knows the flash's jittered intensity and
    position, which the nets do not) and from the photos alone (``"baseline uncalibrated ..."``:
    the nominal flash of :func:`~mi_svbrdf.eval.baseline.default_captures`, photo 0). Each is run
    and scored over all materials at once by :func:`~mi_svbrdf.eval.harness.run_and_score`.
    A fused multi-image net (``NetConfig.fusion``) adds the row :data:`SINGLE_ROW`: its single-image branch on
    photo 1, the N = 1 of ``capture``, against which every N >= 2 is judged.
    Returns ``{"single" | "N=k": metrics, "baseline ...": metrics, "set": ...}`` with the keys of
    :data:`mi_svbrdf.core.metrics.METRIC_KEYS`. ``symmetries``: the net alone (1) and/or as a symmetry
    ensemble of that many (rows :func:`row_name`, e.g. ``"single, 8 symmetries"``).
    """
    single = net.config.kind == "single"
    held = HeldOutSet(size=size, materials=materials, n_images=1 if single else max(counts),
                      preset="single_flash" if single else "multiview")
    info = {"materials": materials, "size": size, "preset": held.preset, "seed": held.seed, "version": VERSION}
    return _accuracy(net, load_heldout(held, progress=progress), counts, info, symmetries)


def foreign_accuracy(net: SVBRDFNet, *, materials: int = 16, size: int = 256,
                     counts: tuple[int, ...] = MULTI_COUNTS, progress: bool = True,
                     symmetries: tuple[int, ...] = (1,)) -> dict[str, Any]:
    """As :func:`held_out_accuracy`, on the foreign captures (:class:`mi_svbrdf.data.foreign.ForeignSet`).

    Both nets see the same foreign photos (the single-image net photo 0, an off-centre close-up
    under an off-camera flash and two raking lamps: nothing it was trained on).
    """
    single = net.config.kind == "single"
    foreign = ForeignSet(size=size, materials=materials, n_images=1 if single else max(counts))
    info = {"materials": materials, "size": size, "set": "foreign", "seed": foreign.seed, "version": FOREIGN_VERSION}
    return _accuracy(net, load_foreign(foreign, progress=progress), counts, info, symmetries)


def _accuracy(net: SVBRDFNet, data: Dataset, counts: tuple[int, ...], info: dict[str, Any],
              symmetries: tuple[int, ...] = (1,)) -> dict[str, Any]:
    kind = net.config.kind
    single = kind == "single"
    lights = eval_lights()
    out: dict[str, Any] = {"set": info}
    nets = {s: make_method(kind, net=net, batch=2, symmetries=s) for s in symmetries}
    baselines = {"baseline ": make_method("trivial"),
                 # what the net knows: the photos only (the nominal flash of the default capture)
                 "baseline uncalibrated ": make_method("trivial", calibrated=False)}
    branch = getattr(net, "single", None) if getattr(net.config, "fusion", False) else None
    if branch is not None:  # a fused multi net: its single-image branch on photo 1 is capture's N = 1
        for s in symmetries:
            method = make_method("single", net=branch, batch=2, symmetries=s)
            out[row_name(SINGLE_ROW, s)] = run_and_score(method, data, 1, lights)[1]
    for n in ([1] if single else counts):
        key = "single" if single else f"N={n}"
        for s, method in nets.items():
            out[row_name(key, s)] = run_and_score(method, data, n, lights)[1]
        for prefix, method in baselines.items():
            out[prefix + key] = run_and_score(method, data, n, lights)[1]
    return out


#: Maps whose RMSE the generalisation targets compare with the trivial baseline's.
TARGET_MAPS = ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular")


def generalisation_targets(heldout: dict[str, Any], foreign: dict[str, Any] | None, symmetries: int = 1, *,
                           max_single_render: float | None = None, max_multi_render: float | None = None,
                           min_foreign_gain: float | None = None) -> dict[str, Any]:
    """How a net generalises, from :func:`held_out_accuracy` and :func:`foreign_accuracy` results, judged
    against the thresholds given (the callers' acceptance targets; a figure without one is reported unjudged).

    Single-image net: the held-out re-rendering RMSE (``<= max_single_render``). Multi-image net: the held-out
    re-rendering RMSE at N = 10 (``<= max_multi_render``); on the foreign set whether the re-rendering RMSE falls
    monotonically with N, how far below N = 1 the largest N is (a fraction, ``>= min_foreign_gain``), and whether
    every map's RMSE is below the (calibrated) trivial baseline's at every N. ``symmetries``: judge the rows of the
    net run as that symmetry ensemble (:func:`row_name`). Returns ``{target: {"value": ..., "met": bool}}``, without
    ``"met"`` for a figure whose threshold is None (its name then leaves the threshold out).
    """
    out: dict[str, Any] = {}

    def add(name: str, value: Any, met: bool | None) -> None:
        out[name] = {"value": value} if met is None else {"value": value, "met": met}

    def at_most(name: str, value: float, threshold: float | None) -> None:
        if threshold is None:
            add(name, round(value, 4), None)
        else:
            add(f"{name} <= {threshold:g}", round(value, 4), value <= threshold)

    if "single" in heldout or "single" in (foreign or {}):  # the single-image net: one held-out target
        if row_name("single", symmetries) in heldout:
            at_most("held-out render", heldout[row_name("single", symmetries)]["rmse_render"], max_single_render)
        return out
    counts = sorted(int(k[2:]) for k in heldout if k.startswith("N=") and "," not in k)
    if 10 in counts and row_name("N=10", symmetries) in heldout:
        at_most("held-out N=10 render", heldout[row_name("N=10", symmetries)]["rmse_render"], max_multi_render)
    if foreign:
        fc = sorted(int(k[2:]) for k in foreign if k.startswith("N=") and "," not in k)
        series = [foreign[row_name(f"N={n}", symmetries)]["rmse_render"] for n in fc]
        add("foreign render falls with N", [round(v, 4) for v in series],
            all(b <= a for a, b in zip(series, series[1:])))
        gain = 1 - series[-1] / series[0]  # the fraction by which the largest N is below the smallest
        if min_foreign_gain is None:
            add(f"foreign N={fc[-1]} below N={fc[0]}", round(gain, 4), None)
        else:
            add(f"foreign N={fc[-1]} >= {100 * min_foreign_gain:g} % below N={fc[0]}", round(gain, 4),
                gain >= min_foreign_gain)
        worse = [f"N={n} {k[5:]}" for n in fc for k in TARGET_MAPS
                 if foreign[row_name(f"N={n}", symmetries)][k] >= foreign[f"baseline N={n}"][k]]
        add("foreign every map below trivial at every N", worse, not worse)
    return out


def accuracy_table(accuracy: dict[str, Any]) -> str:
    """A Markdown table of :func:`held_out_accuracy`'s result, with the thesis's figures."""
    keys = [k for k in METRIC_KEYS if k.startswith("rmse_")] + ["ssim_render"]
    rows = [[name, *(f"{row[k]:.4f}" for k in keys)] for name, row in accuracy.items() if name != "set"]
    rows.append(["thesis (Table 3.1)", *(f"{THESIS[k]:.3f}" if k in THESIS else "–" for k in keys)])
    return markdown_table(["method", *(k.replace("rmse_", "") for k in keys)], rows)


