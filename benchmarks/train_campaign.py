"""Campaign: what limits the single-image net's normals, one cause at a time, charted against CPU-hours.

Every arm continues the bundled single-image net (``init = "bundled:single"``) with the same
schedule (1000 steps at 128^2, then 200 at 256^2, as the bundled net's own runs ended), seed and batch,
and changes **one** thing against the ``control`` arm (the same continuation with nothing changed: what
more steps alone buy):

* ``photo_aug``: photos as a phone delivers them: sensor noise up to 0.022 (median 0.008; the
  training presets stop at 0.017) and JPEG at quality 80-98 per photo. Both stay below the
  foreign set's ranges (noise 0.025-0.04, JPEG 40-75), so the foreign set is still foreign.
* ``normal_l1``: a direct L1 on the normal map (weight 1) beside the rendering loss.
* ``relief``: steeper reliefs in the data (slopes x k, k log-uniform in [1, 2]).
* ``crop256``: 256^2 crops throughout (a quarter of the steps in about the same time).
* ``128_only``: 128^2 crops throughout, no 256^2 finish (it ran 1500 steps).

A machine may not come back: ``--keep ARM`` writes that arm's weights (fp16), step, seconds and log to
``benchmarks/campaign/checkpoint.pt.zz`` (one file, replaced), and a campaign on a machine without the arm's run
folder continues from it: the weights as the start (``init``), the steps and CPU time counted on, Adam re-warmed
(``warmup``) over the steps left.

After each arm its checkpoint is measured on the held-out set and the foreign captures at 256^2
(:func:`mi_svbrdf.eval.accuracy.held_out_accuracy`, :func:`~mi_svbrdf.eval.accuracy.foreign_accuracy`),
the net alone (no symmetry ensemble). An arm whose result is already in the JSON is skipped; a run
folder with a checkpoint resumes, so the campaign can stop at any time and go on elsewhere.

Writes ``docs/benchmarks/nets_campaign.{json,md,png}``.

Usage:
    python benchmarks/train_campaign.py [--arms control photo_aug ...] [--steps 1200] [--threads 2]
"""
from __future__ import annotations

import argparse
import copy
import io
import json
import os
import time
import zlib
from pathlib import Path
from typing import Any

import dataclasses

import torch

from mi_svbrdf.data.foreign import ForeignSet
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.eval.accuracy import foreign_accuracy, held_out_accuracy
from mi_svbrdf.eval.harness import load_foreign, load_heldout
from mi_svbrdf.io.atomic import atomic_path, write_json, write_text
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.train import CACHE, TrainConfig, load_state, train
from mi_svbrdf.nets.network import build_network, config_from_dict
from mi_svbrdf.nets.weights import load_network, read_manifest

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks"
#: The campaign's checkpoint kept in git (``--keep``): one file, replaced.
KEPT = Path(__file__).resolve().parent / "campaign" / "checkpoint.pt.zz"

#: The continuation every arm shares: the bundled net's last recipe (map L1 0.1, lr 5e-5) at 128^2.
BASE: dict[str, Any] = {
    "kind": "single", "preset": "compact", "simulator": {"preset": "single_flash"}, "init": "bundled:single",
    "sizes": [[0, 128], [1000, 256]], "lr": 5e-5, "warmup": 100, "map_weight": 0.1, "validate_every": 400,
    "checkpoint_every_s": 120.0, "seed": 1,
}

#: One change each against ``control``.
ARMS: dict[str, dict[str, Any]] = {
    "control": {},
    "photo_aug": {"simulator": {"capture": {"noise_median": 0.008, "noise_log_std": 0.25}, "jpeg_quality": [80, 98]}},
    "normal_l1": {"normal_weight": 1.0},
    "relief": {"simulator": {"normal_strength": [1.0, 2.0]}},
    "crop256": {"sizes": [[0, 256]]},
    "128_only": {"sizes": [[0, 128]]},
}

KEYS = ("rmse_normal", "rmse_render", "rmse_diffuse", "rmse_roughness", "rmse_specular")


