"""The online capture simulator: capture draws in their ranges, clean render = core render,
presets, determinism (also through DataLoader workers), 8-bit outputs, calibration."""
from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from torch.utils.data import DataLoader

import mi_svbrdf as ms
from mi_svbrdf.core.flash import photo_pipeline
from mi_svbrdf.data import photo_setups as C
from mi_svbrdf.data.examples import example_material
from mi_svbrdf.data.simulator import CaptureSimulator, SimulatorConfig, batch_generator

SMALL = dict(size=32, batch_size=2, classes=("tiles", "metal", "paint"))


def materials(batch: int = 2, size: int = 32) -> torch.Tensor:
    names = ["tiles", "metal_plate"]
    return torch.cat([example_material(names[i % 2], size=size, seed=i) for i in range(batch)])


def draws(config: C.CaptureConfig | str, batch: int = 20000, n: int = 5, seed: int = 0) -> C.Captures:
    return C.sample_captures(batch, n, config, torch.Generator().manual_seed(seed))


def elevation(v: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.asin(v[..., 2] / v.norm(dim=-1)))


# ------------------------------------------------------------------------ clean render = core render

@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_clean_capture_equals_core_render(backend: str) -> None:
    maps = materials()
    cfg = C.capture_config("clean", photo=False)
    cap = draws(cfg, batch=2, n=2)
    assert torch.equal(cap.light, torch.tensor([0.0, 0.0, 2.197]).expand(2, 2, 3))
    distance = 1 / math.tan(math.radians(20.0))
    torch.testing.assert_close(cap.view, torch.tensor([0.0, 0.0, distance]).expand(2, 2, 3))
    expected = ms.render(maps, cap.light, cap.view, intensity=13.0, distance_falloff=True,
                         cone_target=torch.zeros(2, 2, 3), cone_exponent=5.0, backend=backend)
    assert torch.equal(C.simulate(maps, cap, backend=backend), expected)
    # With the photo pipeline (deterministic without noise): the core's flash pipeline.
    cap8 = dataclasses.replace(cap, photo=True)
    assert torch.equal(C.simulate(maps, cap8, backend=backend), photo_pipeline(expected))


def test_clean_simulator_batch_equals_core_render() -> None:
    sim = CaptureSimulator(**SMALL, preset="clean", n_images=(3, 3), capture={"photo": False},
                           rotation=(0.0, 0.0), scale=(1.0, 1.0), mix_probability=0.0)
    assert sim.config.material_size == 32
    b = sim.batch(0)
    light = torch.tensor([0.0, 0.0, 2.197]).expand(2, 3, 3)
    view = torch.tensor([0.0, 0.0, 1 / math.tan(math.radians(20.0))]).expand(2, 3, 3)
    expected = ms.render(b.maps, light, view, intensity=13.0, distance_falloff=True,
                         cone_target=torch.zeros(2, 3, 3), cone_exponent=5.0)
    torch.testing.assert_close(b.inputs, expected, rtol=0, atol=0)
    # Without rotation, scale or mixing the maps are the procedural materials themselves.
    from mi_svbrdf.data import procedural

    d = b.materials[0]
    ref = procedural.generate_batch(d["class"], [d["seed"]], size=32, params=[d["params"]])
    torch.testing.assert_close(b.maps[:1], ref, rtol=0, atol=1e-6)


# ------------------------------------------------------------------------------ draws in ranges

def test_flash_intensity_statistics() -> None:
    cap = draws(C.capture_config("multiview", white_balance=False))
    i = cap.intensity[..., 0]
    assert torch.equal(cap.intensity[..., 0], cap.intensity[..., 2])  # grey without white balance
    # I = |N(10, exp(N(-2, 0.5)))| * exp(N(log 1.5, 0.4)): median ~ 15, log-std ~ 0.4 (+ small spread).
    assert 14.5 < float(i.median()) < 15.5
    assert 0.39 < float(i.log().std()) < 0.43
    # Within a sample the exposure is shared: the images differ by |N(10, s)| only, s ~ exp(N(-2, 0.5)).
    rel = (i / i[:, :1]).log()
    assert 0.005 < float(rel.abs().median()) < 0.03
    assert float(rel.abs().max()) < 0.5


