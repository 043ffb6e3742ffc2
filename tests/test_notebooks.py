"""The notebooks execute top to bottom (fast mode: small sizes; tiny random nets as the weights)."""
from __future__ import annotations

import pathlib

import nbformat
import pytest
import torch
from nbclient import NotebookClient

from mi_svbrdf.nets.network import build_network, network_config
from mi_svbrdf.nets.weights import export_weights

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """Tiny random single and multi nets (accuracy is not tested: the notebooks' code paths are)."""
    folder = tmp_path_factory.mktemp("weights")
    for seed, kind in enumerate(("single", "multi")):
        torch.manual_seed(seed)
        cfg = network_config("compact", kind, encoder_features=(8, 16, 16, 16), last_features=8, resolution=64)
        ckpt = folder / f"{kind}_checkpoint.pt"
        torch.save({"net_config": cfg.to_dict(), "model": build_network(cfg).state_dict(),
                    "config": {"preset": "compact"}, "step": 0, "seconds": 0.0}, ckpt)
        export_weights(ckpt, folder=folder)
    return folder


def test_the_issue_notebooks_exist():
    assert {p.stem for p in NOTEBOOKS} >= {"01_rendering_loss", "02_learned_vs_optimised", "03_dataset_from_scene"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path, monkeypatch, weights):
    monkeypatch.setenv("MI_SVBRDF_FAST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("MI_SVBRDF_WEIGHTS", str(weights))
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    nb = nbformat.read(path, as_version=4)
    assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), "commit notebooks without outputs"
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
