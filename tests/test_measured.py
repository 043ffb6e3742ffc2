"""Measured BRDFs (``mi_svbrdf.io.measured``): the MERL binary format, the tabulated CSV, lookups, bad files."""
from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
import torch

from mi_svbrdf.core import brdf_measured as BM
from mi_svbrdf.core import brdf_torch
from mi_svbrdf.io import measured as MS

PARAMS = {"diffuse": (0.5, 0.3, 0.15), "specular": (0.05, 0.06, 0.08), "roughness": 0.35}


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest: one torch thread for the module


def ggx(diffuse=PARAMS["diffuse"], specular=PARAMS["specular"], roughness=PARAMS["roughness"], scale=1.0,
        distribution="ggx"):
    """Our model (normal z) as a BRDF function of (wi, wo), times ``scale``."""
    d = torch.tensor(diffuse, dtype=torch.float64)
    s = torch.tensor(specular, dtype=torch.float64)
    r = torch.tensor([roughness], dtype=torch.float64)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    return lambda wi, wo: scale * brdf_torch.eval_brdf(n, wi, wo, d, s, r, distribution=distribution, dim=-1)


def random_pairs(count: int, seed: int = 0, max_theta: float = 1.4) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)

    def dirs() -> torch.Tensor:
        return BM.direction(torch.rand(count, generator=g, dtype=torch.float64) * max_theta,
                            torch.rand(count, generator=g, dtype=torch.float64) * 2 * math.pi)

    return dirs(), dirs()


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    """A MERL file of our GGX model times k = 1.7, and its table."""
    table = BM.merl_table(ggx(scale=1.7))
    path = tmp_path_factory.mktemp("merl") / "ggx_x1.7.binary"
    MS.write_merl(path, table)
    return path, table


def test_doctests():
    assert doctest.testmod(MS).failed == 0


def test_half_diff_conventions():
    a = math.radians(30.0)
    # the mirror configuration: h = n, theta_h = 0, theta_d = the incidence, phi_d = 0
    wi = torch.tensor([math.sin(a), 0.0, math.cos(a)])
    wo = torch.tensor([-math.sin(a), 0.0, math.cos(a)])
    th, td, pd = BM.half_diff(wi, wo)
    assert float(th) == pytest.approx(0.0, abs=1e-12) and float(td) == pytest.approx(a) and float(pd) < 1e-12
    # retro-reflection: h = wi, theta_h = the incidence, theta_d = 0
    th, td, _ = BM.half_diff(wi, wi)
    assert float(th) == pytest.approx(a) and float(td) == pytest.approx(0.0, abs=1e-6)
    # inverse and reciprocity (phi_d folded to [0, pi))
    g = torch.Generator().manual_seed(3)
    angles = [torch.rand(500, generator=g, dtype=torch.float64) * x for x in (1.5, 1.5, math.pi, 6.0)]
    wi, wo = BM.from_half_diff(*angles)
    back = BM.half_diff(wi, wo)
    for want, got in zip(angles[:3], back):
        assert torch.allclose(want, got, atol=1e-9)
    swapped = BM.half_diff(wo, wi)
    for want, got in zip(back, swapped):
        assert torch.allclose(want, got, atol=1e-9)