def test_white_balance_cone_and_geometry_ranges() -> None:
    cap = draws(C.capture_config("multiview", intensity_jitter=False))
    wb = cap.intensity / 13.0
    assert abs(float(wb.mean()) - 1.0) < 1e-3 and abs(float(wb.std()) - 0.03) < 1e-3
    # Cone exponent: one per sample (one flash), median 5, log-std 0.35.
    e = cap.cone_exponent
    assert torch.equal(e, e[:, :1].expand_as(e))
    assert abs(float(e[:, 0].median()) - 5.0) < 0.1 and abs(float(e[:, 0].log().std()) - 0.35) < 0.01
    t = cap.cone_target
    assert bool((t[..., 2] == 0).all()) and abs(float(t[..., :2].std()) - 0.25) < 0.005
    # FOV in 40 +- 10 degrees sets the camera distance.
    assert float(cap.fov.min()) >= 30.0 and float(cap.fov.max()) <= 50.0
    assert abs(float(cap.fov.mean()) - 40.0) < 0.1
    torch.testing.assert_close(cap.distance, 1 / torch.tan(torch.deg2rad(cap.fov) / 2))
    # First image: light on the plane z = 2.197 within +-0.75, camera fronto-parallel within +-0.25.
    assert bool((cap.light[:, 0, 2] == 2.197).all()) and float(cap.light[:, 0, :2].abs().max()) <= 0.75
    assert float(cap.light[:, 0, :2].abs().max()) > 0.74
    assert float(cap.view[:, 0, :2].abs().max()) <= 0.25
    torch.testing.assert_close(cap.view[:, 0, 2], cap.distance[:, 0])
    # Images 2..N: on the hemisphere, above 8.13 degrees, cosine-weighted, at their distances.
    v, lt = cap.view[:, 1:], cap.light[:, 1:]
    torch.testing.assert_close(v.norm(dim=-1), cap.distance[:, 1:])
    torch.testing.assert_close(lt.norm(dim=-1), torch.full_like(lt[..., 0], 2.197))
    assert float(elevation(v).min()) >= 8.12 and float(elevation(lt).min()) >= 8.12
    # Mean cos(theta) of the authors' sampler with r1 ~ U(0.001, 0.98) is 0.678 (uniform cap: 0.571).
    assert abs(float((v[..., 2] / v.norm(dim=-1)).mean()) - 0.678) < 0.005
    uni = draws(C.capture_config("multiview", hemisphere_sampling="uniform"))
    z = uni.view[:, 1:, 2] / uni.view[:, 1:].norm(dim=-1)
    assert abs(float(z.mean()) - 0.571) < 0.005 and float(z.min()) >= math.sin(math.radians(8.12))


def test_ambient_and_noise_ranges() -> None:
    cap = draws("multiview")
    a = cap.ambient_light
    assert a.shape == (20000, 1, 3) and float(elevation(a).min()) >= 26.5
    assert abs(float(a.norm(dim=-1).median()) - 30.0) < 0.3
    assert abs(float(a.norm(dim=-1).log().std()) - 0.15) < 0.005
    grey = cap.ambient_intensity.log().mean(dim=-1)
    assert abs(float(grey.median().exp()) - 0.15) < 0.005
    colour = cap.ambient_intensity.log() - grey[..., None]  # per-channel colour around the grey level
    assert abs(float(colour.std()) * math.sqrt(3 / 2) - 0.15) < 0.005
    assert abs(float(cap.noise_std.median()) - 0.005) < 1e-4
    assert abs(float(cap.noise_std.log().std()) - 0.3) < 0.01


