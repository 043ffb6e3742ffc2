"""Scene-file driven dataset rendering: closed form, alignment, determinism, resume, workers, Ray, contract."""
from __future__ import annotations

import dataclasses
import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
import torch

import mi_svbrdf as ms
from mi_svbrdf import scenes
from mi_svbrdf.cli import dataset as dataset_cli
from mi_svbrdf.core import maps as M
from mi_svbrdf.data.augment import transform_maps
from mi_svbrdf.data.dataset import job as D
from mi_svbrdf.data.dataset import output as DO
from mi_svbrdf.data.dataset import renderer as R
from mi_svbrdf.data.dataset import workers as W
from mi_svbrdf.data.examples import example_material, normals_from_height
from mi_svbrdf.io import strip
from mi_svbrdf.io.image_io import read_image

SIZE = 32


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def outputs(folder: Path) -> dict[str, bytes]:
    """The renders (shard files) of a dataset folder."""
    return {k: v for k, v in files(folder).items() if k.startswith("shard_")}


@pytest.fixture(scope="module")
def bank(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two small example materials as strips (48 px: the renders resample them to 32)."""
    root = tmp_path_factory.mktemp("bank")
    strip.write_strip(root / "a_tiles.png", example_material("tiles", size=48, seed=1))
    strip.write_strip(root / "b_metal.png", example_material("metal_plate", size=48, seed=2))
    return root


def small_job(bank: Path, out: Path, **kw) -> D.RenderJob:
    args = {"materials": str(bank), "out": str(out), "renders_per_material": 2, "size": SIZE, "spp": 2, "seed": 5}
    args.update(kw)
    return D.RenderJob(**args)


@pytest.fixture(scope="module")
def reference(bank: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The single-process output of the small job."""
    out = tmp_path_factory.mktemp("reference")
    summary = W.render_dataset(small_job(bank, out), progress=False)
    assert summary.rendered == summary.total == 4 and summary.remaining == 0 and not summary.failed
    return out


def texel_render(maps: torch.Tensor, light, intensity: float, cam_z: float, supersample: int = 1) -> np.ndarray:
    """The closed form (torch reference backend) at pixel centres, or averaged over ``supersample^2``
    points per pixel (maps repeated): ``(H, W, 3)``. Mitsuba's intensity is pi times the texel model's."""
    fine = maps.double().repeat_interleave(supersample, 2).repeat_interleave(supersample, 3)
    img = ms.render(fine, torch.tensor([[list(light)]], dtype=torch.float64),
                    torch.tensor([[[0.0, 0.0, cam_z]]], dtype=torch.float64), intensity=intensity / math.pi,
                    distance_falloff=True, backend="torch")[0, 0]
    return torch.nn.functional.avg_pool2d(img[None], supersample)[0].permute(1, 2, 0).numpy()


# ------------------------------------------------------------------------------ the renderer

def test_flat_constant_material_equals_closed_form() -> None:
    renderer = R.SceneRenderer("flash_capture", size=SIZE, spp=64)
    maps = M.constant_maps(1, SIZE, SIZE, diffuse=(0.6, 0.35, 0.2), roughness=0.45, specular=(0.05, 0.04, 0.03))
    light, intensity = (0.4, -0.3, renderer.cam_z), 18.0
    image = renderer.render(maps, light, intensity, seed=3)
    # Mitsuba's pixel averages its footprint (64 jittered samples): the closed form averaged too.
    expected = texel_render(maps, light, intensity, renderer.cam_z, supersample=8)
    rel = np.abs(image - expected) / expected
    assert rel.mean() < 2e-3 and rel.max() < 1.5e-2, (rel.mean(), rel.max())  # jitter noise only
    assert abs(image.mean() - expected.mean()) < 1e-3 * expected.mean()  # no bias
    # The 8-bit photo of the render is the authors' pipeline of the closed form, within a code.
    codes = DO.photo_codes(torch.from_numpy(image).permute(2, 0, 1))
    ref_codes = DO.photo_codes(torch.from_numpy(expected).permute(2, 0, 1).float())
    assert (codes - ref_codes).abs().max() <= 1
    # It can fail: the light elsewhere gives another image.
    other = texel_render(maps, (-0.4, 0.3, renderer.cam_z), intensity, renderer.cam_z)
    assert (np.abs(image - other) / other).mean() > 0.05


def test_no_kernel_is_compiled_per_render() -> None:
    renderer = R.SceneRenderer("flash_capture", size=16, spp=2)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        hashes = []
        for i in range(3):  # new maps, light, intensity and seed each time
            maps = M.constant_maps(1, 16, 16, diffuse=0.1 + 0.2 * i, roughness=0.3 + 0.1 * i)
            image = renderer.render(maps, (0.1 * i, -0.2, 2.0 + 0.1 * i), 10.0 + i, seed=i)
            hashes.append([k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT])
            assert image.mean() > 0
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert hashes[1] and hashes[1] == hashes[2] == hashes[0][-len(hashes[1]):]


def test_photo_encoding_is_the_authors_pipeline() -> None:
    linear = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0)) * 1.3
    stored = DO.photo_codes(linear) / 255.0
    assert torch.equal(stored * 255.0, torch.round(stored * 255.0)) and stored.max() <= 1.0
    assert torch.allclose(DO.decode_photo(stored), ms.flash.photo_pipeline(linear), rtol=0, atol=1e-6)


