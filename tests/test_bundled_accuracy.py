"""The bundled networks load, match their checksum and beat the trivial baseline on a small held-out set.

The small set is the first 9 materials (one per class) of the fixed held-out benchmark
(:class:`mi_svbrdf.data.heldout.HeldOutSet`) at 256^2: the single-image net on the flash photo, the
multi-image net on the 10 photos. "Beat" is a mean RMSE over the materials strictly below
the baseline's on the same photos:

* the trivial baseline from the photos alone, what the nets are given (the flash's nominal
  intensity): every map (normal, diffuse, roughness, specular) and the re-rendering;
* the baseline told the exact, jittered flash intensity and position, which the nets are not:
  normal, roughness and the diffuse albedo after the best global scale (the scale itself is
  what the unknown intensity leaves ambiguous).
"""
from __future__ import annotations

import pytest
import torch

from mi_svbrdf.eval.accuracy import held_out_accuracy, row_name
from mi_svbrdf.nets import weights as pretrained
from mi_svbrdf.nets.inference import PHOTO_KINDS

#: The symmetry ensemble measured beside the net alone: 2 (the photo and its mirror image, averaged: the ensemble's
#: code path, its maps mapped back) rather than predict's 8, a third of the fixture's cost at (1, 8); the 8-member
#: ensemble's accuracy is the benchmark's (docs/results.md), its transforms are tested in tests/test_ensemble.py.
ENSEMBLE = 2
KEYS = ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_render")
CALIBRATED_KEYS = ("rmse_normal", "rmse_roughness", "rmse_diffuse_scaled")


@pytest.fixture(scope="module")
def accuracy() -> dict[str, dict[str, float]]:
    if not pretrained.read_manifest():
        pytest.skip("no bundled weights in this checkout")
    threads = torch.get_num_threads()
    out: dict[str, dict[str, float]] = {}
    try:
        for kind in pretrained.available():
            if kind not in PHOTO_KINDS:  # the large-scale net has its own benchmark (test below)
                continue
            net = pretrained.load_network(kind).eval()  # verifies the checksum
            out.update(held_out_accuracy(net, materials=9, size=256, counts=(10,), progress=False,
                                         symmetries=(1, ENSEMBLE)))
    finally:
        torch.set_num_threads(threads)
    return out


@pytest.mark.parametrize("symmetries", [1, ENSEMBLE])
@pytest.mark.parametrize("kind, key", [("single", "single"), ("multi", "N=10")])
def test_bundled_net_beats_trivial_baseline_on_every_map(accuracy: dict[str, dict[str, float]], kind: str,
                                                         key: str, symmetries: int) -> None:
    """The net alone and as a symmetry ensemble (:data:`ENSEMBLE`)."""
    if key not in accuracy:
        pytest.skip(f"no bundled {kind} net")
    net = accuracy[row_name(key, symmetries)]
    for baseline, keys in ((f"baseline uncalibrated {key}", KEYS), (f"baseline {key}", CALIBRATED_KEYS)):
        base = accuracy[baseline]
        worse = {k: (round(net[k], 4), round(base[k], 4)) for k in keys if not net[k] < base[k]}
        assert not worse, f"{kind} net: (net, baseline) not below the {baseline!r}: {worse}"


def test_bundled_large_scale_net_records_that_its_exemplars_help() -> None:
    """The bundled large-scale net's recorded held-out benchmark (bundle measures it): with exemplars it
    re-renders better than without, than the single-image net on tiles and than the trivial baseline,
    and the exemplars' roughness moves its roughness the right way on every surface."""
    entry = pretrained.read_manifest().get("large")
    if entry is None:
        pytest.skip("no bundled large-scale net")
    acc = entry["accuracy"]
    render = {name: row["rmse_render"] for name, row in acc["methods"].items()}
    assert render["large"] < min(render["no_exemplar"], render["single"], render["trivial"]), render
    influence = acc["exemplar_influence"]
    assert influence["holds"] and influence["surfaces_holding"] == influence["surfaces"], influence


#: Photo counts at which the bundled multi-image path must not re-render worse than the single net at N = 1.
MORE_PHOTOS = (2, 3, 5, 10)
#: The symmetry ensemble both paths run in the more-photos test: 1 (the nets alone; the ensemble's code path is
#: the accuracy fixture's), an eighth of capture's 8. The claim holds with margin at 1 (docs/benchmarks/more_photos.md,
#: 16 materials per set: the fused net at N >= 2 re-renders 13-15 % below the single net at N = 1 on the held-out set,
#: 6-7 % on the foreign one) and held at 2 and 8 (this test's earlier forms).
MORE_PHOTOS_SYMMETRIES = 1


@pytest.mark.slow
@pytest.mark.parametrize("set_name", ["held-out", "foreign"])
def test_more_photos_never_re_render_worse_than_the_single_net_on_photo_1(set_name: str) -> None:
    """What ``capture`` runs on N >= 2 photos (the bundled multi-image net, fused with the single net when it
    is) against what it runs on photo 1 alone (the single net): the mean re-rendering RMSE over the first 9
    materials (one per class) of the set, each path as a symmetry ensemble of :data:`MORE_PHOTOS_SYMMETRIES`, at
    every N of :data:`MORE_PHOTOS`."""
    from mi_svbrdf.core.metrics import eval_lights
    from mi_svbrdf.data.foreign import ForeignSet
    from mi_svbrdf.data.heldout import HeldOutSet
    from mi_svbrdf.eval.harness import load_foreign, load_heldout, run_and_score
    from mi_svbrdf.eval.methods import make_method

    if not {"single", "multi"} <= set(pretrained.available()):
        pytest.skip("the single and multi-image nets are not both bundled")
    data = (load_heldout(HeldOutSet(size=256, materials=9, n_images=10), progress=False) if set_name == "held-out"
            else load_foreign(ForeignSet(size=256, materials=9, n_images=10), progress=False))
    lights = eval_lights()
    single = run_and_score(make_method("single", symmetries=MORE_PHOTOS_SYMMETRIES), data, 1, lights)[1]["rmse_render"]
    multi = make_method("multi", symmetries=MORE_PHOTOS_SYMMETRIES)
    worse = {n: round(e, 4) for n in MORE_PHOTOS
             if (e := run_and_score(multi, data, n, lights)[1]["rmse_render"]) > single}
    assert not worse, f"{set_name}: the single net on photo 1 re-renders at {single:.4f}, N photos worse: {worse}"