def test_merl_file_round_trip(merl_file):
    path, table = merl_file
    assert path.stat().st_size == MS.MERL_BYTES == 34_992_012
    raw = path.read_bytes()
    assert tuple(np.frombuffer(raw[:12], "<i4")) == (90, 90, 180)
    # the stored doubles are BRDF / scale, channel-major: entry (R, h=0, d=0, p=0) first, blue last
    stored = np.frombuffer(raw[12:], "<f8").reshape(3, 90, 90, 180)
    assert stored[0, 10, 20, 30] * MS.MERL_SCALES[0] == pytest.approx(float(table[0, 10, 20, 30]), rel=1e-14)
    assert stored[2, 10, 20, 30] * MS.MERL_SCALES[2] == pytest.approx(float(table[2, 10, 20, 30]), rel=1e-14)
    assert (stored[table < 0] == -1.0).all()
    brdf = MS.read_merl(path)
    assert torch.allclose(brdf.table[brdf.valid[None].expand(3, -1, -1, -1)], table[table >= 0], rtol=1e-14, atol=0)
    assert torch.equal(brdf.valid, (table >= 0).all(0))
    # the table holds our model (x 1.7) at the documented grid points: entry (h, d, p) at
    # theta_h = (h/90)^2 pi/2, theta_d = d pi/180, phi_d = p pi/180
    h, d, p = torch.tensor([5, 40, 60]), torch.tensor([3, 30, 30]), torch.tensor([0, 90, 170])
    wi, wo = BM.from_half_diff((h.double() / 90) ** 2 * math.pi / 2, d.double() * math.pi / 180,
                               p.double() * math.pi / 180)
    assert torch.allclose(brdf.table[:, h, d, p].T, ggx(scale=1.7)(wi, wo), rtol=1e-12)
    f, valid = brdf.lookup(wi, wo)  # at a grid point, the interpolation is the entry
    assert valid.all() and torch.allclose(f, ggx(scale=1.7)(wi, wo), rtol=1e-9)


def test_merl_lookup_interpolates_our_model(merl_file):
    brdf = MS.read_merl(merl_file[0])
    wi, wo = random_pairs(20000)
    f, valid = brdf.lookup(wi, wo)
    truth = ggx(scale=1.7)(wi, wo)
    assert valid.all()
    rel = (f - truth).abs() / truth
    assert float(rel.median()) < 1e-3 and float(rel.max()) < 0.03
    cos = wo[:, 2:3]
    assert float(((f - truth).abs() * cos).sum() / (truth * cos).sum()) < 2e-3
    # batch shapes are kept, wi and wo broadcast
    f2, v2 = brdf.lookup(wi.view(100, 200, 3)[:, :1], wo.view(100, 200, 3))
    assert f2.shape == (100, 200, 3) and v2.shape == (100, 200)
    # reciprocity: the table folds phi_d over pi
    assert torch.allclose(brdf.lookup(wo, wi)[0], f, rtol=1e-9)


