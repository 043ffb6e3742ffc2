"""More photos never make the maps worse: the multi-image path at N photos against the single-image net at N = 1.

For each material of the held-out set (:class:`mi_svbrdf.data.heldout.HeldOutSet`, ``multiview``: photo 0
is the fronto-parallel flash photo, its light offset by up to 0.75 half-widths, the others lit from anywhere),
of the same set photographed with a phone's flash (``phone``: every photo's flash beside its lens, photo 0 the
single-image net's kind of photo) and of the foreign captures (:class:`mi_svbrdf.data.foreign.ForeignSet`),
the re-rendering RMSE (:func:`mi_svbrdf.core.metrics.evaluate_maps`, the display RMSE under the evaluation
lights) of:

* ``single``: the single-image net on photo 0 (the N = 1 of ``capture``);
* ``multi``: the multi-image net alone on the first N photos (the fused net's multi-image branch: the
  bundled multi-image net before the fusion), N = 1 being "photo 1 alone";
* ``fused``: the fused multi-image net (:mod:`mi_svbrdf.nets.fusion`, what ``capture`` runs on N >= 2).

* ``choice``: what ``capture`` keeps at N >= 2, the candidate chosen by the photos' own evidence
  (:mod:`mi_svbrdf.eval.evidence`: each candidate scored on photos it never saw, leave one photo out for the
  nets that read them all), judged twice: with each held photo's light **estimated** from the photos (what
  ``capture`` does) and with the **true** lights of the capture (so that a poor light estimate shows as
  such). The **oracle** is the candidate with the lowest re-rendering RMSE under the evaluation lights (the
  truth); a wrong choice costs its RMSE minus the oracle's.

Each table gives the mean over the materials and how many materials are worse than the single net at
N = 1 (the criterion: none, at every N >= 2; for the choice, none worse by more than 0.5 %). Writes
``docs/benchmarks/<name>.md`` and ``.json`` (``--out``, ``--name``); ``--checkpoint`` measures a training
checkpoint of a fused net instead of the bundled one; ``--no-judge`` leaves the choice out (it runs the nets once
more per held photo, and the light search once per held photo and candidate).

    python benchmarks/bench_more_photos.py                       # the bundled nets, 16 materials, 8 symmetries
    python benchmarks/bench_more_photos.py --symmetries 1 --no-judge                    # more_photos.md
    python benchmarks/bench_more_photos.py --symmetries 1 --materials 8 --sets held-out,foreign --name more_photos_choice
    python benchmarks/bench_more_photos.py --symmetries 1 --checkpoint ~/.cache/mi_svbrdf/runs/multi_fused/checkpoint.pt
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any


from mi_svbrdf.core.metrics import angle_deg, eval_lights, evaluate_maps
from mi_svbrdf.data.foreign import ForeignSet
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.eval.evidence import CANDIDATES, LIGHTS_FROM, MAX_FOLDS, TIE, choose, held_photos, judge
from mi_svbrdf.eval.harness import load_foreign, load_heldout
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.fusion import NET_CANDIDATES, net_candidates
from mi_svbrdf.nets.network import SVBRDFNet, build_network, config_from_dict
from mi_svbrdf.nets.train import load_state
from mi_svbrdf.nets.weights import load_network

#: Photo counts of the tables (the issue's and the accuracy tables').
COUNTS = (1, 2, 3, 5, 10)
#: The choice may be worse than the single net at N = 1 by at most this (relative) on any material.
WORSE_TOLERANCE = 0.005
ROOT = Path(__file__).resolve().parents[1]


def fused_net(checkpoint: str | None) -> SVBRDFNet:
    """The bundled multi-image net, or a checkpoint's (fp16-rounded, as it would be bundled); it must be fused."""
    if checkpoint is None:
        net = load_network("multi")
    else:
        state = load_state(checkpoint)
        net = build_network(config_from_dict(state["net_config"]))
        net.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in state["model"].items()})
    if not getattr(net.config, "fusion", False):
        raise SystemExit(f"{checkpoint or 'the bundled multi-image net'}: expected a fused multi-image net "
                         "(NetConfig.fusion), got an unfused one")
    return net.eval()


