"""Comparison with a measured BRDF (``mi-svbrdf calibrate``, ``mi_svbrdf.eval.measured_comparison``, ``mi_svbrdf.optim.fit_measured``): the round trip
through a MERL file of our own model, the factor and error definitions, averaging, correction, the direct fit."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from mi_svbrdf import cli
from mi_svbrdf.core import brdf_measured as BM
from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core import maps as M
from mi_svbrdf.eval import measured_report as R
from mi_svbrdf.io import material_io
from mi_svbrdf.io import measured as MS
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.eval import measured_comparison as C
from mi_svbrdf.core import conoscopic as CN
from mi_svbrdf.optim import fit_measured as FM

PARAMS = {"diffuse": (0.5, 0.3, 0.15), "specular": (0.05, 0.06, 0.08), "roughness": 0.35}
K = 1.7


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest: one torch thread for the module


def ggx(scale=1.0, distribution="ggx", **overrides):
    p = {**PARAMS, **overrides}
    d, s = (torch.tensor(p[k], dtype=torch.float64) for k in ("diffuse", "specular"))
    r = torch.tensor([p["roughness"]], dtype=torch.float64)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    return lambda wi, wo: scale * brdf_torch.eval_brdf(n, wi, wo, d, s, r, distribution=distribution, dim=-1)


def material(**overrides) -> torch.Tensor:
    p = {**PARAMS, **overrides}
    return M.constant_maps(1, 8, 8, diffuse=p["diffuse"], specular=p["specular"], roughness=p["roughness"])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A MERL file of our GGX model x K, a folder of the same material and one with the wrong roughness."""
    root = tmp_path_factory.mktemp("calibrate")
    MS.write_merl(root / "ggx.binary", BM.merl_table(ggx(K)))
    material_io.write_material(root / "right", material(), fmt="exr")
    material_io.write_material(root / "wrong", material(roughness=0.55), fmt="exr")
    return root


@pytest.mark.slow
def test_round_trip_cli_finds_the_scale(files, tmp_path, capsys):
    out = tmp_path / "right"
    assert cli.main(["calibrate", str(files / "right"), "--measured", str(files / "ggx.binary"), "-o", str(out),
                     "--apply", "--no-fit"]) == 0
    printed = capsys.readouterr().out
    assert "factor" in printed and "wrote" in printed
    for name in R.REPORT_FILES:
        assert (out / name).is_file(), name
    assert not list(out.glob(".*tmp*"))
    report = json.loads((out / "report.json").read_text())
    for key in ("factor", "abs_error", "rel_error", "abs_error_corrected", "rel_error_corrected"):
        assert len(report[key]) == 3, key
    # measured = K x ours: factor K within 1 %, corrected errors near zero
    assert report["factor"] == pytest.approx([K] * 3, rel=0.01)
    assert report["rel_error"] == pytest.approx([1 - 1 / K] * 3, rel=0.01)  # |o - m| / m = 1 - 1/K
    assert max(report["rel_error_corrected"]) < 0.002
    assert max(report["abs_error_corrected"]) < 1e-3 * max(report["abs_error"]) * 10
    for alt in report["factor_alternatives"].values():
        assert alt == pytest.approx([K] * 3, rel=0.01)
    assert len(report["per_incidence"]) == 5 and report["incidences_deg"] == [10, 22, 45, 60, 69]
    assert report["averaging"]["parameters_vs_reflectance"] == pytest.approx([0.0] * 3, abs=1e-5)
    assert report["valid_fraction"] == 1.0
    # --apply: the corrected material's albedos carry the factor, and it matches the measurement
    corrected = material_io.read_material(out / "material")
    d = M.diffuse(corrected)[0, :, 0, 0]
    s = M.specular(corrected)[0, :, 0, 0]
    assert s.tolist() == pytest.approx([K * v for v in PARAMS["specular"]], abs=2e-4)
    assert report["applied"]["clipped_diffuse"] == 0.0 and report["applied"]["factor_after"] == pytest.approx(
        [1.0] * 3, abs=0.02)
    # what is left: Fresnel's grazing part does not scale with s (see correct_material), and 16-bit PNG
    assert max(report["applied"]["rel_error"]) < 0.05
    assert d.tolist() == pytest.approx([K * v * (1 - s0) / (1 - K * s0)
                                        for v, s0 in zip(PARAMS["diffuse"], PARAMS["specular"])], abs=2e-4)
    summary = (out / "summary.md").read_text()
    assert "| relative error |" in summary and "conoscopic.png" in summary


