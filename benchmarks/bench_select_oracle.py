"""Benchmark: the selection judged by its oracle at full size.

For each capture, every candidate of ``optimize --select`` (:data:`mi_svbrdf.optim.select.LADDER`) is fitted alone at
the capture's full size with the whole budget (as ``--select NAME`` fits it), and the selection
(``--select auto``: its folds and its final fit within the same budget) makes its choice. Every fit sees all photos but
the held-out ones (``--held-out``, default 4 and 7, those the capture has) and is scored on them
(:func:`bench_real.held_out_error`: display RMSE after one exposure fitted on the fit photos). The candidates ranked by
that score are the oracle ranking, which no method can know; the page gives, per capture, the best candidate, the
choice, and the ratio of the choice's held-out error to the best's (the target: within 5 %). Simulated captures
(:mod:`mi_svbrdf.data.realistic`: per-photo exposure and white balance, flash offset, pose errors, vignetting, an
unstated light, JPEG) also give each fit's error on eight new views of the true material (``views``) and its normal
RMSE. The same material at more photos must never choose a candidate that is worse at full size than the one chosen
with fewer photos (the page's last table).

Each capture's results are appended to the JSON as they finish (a cut run keeps what it measured); ``--from-json``
re-renders the page from it; ``--selection-only`` runs the selection again on every capture of the JSON (``--view``: the
folds' view) and keeps the candidates' fits it holds (they do not depend on the selection).

Usage::

    python benchmarks/bench_select_oracle.py --real ../shared/real/yellow_box ../shared/real/bath_tile \\
        --synthetic 13:5,9,20 6:5,9,20 7:9,20 5:9 3:20
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

import mi_svbrdf  # noqa: F401  (first: before torch)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real import held_out_error, load_folder, load_synthetic  # noqa: E402

from mi_svbrdf.io.atomic import write_json, write_text  # noqa: E402
from mi_svbrdf.optim import OptimizeConfig, optimize  # noqa: E402
from mi_svbrdf.optim.select import FOLD_VIEWS, LADDER, SelectConfig, candidate_config, select_and_fit  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The choice is within this fraction of the best candidate's held-out error (the target).
WITHIN = 0.05


def _synthetic(arg: str) -> tuple[int, list[int]]:
    """``M:N1,N2`` -> (material, photo counts)."""
    m, _, counts = arg.partition(":")
    try:
        return int(m), [int(c) for c in (counts or "9").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--synthetic: expected MATERIAL:N1,N2 (e.g. 13:5,9,20), got {arg!r}") from None


def _load(source: dict[str, Any], size: int) -> dict[str, Any]:
    """A capture from its source: ``{"real": folder}`` or ``{"synthetic": [material, photos]}``."""
    if "real" in source:
        return {**load_folder(Path(source["real"]), size), "source": source}
    m, k = source["synthetic"]
    return {**load_synthetic(m, "real", size, k), "material": m, "source": source}


def run_capture(capture: dict[str, Any], args: argparse.Namespace,
                candidates: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """Every candidate alone (unless ``candidates`` holds their fits already) and the selection on one capture: its
    record (strict JSON)."""
    spec, images, valid = capture["spec"], capture["images"], capture["valid"]
    n, size, label = spec.n_images, images.shape[-1], capture["name"]
    held = [k for k in args.held_out if k < n]
    fit = [k for k in range(n) if k not in held]
    truth = capture.get("truth")

    def scored(maps: torch.Tensor) -> dict[str, Any]:
        row = {"held_out": held_out_error(maps, spec, images, fit, held, size)["held_out_rmse"]}
        if truth is not None:
            row["views"] = truth.heldout_error(maps.detach().cpu())
            row["normal"] = truth.map_errors(maps.detach().cpu())["normal"]
        return row

    base = OptimizeConfig(budget_s=args.budget_s, progress=False)
    given = candidates is not None
    candidates = dict(candidates or {})
    for c in LADDER if not given else ():
        t0 = time.perf_counter()
        res = optimize(spec.subset(fit), images[fit], valid[fit], config=candidate_config(c.name, base))
        candidates[c.name] = {**scored(res.maps), "seconds": round(time.perf_counter() - t0, 1), "steps": res.steps,
                              "stop": res.stop_reason}
        print(f"{label}: {c.name:<17} {json.dumps(candidates[c.name])}", flush=True)
    t0 = time.perf_counter()
    sel = select_and_fit(spec.subset(fit), images[fit], valid[fit], config=base, settings=SelectConfig(view=args.view))
    record = sel.selection
    selection = {**scored(sel.result.maps), "seconds": round(time.perf_counter() - t0, 1), "choice": sel.choice,
                 "plan": record.get("plan", {}).get("line", ""), "folds_s": round(record.get("seconds_folds", 0.0), 1),
                 "fold_means": {c["name"]: round(c["mean"], 5) for c in record.get("candidates", [])},
                 "eliminated": [c["name"] for c in record.get("candidates", []) if c["eliminated"]],
                 "why": record.get("why", "")}
    chosen = next((c for c in record.get("candidates", []) if c["name"] == sel.choice), None)
    if chosen is not None:  # would a length inside the schedule (not eligible: a fit never ends there) predict better?
        selection["length"] = chosen["length"]
        selection["eligible_from"] = chosen.get("eligible_from", 0)
        selection["inside"] = _lowest_mean(chosen["fold_curves"])
    print(f"{label}: {selection['plan']}\n{label}: selection {json.dumps(selection)}", flush=True)
    best = min(candidates, key=lambda name: candidates[name]["held_out"])
    return {"capture": label, "about": capture["about"], "photos": n, "fitted": len(fit), "held_out": held,
            "size": size, "real": capture["real"], "material": capture.get("material"), "source": capture["source"],
            "view": args.view, "selection_view": args.view, "candidates": candidates,
            "selection": selection, "best": best,
            "ratio": selection["held_out"] / candidates[best]["held_out"]}


def _lowest_mean(curves: dict[str, list[list[float]]]) -> list[float] | None:
    """``[length, mean error]`` where the mean of the fold curves (every scored length) is lowest; None without a
    length all folds scored."""
    common = set.intersection(*({int(k) for k, _ in c} for c in curves.values())) if curves else set()
    if not common:
        return None
    means = {k: sum(dict((int(a), e) for a, e in c)[k] for c in curves.values()) / len(curves) for k in common}
    best = min(means, key=means.get)
    return [best, round(means[best], 5)]


def _alone(r: dict[str, Any]) -> str:
    """The chosen candidate's held-out error fitted alone over the best's (the choice itself, whatever its final
    fit's share of the budget), or blank when the selection fitted no candidate."""
    c = r["selection"]["choice"]
    if not c:
        return ""
    ratio = r["candidates"][c]["held_out"] / r["candidates"][r["best"]]["held_out"]
    return f"{ratio:.3f}"


def _f(v: Any, fmt: str = ".4f") -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and math.isfinite(v) else ""


def write_page(path: Path, data: dict[str, Any]) -> None:
    """The page: the summary, each capture's oracle ranking, the more-photos check."""
    runs = data["captures"]
    names = [c.name for c in LADDER]
    lines = [
        f"# The selection against its oracle at full size (the folds' view: "
        f"{', '.join(sorted({r.get('view', 'windows') for r in runs}))})",
        "",
        f"Made by `{data['command']}` ({data['machine']}); `--from-json` re-renders it. Every candidate of "
        f"`optimize --select` fitted alone at the capture's size with the whole {data['budget_s']:g} s budget (the "
        "oracle ranking), and the selection (`--select auto`, folds and final fit within the same budget), each on "
        "all photos but the held-out ones and scored on those (display RMSE after one exposure fitted on the fit "
        "photos). Simulated captures also give the error on eight new views of the true material (views) and the "
        "normal RMSE. Ratio: the choice's held-out error over the best candidate's (target: within "
        f"{WITHIN:.0%}). A choice can beat the oracle's error: its final fit is not the candidate's fit alone."
        + (f" The selection rows are from a later run, `{data['selection_command']}`, beside the same candidates' fits."
           if data.get("selection_command") else "")
        + f" The folds' view: {', '.join(sorted({r.get('view', 'windows') for r in runs}))}."
        + (f" {data['note']}" if data.get("note") else ""),
        "",
        "| capture | photos (fitted) | best alone | its held-out | choice | choice's held-out | ratio | "
        "the choice alone / best | views: best / choice | normal: best / choice | full alone: held-out / normal | "
        "folds s / total s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        b, s, full = r["candidates"][r["best"]], r["selection"], r["candidates"]["full"]
        lines.append(
            f"| {r['capture']} | {r['photos']} ({r['fitted']}) | {r['best']} | {_f(b['held_out'])} | {s['choice']} | "
            f"{_f(s['held_out'])} | {r['ratio']:.3f}{'' if r['ratio'] <= 1 + WITHIN else ' **over**'} | "
            f"{_alone(r)} | "
            f"{_f(b.get('views'))} / {_f(s.get('views'))} | {_f(b.get('normal'))} / {_f(s.get('normal'))} | "
            f"{_f(full['held_out'])} / {_f(full.get('normal'))} | {s['folds_s']:.0f} / {s['seconds']:.0f} |")
    within = sum(r["ratio"] <= 1 + WITHIN for r in runs)
    chose = sum(bool(_alone(r)) and float(_alone(r)) <= 1 + WITHIN for r in runs)
    lines += ["", f"Within {WITHIN:.0%} of the best candidate: **{within} of {len(runs)}** captures; the candidate "
              f"chosen, fitted alone, within {WITHIN:.0%} of the best: **{chose} of {len(runs)}**.", "",
              "## Each candidate alone (held-out RMSE; the fold means the selection measured, where it ran them)", "",
              "| capture | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for r in runs:
        cells = []
        for name in names:
            c = r["candidates"][name]
            mean = r["selection"]["fold_means"].get(name)
            mark = "**" if name == r["best"] else ""
            cells.append(f"{mark}{_f(c['held_out'])}{mark}" + (f" ({_f(mean)})" if mean is not None else ""))
        lines.append(f"| {r['capture']} | " + " | ".join(cells) + " |")
    lines += ["", "## More photos of the same material", "",
              "The choice at each photo count, and its candidate's error alone at the larger count: more photos must "
              "not choose a candidate worse at full size than the one chosen with fewer.", "",
              "| material | photos | choice | chosen candidate alone (held-out) | fewer photos' choice alone, "
              "at these photos | worse? |", "|---|---|---|---|---|---|"]
    by_material: dict[Any, list[dict[str, Any]]] = {}
    for r in runs:
        if r.get("material") is not None:
            by_material.setdefault(r["material"], []).append(r)
    for m, rs in by_material.items():
        rs = sorted(rs, key=lambda r: r["photos"])
        for before, r in zip([None, *rs], rs):
            c = r["selection"]["choice"]
            own = r["candidates"].get(c, {}).get("held_out") if c else None
            prev = before["selection"]["choice"] if before else ""
            then = r["candidates"].get(prev, {}).get("held_out") if prev else None
            worse = "" if own is None or then is None else ("**yes**" if own > then * (1 + 1e-9) else "no")
            lines.append(f"| {m} | {r['photos']} | {c} | {_f(own)} | {prev} {_f(then)} | {worse} |")
    lines += ["", "## Lengths inside the schedule", "",
              "The chosen candidate's length (the lowest mean fold error among the lengths after its shortened "
              "schedule decayed) against the lowest mean at any length its folds scored, those inside the schedule "
              "included (a fit never ends there: its learning rate is still decaying).", "",
              "| capture | choice | length chosen (mean) | schedule decayed at | lowest at any length (mean) |",
              "|---|---|---|---|---|"]
    for r in runs:
        s = r["selection"]
        if s.get("inside"):
            mean = s["fold_means"].get(s["choice"])
            lines.append(f"| {r['capture']} | {s['choice']} | {s['length']} ({_f(mean)}) | {s['eligible_from']} | "
                         f"{s['inside'][0]} ({_f(s['inside'][1])}) |")
    lines += ["", "## The plans", ""] + [f"- {r['capture']}: {r['selection']['plan']}" for r in runs]
    write_text(path, "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--real", nargs="*", type=Path, default=[], help="real capture folders (MaterialGAN layout)")
    p.add_argument("--synthetic", nargs="*", type=_synthetic, default=[],
                   help="simulated realistic captures: MATERIAL:N1,N2 (the tune split's material, photo counts)")
    p.add_argument("--size", type=int, default=256, help="texels per side of every capture (default 256)")
    p.add_argument("--budget-s", type=float, default=60.0, help="wall time of every fit (default 60)")
    p.add_argument("--held-out", type=lambda s: [int(v) for v in s.split(",")], default=[4, 7],
                   help="photos held out of every fit, those the capture has (default 4,7)")
    p.add_argument("--name", default="select_oracle", help="the page's name in docs/benchmarks/ (default select_oracle)")
    p.add_argument("--view", choices=FOLD_VIEWS, default=SelectConfig().view, help="what the selection's folds fit")
    p.add_argument("--from-json", action="store_true", help="re-render the page from its JSON, fit nothing")
    p.add_argument("--note", default=None, help="a sentence the page adds to its header (kept in the JSON)")
    p.add_argument("--selection-only", action="store_true",
                   help="run the selection again on the JSON's captures, keeping their candidates' fits")
    p.add_argument("--missing", action="store_true",
                   help="with --selection-only: only the captures whose selection did not run with --view yet")
    args = p.parse_args(argv)
    out = ROOT / "docs" / "benchmarks" / f"{args.name}.json"
    if args.from_json:
        data = json.loads(out.read_text())
        if args.note is not None:
            data["note"] = args.note
            write_json(out, data)
        write_page(out.with_suffix(".md"), data)
        return 0
    if args.selection_only:
        data = json.loads(out.read_text())
        data["selection_command"] = "python benchmarks/bench_select_oracle.py " + " ".join(
            argv if argv is not None else sys.argv[1:])
        for i, old in enumerate(data["captures"]):
            if args.missing and old.get("view") == args.view and "selection_view" in old:
                continue
            src = old.get("source") or ({"real": str(ROOT.parent / "shared" / "real" / old["capture"])} if old["real"]
                                        else {"synthetic": [old["material"], old["photos"]]})
            capture = _load(src, args.size)
            data["captures"][i] = run_capture(capture, args, old["candidates"])
            write_json(out, data)
            write_page(out.with_suffix(".md"), data)
        return 0
    data = {"command": "python benchmarks/bench_select_oracle.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
            "budget_s": args.budget_s, "captures": []}
    sources = [{"real": str(f)} for f in args.real] + [{"synthetic": [m, k]} for m, counts in args.synthetic
                                                       for k in counts]
    for src in sources:
        data["captures"].append(run_capture(_load(src, args.size), args))
        write_json(out, data)
        write_page(out.with_suffix(".md"), data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
