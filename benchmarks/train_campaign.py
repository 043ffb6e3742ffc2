"""Campaign: what limits the single-image net's normals, one cause at a time, charted against CPU-hours.

Every arm continues the bundled single-image net (``init = "bundled:single"``) with the same
schedule, seed, batch and time, and changes **one** thing against the ``control`` arm (the same
continuation with nothing changed: what more steps alone buy):

* ``photo_aug``: photos as a phone delivers them: sensor noise up to 0.022 (median 0.008; the
  training presets stop at 0.017) and JPEG at quality 80-98 per photo. Both stay below the
  foreign set's ranges (noise 0.025-0.04, JPEG 40-75), so the foreign set is still foreign.
* ``normal_l1``: a direct L1 on the normal map (weight 1) beside the rendering loss.
* ``relief``: steeper reliefs in the data (slopes x k, k log-uniform in [1, 2]).
* ``crop256``: 256^2 crops instead of 128^2 (a quarter of the steps in the same time).

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
import json
import os
import time
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.eval.accuracy import foreign_accuracy, held_out_accuracy
from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.nets.train import CACHE, TrainConfig, load_state, train
from mi_svbrdf.nets.network import build_network, config_from_dict
from mi_svbrdf.nets.weights import read_manifest

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks"

#: The continuation every arm shares: the bundled net's last recipe (map L1 0.1, lr 5e-5) at 128^2.
BASE: dict[str, Any] = {
    "kind": "single", "preset": "compact", "simulator": {"preset": "single_flash"}, "init": "bundled:single",
    "sizes": [[0, 128]], "lr": 5e-5, "warmup": 100, "map_weight": 0.1, "validate_every": 400,
    "checkpoint_every_s": 120.0, "seed": 1,
}

#: One change each against ``control``.
ARMS: dict[str, dict[str, Any]] = {
    "control": {},
    "photo_aug": {"simulator": {"capture": {"noise_median": 0.008, "noise_log_std": 0.25}, "jpeg_quality": [80, 98]}},
    "normal_l1": {"normal_weight": 1.0},
    "relief": {"simulator": {"normal_strength": [1.0, 2.0]}},
    "crop256": {"sizes": [[0, 256]]},
}

KEYS = ("rmse_normal", "rmse_render", "rmse_diffuse", "rmse_roughness", "rmse_specular")


def arm_config(name: str, steps: int, threads: int, runs: Path) -> TrainConfig:
    cfg = copy.deepcopy(BASE)
    for key, value in ARMS[name].items():
        cfg[key] = {**cfg[key], **value} if isinstance(value, dict) and isinstance(cfg.get(key), dict) else value
    if name == "crop256":  # the same time: a quarter of the texels per step buys about 4x the steps at 128^2
        steps = max(1, steps // 4)
    return TrainConfig.from_dict({**cfg, "name": f"campaign_{name}", "out": str(runs),
                                  "steps": steps, "threads": threads})


def measure(checkpoint: Path) -> dict[str, Any]:
    state = load_state(checkpoint)
    net = build_network(config_from_dict(state["net_config"]))
    net.load_state_dict(state["model"])
    net.eval()
    held = held_out_accuracy(net, materials=16, size=256, progress=False)
    foreign = foreign_accuracy(net, materials=16, size=256, progress=False)
    pick = lambda acc, row: {k: round(float(acc[row][k]), 5) for k in KEYS}  # noqa: E731
    return {"steps": int(state["step"]), "seconds": round(float(state.get("seconds", 0.0)), 1),
            "heldout": pick(held, "single"), "heldout_flat": pick(held, "baseline single"),
            "foreign": pick(foreign, "single"), "foreign_flat": pick(foreign, "baseline single"),
            "validation": [row for row in state["log"] if "val_rmse_normal" in row]}


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
    parser.add_argument("--steps", type=int, default=1200, help="steps of each 128^2 arm (crop256: a quarter)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=DOCS)
    parser.add_argument("--runs", type=Path, default=CACHE / "campaign", help="folder of the arms' run folders")
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
        cfg = arm_config(name, args.steps, args.threads, args.runs)
        ckpt = cfg.run_dir / "checkpoint.pt"
        t0 = time.time()
        train(cfg, resume=ckpt.is_file(), progress=False, report=print)
        result = measure(ckpt)
        result.update(change=ARMS[name], threads=args.threads, wall_seconds=round(time.time() - t0, 1),
                      cpu=os.cpu_count())
        results["arms"][name] = result
        write_json(path, results)
        print(name, json.dumps({k: result[k] for k in ("steps", "seconds", "heldout", "foreign")}))
    write_json(path, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