def test_switching_one_perturbation_leaves_the_other_draws() -> None:
    on = draws("multiview", batch=64)
    off = draws(C.capture_config("multiview", noise=False, cone_target_jitter=False, ambient=False), batch=64)
    assert torch.equal(on.light, off.light) and torch.equal(on.view, off.view)
    assert torch.equal(on.intensity, off.intensity) and torch.equal(on.cone_exponent, off.cone_exponent)
    assert bool((off.noise_std == 0).all()) and bool((off.cone_target == 0).all())
    assert off.ambient_light.shape == (64, 0, 3)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="unknown keys.*'noize'"):
        C.CaptureConfig.from_dict({"noize": True})
    with pytest.raises(ValueError, match="unknown keys"):
        SimulatorConfig.from_dict({"size": 32, "batchsize": 2})
    with pytest.raises(ValueError, match="white_balance_std: expected a finite number >= 0"):
        C.capture_config("multiview", white_balance_std=-1.0)
    with pytest.raises(ValueError, match="fov"):
        C.capture_config("multiview", fov=175.0)
    with pytest.raises(ValueError, match="preset: expected one of"):
        C.capture_config("studio")
    with pytest.raises(ValueError, match="n_images"):
        SimulatorConfig(n_images=(3, 1))
    with pytest.raises(ValueError, match="bank: expected a material bank root"):
        SimulatorConfig(materials="bank")
    with pytest.raises(ValueError, match="classes"):
        SimulatorConfig(classes=("marble",))
    with pytest.raises(ValueError, match="device: expected cpu, cuda or cuda:N, got 'tpu'"):
        SimulatorConfig(device="tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: expected cpu .this machine has no CUDA device., got 'cuda'"):
            CaptureSimulator(device="cuda", **SMALL)


# ------------------------------------------------------------------------------------- presets

def test_presets_geometry() -> None:
    single = draws("single_flash", batch=2000, n=1)
    assert single.flash and single.ambient_light.shape[1] == 0
    # The camera above the sample centre, fronto-parallel; the flash beside it in its plane.
    assert float(single.view[..., :2].abs().max()) <= 0.25
    assert float(single.fov.min()) >= 45.0 and float(single.fov.max()) <= 55.0
    torch.testing.assert_close(single.light[..., 2], single.view[..., 2])
    off = (single.light - single.view)[..., :2].abs()
    assert float(off.max()) <= 0.1 and float(off.max()) > 0.09
    amb = draws("ambient", batch=100, n=1)
    assert not amb.flash and bool((amb.intensity == 0).all()) and amb.ambient_light.shape == (100, 3, 3)
    multi = draws("multiview", batch=100, n=4)
    assert float(elevation(multi.view[:, 1:]).min()) >= 8.12 and float(multi.view[:, 0, :2].abs().max()) <= 0.25
    # A phone flash on hemisphere cameras: beside the lens, in the image plane (perpendicular to the axis).
    phone = draws(C.capture_config("multiview", flash_at_camera=True), batch=100, n=4)
    off = phone.light - phone.view
    axis = phone.view / phone.view.norm(dim=-1, keepdim=True)
    assert float((off[:, 1:] * axis[:, 1:]).sum(-1).abs().max()) < 1e-5
    assert float(off.norm(dim=-1).max()) <= 0.1 * math.sqrt(2) + 1e-6


@pytest.mark.parametrize("preset,images", [("multiview", (1, 5)), ("single_flash", (1, 1)), ("ambient", (1, 1))])
def test_simulator_presets_shapes(preset: str, images: tuple[int, int]) -> None:
    sim = CaptureSimulator(**SMALL, preset=preset, steps=3)
    assert sim.config.image_range == images
    for b in sim:
        n = b.captures.n_images
        assert images[0] <= n <= images[1]
        assert b.inputs.shape == (2, n, 3, 32, 32) and b.maps.shape == (2, 10, 32, 32)
        assert len(b.materials) == 2 and b.captures.batch_size == 2
    if preset == "ambient":  # lit by the ambient lights only: no flash highlight, still exposed
        assert 0.01 < float(b.inputs.mean()) < 0.9


# ----------------------------------------------------------------------------- outputs, 8 bits

