"""Benchmark: uncalibrated multi-image capture, the net alone against the net refined against the photos.

On the foreign captures (:class:`mi_svbrdf.data.foreign.ForeignSet`, materials and captures outside
the training distribution) in both regimes -- ``flash`` (every photo lit by its own flash, off
the lens) and ``lights`` (photo 0 a flash at the camera, the others lit by unknown point lights
at 15-75 degrees elevation and 1-3 sample widths) -- and for every photo count N, it runs:

* ``net``: the bundled nets as ``mi-svbrdf capture --no-refine`` runs them (single-image net at
  N = 1, multi-image net from 2 photos; symmetry ensemble of 8);
* ``capture``: what ``mi-svbrdf capture`` does by default: the net, then
  :func:`mi_svbrdf.optim.refine.refine` (each photo's light estimated from the photos) for
  ``--budget-s`` seconds (N = 1: the net alone, as the command does);
* ``trivial``: the thesis's trivial baseline from the photos alone (what the nets know);
* ``calibrated``: the bound the light estimation is judged against: the same fit from the same
  net's maps with the same settings (``RefineConfig``'s ``lr`` and ``prior_falloff``) given every
  photo's true camera and light (as the evaluation's ``refine`` method is, with the optimiser's
  settings there), for the same budget.

and records the re-rendering RMSE (display values of the maps under 9 evaluation lights against
the truth's, :func:`mi_svbrdf.core.metrics.rerender_rmse`), the same after the best RGB exposure
of the re-renderings (:func:`~mi_svbrdf.core.metrics.rerender_rmse_scaled`: what uncalibrated photos
can determine, since they cannot tell an albedo from the light's intensity nor a colour from the
white balance), the per-map RMSE, the seconds, and for
``capture`` the estimated lights against the true ones: the angle of the light's direction from
the sample centre, the relative error of its distance, and of its intensity relative to photo 0's
(the global scale is the net's albedo's, not measurable).

Outputs (``--out``, default ``/tmp/bench_uncalibrated``): ``rows.csv`` (one row per fit, appended;
a re-run skips the rows already there), ``summary.md`` (tables and the checks, and the light search
alone under the net's and under the true maps), ``error_vs_n.png``.

Usage:
    python benchmarks/bench_uncalibrated.py [--regimes lights,flash] [--materials 4] [--n 1,2,3,5,10]
        [--budget-s 60] [--quick] [--out /tmp/bench_uncalibrated]
"""
from __future__ import annotations

import argparse
import csv
import math
import statistics
import time
from pathlib import Path
from typing import Any

import torch

METHODS = ("trivial", "net", "capture", "calibrated")
FIELDS = ["regime", "material", "cls", "n", "method", "seconds", "steps", "stop_reason", "rerender", "rerender_scaled",
          "rmse_normal",
          "rmse_diffuse", "rmse_roughness", "rmse_specular", "light_angle_deg", "light_distance_rel",
          "light_intensity_rel", "used"]


def light_errors(est: list[dict[str, Any]], captures: Any, b: int) -> dict[str, float]:
    """Median light errors over photos 1..N-1 used by the refinement (photo 0's light is its camera)."""
    from mi_svbrdf.core.metrics import angle_deg

    true_l = captures.light[b]  # (N, 3)
    true_i = captures.intensity[b].mean(dim=-1)  # (N,)
    angles, dists, ints = [], [], []
    g0 = sum(est[0]["gain"]) / 3
    for k in range(1, len(est)):
        if not est[k].get("used"):
            continue
        e = torch.tensor(est[k]["light"])
        t = true_l[k]
        angles.append(angle_deg(e, t))
        dists.append(abs(float(e.norm() / t.norm()) - 1.0))
        ints.append(abs((sum(est[k]["gain"]) / 3 / g0) / float(true_i[k] / true_i[0]) - 1.0))
    med = lambda v: round(statistics.median(v), 4) if v else ""  # noqa: E731
    return {"light_angle_deg": med(angles), "light_distance_rel": med(dists), "light_intensity_rel": med(ints),
            "used": sum(1 for e in est if e.get("used"))}