def test_merl_missing_entries_and_nearest():
    n = (6, 5, 8)
    table = torch.rand(3, *n, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    table[:, 2] = -1.0  # theta_h entry 2: no data
    brdf = BM.MerlBRDF(table)
    near = BM.MerlBRDF(table, interpolation="nearest")
    # the reference reader truncates: u in [i, i + 1) reads entry i
    u_h, u_d, u_p = (torch.tensor(v, dtype=torch.float64) for v in ([1.6, 3.2], [2.7, 0.1], [5.9, 7.5]))
    theta_h = (u_h / n[0]) ** 2 * math.pi / 2
    wi, wo = BM.from_half_diff(theta_h, u_d / n[1] * math.pi / 2, u_p / n[2] * math.pi)
    f, valid = near.lookup(wi, wo)
    assert valid.all()
    assert torch.allclose(f, table[:, [1, 3], [2, 0], [5, 7]].T)
    # linear: the u_h = 1.6 point lies between entries 1 and 2; entry 2 has no data, so entry 1 alone counts
    f, valid = brdf.lookup(wi[:1], wo[:1])
    d0, p0, td, tp = 2, 5, 0.7, 0.9
    plane = table[:, 1]
    want = ((1 - td) * ((1 - tp) * plane[:, d0, p0] + tp * plane[:, d0, p0 + 1])
            + td * ((1 - tp) * plane[:, d0 + 1, p0] + tp * plane[:, d0 + 1, p0 + 1]))
    assert valid.all() and torch.allclose(f[0], want, rtol=1e-9)
    # phi_d is cyclic: u_p = 7.5 mixes entries 7 and 0
    f, _ = brdf.lookup(wi[1:], wo[1:])
    assert torch.isfinite(f).all()
    # a point whose every corner lacks data is invalid, value 0
    empty = table.clone()
    empty[:] = -1.0
    f, valid = BM.MerlBRDF(empty).lookup(wi, wo)
    assert not valid.any() and (f == 0).all()


def test_merl_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        MS.read_merl(tmp_path / "missing.binary")
    short = tmp_path / "short.binary"
    short.write_bytes(b"\x00" * 7)
    with pytest.raises(ValueError, match=r"short\.binary.*header"):
        MS.read_merl(short)
    dims = tmp_path / "dims.binary"
    dims.write_bytes(np.array([90, 90, 360], "<i4").tobytes() + b"\x00" * 64)
    with pytest.raises(ValueError, match=r"dims\.binary.*90 x 90 x 180.*90 x 90 x 360"):
        MS.read_merl(dims)
    truncated = tmp_path / "truncated.binary"
    truncated.write_bytes(np.array(BM.MERL_DIMS, "<i4").tobytes() + np.zeros(1000, "<f8").tobytes())
    with pytest.raises(ValueError, match=r"truncated\.binary.*34992012 bytes.*\(truncated\)"):
        MS.read_merl(truncated)
    data = np.zeros(3 * 90 * 90 * 180, "<f8")
    data[12345] = np.nan
    nan = tmp_path / "nan.binary"
    nan.write_bytes(np.array(BM.MERL_DIMS, "<i4").tobytes() + data.tobytes())
    with pytest.raises(ValueError, match=r"nan\.binary.*1 NaN"):
        MS.read_merl(nan)
    longer = tmp_path / "long.binary"
    longer.write_bytes(np.array(BM.MERL_DIMS, "<i4").tobytes() + np.zeros(data.size + 1, "<f8").tobytes())
    with pytest.raises(ValueError, match="trailing bytes"):
        MS.read_merl(longer)
    with pytest.raises(ValueError, match="table: expected shape"):
        MS.write_merl(tmp_path / "x.binary", torch.zeros(3, 90, 90, 90))
    with pytest.raises(ValueError, match="wi: expected shape"):
        BM.MerlBRDF(torch.zeros(3, 4, 4, 4)).lookup(torch.zeros(4, 2), torch.zeros(4, 3))


def gonio_csv(path, brdf=None):
    samples = BM.gonio_samples(brdf or ggx(), [10.0, 30.0, 50.0], np.arange(0.0, 86.0, 5.0),
                               np.arange(0.0, 181.0, 15.0))
    MS.write_tabulated_csv(path, *samples, comment="our GGX model\nsampled as a gonioreflectometer")
    return samples


def test_csv_round_trip_and_lookup(tmp_path):
    path = tmp_path / "gonio.csv"
    ti, pi, to, po, values = gonio_csv(path)
    text = path.read_text()
    assert text.startswith("# our GGX model\n# sampled") and "theta_i,phi_i,theta_o,phi_o,r,g,b" in text
    brdf = MS.read_measured(path)
    assert isinstance(brdf, BM.TabulatedBRDF) and brdf.incidences.tolist() == pytest.approx([10.0, 30.0, 50.0])
    wi = BM.direction(torch.deg2rad(torch.as_tensor(ti)), torch.deg2rad(torch.as_tensor(pi)))
    wo = BM.direction(torch.deg2rad(torch.as_tensor(to)), torch.deg2rad(torch.as_tensor(po)))
    f, valid = brdf.lookup(wi, wo)
    inside = torch.as_tensor(to) < 85.0
    assert valid[inside].all()
    assert torch.allclose(f, torch.as_tensor(values), rtol=1e-8)  # exact at the samples
    # isotropy: the mirrored azimuth and a rotated frame read the same
    flip = torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)
    assert torch.allclose(brdf.lookup(wi * flip, wo * flip)[0], f, rtol=1e-8)
    c, s = math.cos(0.7), math.sin(0.7)
    rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    assert torch.allclose(brdf.lookup(wi @ rot.T, wo @ rot.T)[0], f, rtol=1e-6)
    # between samples and incidences: close to the model where it is smooth (off the highlight)
    g = torch.Generator().manual_seed(0)
    theta_i = torch.deg2rad(12 + 35 * torch.rand(2000, generator=g, dtype=torch.float64))
    wi = BM.direction(theta_i, torch.zeros_like(theta_i))
    wo = BM.direction(torch.deg2rad(70 * torch.rand(2000, generator=g, dtype=torch.float64)),
                      torch.rand(2000, generator=g, dtype=torch.float64) * 2 * math.pi)
    f, valid = brdf.lookup(wi, wo)
    truth = ggx()(wi, wo)
    assert valid.all()
    rel = ((f - truth).abs() / truth)
    assert float(rel.median()) < 0.05
    # outside the measured incidences: flagged, still finite
    wi = BM.direction(torch.deg2rad(torch.tensor([5.0, 70.0])), torch.zeros(2))
    f, valid = brdf.lookup(wi, BM.direction(torch.tensor([0.3, 0.3]), torch.zeros(2)))
    assert not valid.any() and torch.isfinite(f).all()