def test_outputs_finite_in_range_and_8_bit() -> None:
    sim = CaptureSimulator(**SMALL, n_images=(3, 3), mix_probability=1.0)
    b = sim.batch(0)
    assert torch.isfinite(b.inputs).all() and torch.isfinite(b.maps).all()
    assert float(b.inputs.min()) >= 0.0 and float(b.inputs.max()) <= 1.0
    codes = b.inputs.double() ** (1 / 2.2) * 255
    assert float((codes - codes.round()).abs().max()) < 1e-3
    assert len(codes.round().unique()) > 50
    torch.testing.assert_close(b.maps[:, :3].norm(dim=1), torch.ones(2, 32, 32))
    assert float(b.maps[:, 3:].min()) >= 0.0 and float(b.maps[:, 3:].max()) <= 1.0
    assert all(d["source"] == "mix" and 0.1 <= d["alpha"] <= 0.9 for d in b.materials)


def test_sample_any_n_images() -> None:
    sim = CaptureSimulator(**SMALL)
    b = sim.sample(7, torch.Generator().manual_seed(0), batch_size=1)
    assert b.inputs.shape == (1, 7, 3, 32, 32) and b.index == -1


# -------------------------------------------------------------------------------- determinism

def test_same_seed_same_batches_other_seed_differs() -> None:
    a = CaptureSimulator(**SMALL, seed=3, steps=2)
    b = CaptureSimulator(**SMALL, seed=3, steps=2)
    for x, y in zip(a, b):
        assert torch.equal(x.inputs, y.inputs) and torch.equal(x.maps, y.maps)
        assert x.captures.to_dict() == y.captures.to_dict() and x.materials == y.materials
    other = CaptureSimulator(**SMALL, seed=4).batch(0)
    assert not torch.equal(other.maps, a.batch(0).maps)
    # A batch is a pure function of (seed, index): resuming at start=1 continues the stream.
    resumed = next(iter(CaptureSimulator(**SMALL, seed=3, start=1, steps=1)))
    assert resumed.index == 1 and torch.equal(resumed.inputs, a.batch(1).inputs)


def test_dataloader_workers_reproduce_the_stream() -> None:
    sim = CaptureSimulator(**SMALL, seed=7, steps=4)
    serial = list(DataLoader(sim, batch_size=None, num_workers=0))
    parallel = list(DataLoader(sim, batch_size=None, num_workers=2))
    again = list(DataLoader(sim, batch_size=None, num_workers=2))
    assert [b.index for b in parallel] == [0, 1, 2, 3]
    for s, p, q in zip(serial, parallel, again):
        assert torch.equal(s.inputs, p.inputs) and torch.equal(p.inputs, q.inputs)
        assert torch.equal(s.maps, p.maps) and s.captures.to_dict() == p.captures.to_dict()
    # Workers 0 and 1 make batches 0, 2 and 1, 3: different streams.
    assert not torch.equal(parallel[0].maps, parallel[1].maps)
    assert not torch.equal(parallel[0].captures.light, parallel[1].captures.light)


# -------------------------------------------------------------------------------- calibration

def test_captures_reproduce_the_inputs() -> None:
    # Noise off: re-rendering the returned captures and the pipeline gives the inputs exactly.
    sim = CaptureSimulator(**SMALL, n_images=(4, 4), capture={"noise": False})
    b = sim.batch(5)
    assert torch.equal(C.simulate(b.maps, b.captures), b.inputs)
    # One sample, one image at a time (what a calibrated optimisation would render).
    one = C.simulate(b.maps[1:2], b.captures.take(1).images(2))
    assert torch.equal(one, b.inputs[1:2, 2:3])
    # Noise on: the residual against the noise-free re-render is the drawn noise (plus 8-bit steps).
    noisy = CaptureSimulator(**SMALL, n_images=(4, 4)).batch(5)
    clean = C.render_captures(noisy.maps, noisy.captures)
    assert torch.equal(noisy.captures.light, b.captures.light)  # the switch leaves the geometry
    for i in range(2):
        keep = (clean[i] > 0.05) & (clean[i] < 0.8)
        res = (noisy.inputs[i] - clean[i])[keep]
        sigma = float(noisy.captures.noise_std[i])
        assert abs(float(res.mean())) < 0.3 * sigma
        assert 0.85 * sigma < float(res.std()) < 1.3 * sigma


