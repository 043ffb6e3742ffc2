"""Bundled network weights: export from a training checkpoint, load with a checksum check.

The package folder ``mi_svbrdf/weights/`` holds one fp16 state dict per network, zlib-compressed
(``single_compact.pt.zz``, ``multi_compact.pt.zz``, ~18 MB each: the compact nets' ~10 M fp16
parameters are 20 MB raw) and ``manifest.json``, which records for each:
the architecture (:class:`~mi_svbrdf.nets.network.NetConfig`), the training recipe and data settings,
steps and training time, the file's SHA-256, the machine that exported it (:func:`machine`) and
the held-out accuracy measured when it was exported, and the net's output BRDF model (``"distribution"``:
``"ggx"``, or ``"beckmann"`` for a net trained with ``TrainConfig.distribution="beckmann"``; entries without
it are GGX, :func:`entry_distribution`). A fused multi-image net (``NetConfig.fusion``) stores its fusion head and
multi-image branch; its entry's ``base`` names the bundled single net that is its single-image branch, by
checksum. :func:`load_network` verifies the checksum and refuses a file
whose architecture does not match the manifest (or a caller's expectation) with a clear error. Nothing
is downloaded.

Examples:
    >>> from mi_svbrdf.nets.weights import available
    >>> sorted(available())  # doctest: +SKIP
    ['multi', 'single']
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import platform
import zlib
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.nets.curve import plot_curve
from mi_svbrdf.nets.network import NetConfig, SVBRDFNet, build_network, config_from_dict

#: The package folder of the bundled weights (``mi_svbrdf/weights/``).
WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "weights"
MANIFEST = "manifest.json"
#: The output BRDF model of a net whose manifest entry does not record one.
DEFAULT_DISTRIBUTION = "ggx"
#: Largest bundled weights file (bytes, compressed): every bundled net stays under 20 MB.
MAX_BYTES = 20_000_000
#: Name prefix of a fused multi net's single-image branch (``NetConfig.fusion``): not stored in its file, whose
#: manifest entry names the bundled single net instead (``"base": {"kind": "single", "sha256": ...}``).
BRANCH = "single."


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
    """Kinds (``"single"``, ``"multi"``, ``"large"``) with bundled weights."""
    return sorted(read_manifest(folder))


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``'s "model name", else :func:`platform.processor`; "" if unknown)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and value.strip():
                    return value.strip()
    except OSError:
        pass
    return platform.processor() or ""


def machine() -> dict[str, Any]:
    """The running machine, as the manifest records it: ``{"cpu": model, "cores": os.cpu_count(),
    "gpu": CUDA device name or None}``."""
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu}


def export_weights(checkpoint: str | Path, *, accuracy: dict[str, Any] | None = None,
                   foreign_accuracy: dict[str, Any] | None = None, folder: Path = WEIGHTS_DIR,
                   note: str = "") -> dict[str, Any]:
    """Write the fp16 weights of a training checkpoint and its manifest entry; returns the entry.

    Args:
        checkpoint: a ``checkpoint.pt`` of :mod:`mi_svbrdf.nets.train`.
        accuracy: held-out figures to record (e.g. from ``mi-svbrdf evaluate``).
        foreign_accuracy: the same figures on the foreign captures (recorded when given).
        folder: destination (default: the package's weights folder).
        note: how the run went beyond its recorded config (e.g. a resume with another lr), kept
            in the manifest entry.

    A run that continued the bundled net of its own kind (``init: "bundled:KIND"``, e.g. on a machine
    without the earlier run's checkpoint) adds to it: the entry's steps, hours, validation history and
    curve are those of the bundled net (from the package's manifest) followed by the run's, its steps
    offset by the bundled net's, and ``continues`` records what it started from.

    Raises:
        ValueError: the compressed weights would exceed :data:`MAX_BYTES` (nothing is written).
    """
    state = torch.load(Path(checkpoint).expanduser(), map_location="cpu", weights_only=False)
    cfg = config_from_dict(state["net_config"])
    # a fused multi net's single-image branch is the bundled single net's weights: referenced, not stored twice
    weights = {k: v.half() if v.is_floating_point() else v for k, v in state["model"].items()
               if not (cfg.fusion and k.startswith(BRANCH))}
    base = _base_reference(state["model"], folder) if cfg.fusion else None
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{cfg.kind}_compact.pt.zz" if state["config"].get("preset") == "compact" else f"{cfg.kind}.pt.zz"
    path = folder / name
    buffer = io.BytesIO()
    torch.save(weights, buffer)
    packed = zlib.compress(buffer.getvalue(), 9)
    if len(packed) >= MAX_BYTES:
        raise ValueError(f"{checkpoint}: expected weights under {MAX_BYTES / 1e6:.0f} MB compressed (the bundle's "
                         f"size limit), got {len(packed) / 1e6:.2f} MB for {name}; nothing written")
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(packed)
    train = state["config"]
    earlier = continued_entry(train.get("init"), cfg.kind) or {}
    offset, earlier_seconds = earlier.get("steps", 0), earlier.get("training_hours", 0.0) * 3600
    earlier_validation = earlier.get("validation", [])
    log = [{**r, "step": r["step"] + offset, **({"seconds": r["seconds"] + earlier_seconds} if "seconds" in r else {})}
           for r in state.get("log", [])]
    validation = [*earlier_validation,
                  *({k: (round(v, 5) if isinstance(v, float) else v) for k, v in r.items()
                     if k in ("step", "seconds") or k.startswith("val_rmse_")}
                    for r in log if any(k.startswith("val_") for k in r))]
    curve = None
    if log:  # the training curve, documented beside the weights (the continued net's validation first)
        curve = name.replace(".pt.zz", "_curve.png")
        plot_curve([*earlier_validation, *log], folder / curve)
    entry = {"file": name, "sha256": sha256(path), "bytes": path.stat().st_size, "net_config": cfg.to_dict(),
             "steps": offset + state["step"], "training_hours": round((earlier_seconds + state["seconds"]) / 3600, 3),
             "training": {k: train[k] for k in ("preset", "simulator", "batch_size", "sizes", "lr", "betas",
                                                "loss_preset", "map_weight", "ms_ssim_weight", "bf16", "seed", "init",
                                                "render_weight") if k in train},
             "distribution": train.get("distribution", DEFAULT_DISTRIBUTION),
             "machine": machine(), "curve": curve, "validation": validation,
             "accuracy": accuracy or {}}
    if base is not None:
        entry["base"] = base
    if foreign_accuracy:
        entry["foreign_accuracy"] = foreign_accuracy
    if earlier:
        entry["continues"] = {k: earlier.get(k) for k in ("sha256", "steps", "training_hours", "training", "note")
                              if earlier.get(k) is not None}
    if note:
        entry["note"] = note
    manifest = read_manifest(folder)
    manifest[cfg.kind] = entry
    write_json(folder / MANIFEST, manifest)
    return entry


def _base_reference(model: dict[str, torch.Tensor], folder: Path) -> dict[str, str]:
    """``{"kind": "single", "sha256": ...}``: the bundled single net of ``folder`` that a fused multi net's
    single-image branch (the ``single.`` tensors of ``model``) is.

    Raises:
        ValueError: ``folder`` bundles no single net, or its weights differ from the branch's (fp16).
    """
    manifest = read_manifest(folder)
    if "single" not in manifest:
        raise ValueError(f"{folder}: a fused multi-image net needs the bundled single-image net its branch is, "
                         f"got no 'single' entry in {folder / MANIFEST}")
    bundled = read_weights(folder / manifest["single"]["file"])
    branch = {k[len(BRANCH):]: v for k, v in model.items() if k.startswith(BRANCH)}
    same = branch.keys() == bundled.keys() and all(torch.equal(branch[k].half() if branch[k].is_floating_point()
                                                               else branch[k], bundled[k]) for k in bundled)
    if not same:
        raise ValueError(f"{folder}: the fused net's single-image branch differs from the bundled single net "
                         f"({manifest['single']['file']}); bundle that single net first")
    return {"kind": "single", "sha256": manifest["single"]["sha256"]}


def continued_entry(init: str | None, kind: str) -> dict[str, Any] | None:
    """The package's manifest entry a run of ``kind`` continued (``init == "bundled:KIND"``), else None."""
    if init != f"bundled:{kind}":
        return None
    entry = read_manifest(WEIGHTS_DIR).get(kind)
    if entry is None:
        raise ValueError(f"init: the run continued 'bundled:{kind}', but the package bundles no {kind!r} net "
                         f"to add its steps to (got {sorted(read_manifest(WEIGHTS_DIR))})")
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
    if cfg.fusion:  # the single-image branch: the bundled single net the entry names
        base = entry.get("base", {})
        single = manifest.get(base.get("kind", "single"), {})
        if not base or single.get("sha256") != base.get("sha256"):
            raise ValueError(f"{path}: the fused multi-image net expected the bundled single net with sha256 "
                             f"{base.get('sha256')}, got {single.get('sha256')} in {folder / MANIFEST}")
        branch = load_network(base["kind"], folder=folder).state_dict()
        state = {**{BRANCH + k: v for k, v in branch.items()}, **state}
    try:
        net.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})
    except RuntimeError as exc:
        raise ValueError(f"{path}: expected weights of the manifest's architecture, got mismatched tensors "
                         f"({str(exc).splitlines()[0]})") from exc
    return net.eval()


def entry_distribution(entry: dict[str, Any]) -> str:
    """The output BRDF model of a manifest entry: its ``"distribution"``, ``"ggx"`` when absent (older entries)."""
    return entry.get("distribution", DEFAULT_DISTRIBUTION)


def manifest_entry(kind: str, folder: Path = WEIGHTS_DIR) -> dict[str, Any]:
    """The manifest entry of ``kind`` (config, steps, accuracy ...)."""
    manifest = read_manifest(folder)
    if kind not in manifest:
        raise ValueError(f"kind: expected one of the bundled networks {sorted(manifest)}, got {kind!r}")
    return manifest[kind]