def run_material(data: dict[str, Any], regime: str, m: int, cls: str, ns: list[int], budget_s: float,
                 nets: dict[str, Any], calibrated: Any, done: set[tuple]) -> list[dict[str, Any]]:
    """The rows of material ``m`` (every N and method not in ``done``); ``calibrated`` the OptimizeConfig of
    the bound given the true calibration."""
    from mi_svbrdf.core.metrics import eval_lights, map_rmse, rerender_rmse, rerender_rmse_scaled
    from mi_svbrdf.eval.baseline import trivial_baseline
    from mi_svbrdf.io.calibrated_photos import capture_from_simulator
    from mi_svbrdf.optim import optimize
    from mi_svbrdf.optim.refine import RefineConfig, refine

    gt, inputs, captures = data["maps"][m:m + 1], data["inputs"][m:m + 1], data["captures"]
    lights = eval_lights()
    rows = []

    def row(method: str, n: int, maps: torch.Tensor, seconds: float, **extra: Any) -> dict[str, Any]:
        errs = map_rmse(maps, gt)
        return {"regime": regime, "material": m, "cls": cls, "n": n, "method": method, "seconds": round(seconds, 3),
                "rerender": float(rerender_rmse(maps, gt, lights)[0]),
                "rerender_scaled": float(rerender_rmse_scaled(maps, gt, lights)[0]),
                **{f"rmse_{k}": float(v[0]) for k, v in errs.items()}, **extra}

    for n in ns:
        photos = inputs[:, :n]
        if (regime, m, n, "trivial") not in done:
            t = time.perf_counter()
            rows.append(row("trivial", n, trivial_baseline(photos), time.perf_counter() - t))
        kind = "single" if n == 1 else "multi"
        t = time.perf_counter()
        net_maps = nets[kind](photos[:, :1] if n == 1 else photos)
        net_s = time.perf_counter() - t
        if (regime, m, n, "net") not in done:
            rows.append(row("net", n, net_maps, net_s))
        if (regime, m, n, "capture") not in done:
            if n == 1:
                rows.append(row("capture", n, net_maps, net_s))
            else:
                t = time.perf_counter()
                res = refine(photos[0], net_maps, config=RefineConfig(budget_s=budget_s, progress=False))
                sub = captures.take(m) if hasattr(captures, "take") else captures
                rows.append(row("capture", n, res.maps, net_s + time.perf_counter() - t, steps=res.steps,
                                stop_reason=res.stop_reason, **light_errors(res.lights, sub, 0)))
        if (regime, m, n, "calibrated") not in done:
            t = time.perf_counter()
            spec, images = capture_from_simulator(captures.take(m).images(slice(0, n)), 0, photos, encoding="srgb8")
            fit = optimize(spec, images, config=calibrated, init_maps=net_maps)
            rows.append(row("calibrated", n, fit.maps, net_s + time.perf_counter() - t, steps=fit.steps,
                            stop_reason=fit.stop_reason))
    return rows


