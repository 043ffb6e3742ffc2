"""Bundled network weights: export from a training checkpoint, load with a checksum check.

The package folder ``mi_svbrdf/weights/`` holds one fp16 state dict per network, zlib-compressed
(``single_compact.pt.zz``, ``multi_compact.pt.zz``, ~18 MB each: the compact nets' ~10 M fp16
parameters are 20 MB raw) and ``manifest.json``, which records for each:
the architecture (:class:`~mi_svbrdf.network.NetConfig`), the training recipe and data settings,
steps and training time, the file's SHA-256, and the held-out accuracy measured when it was
exported. :func:`load_network` verifies the checksum and refuses a file whose architecture does
not match the manifest (or a caller's expectation) with a clear error. Nothing is downloaded.

Examples:
    >>> from mi_svbrdf.pretrained import available
    >>> sorted(available())  # doctest: +SKIP
    ['multi', 'single']
"""
from __future__ import annotations

import hashlib
import io
import json
import zlib
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.image_io import atomic_path
from mi_svbrdf.metrics import METRIC_KEYS
from mi_svbrdf.network import NetConfig, SVBRDFNet, build_network, config_from_dict

WEIGHTS_DIR = Path(__file__).parent / "weights"
MANIFEST = "manifest.json"


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_manifest(folder: Path = WEIGHTS_DIR) -> dict[str, Any]:
    """The manifest ``{kind: entry}`` (empty when no weights are bundled)."""
    path = folder / MANIFEST
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: expected a JSON manifest, got invalid JSON ({exc})") from exc


def available(folder: Path = WEIGHTS_DIR) -> list[str]:
    """Kinds (``"single"``, ``"multi"``) with bundled weights."""
    return sorted(read_manifest(folder))


def export_weights(checkpoint: str | Path, *, accuracy: dict[str, Any] | None = None,
                   folder: Path = WEIGHTS_DIR, note: str = "") -> dict[str, Any]:
    """Write the fp16 weights of a training checkpoint and its manifest entry; returns the entry.

    Args:
        checkpoint: a ``checkpoint.pt`` of :mod:`mi_svbrdf.train`.
        accuracy: held-out figures to record (e.g. from ``mi-svbrdf evaluate``).
        folder: destination (default: the package's weights folder).
        note: how the run went beyond its recorded config (e.g. a resume with another lr), kept
            in the manifest entry.
    """
    state = torch.load(Path(checkpoint).expanduser(), map_location="cpu", weights_only=False)
    cfg = config_from_dict(state["net_config"])
    weights = {k: v.half() if v.is_floating_point() else v for k, v in state["model"].items()}
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{cfg.kind}_compact.pt.zz" if state["config"].get("preset") == "compact" else f"{cfg.kind}.pt.zz"
    path = folder / name
    buffer = io.BytesIO()
    torch.save(weights, buffer)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(zlib.compress(buffer.getvalue(), 9))
    train = state["config"]
    log = state.get("log", [])
    validation = [{k: (round(v, 5) if isinstance(v, float) else v) for k, v in r.items()
                   if k in ("step", "seconds") or k.startswith("val_rmse_")}
                  for r in log if any(k.startswith("val_") for k in r)]
    curve = None
    if log:  # the training curve, documented beside the weights
        from mi_svbrdf.train import plot_curve

        curve = name.replace(".pt.zz", "_curve.png")
        plot_curve(log, folder / curve)
    entry = {"file": name, "sha256": sha256(path), "bytes": path.stat().st_size, "net_config": cfg.to_dict(),
             "steps": state["step"], "training_hours": round(state["seconds"] / 3600, 3),
             "training": {k: train[k] for k in ("preset", "simulator", "batch_size", "sizes", "lr", "betas",
                                                "loss_preset", "map_weight", "bf16", "seed", "init") if k in train},
             "machine": "2-core CPU (AVX-512 bf16), no GPU", "curve": curve, "validation": validation,
             "accuracy": accuracy or {}}
    if note:
        entry["note"] = note
    manifest = read_manifest(folder)
    manifest[cfg.kind] = entry
    with atomic_path(folder / MANIFEST) as tmp:
        Path(tmp).write_text(json.dumps(manifest, indent=2) + "\n")
    return entry


def read_weights(path: Path) -> dict[str, torch.Tensor]:
    """The state dict of a bundled weights file (zlib-compressed ``torch.save``), unverified."""
    try:
        return torch.load(io.BytesIO(zlib.decompress(Path(path).read_bytes())), map_location="cpu", weights_only=True)
    except zlib.error as exc:
        raise ValueError(f"{path}: expected a zlib-compressed weights file, got undecodable data ({exc})") from exc