@pytest.mark.parametrize("compressor", DO.COMPRESSORS)
def test_strip_codes_equal_write_strip(tmp_path: Path, compressor: str) -> None:
    if compressor == "isal":
        pytest.importorskip("isal", reason="the isal package is optional (the zlib path is tested without it)")
    maps = example_material("tiles", size=24)
    maps = torch.cat([maps[:, :3], torch.rand(1, 7, 24, 24, generator=torch.Generator().manual_seed(1))], 1)
    codes = torch.randint(0, 256, (3, 24, 24), generator=torch.Generator().manual_seed(2)).float()
    DO.write_strip_codes(tmp_path / "fast.png", maps, codes, compressor)
    strip.write_strip(tmp_path / "ref.png", maps, codes / 255.0)
    fast, info = read_image(tmp_path / "fast.png")
    ref, _ = read_image(tmp_path / "ref.png")
    assert info.bit_depth == 8 and fast.shape == (24, 120, 3)
    assert np.array_equal(fast, ref)


def test_shot_draws_stay_in_their_ranges() -> None:
    ranges = D.ShotRanges()
    shots = [D.draw_shot(7, i, ranges, size=256, material_size=256) for i in range(300)]
    assert D.draw_shot(7, 11, ranges, size=256, material_size=256) == shots[11]
    assert D.draw_shot(8, 11, ranges, size=256, material_size=256) != shots[11]
    angles = np.array([c.angle for c in shots])
    zooms = np.array([c.zoom for c in shots])
    lights = np.array([c.light for c in shots])
    exposures = np.array([c.exposure for c in shots])
    assert np.all(np.abs(angles) <= math.pi) and angles.min() < -2.5 and angles.max() > 2.5
    assert np.all((zooms >= 1.0) & (zooms <= 2.0)) and np.allclose([c.scale for c in shots], zooms)
    assert np.all(np.abs(lights[:, :2]) <= 0.75) and np.allclose(lights[:, 2], ranges.cam_z)
    assert np.all((exposures >= 1.0) & (exposures <= 3.0))
    assert np.allclose([c.intensity for c in shots], exposures * math.pi * ranges.cam_z**2)
    # The window stays inside the material whenever it fits.
    for c in shots:
        half = 1.0 / c.zoom * (abs(math.cos(c.angle)) + abs(math.sin(c.angle)))
        assert max(abs(t) for t in c.translation) <= max(0.0, 1.0 - half) + 1e-12