def test_scattered_samples_use_inverse_distance_weighting():
    """Samples that fill no grid (random outgoing directions) are interpolated by inverse distance weighting."""
    g = torch.Generator().manual_seed(5)
    count = 800
    theta_o = 60.0 * torch.sqrt(torch.rand(count, generator=g, dtype=torch.float64))
    phi_o = 360.0 * torch.rand(count, generator=g, dtype=torch.float64)
    theta_i = torch.full((count,), 30.0, dtype=torch.float64)
    wi = BM.direction(torch.deg2rad(theta_i), torch.zeros(count, dtype=torch.float64))
    wo = BM.direction(torch.deg2rad(theta_o), torch.deg2rad(phi_o))
    rough = ggx(roughness=0.8)
    brdf = BM.TabulatedBRDF(theta_i, torch.zeros(count), theta_o, phi_o, rough(wi, wo))
    assert brdf.grids == [None]
    f, valid = brdf.lookup(wi, wo)
    assert valid.all() and torch.allclose(f, rough(wi, wo), rtol=1e-9)
    q_wo = BM.direction(torch.deg2rad(55.0 * torch.sqrt(torch.rand(500, generator=g, dtype=torch.float64))),
                        torch.rand(500, generator=g, dtype=torch.float64) * 2 * math.pi)
    f, valid = brdf.lookup(wi[:1], q_wo)
    assert valid.double().mean() > 0.95
    rel = (f - rough(wi[:1], q_wo)).abs() / rough(wi[:1], q_wo)
    assert float(rel[valid].median()) < 0.02
    far = BM.direction(torch.tensor(math.radians(85.0), dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64))
    assert not bool(brdf.lookup(wi[0], far)[1])  # no sample near theta_o = 85 degrees


def test_csv_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        MS.read_tabulated_csv(tmp_path / "missing.csv")
    cases = {
        "nan.csv": ("theta_i,phi_i,theta_o,phi_o,r,g,b\n10,0,0,0,0.1,0.1,0.1\n10,0,5,0,nan,0.1,0.1\n",
                    r"nan\.csv:3: expected finite numbers"),
        "cols.csv": ("10,0,0,0,0.1,0.1\n", r"cols\.csv:1: expected 7 values"),
        "text.csv": ("10,0,0,0,0.1,0.1,0.1\n10,0,x,0,0.1,0.1,0.1\n", r"text\.csv:2: expected 7 numbers"),
        "negative.csv": ("10,0,0,0,-0.1,0.1,0.1\n", r"negative\.csv: expected BRDF values >= 0"),
        "angle.csv": ("95,0,0,0,0.1,0.1,0.1\n", r"angle\.csv: expected theta_i in \[0, 90\]"),
        "empty.csv": ("# nothing\ntheta_i,phi_i,theta_o,phi_o,r,g,b\n", r"empty\.csv: expected rows"),
    }
    for name, (text, message) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=message):
            MS.read_tabulated_csv(tmp_path / name)