def load_network(kind: str = "single", *, expected: NetConfig | None = None,
                 folder: Path = WEIGHTS_DIR) -> SVBRDFNet:
    """The bundled ``kind`` network in eval mode (float32), checksum verified.

    Raises:
        ValueError: no weights for ``kind``, a checksum mismatch (a corrupt or replaced file), or
            an architecture different from the manifest's or from ``expected``.
    """
    manifest = read_manifest(folder)
    if kind not in manifest:
        raise ValueError(f"kind: expected one of the bundled networks {sorted(manifest)}, got {kind!r}")
    entry = manifest[kind]
    path = folder / entry["file"]
    if not path.is_file():
        raise ValueError(f"{path}: expected the bundled weights file named in {folder / MANIFEST}, not found")
    digest = sha256(path)
    if digest != entry["sha256"]:
        raise ValueError(f"{path}: checksum mismatch: expected sha256 {entry['sha256']}, got {digest} "
                         "(the file is corrupt or does not belong to this manifest)")
    cfg = config_from_dict(entry["net_config"])
    if expected is not None and expected != cfg:
        raise ValueError(f"{path}: expected a network with config {expected.to_dict()}, "
                         f"got {cfg.to_dict()}")
    net = build_network(cfg)
    state = read_weights(path)
    try:
        net.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})
    except RuntimeError as exc:
        raise ValueError(f"{path}: expected weights of the manifest's architecture, got mismatched tensors "
                         f"({str(exc).splitlines()[0]})") from exc
    return net.eval()


def manifest_entry(kind: str, folder: Path = WEIGHTS_DIR) -> dict[str, Any]:
    """The manifest entry of ``kind`` (config, steps, accuracy ...)."""
    manifest = read_manifest(folder)
    if kind not in manifest:
        raise ValueError(f"kind: expected one of the bundled networks {sorted(manifest)}, got {kind!r}")
    return manifest[kind]


#: Held-out photo counts reported for the multi-image net (issue 5).
MULTI_COUNTS = (1, 2, 3, 5, 10)
#: The thesis's Table 3.1 figures of its single-image net (a different test set; our target).
THESIS = {"rmse_render": 0.083, "rmse_normal": 0.035, "rmse_diffuse": 0.019, "rmse_specular": 0.050,
          "rmse_roughness": 0.129}


def held_out_accuracy(net: SVBRDFNet, *, materials: int = 16, size: int = 256,
                      counts: tuple[int, ...] = MULTI_COUNTS, progress: bool = True) -> dict[str, Any]:
    """The issue's accuracy table on the fixed held-out set (:class:`mi_svbrdf.heldout.HeldOutSet`).

    The single-image net sees the ``single_flash`` set; the multi-image net the ``multiview`` set
    at each N of ``counts`` (the first N photos; photo 0 is the fronto-parallel flash). The trivial
    baseline (:func:`mi_svbrdf.baseline.trivial_baseline`) is measured on the same photos twice:
    with the exact captures (``"baseline ..."``: it knows the flash's jittered intensity and
    position, which the nets do not) and from the photos alone (``"baseline uncalibrated ..."``:
    the nominal flash of :func:`~mi_svbrdf.baseline.default_captures`, photo 0). Returns
    ``{"single" | "N=k": metrics, "baseline ...": metrics, "set": ...}`` with the keys of
    :data:`mi_svbrdf.metrics.METRIC_KEYS`.
    """
    from mi_svbrdf.baseline import trivial_baseline
    from mi_svbrdf.heldout import VERSION, HeldOutSet
    from mi_svbrdf.metrics import eval_lights, evaluate_maps

    single = net.config.kind == "single"
    held = HeldOutSet(size=size, materials=materials, n_images=1 if single else max(counts),
                      preset="single_flash" if single else "multiview")
    maps, inputs, captures = held.load(progress=progress)
    lights = eval_lights()
    out: dict[str, Any] = {"set": {"materials": materials, "size": size, "preset": held.preset, "seed": held.seed,
                              "version": VERSION}}

    def run(photos: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            return torch.cat([net(photos[i:i + 2]).float() for i in range(0, photos.shape[0], 2)])

    for n in ([1] if single else counts):
        key = "single" if single else f"N={n}"
        out[key] = evaluate_maps(run(inputs[:, :n]), maps, lights)
        out[f"baseline {key}"] = evaluate_maps(trivial_baseline(inputs[:, :n], captures.images(slice(0, n))),
                                               maps, lights)
        # what the net knows: the photos only (the nominal flash of the default capture)
        out[f"baseline uncalibrated {key}"] = evaluate_maps(trivial_baseline(inputs[:, :n]), maps, lights)
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


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.pretrained CHECKPOINT [--materials 16] [--size 256] [--dry-run] [--note TEXT]``:
    measure the held-out accuracy of a training checkpoint and bundle it (fp16 + manifest)."""
    import argparse

    from mi_svbrdf.train import load_state

    parser = argparse.ArgumentParser(prog="python -m mi_svbrdf.pretrained", description=main.__doc__)
    parser.add_argument("checkpoint")
    parser.add_argument("--materials", type=int, default=16)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--dry-run", action="store_true", help="measure and print, do not bundle")
    parser.add_argument("--note", default="", help="how the run went beyond its config (kept in the manifest)")
    args = parser.parse_args(argv)
    state = load_state(args.checkpoint)
    net = build_network(config_from_dict(state["net_config"]))
    # measure the weights as they will be bundled: rounded to fp16
    net.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in state["model"].items()})
    accuracy = held_out_accuracy(net.eval(), materials=args.materials, size=args.size)
    print(accuracy_table(accuracy))
    if not args.dry_run:
        entry = export_weights(args.checkpoint, accuracy=accuracy, note=args.note)
        print(f"bundled {entry['file']} ({entry['bytes'] / 1e6:.1f} MB, sha256 {entry['sha256'][:12]}...)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
