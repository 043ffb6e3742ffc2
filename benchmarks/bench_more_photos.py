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

Each table gives the mean over the materials and how many materials are worse than the single net at
N = 1 (the criterion: none, at every N >= 2). Writes ``docs/benchmarks/more_photos.md`` and ``.json``
(``--out``); ``--checkpoint`` measures a training checkpoint of a fused net instead of the bundled one.

    python benchmarks/bench_more_photos.py                       # the bundled nets, 16 materials, 8 symmetries
    python benchmarks/bench_more_photos.py --symmetries 1 --checkpoint ~/.cache/mi_svbrdf/runs/multi_fused/checkpoint.pt
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core.metrics import eval_lights, evaluate_maps
from mi_svbrdf.data.foreign import ForeignSet
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.eval.harness import load_foreign, load_heldout
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.core.maps import normalize_normals, symmetry_image, symmetry_maps
from mi_svbrdf.nets.ensemble import symmetry_ensemble
from mi_svbrdf.nets.network import SVBRDFNet, build_network, config_from_dict
from mi_svbrdf.nets.train import load_state
from mi_svbrdf.nets.weights import load_network

#: Photo counts of the tables (the issue's and the accuracy tables').
COUNTS = (1, 2, 3, 5, 10)
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


def _both(net: SVBRDFNet, photos: torch.Tensor, symmetries: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The multi-image branch's maps and the fused net's, each as its symmetry ensemble, from one pass of each
    net per symmetry (the fused net's forward, with the branch's maps kept)."""
    multi = fused = None
    for k in range(symmetries):
        f, m = net.fused_and_branch(symmetry_image(photos, k))
        m, f = symmetry_maps(m, k, inverse=True), symmetry_maps(f, k, inverse=True)
        multi, fused = (m, f) if multi is None else (multi + m, fused + f)
    assert multi is not None and fused is not None
    return normalize_normals(multi / symmetries), normalize_normals(fused / symmetries)


def measure(net: SVBRDFNet, data: Any, symmetries: int, counts: tuple[int, ...]) -> dict[str, Any]:
    """``{"single": [per material], "multi": {N: [...]}, "fused": {N: [...]}}`` on one set: re-rendering RMSE."""
    lights = eval_lights()
    inputs, maps = data.inputs, data.maps
    out: dict[str, Any] = {"single": [], "multi": {n: [] for n in counts}, "fused": {n: [] for n in counts}}
    score = lambda pred, m: evaluate_maps(pred.float(), maps[m:m + 1], lights)["rmse_render"]  # noqa: E731
    with torch.inference_mode():
        for m in range(inputs.shape[0]):
            out["single"].append(score(symmetry_ensemble(net.single, inputs[m:m + 1, :1], symmetries), m))
            for n in counts:
                multi, fused = _both(net, inputs[m:m + 1, :n], symmetries)
                out["multi"][n].append(score(multi, m))
                out["fused"][n].append(score(fused, m))
    return out


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
    for name, label in (("multi", "multi-image net alone"), ("fused", "fused (capture's path)")):
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
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    net = fused_net(args.checkpoint)
    counts = COUNTS
    sets_by_name = loaders(args.materials, args.size, max(counts))
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    unknown = [s for s in sets if s not in sets_by_name]
    if unknown:
        parser.error(f"--sets: expected names among {sorted(sets_by_name)}, got {unknown}")
    results: dict[str, Any] = {"materials": args.materials, "size": args.size, "symmetries": args.symmetries,
                               "checkpoint": args.checkpoint, "counts": list(counts), "sets": {}}
    text = [f"# More photos never make the maps worse\n",
            f"Written by `python benchmarks/bench_more_photos.py --symmetries {args.symmetries}` ({args.materials} "
            f"materials per set, {args.size} px, "
            f"every path as its symmetry ensemble of {args.symmetries}). Re-rendering RMSE (display values under the "
            "evaluation lights) of the single-image net on photo 1, the multi-image net alone on the first N photos, "
            "and the fused multi-image net that `capture` runs on N >= 2 photos; 'worse' counts the materials whose "
            "RMSE is above the single-image net's at N = 1.\n"]
    for name in sets:
        t0 = time.perf_counter()
        result = measure(net, sets_by_name[name](), args.symmetries, counts)
        results["sets"][name] = {"single": result["single"],
                                 **{k: {str(n): v for n, v in result[k].items()} for k in ("multi", "fused")},
                                 "seconds": round(time.perf_counter() - t0, 1)}
        text += [f"## {name}\n", table(result, counts), ""]
        print(f"{name} ({time.perf_counter() - t0:.0f} s):\n{table(result, counts)}\n", flush=True)
    if not args.no_write:
        args.out.mkdir(parents=True, exist_ok=True)
        write_json(args.out / "more_photos.json", results)
        write_text(args.out / "more_photos.md", "\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