def summary(rows: list[dict[str, Any]], ns: list[int]) -> str:
    from mi_svbrdf.io.tables import markdown_table

    out = []
    for regime in dict.fromkeys(r["regime"] for r in rows):
        rr = [r for r in rows if r["regime"] == regime]
        classes = list(dict.fromkeys(r["cls"] for r in rr))

        def mean(cls: str | None, n: int, method: str, key: str) -> float:
            v = [float(r[key]) for r in rr if (cls is None or r["cls"] == cls) and int(r["n"]) == n
                 and r["method"] == method and r.get(key) not in ("", None)]
            return sum(v) / len(v) if v else math.nan

        errors = (("rerender", "Re-rendering RMSE"), ("rerender_scaled", "Re-rendering RMSE after the best RGB exposure"),
                  ("rmse_normal", "Normal RMSE"))
        for key, title in errors:
            table = []
            for cls in [*classes, None]:
                for method in METHODS:
                    table.append([cls or "all", method, *(f"{mean(cls, n, method, key):.4f}" for n in ns)])
            out += [f"## {regime}: {title} (mean over materials; lower is better)", "",
                    markdown_table(["class", "method", *(f"N={n}" for n in ns)], table), ""]
        checks = []
        n_max = max(ns)
        for cls in classes:
            for key, _ in errors:
                def beats(method: str) -> str:
                    v = mean(cls, n_max, method, key)
                    ok = (v < mean(cls, n_max, "net", key) and v < mean(cls, 1, "net", key)
                          and v < mean(cls, n_max, "trivial", key))
                    return "yes" if ok else "NO"

                checks.append([cls, key, f"{mean(cls, n_max, 'capture', key):.4f}", f"{mean(cls, n_max, 'net', key):.4f}",
                               f"{mean(cls, 1, 'net', key):.4f}", f"{mean(cls, n_max, 'trivial', key):.4f}",
                               beats("capture"), f"{mean(cls, n_max, 'calibrated', key):.4f}", beats("calibrated")])
        out += [f"## {regime}: capture at N={n_max} against the net at N={n_max} and N=1 and the trivial baseline "
                "(and the bound given the true lights)", "",
                markdown_table(["class", "error", f"capture N={n_max}", f"net N={n_max}", "net N=1", "trivial",
                                "capture beats all", f"calibrated N={n_max}", "calibrated beats all"], checks), ""]
        for key, title in errors[:2]:
            curve = [mean(None, n, "capture", key) for n in ns]
            steps = []
            for (a, n0), (b, n1) in zip(zip(curve, ns), zip(curve[1:], ns[1:])):
                diffs = [float(r1[key]) - float(r0[key]) for r0 in rr for r1 in rr
                         if r0["method"] == r1["method"] == "capture" and r0["material"] == r1["material"]
                         and int(r0["n"]) == n0 and int(r1["n"]) == n1]
                se = statistics.stdev(diffs) / math.sqrt(len(diffs)) if len(diffs) > 1 else math.nan
                if b > a:
                    steps.append(f"N={n0} -> {n1}: +{b - a:.4f} ({'within' if b - a <= 2 * se else 'beyond'} "
                                 f"2 standard errors of the paired difference, {2 * se:.4f})")
            out += [f"capture's mean {title.lower()} over N {ns}: {', '.join(f'{c:.4f}' for c in curve)}; "
                    f"{'non-increasing' if not steps else 'rises at ' + '; '.join(steps)}", ""]
        lt = []
        for n in ns[1:]:
            sel = [r for r in rr if r["method"] == "capture" and int(r["n"]) == n and r.get("light_angle_deg") not in ("", None)]
            if sel:
                med = lambda k: statistics.median(float(r[k]) for r in sel)  # noqa: E731
                secs = statistics.median(float(r["seconds"]) for r in sel)
                net_secs = statistics.median(float(r["seconds"]) for r in rr if r["method"] == "net" and int(r["n"]) == n)
                lt.append([n, f"{med('light_angle_deg'):.1f}", f"{med('light_distance_rel'):.2f}",
                           f"{med('light_intensity_rel'):.2f}", f"{secs:.1f}", f"{net_secs:.1f}"])
        if lt:
            out += [f"## {regime}: estimated lights (median over materials of the per-capture median) and time", "",
                    markdown_table(["N", "direction error (deg)", "distance rel. error", "intensity rel. error (to photo 0)",
                                    "capture s", "net s"], lt), ""]
    return "\n".join(out)