def measure(net: SVBRDFNet, data: Any, symmetries: int, counts: tuple[int, ...], *, judged: bool = True,
            folds: int = MAX_FOLDS) -> dict[str, Any]:
    """On one set: ``{"single": [per material], "multi": {N: [...]}, "fused": {N: [...]}}`` re-rendering RMSE, and
    with ``judged`` ``"choice": {N: [per material {"estimated": ..., "true": ...}]}`` (each the judgement's
    summary; N >= 2)."""
    lights = eval_lights()
    inputs, maps = data.inputs, data.maps
    out: dict[str, Any] = {"single": [], "multi": {n: [] for n in counts}, "fused": {n: [] for n in counts},
                           "choice": {n: [] for n in counts if n >= 2}}
    score = lambda pred, m: evaluate_maps(pred.float(), maps[m:m + 1], lights)["rmse_render"]  # noqa: E731
    for m in range(inputs.shape[0]):
        for n in counts:
            photos = inputs[m:m + 1, :n]
            cands = net_candidates(net, photos, symmetries)
            if len(out["single"]) == m:  # the single-image net reads photo 0 alone: the same at every N
                out["single"].append(score(cands["single"], m))
            out["multi"][n].append(score(cands["multi"], m))
            out["fused"][n].append(score(cands["fused"], m))
            if not judged or n < 2:
                continue
            fold_maps = {}
            for k in held_photos(n, folds):
                without = net_candidates(net, photos[:, [i for i in range(n) if i != k]], symmetries)
                fold_maps[k] = {c: without[c] for c in NET_CANDIDATES if c != "single"}
            spec, _ = capture_from_simulator(data.captures.take(m).images(slice(0, n)), 0, photos[0])
            row = {"truth": {"single": out["single"][m], "multi": out["multi"][n][m], "fused": out["fused"][n][m]}}
            for mode, known in (("estimated", None), ("true", spec)):
                row[mode] = judge(photos[0], cands, fold_maps, spec=known, lights_from=STARTS).summary()
            est = row["estimated"]
            true_at = [spec.images[k - 1].light.position for k in est["held_photos"]]
            row["light_error_deg"] = {
                "kept": [angle_deg(est["by_start"][c]["light"][i], t) for i, (c, t) in
                         enumerate(zip(est["light_start"], true_at))],
                **{c: [angle_deg(p, t) for p, t in zip(r["light"], true_at)] for c, r in est["by_start"].items()}}
            out["choice"][n].append(row)
    return out


def flat_choice(scores: dict[str, float | None], tie: float = TIE) -> str:
    """The rule before the levels (for comparison): the lowest, or the first of ``CANDIDATES`` within ``tie`` of it."""
    valid = {c: v for c, v in scores.items() if v is not None}
    low = min(valid.values())
    return next(c for c in CANDIDATES if c in valid and valid[c] <= low * (1.0 + tie))


def _start_scores(judgement: dict[str, Any], start: str = LIGHTS_FROM[0]) -> dict[str, float]:
    """Per candidate, its mean error under the lights one start's search found (an estimated judgement's summary)."""
    errors = judgement["by_start"][start]["errors"]
    return {c: sum(v) / len(v) for c, v in errors.items()}


def capture_choice(judgement: dict[str, Any]) -> str:
    """What ``capture`` keeps (:data:`~mi_svbrdf.eval.evidence.LIGHTS_FROM`'s light, 2 %) from a judgement's
    summary: the estimated judgement searched every start's light, and capture's start's are among them."""
    return choose(_start_scores(judgement))[0]


#: The rules the page compares, each ``(label, light source, choose(judgement summary) -> candidate)``: capture's
#: first.
RULES: list[tuple[str, str, Any]] = [
    ("levels, 2 % (capture)", "estimated", capture_choice),
    ("levels, 2 %, the light searched from every candidate's maps, the best under the fused net's kept",
     "estimated", lambda j: j["choice"]),
    ("levels, 0 %", "estimated", lambda j: choose(_start_scores(j), 0.0)[0]),
    ("levels, 5 %", "estimated", lambda j: choose(_start_scores(j), 0.05)[0]),
    ("lowest, within 2 % the simplest (single < multi < fused)", "estimated",
     lambda j: flat_choice(_start_scores(j))),
    ("levels, 2 % (capture's rule)", "true", lambda j: j["choice"]),
    ("lowest, within 2 % the simplest (single < multi < fused)", "true", lambda j: flat_choice(j["scores"])),
]
#: The starts of the benchmark's light searches (:func:`mi_svbrdf.eval.evidence.judge`'s ``lights_from``):
#: capture's and the other candidates', so that the page compares them from one run.
STARTS = ("fused", "multi", "single")