def test_wrong_roughness_gives_a_larger_error(files):
    measured = MS.read_merl(files / "ggx.binary")
    right = C.compare(measured, C.average_material(material_io.read_material(files / "right"))).figures()
    wrong = C.compare(measured, C.average_material(material_io.read_material(files / "wrong"))).figures()
    assert min(wrong["rel_error_corrected"]) > 0.05
    assert min(wrong["rel_error_corrected"]) > 30 * max(right["rel_error_corrected"])
    # one factor per incidence can absorb part of the difference, never make it worse
    per_inc = C.compare(measured, C.average_material(material_io.read_material(files / "wrong")),
                        correction="per-incidence").figures()
    assert per_inc["rel_error_corrected"] == per_inc["rel_error_corrected_per_incidence"]
    assert all(a <= b + 1e-9 for a, b in zip(per_inc["rel_error_corrected"], wrong["rel_error_corrected"]))


def test_factor_and_error_definitions():
    g = torch.Generator().manual_seed(0)
    ours = torch.rand(50, 3, generator=g, dtype=torch.float64) + 0.1
    w = torch.rand(50, generator=g, dtype=torch.float64)
    k = torch.tensor([2.0, 0.5, 1.3], dtype=torch.float64)
    for method in CN.FACTOR_METHODS:
        assert torch.allclose(CN.scale_factor(ours * k, ours, w, method), k)
    # one direction far off (a shifted highlight): the L1 factor stays, the others move
    meas = ours * k
    meas[0] = 100.0
    w[0] = 0.02
    assert torch.allclose(CN.scale_factor(meas, ours, w, "l1"), k)
    assert (CN.scale_factor(meas, ours, w, "lsq") - k).abs().min() > 0.1
    # l1 minimises sum w |k o - m|
    meas = ours * k * (1 + 0.3 * torch.randn(50, 3, generator=g, dtype=torch.float64))
    best = CN.scale_factor(meas, ours, w, "l1")
    for c in range(3):
        def cost(f: torch.Tensor, c: int = c) -> float:
            return float((w * (f * ours[:, c] - meas[:, c]).abs()).sum())
        assert cost(best[c]) <= min(cost(best[c] * (1 + e)) for e in (-0.01, 0.01, -0.1, 0.1)) + 1e-12
    m = torch.tensor([[1.0, 2.0, 4.0], [3.0, 2.0, 0.0]], dtype=torch.float64)
    o = torch.tensor([[2.0, 2.0, 3.0], [3.0, 1.0, 1.0]], dtype=torch.float64)
    w = torch.tensor([1.0, 3.0], dtype=torch.float64)
    assert CN.abs_error(m, o, w).tolist() == pytest.approx([0.25, 0.75, 1.0])
    assert CN.rel_error(m, o, w).tolist() == pytest.approx([1 / 10, 3 / 8, 4 / 4])