def plot(rows: list[dict[str, Any]], ns: list[int], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    regimes = list(dict.fromkeys(r["regime"] for r in rows))
    keys = (("rerender", "re-rendering RMSE"), ("rerender_scaled", "after the best RGB exposure"))
    fig, axes = plt.subplots(len(keys), len(regimes), figsize=(5 * len(regimes), 3.4 * len(keys)), squeeze=False)
    for col, regime in enumerate(regimes):
        for row_i, (key, label) in enumerate(keys):
            ax = axes[row_i][col]
            for method, style in (("trivial", ":"), ("net", "--"), ("capture", "-"), ("calibrated", "-.")):
                ys = []
                for n in ns:
                    v = [float(r[key]) for r in rows if r["regime"] == regime and r["method"] == method
                         and int(r["n"]) == n and r.get(key) not in ("", None)]
                    ys.append(sum(v) / len(v) if v else math.nan)
                ax.plot(ns, ys, style, marker="o", label=method)
            ax.set(title=f"foreign captures, regime {regime}", xlabel="photos N", ylabel=label, xscale="log")
            ax.set_xticks(ns, [str(n) for n in ns])
            ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def search_accuracy(sets: dict[str, dict[str, Any]], ns: list[int], nets: dict[str, Any]) -> str:
    """The light search alone (no fit): median direction error of photos 1..N-1's lights, searched under the
    net's maps and under the true maps, per regime and N: how much of the light error the net's maps cause."""
    from mi_svbrdf.core.metrics import angle_deg
    from mi_svbrdf.io.tables import markdown_table
    from mi_svbrdf.optim.refine import RefineConfig, estimate_lights

    table = []
    for regime, data in sets.items():
        maps, inputs, captures = data["maps"], data["inputs"], data["captures"]
        for n in [n for n in ns if n >= 2]:
            under: dict[str, list[float]] = {"net": [], "truth": []}
            for m in range(maps.shape[0]):
                photos = inputs[m:m + 1, :n]
                usable = (photos[0] < RefineConfig.clip_level).all(dim=1, keepdim=True)
                for which, start in (("net", nets["multi"](photos)), ("truth", maps[m:m + 1])):
                    est = estimate_lights(photos[0], start, RefineConfig(), usable)
                    for k in range(1, n):
                        under[which].append(angle_deg(est[k]["light"], captures.light[m, k]))
            table.append([regime, n, f"{statistics.median(under['net']):.1f}", f"{statistics.median(under['truth']):.1f}"])
    return "\n".join(["## The light search alone: direction error (median over photos 1..N-1 of every material, degrees)",
                      "", markdown_table(["regime", "N", "under the net's maps", "under the true maps"], table), ""])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--regimes", default="lights,flash")
    p.add_argument("--materials", type=int, default=4, help="foreign materials (classes in turn; default 4)")
    p.add_argument("--n", default="1,2,3,5,10", help="photo counts")
    p.add_argument("--budget-s", type=float, default=60.0, help="refinement budget per capture, seconds")
    p.add_argument("--quick", action="store_true", help="budget 20 s, N = 1, 3, 10")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", default="/tmp/bench_uncalibrated")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    from mi_svbrdf.data.foreign import FOREIGN_CLASSES, ForeignSet
    from mi_svbrdf.eval.methods import make_method

    ns = [1, 3, 10] if args.quick else [int(v) for v in args.n.split(",")]
    budget = 20.0 if args.quick else args.budget_s
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "rows.csv"
    rows = list(csv.DictReader(csv_path.open())) if csv_path.is_file() else []
    done = {(r["regime"], int(r["material"]), int(r["n"]), r["method"]) for r in rows}
    from mi_svbrdf.optim import OptimizeConfig
    from mi_svbrdf.optim.refine import RefineConfig

    refine_defaults = RefineConfig()
    calibrated = OptimizeConfig(iterations=100_000, lr=refine_defaults.lr, prior_falloff=refine_defaults.prior_falloff,
                                budget_s=budget, progress=False)
    methods = {kind: make_method(kind) for kind in ("single", "multi")}
    nets = {kind: (lambda photos, meth=meth: meth.fn(photos, None, {})) for kind, meth in methods.items()}
    print(f"outputs in {out}", flush=True)
    sets: dict[str, dict[str, Any]] = {}
    for regime in args.regimes.split(","):
        data_set = ForeignSet(materials=args.materials, n_images=max(ns), regime=regime)
        maps, inputs, captures = data_set.load()
        data = sets[regime] = {"maps": maps, "inputs": inputs, "captures": captures}
        for m in range(args.materials):
            cls = list(FOREIGN_CLASSES)[m % len(FOREIGN_CLASSES)]
            if all((regime, m, n, meth) in done for n in ns for meth in METHODS):
                continue
            for r in run_material(data, regime, m, cls, ns, budget, nets, calibrated, done):
                new = not csv_path.is_file()
                with csv_path.open("a", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
                    if new:
                        w.writeheader()
                    w.writerow({k: r.get(k, "") for k in FIELDS})
                rows.append({k: str(r.get(k, "")) for k in FIELDS})
                print(f"{regime:6s} {m:2d} {cls:16s} N={r['n']:2d} {r['method']:8s} rerender {r['rerender']:.4f} "
                      f"normal {r['rmse_normal']:.4f} {r['seconds']:.1f} s {r.get('stop_reason', '')} "
                      f"{r.get('light_angle_deg', '')}", flush=True)
    text = summary(rows, ns) + "\n" + search_accuracy(sets, ns, nets)
    (out / "summary.md").write_text(text + "\n")
    plot(rows, ns, out / "error_vs_n.png")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