def arm_config(name: str, steps: int, threads: int, runs: Path, device: str = "cpu") -> TrainConfig:
    cfg = copy.deepcopy(BASE)
    for key, value in ARMS[name].items():
        cfg[key] = {**cfg[key], **value} if isinstance(value, dict) and isinstance(cfg.get(key), dict) else value
    if name == "crop256":  # the same time: a quarter of the texels per step buys about 4x the steps at 128^2
        steps = max(1, steps // 4)
    return TrainConfig.from_dict({**cfg, "name": f"campaign_{name}", "out": str(runs),
                                  "steps": steps, "threads": threads, "device": device})


def keep(name: str, checkpoint: Path, path: Path = KEPT) -> int:
    """Write arm ``name``'s weights (fp16), step, seconds and log to ``path`` (zlib, atomic); returns its bytes."""
    state = load_state(checkpoint)
    kept = {"arm": name, "step": int(state["step"]), "seconds": float(state["seconds"]), "log": state["log"],
            "config": state["config"], "net_config": state["net_config"],
            "model": {k: v.half() if v.is_floating_point() else v for k, v in state["model"].items()}}
    buffer = io.BytesIO()
    torch.save(kept, buffer)
    packed = zlib.compress(buffer.getvalue(), 9)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(packed)
    return len(packed)


def kept_start(name: str, cfg: TrainConfig, path: Path = KEPT) -> TrainConfig:
    """``cfg`` continued from the kept checkpoint when it holds arm ``name`` (and the run folder has none): its
    weights as ``init`` (written into the run folder), the steps left, the log's offset recorded in ``kept.json``."""
    if not path.is_file():
        return cfg
    state = torch.load(io.BytesIO(zlib.decompress(path.read_bytes())), map_location="cpu", weights_only=False)
    if state["arm"] != name or state["step"] >= cfg.steps:
        return cfg
    cfg.run_dir.mkdir(parents=True, exist_ok=True)
    weights = cfg.run_dir / "kept_weights.pt"
    torch.save({k: v.float() if v.is_floating_point() else v for k, v in state["model"].items()}, weights)
    write_json(cfg.run_dir / "kept.json", {"step": state["step"], "seconds": state["seconds"], "log": state["log"]})
    return TrainConfig.from_dict({**dataclasses.asdict(cfg), "init": str(weights), "steps": cfg.steps - state["step"]})


def offset_of(run: Path) -> tuple[int, float]:
    """The steps and seconds a run continued from a kept checkpoint had behind it (0, 0.0 otherwise)."""
    path = run / "kept.json"
    if not path.is_file():
        return 0, 0.0
    data = json.loads(path.read_text())
    return int(data["step"]), float(data["seconds"])


def net_of(checkpoint: Path) -> torch.nn.Module:
    state = load_state(checkpoint)
    net = build_network(config_from_dict(state["net_config"]))
    net.load_state_dict(state["model"])
    return net.eval()


def measure(checkpoint: Path) -> dict[str, Any]:
    state = load_state(checkpoint)
    net = net_of(checkpoint)
    held = held_out_accuracy(net, materials=16, size=256, progress=False)
    foreign = foreign_accuracy(net, materials=16, size=256, progress=False)
    pick = lambda acc, row: {k: round(float(acc[row][k]), 5) for k in KEYS}  # noqa: E731
    return {"steps": int(state["step"]), "seconds": round(float(state.get("seconds", 0.0)), 1),
            "heldout": pick(held, "single"), "heldout_flat": pick(held, "baseline single"),
            "foreign": pick(foreign, "single"), "foreign_flat": pick(foreign, "baseline single"),
            "validation": [row for row in state["log"] if "val_rmse_normal" in row]}


def relief(net: torch.nn.Module) -> dict[str, Any]:
    """How much relief the net's normals carry, on the held-out set and the foreign captures at 256^2: the ratio of
    the predicted slopes' energy to the true slopes' (``n.xy / n.z``, mean square over texels), and the mean over
    materials of the per-material correlation of predicted and true slopes (x and y pooled)."""
    out = {}
    for name, data in (("heldout", load_heldout(HeldOutSet(size=256, materials=16, n_images=1,
                                                           preset="single_flash"), progress=False)),
                       ("foreign", load_foreign(ForeignSet(size=256, materials=16, n_images=1), progress=False))):
        with torch.inference_mode():
            pred = torch.cat([net(data.inputs[i:i + 2, :1]) for i in range(0, len(data.inputs), 2)])
        true_s = data.maps[:, 0:2] / data.maps[:, 2:3].clamp_min(1e-3)
        pred_s = pred[:, 0:2] / pred[:, 2:3].clamp_min(1e-3)
        a = (true_s - true_s.mean((2, 3), keepdim=True)).flatten(1)
        b = (pred_s - pred_s.mean((2, 3), keepdim=True)).flatten(1)
        corr = (a * b).sum(1) / (a.norm(dim=1) * b.norm(dim=1)).clamp_min(1e-12)
        out[name] = {"energy_ratio": round(float(pred_s.pow(2).mean() / true_s.pow(2).mean()), 4),
                     "correlation": round(float(corr.mean()), 4)}
    return out


def bundled_point() -> dict[str, Any]:
    entry = read_manifest()["single"]
    held, foreign = entry["accuracy"], entry["foreign_accuracy"]
    pick = lambda acc, row: {k: acc[row][k] for k in KEYS}  # noqa: E731
    return {"steps": entry["steps"], "hours": entry["training_hours"], "cores": entry["machine"]["cores"],
            "heldout": pick(held, "single"), "heldout_flat": pick(held, "baseline single"),
            "foreign": pick(foreign, "single"), "foreign_flat": pick(foreign, "baseline single")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--steps", type=int, default=1200, help="steps of each arm (crop256: a quarter)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="training device: cpu, cuda or cuda:N (TrainConfig.device)")
    parser.add_argument("--out", type=Path, default=DOCS)
    parser.add_argument("--runs", type=Path, default=CACHE / "campaign", help="folder of the arms' run folders")
    parser.add_argument("--keep", choices=list(ARMS), default=None,
                        help=f"keep this arm's checkpoint in git ({KEPT.relative_to(KEPT.parents[2])}, replaced)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    path = args.out / "nets_campaign.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    results["bundled"] = bundled_point()
    results.setdefault("arms", {})
    for name in args.arms:
        if name in results["arms"]:
            print(f"{name}: measured already, skipped")
            continue
        cfg = arm_config(name, args.steps, args.threads, args.runs, args.device)
        ckpt = cfg.run_dir / "checkpoint.pt"
        if not ckpt.is_file():
            cfg = kept_start(name, cfg)
        t0 = time.time()
        train(cfg, resume=ckpt.is_file(), progress=False, report=print)
        if int(load_state(ckpt)["step"]) < cfg.steps:  # stopped (Ctrl-C, SIGTERM): the campaign stops with it
            print(f"{name}: stopped before its last step; run the campaign again to continue it")
            break
        result = measure(ckpt)
        steps_before, seconds_before = offset_of(cfg.run_dir)
        result["steps"] += steps_before
        result["seconds"] = round(result["seconds"] + seconds_before, 1)
        result.update(change=ARMS[name], threads=args.threads, wall_seconds=round(time.time() - t0, 1),
                      cpu=os.cpu_count())
        results["arms"][name] = result
        write_json(path, results)
        print(name, json.dumps({k: result[k] for k in ("steps", "seconds", "heldout", "foreign")}, allow_nan=False))
    if args.keep is not None:
        ckpt = arm_config(args.keep, args.steps, args.threads, args.runs).run_dir / "checkpoint.pt"
        if ckpt.is_file():
            print(f"kept {args.keep}: {KEPT} ({keep(args.keep, ckpt) / 1e6:.1f} MB)")
    if "relief" not in results["bundled"]:
        results["bundled"]["relief"] = results.get("bundled_relief") or relief(load_network("single").eval())
        results["bundled_relief"] = results["bundled"]["relief"]
    for name, r in results["arms"].items():
        ckpt = arm_config(name, args.steps, args.threads, args.runs).run_dir / "checkpoint.pt"
        if "relief" not in r and ckpt.is_file():
            r["relief"] = relief(net_of(ckpt))
    write_json(path, results)
    write_text(args.out / "nets_campaign.md", page(results))
    plot(results, args.out / "nets_campaign.png")
    return 0


def cpu_hours(seconds: float, threads: int) -> float:
    return seconds * threads / 3600.0


def page(results: dict[str, Any]) -> str:
    """The campaign's page: each arm against the bundled net and the control, held-out and foreign at 256^2."""
    b = results["bundled"]
    start = b["hours"] * b["cores"]
    lines = ["# What limits the single-image net's normals", "",
             "Generated by `python benchmarks/train_campaign.py`; do not edit by hand. Each arm continues the "
             f"bundled single-image net ({b['steps']} steps, {start:.2f} CPU-hours) with one change against "
             "`control` (the same continuation, nothing changed); measured on the held-out set and the foreign "
             "captures at 256^2, 16 materials each, the net alone. `/ flat`: the normal RMSE over a flat normal "
             "map's (the trivial baseline's); `/ trivial`: the re-rendering RMSE over the trivial baseline's. "
             "CPU-hours: the runs' wall seconds x their threads, so a run beside other work counts its waits too (the "
             "steps are the measure of work).", "",
             "![normal RMSE against CPU-hours](nets_campaign.png)", ""]
    rows = [["bundled", "", f"{start:.2f}", str(b["steps"]),
             *cells(b)]]
    for name, r in results["arms"].items():
        rows.append([name, json.dumps(r["change"], allow_nan=False), f"{start + cpu_hours(r['seconds'], r['threads']):.2f}",
                     str(b["steps"] + r["steps"]), *cells(r)])
    lines += [markdown_table(["arm", "change", "CPU-hours", "steps", "held-out normal", "/ flat", "held-out render",
                              "/ trivial", "foreign normal", "/ flat", "foreign render", "/ trivial"], rows), ""]
    rel = [["bundled", *relief_cells(b)]] if "relief" in b else []
    rel += [[name, *relief_cells(r)] for name, r in results["arms"].items() if "relief" in r]
    if rel:
        lines += ["How much relief the normals carry: the predicted slopes' energy over the true slopes' (1: as "
                  "much relief as the truth), and the mean per-material correlation of predicted and true slopes "
                  "(1: the right relief; a fit of the best scalar gain removes a fraction correlation^2 of the "
                  "error's variance, no more).", "",
                  markdown_table(["net", "held-out energy ratio", "held-out correlation", "foreign energy ratio",
                                  "foreign correlation"], rel), ""]
    control = results["arms"].get("control")
    if control:
        lines += ["Against `control` (below 1: the change helps):", ""]
        crow = []
        for name, r in results["arms"].items():
            if name == "control":
                continue
            crow.append([name, *(f"{r[s][k] / control[s][k]:.3f}" for s in ("heldout", "foreign")
                                 for k in ("rmse_normal", "rmse_render", "rmse_diffuse", "rmse_roughness",
                                           "rmse_specular"))])
        lines += [markdown_table(["arm", *(f"{s} {k}" for s in ("held-out", "foreign")
                                           for k in ("normal", "render", "diffuse", "roughness", "specular"))],
                                 crow), ""]
    return "\n".join(lines)


def relief_cells(r: dict[str, Any]) -> list[str]:
    return [f"{r['relief'][s][k]:.3f}" for s in ("heldout", "foreign") for k in ("energy_ratio", "correlation")]


def cells(r: dict[str, Any]) -> list[str]:
    out = []
    for s in ("heldout", "foreign"):
        n, f = r[s]["rmse_normal"], r[f"{s}_flat"]["rmse_normal"]
        rr, fr = r[s]["rmse_render"], r[f"{s}_flat"]["rmse_render"]
        out += [f"{n:.4f}", f"{n / f:.3f}", f"{rr:.4f}", f"{rr / fr:.3f}"]
    return out


def plot(results: dict[str, Any], path: Path) -> None:
    """Normal RMSE over flat against CPU-hours: the bundled net, then each arm's end, held-out and foreign."""
    plt = pyplot()
    b = results["bundled"]
    start = b["hours"] * b["cores"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, s, title in ((axes[0], "heldout", "held-out (like training)"), (axes[1], "foreign", "foreign captures")):
        ratio = lambda r: r[s]["rmse_normal"] / r[f"{s}_flat"]["rmse_normal"]  # noqa: E731
        ax.plot([start], [ratio(b)], "ko", label="bundled")
        for name, r in results["arms"].items():
            end = start + cpu_hours(r["seconds"], r["threads"])
            ax.plot([start, end], [ratio(b), ratio(r)], "o-", label=name)
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        if s == "heldout":
            ax.axhline(0.7, color="green", lw=0.8, ls=":", label="target 0.7")
        ax.set_xlabel("CPU-hours of training (2 cores)"), ax.set_ylabel("normal RMSE / flat normal's")
        ax.set_title(title), ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    raise SystemExit(main())
