"""Held-out parameter ranges (train never, test always), the simulator's hold-out switch and the
fixed held-out benchmark (deterministic, cached, class coverage, frontal first photo)."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mi_svbrdf.data import heldout, procedural
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.data.parameter_split import HELD_OUT_RANGES, apply_holdout, is_held_out
from mi_svbrdf.data.simulator import CaptureSimulator, SimulatorConfig


def test_ranges_one_parameter_per_class_at_one_end() -> None:
    assert set(HELD_OUT_RANGES) == set(procedural.CLASSES) == set(heldout.CLASS_ORDER)
    for cls, ranges in HELD_OUT_RANGES.items():
        assert len(ranges) == 1
        (param, (lo, hi)), = ranges.items()
        spec = procedural.CLASSES[cls].params[param]
        assert not spec.integer
        assert (lo == spec.low) != (hi == spec.high), cls  # at exactly one end
        assert 0.15 <= (hi - lo) / (spec.high - spec.low) <= 0.20, cls


@pytest.mark.parametrize("spread", [1.0, 0.3])
def test_train_never_and_test_always_over_many_draws(spread: float) -> None:
    gen = torch.Generator().manual_seed(0)
    for cls in procedural.CLASSES:
        raw_held = 0
        for _ in range(400):
            params = procedural.sample_parameters(cls, gen, spread)
            raw_held += is_held_out(cls, params)
            train, test = apply_holdout(cls, params, "train"), apply_holdout(cls, params, "test")
            assert not is_held_out(cls, train) and is_held_out(cls, test)
            assert procedural.validate_parameters(cls, train) == train
            assert procedural.validate_parameters(cls, test) == test
            changed = {k for k in params if train[k] != params[k] or test[k] != params[k]}
            assert changed <= set(HELD_OUT_RANGES[cls])
            assert apply_holdout(cls, params, "none") == params
        if spread == 1.0:
            assert raw_held > 20  # without the switch a sizeable share would be held-out
    # The ends of the valid range.
    for cls in procedural.CLASSES:
        (param, _), = HELD_OUT_RANGES[cls].items()
        spec = procedural.CLASSES[cls].params[param]
        for v in (spec.low, spec.high):
            assert not is_held_out(cls, apply_holdout(cls, {param: v}, "train"))
            assert is_held_out(cls, apply_holdout(cls, {param: v}, "test"))
    with pytest.raises(ValueError, match="holdout: expected"):
        apply_holdout("tiles", {"aspect": 1.0}, "val")


def _procedural(info: dict) -> list[dict]:
    if info["source"] == "mix":
        return _procedural(info["a"]) + _procedural(info["b"])
    return [info]


def test_simulator_switch() -> None:
    with pytest.raises(ValueError, match="holdout: expected one of"):
        SimulatorConfig(holdout="heldout")
    small = dict(size=8, source_size=8, batch_size=4, n_images=(1, 1), pool_size=0, seed=3)
    seen = {}
    for mode in ("none", "train", "test"):
        sim = CaptureSimulator(SimulatorConfig(holdout=mode, **small))
        seen[mode] = [m for i in range(6) for d in sim.batch(i).materials for m in _procedural(d)]
    assert len(seen["none"]) >= 24
    assert all(not is_held_out(m["class"], m["params"]) for m in seen["train"])
    assert all(is_held_out(m["class"], m["params"]) for m in seen["test"])
    # Same draws: same classes, seeds and every other parameter as without the switch.
    for a, b in zip(seen["none"], seen["train"]):
        assert (a["class"], a["seed"]) == (b["class"], b["seed"])
        held = set(HELD_OUT_RANGES[a["class"]])
        assert {k: v for k, v in a["params"].items() if k not in held} == \
            {k: v for k, v in b["params"].items() if k not in held}


def test_held_out_set_is_fixed(tmp_path: Path) -> None:
    hs = HeldOutSet(size=16, materials=3, n_images=3, cache=False)
    maps, inputs, cap = hs.load(progress=False)
    assert tuple(maps.shape) == (3, 10, 16, 16) and tuple(inputs.shape) == (3, 3, 3, 16, 16)
    assert cap.batch_size == 3 and cap.n_images == 3
    again = hs.load(progress=False)
    assert torch.equal(maps, again[0]) and torch.equal(inputs, again[1]) and torch.equal(cap.light, again[2].light)
    info = hs.info(progress=False)
    assert [d["class"] for d in info] == list(heldout.CLASS_ORDER[:3])
    assert all(is_held_out(d["class"], d["params"]) for d in info)
    # Image 0 is the fronto-parallel photo: camera straight above (up to the view offset).
    assert torch.allclose(cap.view[:, 0, 2], cap.distance[:, 0])
    # A smaller set is a prefix; another seed is another set.
    two = HeldOutSet(size=16, materials=2, n_images=3, cache=False).load(progress=False)
    assert torch.equal(two[0], maps[:2]) and torch.equal(two[1], inputs[:2])
    # Fewer photos are a prefix too: photo k does not depend on N (nor on the noise of later photos).
    five = HeldOutSet(size=16, materials=2, n_images=5, cache=False).load(progress=False)
    assert torch.equal(five[1][:, :3], inputs[:2]) and torch.equal(five[2].images(slice(0, 3)).light, cap.light[:2])
    other = HeldOutSet(size=16, materials=2, n_images=3, cache=False, seed=5000).load(progress=False)
    assert not torch.equal(other[0], maps[:2])
    # The cache: written once (atomically, keyed by the settings), read back identical.
    cached = HeldOutSet(size=16, materials=3, n_images=3, cache_dir=str(tmp_path))
    first = cached.load(progress=False)
    assert cached.path().exists() and [p.name for p in tmp_path.iterdir()] == [cached.path().name]
    assert torch.equal(first[0], maps) and torch.equal(first[1], inputs)
    second = cached.load(progress=False)
    assert torch.equal(second[1], inputs) and torch.equal(second[2].intensity, cap.intensity)
    assert HeldOutSet(size=16, materials=3, n_images=2, cache_dir=str(tmp_path)).path() != cached.path()


def test_held_out_set_validation() -> None:
    with pytest.raises(ValueError, match="n_images"):
        HeldOutSet(n_images=51)
    with pytest.raises(ValueError, match="seed"):
        HeldOutSet(seed=7)
    with pytest.raises(ValueError, match="preset"):
        HeldOutSet(preset="studio")
