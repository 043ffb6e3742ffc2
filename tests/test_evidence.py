"""The choice by evidence (mi_svbrdf.eval.evidence): the rule, the held photos, the leave-one-out folds, the
scores with estimated and with known lights, the refined candidate, and a strict-JSON summary."""
from __future__ import annotations

import json
import math

import pytest
import torch

from mi_svbrdf.core.render import render
from mi_svbrdf.data import procedural
from mi_svbrdf.eval.evidence import (
    Judgement,
    choose,
    estimated_pair,
    held_photos,
    judge,
    photo_error,
    polish_light,
    with_refinement,
)
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, ImageSpec, LightSpec
from mi_svbrdf.optim.refine import RefineConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SIZE = 32
SEARCH = RefineConfig(search_size=16, progress=False)
LIGHTS = ((0.0, 0.0, 2.0), (1.2, 0.5, 1.5), (-1.0, -0.8, 1.6))
CAMERA = (0.0, 0.0, 2.0)


@pytest.fixture(scope="module")
def scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, CaptureSpec]:
    """The truth, worse maps (flat normals), the photos of the truth under three lights, and their capture."""
    truth = procedural.generate("tiles", 0, SIZE)[None]
    flat = truth.clone()
    flat[:, :3] = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
    light = torch.tensor([LIGHTS])
    view = torch.tensor([[CAMERA] * len(LIGHTS)])
    photos = render(truth, light, view, distance_falloff=True)[0].clamp(0.0, 1.0)
    spec = CaptureSpec(tuple(ImageSpec(f"{k:03d}.exr", "linear_exr", True, CameraSpec(CAMERA),
                                       LightSpec(pos, (1.0, 1.0, 1.0))) for k, pos in enumerate(LIGHTS)))
    return truth, flat, photos, spec


def test_the_rule_a_level_replaces_the_simpler_choice_only_clearly_below_it() -> None:
    assert choose({"single": 0.10, "multi": 0.09, "fused": 0.08})[0] == "fused"
    assert choose({"single": 0.100, "multi": 0.0985, "fused": 0.0999})[0] == "single"  # all within 2 %
    # the multi-image and fused nets read the same photos: one level, the lower wins however close
    assert choose({"single": 0.12, "multi": 0.0985, "fused": 0.0984})[0] == "fused"
    assert choose({"single": 0.12, "multi": 0.0984, "fused": 0.0985})[0] == "multi"
    choice, why = choose({"fused": 0.0970, "multi": 0.0985}, tie=0.0)
    assert choice == "fused" and "lowest" in why
    assert choose({"single": None, "multi": math.nan, "fused": 0.3})[0] == "fused"  # unscored ones are skipped
    assert choose({"fused": 0.1, "refined": 0.0995})[0] == "fused"  # the refinement must clearly win
    assert choose({"single": 0.1, "fused": 0.09, "refined": 0.0899})[0] == "fused"  # over the level below it
    assert choose({"single": 0.1, "fused": 0.0995, "refined": 0.09})[0] == "refined"
    assert "not clearly below" in choose({"single": 0.100, "fused": 0.099})[1]
    # tie 0: the lowest
    for scores in ({"single": 0.1, "multi": 0.0999}, {"single": 0.0999, "fused": 0.1, "refined": 0.09991}):
        assert choose(scores, tie=0.0)[0] == min(scores, key=scores.__getitem__)
    with pytest.raises(ValueError, match="expected at least one finite score"):
        choose({"single": None})
    with pytest.raises(ValueError, match="expected candidates among"):
        choose({"ensemble": 0.1})
    with pytest.raises(ValueError, match="tie: expected a margin >= 0"):
        choose({"single": 0.1}, tie=-0.1)


def test_held_photos_are_never_photo_0_and_spread_over_the_rest() -> None:
    assert held_photos(2) == [1] and held_photos(5) == [1, 2, 3, 4]
    assert held_photos(10, 4) == [1, 4, 6, 9] and held_photos(10, 1) == [9]
    with pytest.raises(ValueError, match="expected 2 photos or more"):
        held_photos(1)
    with pytest.raises(ValueError, match="expected at least 1 held photo"):
        held_photos(5, 0)


def test_photo_error_is_low_for_the_truth_with_known_and_with_estimated_lights(scene) -> None:
    truth, flat, photos, spec = scene
    known = photo_error(truth, photos, 1, spec=spec)
    assert known < 1e-3  # the photo is the truth's render: only the clip remains
    darker = truth * torch.tensor([1, 1, 1, .5, .5, .5, 1, 1, 1, 1.])[None, :, None, None]
    assert photo_error(darker, photos, 1, spec=spec) > 10 * known and photo_error(flat, photos, 1, spec=spec) > 10 * known
    # the light estimated under the truth, the search's grid then polished: near the known light's error
    assert photo_error(truth, photos, 1, config=SEARCH) < 0.01
    with pytest.raises(ValueError, match=r"k: expected a held photo in \[1, 3\)"):
        photo_error(truth, photos, 0, spec=spec)
    assert photo_error(truth, photos, 2, spec=spec.subset([0, 2])) == pytest.approx(photo_error(truth, photos, 2, spec=spec))
    with pytest.raises(ValueError, match="expected the capture of the 3 photos or of photos 0 and 1"):
        photo_error(truth, photos, 1, spec=spec.subset([0]))