def choice_stats(rows: list[dict[str, Any]], single: list[float], mode: str, rule: Any = None) -> dict[str, Any]:
    """Over the materials of one N: the chosen maps' RMSE, how often the choice is the oracle, what a wrong one
    costs, and the materials worse than the single net at N = 1 by more than :data:`WORSE_TOLERANCE`; ``rule``
    (a judgement summary -> candidate) chooses again from the stored scores (None: the judgement's choice)."""
    chosen, wrong, worse, rel = [], [], [], []
    picks = [row[mode]["choice"] if rule is None else rule(row[mode]) for row in rows]
    for m, row in enumerate(rows):
        truth = row["truth"]
        pick = picks[m]
        oracle = min(truth, key=truth.__getitem__)
        err = truth[pick]
        chosen.append(err)
        rel.append(err / single[m] - 1.0)
        if err > truth[oracle]:
            wrong.append(err - truth[oracle])
        if err > single[m] * (1.0 + WORSE_TOLERANCE):
            worse.append(m)
    counts = {c: picks.count(c) for c in CANDIDATES if c != "refined"}
    return {"rmse": sum(chosen) / len(chosen), "oracle": len(rows) - len(wrong), "materials": len(rows),
            "wrong_cost_mean": sum(wrong) / len(wrong) if wrong else 0.0, "wrong_cost_max": max(wrong, default=0.0),
            "worse": worse, "largest_rel_loss": max(rel), "picked": counts}


def choice_table(result: dict[str, Any], counts: tuple[int, ...]) -> str:
    """Markdown: per N, each candidate's mean RMSE, the oracle's, and per light source the choice's RMSE, how
    often it is the oracle, the cost of a wrong choice and the materials worse than N = 1 beyond 0.5 %."""
    single = result["single"]
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    rows = []
    for n in counts:
        if n < 2:
            continue
        data = result["choice"][n]
        oracle = mean([min(r["truth"].values()) for r in data])
        for mode in ("estimated", "true"):
            st = choice_stats(data, single, mode, capture_choice if mode == "estimated" else None)
            picked = ", ".join(f"{c} {k}" for c, k in st["picked"].items() if k)
            rows.append([str(n), mode, f"{mean(single):.4f}", f"{mean(result['multi'][n]):.4f}",
                         f"{mean(result['fused'][n]):.4f}", f"{oracle:.4f}", f"{st['rmse']:.4f}", picked,
                         f"{st['oracle']} / {st['materials']}",
                         f"{st['wrong_cost_mean']:.4f} / {st['wrong_cost_max']:.4f}",
                         f"{len(st['worse'])} / {st['materials']}", f"{100 * st['largest_rel_loss']:+.1f} %"])
    return markdown_table(["N", "lights", "single (N = 1)", "multi", "fused", "oracle", "choice", "picked",
                           "choice = oracle", "wrong: mean / max cost", "worse than N = 1 by > 0.5 %",
                           "largest loss vs N = 1"], rows)


def rules_table(result: dict[str, Any], counts: tuple[int, ...]) -> str:
    """Markdown: per rule of :data:`RULES`, the chosen maps' mean RMSE, how often the choice is the oracle and the
    materials worse than N = 1 beyond 0.5 %, per N (the nets alone first)."""
    single = result["single"]
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    ns = [n for n in counts if n >= 2]
    rows = [[f"{net} net alone", "–", *(f"{mean(result[net][n]):.4f}" for n in ns)] for net in ("fused", "multi")]
    for label, mode, rule in RULES:
        cells = []
        for n in ns:
            st = choice_stats(result["choice"][n], single, mode, rule)
            cells.append(f"{st['rmse']:.4f}, oracle {st['oracle']}/{st['materials']}, worse {len(st['worse'])}")
        rows.append([label, mode, *cells])
    return markdown_table(["rule", "lights", *(f"N = {n}" for n in ns)], rows)


def lights_table(result: dict[str, Any], counts: tuple[int, ...]) -> str:
    """Markdown: per N, the mean angle (degrees, from the sample's centre) between the true light of the held
    photos and the light found by each start's search and the one kept, and how often each start was kept."""
    rows = []
    starts: list[str] = []
    for n in counts:
        if n < 2:
            continue
        data = result["choice"][n]
        errs: dict[str, list[float]] = {}
        for row in data:
            for c, v in row["light_error_deg"].items():
                errs.setdefault(c, []).extend(v)
        starts = [c for c in errs if c != "kept"]
        kept = [c for row in data for c in row["estimated"]["light_start"]]
        rows.append([str(n), str(len(kept)), *(f"{sum(errs[c]) / len(errs[c]):.1f}" for c in ["kept", *starts]),
                     ", ".join(f"{c} {kept.count(c)}" for c in starts if kept.count(c))])
    return markdown_table(["N", "held photos", "kept", *(f"from {c}'s maps" for c in starts), "kept from"], rows)