def test_averaging_mask_and_grid(tmp_path):
    grid = CN.conoscopic_grid((0.0,), n_theta=64, n_phi=8, theta_max_deg=89.9)
    assert float(grid.solid_angle.sum()) == pytest.approx(2 * math.pi * (1 - math.cos(math.radians(89.9))))
    # the in-plane slice: s > 0 on the mirror side (phi_o = 180 degrees)
    mirror = BM.direction(torch.tensor(math.radians(89.9), dtype=torch.float64),
                          torch.tensor(math.pi, dtype=torch.float64))
    assert torch.allclose(grid.slice_wo[-1], mirror, atol=1e-9)
    # left half the right material, right half another: the mask selects the left
    left, other = material(), material(diffuse=(0.1, 0.1, 0.1), roughness=0.8)
    maps = torch.cat([left[..., :4], other[..., 4:]], dim=-1)
    mask = torch.zeros(8, 8, dtype=torch.bool)
    mask[:, :4] = True
    image = np.zeros((8, 8), np.float32)
    image[:, :4] = 1.0
    write_image(tmp_path / "mask.png", image)
    assert torch.equal(C.read_mask(tmp_path / "mask.png", 8, 8), mask)
    with pytest.raises(ValueError, match=r"mask\.png: expected a mask of 4x4"):
        C.read_mask(tmp_path / "mask.png", 4, 4)
    measured = BM.MerlBRDF(BM.merl_table(ggx(K), dims=(45, 45, 90)), name="coarse")
    masked = C.compare(measured, C.average_material(maps, mask)).figures()
    whole = C.compare(measured, C.average_material(maps)).figures()
    assert masked["factor"] == pytest.approx([K] * 3, rel=0.02)
    assert max(whole["rel_error_corrected"]) > 5 * max(masked["rel_error_corrected"])
    # normal-mapped texels: the reflectance average spreads the highlight, the parameter average does not
    bumpy = material().repeat(1, 1, 1, 1)
    tilt = torch.linspace(-0.4, 0.4, 8)
    bumpy[:, 0] = tilt[None, None, :]
    bumpy = M.normalize_normals(bumpy)
    avg = C.average_material(bumpy)
    wi = BM.direction(torch.tensor(0.5), torch.tensor(0.0))
    wo = BM.direction(torch.tensor(0.5), torch.tensor(math.pi))
    assert float(avg.brdf(wi, wo, "reflectance")[1]) < 0.8 * float(avg.brdf(wi, wo, "parameters")[1])
    assert C.average_material(bumpy, max_texels=5).texels.shape == (5, 10)


def test_correct_material():
    maps = material()
    k = torch.tensor([1.5, 2.0, 0.5])
    out, info = C.correct_material(maps, k)
    wi = BM.direction(torch.tensor([0.2, 0.6]), torch.tensor([0.0, 0.0]))
    wo = BM.direction(torch.tensor([0.4, 0.6]), torch.tensor([2.0, math.pi]))
    before = C.model_brdf(maps[0, :, 0, :1].T, wi, wo)
    after = C.model_brdf(out[0, :, 0, :1].T, wi, wo)
    assert torch.allclose(after / before, k.double().expand(2, 3), rtol=0.02)
    assert info["clipped_diffuse"] == 0.0
    _, info = C.correct_material(maps, [3.0, 3.0, 3.0])
    assert info["clipped_diffuse"] > 0.0
    with pytest.raises(ValueError, match="factor: expected three positive"):
        C.correct_material(maps, [1.0, -1.0, 1.0])


def test_synthetic_merl_is_our_model(tmp_path):
    table = C.write_synthetic_merl(material(), tmp_path / "synthetic.binary", scale=K)
    again = MS.read_merl(tmp_path / "synthetic.binary")
    want = BM.merl_table(ggx(K))
    assert torch.equal(again.valid, (want >= 0).all(0))
    assert torch.allclose(again.table[:, again.valid], want[:, again.valid], rtol=1e-6)
    assert torch.allclose(table, want, rtol=1e-6)