def test_polish_moves_a_grid_light_to_the_photo_and_zero_steps_keep_it(scene) -> None:
    truth, _, photos, spec = scene
    grid = estimated_pair(truth, photos, 2, config=SEARCH, polish=0)
    assert estimated_pair(truth, photos, 2, config=SEARCH, polish=0) == grid  # the search is deterministic
    assert polish_light(truth, photos[2], grid.images[1], steps=0) is grid.images[1]
    moved = polish_light(truth, photos[2], grid.images[1], steps=40)
    off = lambda im: math.dist(im.light.position, LIGHTS[2])  # noqa: E731
    assert off(moved) < off(grid.images[1])
    assert photo_error(truth, photos, 2, spec=CaptureSpec((grid.images[0], moved))) < photo_error(
        truth, photos, 2, spec=grid)


@pytest.mark.parametrize("known", [False, True], ids=["estimated", "true"])
def test_judge_keeps_the_maps_that_explain_the_photos(scene, known: bool) -> None:
    truth, flat, photos, spec = scene
    j = judge(photos, {"single": flat, "multi": truth}, spec=spec if known else None, config=SEARCH)
    assert j.choice == "multi" and j.held == [1, 2] and j.lights == ("true" if known else "estimated")
    assert j.scores["multi"] < j.scores["single"] and set(j.best_per_photo().values()) == {"multi"}
    assert "choice by the photos' own evidence: multi" in j.line() and "held photo(s) 2, 3" in j.line()


def test_leave_one_out_folds_replace_the_maps_of_the_nets_that_saw_the_photo(scene, tmp_path) -> None:
    truth, flat, photos, spec = scene
    # the multi net's maps from all photos are the truth, but without photo k it only knew flat normals
    folds = {k: {"multi": flat} for k in (1, 2)}
    j = judge(photos, {"single": truth, "multi": truth}, folds, spec=spec)
    assert j.per_photo["multi"][0] > j.per_photo["single"][0] and j.choice == "single"
    assert judge(photos, {"single": truth, "multi": truth}, spec=spec, held=[2]).held == [2]
    summary = j.summary()
    write_json(tmp_path / "choice.json", summary)  # strict JSON
    back = json.loads((tmp_path / "choice.json").read_text())
    assert back["choice"] == "single" and back["held_photos"] == [2, 3] and back["best_per_photo"]["2"] == "single"
    assert "(single < multi = fused < refined)" in back["rule"]


def test_the_refined_candidate_counts_only_where_it_validated() -> None:
    base = Judgement("fused", "fused: the lowest", {"single": 0.11, "multi": 0.12, "fused": 0.10}, {}, [1])
    better = with_refinement(base, {0.0: 0.050, 0.5: 0.040, 1.0: 0.045}, 0.5)
    assert better.choice == "refined" and better.scores["refined"] == pytest.approx(0.08)
    slight = with_refinement(base, {0.0: 0.050, 1.0: 0.0495}, 1.0)
    assert slight.choice == "fused" and slight.scores["refined"] == pytest.approx(0.099)
    kept = with_refinement(base, {0.0: 0.05, 1.0: 0.06}, 0.0)
    assert kept.choice == "fused" and kept.scores["refined"] == pytest.approx(0.10)
    none = with_refinement(base, None, None)
    assert none.choice == "fused" and none.scores["refined"] is None and "not scored" in none.notes[0]
    json.dumps(none.summary(), allow_nan=False)


def test_lights_from_one_candidate_score_every_candidate_alike(scene) -> None:
    truth, flat, photos, _ = scene
    candidates = {"single": flat, "multi": flat, "fused": truth}
    common = judge(photos, candidates, config=SEARCH, held=[1])
    assert common.choice == "fused" and common.per_photo["single"] == common.per_photo["multi"]
    # photo 3's search under the truth alone stops in a local minimum here; a search from the other candidates'
    # maps finds a light under which the truth explains the photo better, and that light is kept
    stuck = judge(photos, candidates, config=SEARCH, held=[2])
    started = judge(photos, candidates, config=SEARCH, held=[2], lights_from=("fused", "multi", "single"))
    assert started.per_photo["fused"][0] < stuck.per_photo["fused"][0] and started.light_start != ["fused"]
    assert started.by_start["fused"]["errors"]["fused"] == stuck.per_photo["fused"]
    assert started.choice == "fused" and set(started.summary()["by_start"]) == {"fused", "multi", "single"}
    pooled = judge(photos, candidates, config=SEARCH, held=[2], lights_from=None)
    assert pooled.choice == "fused" and pooled.per_photo["fused"][0] < stuck.per_photo["fused"][0]