def material_table(result: dict[str, Any], counts: tuple[int, ...], classes: list[str]) -> str:
    """Markdown: per material, the single net at N = 1 and at each N >= 2 the choice (estimated lights) with its
    RMSE, its change against N = 1, and the oracle when the choice is not it."""
    single = result["single"]
    rows = []
    for m, s1 in enumerate(single):
        cells = [f"{m} {classes[m % len(classes)]}", f"{s1:.4f}"]
        for n in counts:
            if n < 2:
                continue
            row = result["choice"][n][m]
            truth, pick = row["truth"], capture_choice(row["estimated"])
            oracle = min(truth, key=truth.__getitem__)
            cells.append(f"{pick} {truth[pick]:.4f} ({100 * (truth[pick] / s1 - 1):+.1f} %)"
                         + ("" if pick == oracle else f"; oracle {oracle}"))
        rows.append(cells)
    return markdown_table(["material", "N = 1", *(f"N = {n}: choice" for n in counts if n >= 2)], rows)


def loaders(materials: int, size: int, n: int) -> dict[str, Any]:
    """The sets, by name, each a function returning its :class:`~mi_svbrdf.eval.harness.Dataset`."""
    return {"held-out": lambda: load_heldout(HeldOutSet(size=size, materials=materials, n_images=n), progress=False),
            "phone": lambda: load_heldout(HeldOutSet(size=size, materials=materials, n_images=n,
                                                     capture={"flash_at_camera": True}), progress=False),
            "foreign": lambda: load_foreign(ForeignSet(size=size, materials=materials, n_images=n), progress=False)}


