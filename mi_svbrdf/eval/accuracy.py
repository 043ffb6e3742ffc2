"""Held-out accuracy of a network: the figures the bundled weights' manifest records.

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
from mi_svbrdf.data.heldout import VERSION, HeldOutSet
from mi_svbrdf.eval.harness import load_heldout, run_and_score
from mi_svbrdf.eval.methods import make_method
from mi_svbrdf.nets.network import SVBRDFNet

#: Held-out photo counts reported for the multi-image net.
MULTI_COUNTS = (1, 2, 3, 5, 10)
#: The thesis's Table 3.1 figures of its single-image net (a different test set; our target).
THESIS = {"rmse_render": 0.083, "rmse_normal": 0.035, "rmse_diffuse": 0.019, "rmse_specular": 0.050,
          "rmse_roughness": 0.129}


def held_out_accuracy(net: SVBRDFNet, *, materials: int = 16, size: int = 256,
                      counts: tuple[int, ...] = MULTI_COUNTS, progress: bool = True) -> dict[str, Any]:
    """The net's accuracy table on the fixed held-out set (:class:`mi_svbrdf.data.heldout.HeldOutSet`).

    The single-image net sees the ``single_flash`` set; the multi-image net the ``multiview`` set
    at each N of ``counts`` (the first N photos; photo 0 is the fronto-parallel flash), at the
    set's size, two materials per call. The trivial baseline
    (:func:`mi_svbrdf.eval.baseline.trivial_baseline`) is measured on the same photos twice:
    with the exact captures (``"baseline ..."``: it knows the flash's jittered intensity and
    position, which the nets do not) and from the photos alone (``"baseline uncalibrated ..."``:
    the nominal flash of :func:`~mi_svbrdf.eval.baseline.default_captures`, photo 0). Each is run
    and scored over all materials at once by :func:`~mi_svbrdf.eval.harness.run_and_score`.
    Returns ``{"single" | "N=k": metrics, "baseline ...": metrics, "set": ...}`` with the keys of
    :data:`mi_svbrdf.core.metrics.METRIC_KEYS`.
    """
    kind = net.config.kind
    single = kind == "single"
    held = HeldOutSet(size=size, materials=materials, n_images=1 if single else max(counts),
                      preset="single_flash" if single else "multiview")
    data = load_heldout(held, progress=progress)
    lights = eval_lights()
    out: dict[str, Any] = {"set": {"materials": materials, "size": size, "preset": held.preset, "seed": held.seed,
                                   "version": VERSION}}
    methods = {"": make_method(kind, net=net, batch=2), "baseline ": make_method("trivial"),
               # what the net knows: the photos only (the nominal flash of the default capture)
               "baseline uncalibrated ": make_method("trivial", calibrated=False)}
    for n in ([1] if single else counts):
        key = "single" if single else f"N={n}"
        for prefix, method in methods.items():
            out[prefix + key] = run_and_score(method, data, n, lights)[1]
    return out


def accuracy_table(accuracy: dict[str, Any]) -> str:
    """A Markdown table of :func:`held_out_accuracy`'s result, with the thesis's figures."""
    keys = [k for k in METRIC_KEYS if k.startswith("rmse_")] + ["ssim_render"]
    lines = ["| method | " + " | ".join(k.replace("rmse_", "") for k in keys) + " |",
             "|---" * (len(keys) + 1) + "|"]
    for name, row in accuracy.items():
        if name == "set":
            continue
        lines.append(f"| {name} | " + " | ".join(f"{row[k]:.4f}" for k in keys) + " |")
    lines.append("| thesis (Table 3.1) | " + " | ".join(f"{THESIS[k]:.3f}" if k in THESIS else "–"
                                                         for k in keys) + " |")
    return "\n".join(lines)