@pytest.mark.slow
def test_direct_fit_ggx_vs_other_models():
    """Our model fitted to 'measurements' of itself (near zero error), of a Beckmann lobe and of two lobes."""
    ggx_meas = BM.MerlBRDF(BM.merl_table(ggx()), name="ggx")
    fit = FM.fit_measured(ggx_meas)
    s = fit.summary()
    assert fit.loss < 2e-3 and max(s["rel_error"]) < 0.005
    assert s["roughness"] == pytest.approx(PARAMS["roughness"], abs=0.005)
    assert s["diffuse"] == pytest.approx(list(PARAMS["diffuse"]), abs=0.005)
    assert s["specular"] == pytest.approx(list(PARAMS["specular"]), abs=0.005)
    coarse = (60, 60, 120)  # smaller tables: enough to tell these apart
    beck = FM.fit_measured(BM.MerlBRDF(BM.merl_table(ggx(distribution="beckmann"), coarse), name="beckmann"))
    sharp, broad = ggx(diffuse=(0.3,) * 3, specular=(0.04,) * 3, roughness=0.2), ggx(
        diffuse=(0.0,) * 3, specular=(0.02,) * 3, roughness=0.7)
    two = FM.fit_measured(BM.MerlBRDF(BM.merl_table(lambda a, b: sharp(a, b) + broad(a, b), coarse), name="two"))
    for other in (beck, two):
        assert other.loss > 10 * fit.loss and float(other.rel_error.max()) > 0.03


def test_csv_measurement_through_compare(tmp_path):
    """A gonioreflectometer-style CSV of our model x K: the factor is found; what remains is the
    bilinear interpolation between its azimuths, halving with the azimuth step."""
    errors = []
    for step in (10.0, 5.0):
        samples = BM.gonio_samples(ggx(K), list(CN.DEFAULT_INCIDENCES), np.arange(0.0, 86.0, 2.5),
                                   np.arange(0.0, 181.0, step))
        MS.write_tabulated_csv(tmp_path / "gonio.csv", *samples)
        figures = C.compare(MS.read_measured(tmp_path / "gonio.csv"), C.average_material(material())).figures()
        assert figures["factor"] == pytest.approx([K] * 3, rel=0.01)
        assert figures["valid_fraction"] == 1.0
        errors.append(max(figures["rel_error_corrected"]))
    assert errors[0] < 0.05 and errors[1] < 0.6 * errors[0]


def test_cli_errors_and_help(files, tmp_path, capsys):
    assert cli.main(["calibrate", str(files / "right"), "--measured", str(tmp_path / "none.binary"),
                     "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mi-svbrdf calibrate: error:") and "none.binary" in err and "\n" not in err
    bad = tmp_path / "bad.binary"
    bad.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + b"\x00" * 80)
    assert cli.main(["calibrate", str(files / "right"), "--measured", str(bad), "-o", str(tmp_path / "o")]) == 2
    assert "truncated" in capsys.readouterr().err
    write_image(tmp_path / "mask.png", np.ones((4, 4), np.float32))
    assert cli.main(["calibrate", str(files / "right"), "--measured", str(files / "ggx.binary"), "--mask",
                     str(tmp_path / "mask.png"), "-o", str(tmp_path / "o")]) == 2
    assert "expected a mask of 8x8" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["calibrate", str(files / "right"), "--measured", "x", "--incidences", "10,95", "-o", "o"])
    assert "expected comma-separated angles" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["calibrate", "--help"])
    text = capsys.readouterr().out
    assert "report.json" in text and "mi-svbrdf calibrate example:tiles --measured" in text