def table(result: dict[str, Any], counts: tuple[int, ...]) -> str:
    """Markdown: one row per path and N, the mean re-rendering RMSE and the materials worse than N = 1."""
    single = result["single"]
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    rows = [["N = 1: single-image net on photo 1", f"{mean(single):.4f}", "–", "–"]]
    for name, label in (("multi", "multi-image net alone"), ("fused", "fused net")):
        for n in counts:
            errs = result[name][n]
            worse = [i for i, (e, s) in enumerate(zip(errs, single)) if e > s]
            what = "photo 1 alone" if n == 1 else f"N = {n}"
            rows.append([f"{what}: {label}", f"{mean(errs):.4f}", f"{len(worse)} / {len(errs)}",
                         f"{max(e - s for e, s in zip(errs, single)):+.4f}"])
    return markdown_table(["path", "re-render RMSE", "materials worse than N = 1", "largest loss vs N = 1"], rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--materials", type=int, default=16, help="materials of each set (default 16)")
    parser.add_argument("--size", type=int, default=256, help="resolution (default 256)")
    parser.add_argument("--symmetries", type=int, default=8, help="symmetry ensemble of every path (default 8, capture's)")
    parser.add_argument("--checkpoint", default=None, help="a fused net's training checkpoint (default: the bundled net)")
    parser.add_argument("--sets", default="held-out,phone,foreign", help="comma-separated: held-out, phone, foreign")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks",
                        help="folder of more_photos.md and .json (default docs/benchmarks)")
    parser.add_argument("--no-judge", action="store_true", help="leave the choice by evidence out")
    parser.add_argument("--folds", type=int, default=MAX_FOLDS, help=f"held photos judged at most (default {MAX_FOLDS})")
    parser.add_argument("--name", default="more_photos", help="the page's name in --out (default more_photos: "
                        "the nets' tables, --no-judge; the choice's page is more_photos_choice)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--from-json", type=Path, default=None, help="write the page again from this run's JSON "
                        "(its materials, size and symmetries; nothing measured)")
    args = parser.parse_args(argv)
    prior = json.loads(args.from_json.read_text()) if args.from_json else None
    if prior is not None:
        args.materials, args.size, args.symmetries = prior["materials"], prior["size"], prior["symmetries"]
        args.no_judge = not any(stored.get("choice") for stored in prior["sets"].values())
    net = fused_net(args.checkpoint) if prior is None else None
    counts = COUNTS
    sets_by_name = loaders(args.materials, args.size, max(counts))
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    unknown = [s for s in sets if s not in sets_by_name]
    if unknown:
        parser.error(f"--sets: expected names among {sorted(sets_by_name)}, got {unknown}")
    results: dict[str, Any] = {"materials": args.materials, "size": args.size, "symmetries": args.symmetries,
                               "checkpoint": args.checkpoint, "counts": list(counts), "sets": {}}
    text = [f"# More photos never make the maps worse{'' if args.no_judge else ': the choice by evidence'}\n",
            f"Written by `python benchmarks/bench_more_photos.py --symmetries {args.symmetries} --materials "
            f"{args.materials} --sets {','.join(sets)}{' --no-judge' if args.no_judge else ''}"
            f"{'' if args.name == 'more_photos' else ' --name ' + args.name}` ({args.materials} "
            f"materials per set, {args.size} px, "
            f"every path as its symmetry ensemble of {args.symmetries}). Re-rendering RMSE (display values under the "
            "evaluation lights) of the single-image net on photo 1, the multi-image net alone on the first N photos, "
            "and the fused multi-image net (`capture --no-choose` at N >= 2); 'worse' counts the materials whose "
            "RMSE is above the single-image net's at N = 1.\n"]
    if not args.no_judge:
        text += [f"The choice by evidence (`mi_svbrdf.eval.evidence`, what `capture` keeps at N >= 2): each candidate "
                 f"(single, multi, fused) scored on up to {args.folds} held photos among photos 2..N, which the single "
                 "net never reads and which the multi and fused nets are run without (leave one photo out); each "
                 "photo's light searched as `--refine` starts under the fused net's maps from all N photos, every "
                 "candidate scored under it ('estimated', what `capture` does; the run searched also from the other "
                 "candidates' maps, compared below), or the capture's true one ('true'); exposure fitted robustly per "
                 "photo, display "
                 "RMSE; the lower of the multi and fused nets replaces the single net only with a score lower by more "
                 f"than {100 * TIE:g} %. 'oracle': the candidate with the lowest "
                 "re-rendering RMSE against the truth; a wrong choice costs its RMSE minus the oracle's; 'worse' counts "
                 f"the materials whose chosen maps are worse than the single net at N = 1 by more than "
                 f"{100 * WORSE_TOLERANCE:g} %. The refined candidate is not measured here.\n"]
    for name in sets:
        t0 = time.perf_counter()
        data = sets_by_name[name]()
        if prior is not None:
            stored = prior["sets"][name]
            result = {"single": stored["single"],
                      **{k: {int(n): v for n, v in stored[k].items()} for k in ("multi", "fused", "choice")}}
        else:
            result = measure(net, data, args.symmetries, counts, judged=not args.no_judge, folds=args.folds)
        results["sets"][name] = {"single": result["single"],
                                 **{k: {str(n): v for n, v in result[k].items()} for k in ("multi", "fused", "choice")},
                                 "seconds": stored["seconds"] if prior is not None
                                 else round(time.perf_counter() - t0, 1)}
        text += [f"## {name}\n", table(result, counts), ""]
        if not args.no_judge:
            text += [f"### {name}: the choice by evidence\n", choice_table(result, counts), "",
                     "Per material (estimated lights):\n", material_table(result, counts, data.classes), "",
                     f"Other rules, chosen again from the same scores (mean re-rendering RMSE of the chosen maps, "
                     f"choice = oracle, materials worse than N = 1 by more than {100 * WORSE_TOLERANCE:g} %):\n",
                     rules_table(result, counts), "",
                     "The held photos' lights: mean angle to the true light (degrees) of the light kept and of each "
                     "start's search (`lights_from`), and which start was kept:\n", lights_table(result, counts), ""]
        print(f"{name} ({time.perf_counter() - t0:.0f} s):\n{table(result, counts)}\n", flush=True)
        if not args.no_judge:
            print(f"{choice_table(result, counts)}\n\n{material_table(result, counts, data.classes)}\n\n"
                  f"{rules_table(result, counts)}\n\n{lights_table(result, counts)}\n", flush=True)
    if not args.no_write:
        args.out.mkdir(parents=True, exist_ok=True)
        write_json(args.out / f"{args.name}.json", results)
        write_text(args.out / f"{args.name}.md", "\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