def test_rotated_material_maps_align_with_the_render() -> None:
    n = 48
    coord = (torch.arange(n) + 0.5) / n * 2 - 1
    y, x = -coord.view(n, 1).expand(n, n), coord.view(1, n).expand(n, n)  # row 0 at y = +1
    height = torch.exp(-((x - 0.45) ** 2 + (y - 0.3) ** 2) / 0.08)[None, None]  # off-centre bump
    diffuse = torch.stack([0.1 + 0.35 * (x + 1), 0.1 + 0.35 * (y + 1), torch.full_like(x, 0.2)])[None]
    material = M.make_maps(normals_from_height(height, strength=n / 8.0), diffuse,
                           (0.35 + 0.15 * (x + 1))[None, None], torch.full((1, 3, n, n), 0.04))
    job = D.RenderJob(materials="unused", out="unused", size=n, spp=16,
                      shots=D.ShotRanges(angle=(90.0, 90.0), zoom=(1.0, 1.0), exposure=(1.5, 1.5)))
    renderer = R.SceneRenderer(size=n, spp=16)
    maps, linear, record = R.render_one(job, renderer, material[0], "bump", 0, 0)
    assert record["material_transform"]["angle_degrees"] == pytest.approx(90.0)
    # Turned a quarter counter-clockwise: texel (i, j) comes from (j, n-1-i); normals turn too.
    turned = torch.rot90(material, 1, dims=(2, 3))
    turned = torch.cat([-turned[:, 1:2], turned[:, 0:1], turned[:, 2:]], dim=1)
    assert torch.allclose(maps, turned, atol=1e-5)
    # The render shows the written maps: the closed form of the written maps at pixel centres.
    light, intensity = record["light"]["position"], record["light"]["intensity"][0]
    expected = texel_render(maps, light, intensity, renderer.cam_z)
    unrotated = texel_render(material, light, intensity, renderer.cam_z)
    err = np.abs(linear - expected).mean() / expected.mean()
    err_unrotated = np.abs(linear - unrotated).mean() / unrotated.mean()
    assert err < 0.01 and err_unrotated > 10 * err, (err, err_unrotated)


# -------------------------------------------------------------------------------- the dataset

def test_output_layout_and_records(reference: Path, bank: Path) -> None:
    names = sorted(files(reference))
    assert names == ["manifest.json"] + [f"shard_0000/{i:06d}.{e}" for i in range(4) for e in ("json", "png")]
    # The shot ranges keep their earlier manifest key, so datasets rendered before the rename resume.
    manifest = json.loads((reference / "manifest.json").read_text())
    assert manifest["capture"] == json.loads(json.dumps(dataclasses.asdict(D.ShotRanges())))
    record = json.loads((reference / "shard_0000" / "000003.json").read_text())
    assert record["material"] == "b_metal.png" and record["material_index"] == 1 and record["render"] == 1
    assert record["scene_parameters"] == {"res": str(SIZE), "spp": "2", "fov": "50.0",
                                          "cam_z": repr(1 / math.tan(math.radians(25)))}
    assert record["light"]["position"][2] == pytest.approx(scenes.CAPTURE_DISTANCE)
    inputs, maps = strip.read_strip(reference / "shard_0000" / "000003.png", crop=None)
    assert inputs.shape == (1, 3, SIZE, SIZE) and maps.shape == (1, 10, SIZE, SIZE)
    linear = DO.decode_photo(inputs)
    assert 0.02 < float(linear.mean()) < 0.9  # a plausible exposure, not black nor clipped
    # The record alone rebuilds the render: material transform, light, seed.
    material = strip.read_strip(bank / record["material"], crop=None)[1]
    t = record["material_transform"]
    rebuilt = transform_maps(material, t["angle"], t["scale"], t["translation"], SIZE, padding=t["padding"])
    assert (rebuilt - maps).abs().max() < 0.5 / 255 + 1e-2  # maps stored in 8 bits (normals renormalised)
    renderer = R.SceneRenderer(record["scene"], size=SIZE, spp=record["spp"], fov=record["camera"]["fov"])
    again = renderer.render(rebuilt, record["light"]["position"], record["light"]["intensity"], record["mitsuba_seed"])
    assert torch.equal(DO.photo_codes(torch.from_numpy(again).permute(2, 0, 1)) / 255.0, inputs[0])