def test_write_synthetic_cli_writes_the_scaled_model(files, tmp_path, capsys):
    """``calibrate MATERIAL --write-synthetic --scale R,G,B -o FILE.binary``: the file write_synthetic_merl writes,
    in which the comparison finds the scale per channel."""
    out = tmp_path / "sub" / "sample.binary"
    assert cli.main(["calibrate", str(files / "right"), "--write-synthetic", "--scale", "1.7,1.5,1.2",
                     "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "ggx BRDF of its averaged parameters x 1.7/1.5/1.2" in printed
    assert sorted(p.name for p in out.parent.iterdir()) == ["sample.binary"]  # no temporary file left
    measured = MS.read_merl(out)
    want = BM.merl_table(ggx(torch.tensor([1.7, 1.5, 1.2], dtype=torch.float64)))
    assert torch.allclose(measured.table[:, measured.valid], want[:, measured.valid], rtol=1e-6)
    figures = C.compare(measured, C.average_material(material())).figures()
    assert figures["factor"] == pytest.approx([1.7, 1.5, 1.2], rel=1e-3)
    # one number: every channel; the default: 1
    assert cli.main(["calibrate", str(files / "right"), "--write-synthetic", "-o", str(tmp_path / "one.binary")]) == 0
    one = MS.read_merl(tmp_path / "one.binary")
    assert torch.allclose(one.table[:, one.valid], BM.merl_table(ggx())[:, one.valid], rtol=1e-6)


def test_textured_x1_5_reads_1_7_and_calibrate_says_why(tmp_path, capsys):
    """The help's example: the tiles' synthetic x1.5 measurement (the BRDF of their averaged parameters x 1.5) reads as
    a factor of about 1.7 against the texels' averaged reflectance, which is what calibrate compares (an instrument
    sees the texels' light averaged); the printed line says so, and against the averaged parameters' BRDF the
    factor is the scale, 1.5."""
    assert cli.main(["calibrate", "example:tiles", "--write-synthetic", "--scale", "1.5", "-o",
                     str(tmp_path / "x1.5.binary")]) == 0
    assert cli.main(["calibrate", "example:tiles", "--measured", str(tmp_path / "x1.5.binary"), "--no-fit",
                     "-o", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert all(1.6 < f < 1.8 for f in report["factor"]), report["factor"]
    assert report["averaging"]["with_parameter_average"]["factor"] == pytest.approx([1.5] * 3, rel=1e-3)
    assert "compared with the texels' averaged reflectance" in printed and "the factor would be 1.5/1.5/1.5" in printed


#: (case, argv after ``calibrate`` ({r}: the fixture folder, {t}: the test's), what the error line must name).
SYNTHETIC_BAD = [
    ("not a .binary", "{r}/right --write-synthetic -o {t}/out.csv", ["-o/--out", ".binary", "out.csv"]),
    ("a folder", "{r}/right --write-synthetic -o {r}", ["-o/--out", "expected a MERL file name"]),
    ("measured too", "{r}/right --write-synthetic --measured {r}/ggx.binary -o {t}/s.binary",
     ["--measured", "expected none with --write-synthetic"]),
    ("apply too", "{r}/right --write-synthetic --apply -o {t}/s.binary", ["--apply", "--write-synthetic"]),
    ("scale without", "{r}/right --measured {r}/ggx.binary --scale 2 -o {t}/o", ["--scale", "--write-synthetic"]),
    ("no measurement", "{r}/right -o {t}/o", ["--measured", "--write-synthetic writes one"]),
    ("missing material", "{t}/none --write-synthetic -o {t}/s.binary", ["MATERIAL_DIR", "none"]),
]


@pytest.mark.parametrize("case, argv, names", SYNTHETIC_BAD, ids=[c[0] for c in SYNTHETIC_BAD])
def test_write_synthetic_and_measured_errors(files, tmp_path, capsys, case, argv, names):
    assert cli.main(["calibrate", *argv.format(r=files, t=tmp_path).split()]) == 2, case
    err = capsys.readouterr().err.strip()
    assert err.startswith("mi-svbrdf calibrate: error:") and "\n" not in err, err
    for name in names:
        assert name in err, f"{case}: expected {name!r} in {err!r}"
    assert not list(tmp_path.iterdir()), f"{case}: files written on bad input"


def test_write_synthetic_scale_must_be_positive(files, tmp_path, capsys):
    for bad in ("0", "1,2", "-1,1,1", "x"):
        with pytest.raises(SystemExit):
            cli.main(["calibrate", str(files / "right"), "--write-synthetic", f"--scale={bad}", "-o",
                      str(tmp_path / "s.binary")])
        assert "expected one positive number or three (R,G,B)" in capsys.readouterr().err
