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
* ``trivial``: the thesis's trivial baseline from the photos alone (what the nets know).

and records the re-rendering RMSE (display values of the maps under 9 evaluation lights against
the truth's, :func:`mi_svbrdf.core.metrics.rerender_rmse`), the per-map RMSE, the seconds, and for
``capture`` the estimated lights against the true ones: the angle of the light's direction from
the sample centre, the relative error of its distance, and of its intensity relative to photo 0's
(the global scale is the net's albedo's, not measurable).

Outputs (``--out``, default ``/tmp/bench_uncalibrated``): ``rows.csv`` (one row per fit, appended;
a re-run skips the rows already there), ``summary.md`` (tables and the checks), ``error_vs_n.png``.

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

FIELDS = ["regime", "material", "cls", "n", "method", "seconds", "steps", "stop_reason", "rerender", "rmse_normal",
          "rmse_diffuse", "rmse_roughness", "rmse_specular", "light_angle_deg", "light_distance_rel",
          "light_intensity_rel", "used"]


def light_errors(est: list[dict[str, Any]], captures: Any, b: int) -> dict[str, float]:
    """Median light errors over photos 1..N-1 used by the refinement (photo 0's light is its camera)."""
    true_l = captures.light[b]  # (N, 3)
    true_i = captures.intensity[b].mean(dim=-1)  # (N,)
    angles, dists, ints = [], [], []
    g0 = sum(est[0]["gain"]) / 3
    for k in range(1, len(est)):
        if not est[k].get("used"):
            continue
        e = torch.tensor(est[k]["light"])
        t = true_l[k]
        cos = float((e @ t) / (e.norm() * t.norm()))
        angles.append(math.degrees(math.acos(max(-1.0, min(1.0, cos)))))
        dists.append(abs(float(e.norm() / t.norm()) - 1.0))
        ints.append(abs((sum(est[k]["gain"]) / 3 / g0) / float(true_i[k] / true_i[0]) - 1.0))
    med = lambda v: round(statistics.median(v), 4) if v else ""  # noqa: E731
    return {"light_angle_deg": med(angles), "light_distance_rel": med(dists), "light_intensity_rel": med(ints),
            "used": sum(1 for e in est if e.get("used"))}


def run_material(data: dict[str, Any], regime: str, m: int, cls: str, ns: list[int], budget_s: float,
                 nets: dict[str, Any], done: set[tuple]) -> list[dict[str, Any]]:
    from mi_svbrdf.core.metrics import eval_lights, map_rmse, rerender_rmse
    from mi_svbrdf.eval.baseline import trivial_baseline
    from mi_svbrdf.optim.refine import RefineConfig, refine

    gt, inputs, captures = data["maps"][m:m + 1], data["inputs"][m:m + 1], data["captures"]
    lights = eval_lights()
    rows = []

    def row(method: str, n: int, maps: torch.Tensor, seconds: float, **extra: Any) -> dict[str, Any]:
        errs = map_rmse(maps, gt)
        return {"regime": regime, "material": m, "cls": cls, "n": n, "method": method, "seconds": round(seconds, 3),
                "rerender": float(rerender_rmse(maps, gt, lights)[0]),
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

        for key, title in (("rerender", "Re-rendering RMSE"), ("rmse_normal", "Normal RMSE")):
            table = []
            for cls in [*classes, None]:
                for method in ("trivial", "net", "capture"):
                    table.append([cls or "all", method, *(f"{mean(cls, n, method, key):.4f}" for n in ns)])
            out += [f"## {regime}: {title} (mean over materials; lower is better)", "",
                    markdown_table(["class", "method", *(f"N={n}" for n in ns)], table), ""]
        checks = []
        n_max = max(ns)
        for cls in classes:
            for key in ("rerender", "rmse_normal"):
                cap = mean(cls, n_max, "capture", key)
                ok = (cap < mean(cls, n_max, "net", key) and cap < mean(cls, 1, "net", key)
                      and cap < mean(cls, n_max, "trivial", key))
                checks.append([cls, key, f"{cap:.4f}", f"{mean(cls, n_max, 'net', key):.4f}",
                               f"{mean(cls, 1, 'net', key):.4f}", f"{mean(cls, n_max, 'trivial', key):.4f}",
                               "yes" if ok else "NO"])
        out += [f"## {regime}: capture at N={n_max} against the net at N={n_max} and N=1 and the trivial baseline", "",
                markdown_table(["class", "error", f"capture N={n_max}", f"net N={n_max}", "net N=1", "trivial", "beats all"],
                               checks), ""]
        curve = [mean(None, n, "capture", "rerender") for n in ns]
        rises = [f"{a:.4f} -> {b:.4f} (N={n0} -> {n1})" for (a, n0), (b, n1) in zip(zip(curve, ns), zip(curve[1:], ns[1:]))
                 if b > a]
        out += [f"capture's mean re-rendering RMSE over N {ns}: {', '.join(f'{c:.4f}' for c in curve)}; "
                f"{'non-increasing' if not rises else 'rises: ' + '; '.join(rises)}", ""]
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
    fig, axes = plt.subplots(1, len(regimes), figsize=(5 * len(regimes), 3.6), squeeze=False)
    for ax, regime in zip(axes[0], regimes):
        for method, style in (("trivial", ":"), ("net", "--"), ("capture", "-")):
            ys = []
            for n in ns:
                v = [float(r["rerender"]) for r in rows if r["regime"] == regime and r["method"] == method
                     and int(r["n"]) == n]
                ys.append(sum(v) / len(v) if v else math.nan)
            ax.plot(ns, ys, style, marker="o", label=method)
        ax.set(title=f"foreign captures, regime {regime}", xlabel="photos N", ylabel="re-rendering RMSE", xscale="log")
        ax.set_xticks(ns, [str(n) for n in ns])
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    methods = {kind: make_method(kind) for kind in ("single", "multi")}
    nets = {kind: (lambda photos, meth=meth: meth.fn(photos, None, {})) for kind, meth in methods.items()}
    print(f"outputs in {out}", flush=True)
    for regime in args.regimes.split(","):
        data_set = ForeignSet(materials=args.materials, n_images=max(ns), regime=regime)
        maps, inputs, captures = data_set.load()
        data = {"maps": maps, "inputs": inputs, "captures": captures}
        for m in range(args.materials):
            cls = list(FOREIGN_CLASSES)[m % len(FOREIGN_CLASSES)]
            if all((regime, m, n, meth) in done for n in ns for meth in ("trivial", "net", "capture")):
                continue
            for r in run_material(data, regime, m, cls, ns, budget, nets, done):
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
    text = summary(rows, ns)
    (out / "summary.md").write_text(text + "\n")
    plot(rows, ns, out / "error_vs_n.png")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