def test_same_seed_same_files_and_workers_agree(bank: Path, reference: Path, tmp_path: Path) -> None:
    code = dataset_cli.main(["dataset", "render", "--materials", str(bank), "--out", str(tmp_path / "again"),
                   "--renders-per-material", "2", "--size", str(SIZE), "--spp", "2", "--seed", "5", "-q"])
    assert code == 0
    assert outputs(tmp_path / "again") == outputs(reference)
    other = W.render_dataset(small_job(bank, tmp_path / "other", seed=6), progress=False)
    assert other.rendered == 4
    assert all(a != b for a, b in zip(outputs(tmp_path / "other").values(), outputs(reference).values()))
    pooled = W.render_dataset(small_job(bank, tmp_path / "pool"), workers=2, progress=False)
    assert pooled.executor == "processes" and pooled.workers == 2 and pooled.rendered == 4
    assert outputs(tmp_path / "pool") == outputs(reference)
    assert pooled.cpu_seconds > 0 and pooled.render_cpu_per_image > 0


def test_resume_after_kill_gives_the_uninterrupted_dataset(bank: Path, tmp_path: Path) -> None:
    args = ["--materials", str(bank), "--renders-per-material", "40", "--size", "24", "--spp", "1", "--seed", "2"]
    full = tmp_path / "full"
    assert dataset_cli.main(["dataset", "render", *args, "--out", str(full), "-q"]) == 0
    killed = tmp_path / "killed"
    entry = "import sys; from mi_svbrdf.cli import main; sys.exit(main())"  # what `mi-svbrdf` runs
    proc = subprocess.Popen([sys.executable, "-c", entry, "dataset", "render", *args,
                             "--out", str(killed), "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    done_at_kill = 0
    while time.monotonic() < deadline and proc.poll() is None:
        done_at_kill = len(list(killed.glob("shard_*/*.json")))
        if done_at_kill >= 5:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.005)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    assert 5 <= done_at_kill < 80
    shard = killed / "shard_0000"
    # What a crash can leave: a stray temporary file, a PNG whose JSON was never written, and
    # (an operating-system crash: shards are written without fsync) a renamed but truncated PNG.
    (shard / ".000070.tmpdeadbeef.png").write_bytes(b"\x89PNG half")
    done = sorted(int(p.stem) for p in shard.glob("[0-9]*.json"))
    (shard / f"{done[-1]:06d}.json").unlink()
    (shard / "000079.png").write_bytes(b"\x89PNG truncated")
    first = shard / f"{done[0]:06d}.png"
    first.write_bytes(first.read_bytes()[:100])
    resumed = W.render_dataset(small_job(bank, killed, renders_per_material=40, size=24, spp=1, seed=2),
                               progress=False)
    assert resumed.already_done == len(done) - 2 and resumed.rendered == 80 - resumed.already_done
    assert files(killed) == files(full)


@pytest.mark.slow
def test_ray_cluster_output_equals_single_process(bank: Path, reference: Path, tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="Ray is an optional extra (pip install ray)")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="warning")
    try:
        summary = W.render_dataset(small_job(bank, tmp_path / "ray"), ray="auto", workers=2, progress=False)
        assert ray.is_initialized()  # an existing connection is used, not shut down
    finally:
        ray.shutdown()
    assert summary.executor == "ray" and summary.workers == 2 and summary.rendered == 4
    assert outputs(tmp_path / "ray") == outputs(reference)


# --------------------------------------------------------------------------------- bad input