def test_batch_generator_is_seeded_by_seed_and_index() -> None:
    a = torch.rand(4, generator=batch_generator(1, 2))
    assert torch.equal(a, torch.rand(4, generator=batch_generator(1, 2)))
    assert not torch.equal(a, torch.rand(4, generator=batch_generator(1, 3)))
    assert not torch.equal(a, torch.rand(4, generator=batch_generator(2, 2)))


def test_bank_and_mixed_sources(tmp_path) -> None:
    from mi_svbrdf.io import strip

    for i, name in enumerate(["tiles", "metal_plate"]):
        strip.write_strip(tmp_path / f"{i}_{name}.png", example_material(name, size=48, seed=i))
    sim = CaptureSimulator(size=32, batch_size=3, materials="bank", bank=str(tmp_path), mix_probability=0.0,
                           rotation=(0.0, 0.0), scale=(1.0, 1.0), source_size=48)
    b = sim.batch(0)
    assert [d["source"] for d in b.materials] == ["bank"] * 3
    assert {d["name"] for d in b.materials} <= {"0_tiles.png", "1_metal_plate.png"}
    assert b.inputs.shape[0] == 3 and torch.isfinite(b.inputs).all()
    mixed = CaptureSimulator(size=32, batch_size=8, materials="mixed", bank=str(tmp_path), bank_fraction=0.5,
                             mix_probability=0.0, classes=("paint",)).batch(0)
    sources = {d["source"] for d in mixed.materials}
    assert sources == {"bank", "procedural"}


def _pool_ids(descriptions: list[dict]) -> list[int]:
    ids = []
    for d in descriptions:
        for part in (d["a"], d["b"]) if d["source"] == "mix" else (d,):
            if "pool_id" in part:
                ids.append(part["pool_id"])
    return ids


def test_pool_batches_do_not_depend_on_the_cache() -> None:
    warm = CaptureSimulator(**SMALL, seed=2, pool_size=3, pool_refresh=2, mix_probability=1.0)
    for i in range(3):
        warm.batch(i)
    cold = CaptureSimulator(**SMALL, seed=2, pool_size=3, pool_refresh=2, mix_probability=1.0)
    a, b = warm.batch(3), cold.batch(3)
    assert torch.equal(a.inputs, b.inputs) and torch.equal(a.maps, b.maps) and a.materials == b.materials
    ids = _pool_ids(a.materials)
    assert len(ids) == 4 and all(6 <= i < 9 for i in ids)  # batch 3's window: ids [3 r, 3 r + P)
    assert min(warm._pool) >= 6 and len(warm._pool) <= 3  # members that left the pool are dropped
    fresh = CaptureSimulator(**SMALL, pool_size=0).batch(0)
    assert _pool_ids(fresh.materials) == []


def test_jpeg_photos_are_the_lossless_ones_compressed() -> None:
    """jpeg_quality compresses each photo of the batch (8-bit sRGB through Pillow's JPEG, decoded); the materials and
    the lossless pipeline before it are the same draws. Bad ranges are refused with the field's name."""
    base = dict(size=32, batch_size=2, n_images=(2, 2), preset="multiview", seed=3)
    plain = CaptureSimulator(SimulatorConfig(**base)).batch(0)
    lossy = CaptureSimulator(SimulatorConfig(**base, jpeg_quality=(40, 60))).batch(0)
    assert torch.equal(plain.maps, lossy.maps)
    assert lossy.inputs.shape == plain.inputs.shape and lossy.inputs.dtype == torch.float32
    diff = (lossy.inputs - plain.inputs).abs()
    assert 0.0 < float(diff.mean()) < 0.05  # compressed, not another photo (measured about 0.005)
    assert torch.equal(C.jpeg(plain.inputs[0, 0], 100), C.jpeg(plain.inputs[0, 0], 100))  # deterministic
    for bad in ((0, 50), (60, 50), (50, 101), (50.5, 60)):
        with pytest.raises(ValueError, match="jpeg_quality: expected None or"):
            SimulatorConfig(**base, jpeg_quality=bad)