def test_scene_missing_a_parameter_is_rejected(tmp_path: Path, bank: Path, capsys) -> None:
    xml = scenes.scene_path("flash_capture").read_text()
    no_cam = tmp_path / "no_cam_z.xml"
    no_cam.write_text(xml.replace('origin="0, 0, $cam_z"', 'origin="0, 0, 2.1445069"'))
    with pytest.raises(ValueError, match=r"no_cam_z.xml: expected a capture scene using .*\['\$cam_z'\]"):
        R.SceneRenderer(no_cam, size=16, spp=1)
    no_light = tmp_path / "no_light.xml"
    no_light.write_text(xml.replace('id="light"', 'id="flash"'))
    with pytest.raises(ValueError, match=r"no_light.xml: .*got no \['light.position', 'light.intensity.value'\]"):
        R.SceneRenderer(no_light, size=16, spp=1)
    code = dataset_cli.main(["dataset", "render", "--scene", str(no_cam), "--materials", str(bank),
                   "--out", str(tmp_path / "out"), "-q"])
    assert code == 2 and "$cam_z" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match=r"params: expected parameters the scene .* got \['bogus'\]"):
        R.SceneRenderer("flash_capture", size=16, spp=1, params={"bogus": "1"})
    with pytest.raises(ValueError, match=r"params: expected other scene parameters .* got \['light_x', 'spp'\]"):
        D.RenderJob(materials=str(bank), out=str(tmp_path), params={"spp": "8", "light_x": "0.2"})


def test_a_user_scene_renders_like_the_bundled_one(tmp_path: Path) -> None:
    copy = tmp_path / "my_capture.xml"
    copy.write_text(scenes.scene_path("flash_capture").read_text())  # its textures/ are not beside it
    maps = example_material("tiles", size=16)
    a = R.SceneRenderer(copy, size=16, spp=2).render(maps, (0.2, 0.1, 2.0), 15.0, seed=1)
    b = R.SceneRenderer("flash_capture", size=16, spp=2).render(maps, (0.2, 0.1, 2.0), 15.0, seed=1)
    assert np.array_equal(a, b)
    beckmann = R.SceneRenderer(copy, size=16, spp=2, params={"distribution": "beckmann"})
    assert not np.array_equal(beckmann.render(maps, (0.2, 0.1, 2.0), 15.0, seed=1), a)


def test_limit_stops_early_and_a_rerun_completes(bank: Path, reference: Path, tmp_path: Path) -> None:
    first = W.render_dataset(small_job(bank, tmp_path), limit=3, progress=False)
    assert (first.rendered, first.remaining) == (3, 1)
    assert sorted(outputs(tmp_path)) == sorted(outputs(reference))[:6]  # renders 0, 1, 2 (json + png)
    second = W.render_dataset(small_job(bank, tmp_path), progress=False)
    assert (second.already_done, second.rendered, second.remaining) == (3, 1, 0)
    assert outputs(tmp_path) == outputs(reference)


def test_resume_into_a_different_job_is_refused(bank: Path, reference: Path) -> None:
    with pytest.raises(ValueError, match=r"manifest.json: expected the manifest of this job .*seed: 5 -> 9"):
        W.render_dataset(small_job(bank, reference, seed=9), progress=False)


def test_bad_material_files_are_reported_and_skipped(bank: Path, tmp_path: Path) -> None:
    root = tmp_path / "mixed"
    root.mkdir()
    for p in bank.iterdir():
        (root / p.name).write_bytes(p.read_bytes())
    (root / "c_broken.png").write_bytes(b"not a png")
    good = (root / "a_tiles.png").read_bytes()
    # A complete PNG header and end whose pixel data are damaged: passes the scan, fails on read.
    (root / "d_corrupt.png").write_bytes(good[:200] + bytes(len(good) - 212) + good[-12:])
    with pytest.warns(UserWarning):
        summary = W.render_dataset(small_job(root, tmp_path / "out", renders_per_material=1), progress=False)
    assert [Path(p).name for p, _ in summary.skipped_at_scan] == ["c_broken.png"]
    assert [name for name, _ in summary.failed] == ["d_corrupt.png"]
    assert summary.rendered == 2 and summary.remaining == 1 and summary.total == 3
