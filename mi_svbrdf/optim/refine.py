"""Refinement of a net's maps against uncalibrated photos, each photo's light estimated from the photos.

The multi-image net takes photos nobody calibrated; the optimiser (:func:`~mi_svbrdf.optim.fit.optimize`)
needs every photo's camera and light. :func:`refine` bridges them: it estimates each photo's
light and camera from the photos themselves, under the net's maps, then fits the maps and that
calibration jointly by the rendering loss (the optimiser with self-calibration on,
:mod:`mi_svbrdf.optim.selfcal`), pulled towards the net's maps.

**Assumed** (what the nets assume too): each photo is a rectified, fronto-parallel square of the
flat sample spanning ``[-1, 1]^2`` (texel ``(i, j)`` at ``x = -1 + (2j+1)/W, y = 1 - (2i+1)/H``);
photo 0 is a flash photo, its light at its camera (the first photo of the thesis's protocol);
each other photo is lit by one point light anywhere above the sample (its own flash, or a lamp);
no other light. Positions are in the sample's units (its half-width is 1).

**Initialisation** (:func:`estimate_lights`, at ``search_size``\\ :sup:`2` texels): every light
and camera hypothesis of a grid renders the net's maps; each photo keeps the hypothesis whose
rendering, scaled by its best per-channel gain, is closest to the photo in log space. Photo 0
searches its camera's offset and distance with the light at the camera (the highlight sits
below a flash); each other photo searches its light (elevation, azimuth, distance) from a camera
above the centre, then its camera (elevation, azimuth, and the light at the camera: its own
flash), then its light again from that camera. The highlight's position and shape and the
shading of the net's normals decide.

**Ambiguities and how they are pinned.** Albedo and light intensity trade a global scale: the
gains start from the net's maps (the net's albedo scale) and the self-calibration keeps each
channel's geometric-mean gain fixed. Distant lights leave the bas-relief family of normals and
lights: the lights here are near (1-3 sample widths), the flash photo fixes its light at the
camera, and the fit is pulled towards the net's normals. A photo's camera distance trades with
its light's for the highlight's size; the search takes the best pair and the fit moves both
within ``trust_pose``.

**Robust.** A photo that holds no measurement (its brightest texels below ``dark_level``, or
more than ``max_saturated`` of its texels clipped) or whose light the search could not explain
(best log error above ``max_search_error``) is dropped with a note. At every photo count
(``validate``) the optimiser's validation (:func:`~mi_svbrdf.optim.fit.optimize`, ``validate_photo``)
fits all photos but the last one kept, re-renders that held-out photo under its estimated light
from maps between the net's and the fit's, and keeps the blend that explains it best: the
refinement does not end worse on a photo it did not fit than the net's maps (the net's maps
themselves are one of the blends). On captures whose lights the search cannot pin down, that
keeps the net's maps, or close to them.

Examples:
    >>> import torch
    >>> from mi_svbrdf.data import procedural
    >>> from mi_svbrdf.optim.refine import RefineConfig, refine
    >>> maps = procedural.generate("tiles", 0, 16)[None]
    >>> photos = torch.rand(2, 3, 16, 16) * 0.3
    >>> res = refine(photos, maps, config=RefineConfig(budget_s=2.0, progress=False))
    >>> tuple(res.maps.shape), len(res.lights)
    ((1, 10, 16, 16), 2)
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.maps import check_maps
from mi_svbrdf.core.metrics import display
from mi_svbrdf.core.render import point, texel_positions
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, ImageSpec, LightSpec
from mi_svbrdf.optim.fit import OptimizeConfig, OptimizeResult, optimize, resize_maps_to, stop_notes
from mi_svbrdf.plugins.model import DISTRIBUTIONS

__all__ = ["RefineConfig", "RefineResult", "estimate_lights", "estimated_capture", "refine"]

#: Height of the ambient fill light (far: its direction is the zenith at every texel).
FILL_HEIGHT = 1000.0


@dataclass
class RefineConfig:
    """Settings of :func:`refine`; :meth:`from_dict` rejects unknown keys."""

    budget_s: float = 60.0  #: wall time of the whole refinement (search + fit), seconds > 0
    camera_distance: float = 2.75  #: the cameras' assumed distance from the sample centre (2.75: a 40 degree FOV filled by the sample), > 0
    search_size: int = 32  #: texels per side the light search renders at, >= 4
    distances: tuple[float, ...] = (1.0, 1.4, 2.0, 2.8, 4.0)  #: light (and photo 0's camera) distances searched
    elevations: tuple[float, ...] = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)  #: light elevations searched, degrees
    azimuths: int = 16  #: light azimuths searched (evenly spaced), >= 4
    camera_elevations: tuple[float, ...] = (40.0, 50.0, 60.0, 70.0, 80.0)  #: other photos' camera elevations searched (and 90), degrees
    lr: float = 0.02  #: the fit's Adam learning rate (the maps start from the net's: smaller than a fit from scratch)
    prior_falloff: float = 2.0  #: the pull towards the net's maps weighs prior_weight / N**prior_falloff (OptimizeConfig)
    trust_pose: float = 0.15  #: prior width of the fit's light and camera corrections, fraction of their distance, > 0
    trust_exposure_stops: float = 1.0  #: prior width of a photo's exposure around its estimate, stops, > 0
    calibrate_after: int = 50  #: steps of the maps alone before lights and gains move, >= 0
    dark_level: float = 0.02  #: a photo whose 99th-percentile texel is below this (linear) holds no measurement
    max_saturated: float = 0.5  #: a photo with more than this fraction of texels clipped holds no measurement
    clip_level: float = 0.99  #: a texel with a channel at or above this (linear) is clipped (one-sided in the fit)
    max_search_error: float = 0.15  #: a photo whose best hypothesis errs more (mean displayed difference) is dropped
    ambient: bool = True  #: model each photo's room light as a fill from above (an extra light at the zenith, no fall-off)
    validate: bool = True  #: choose the blend of the net's and the fit's maps on a held-out photo at every N (module docstring)
    distribution: str = "ggx"  #: BRDF model of the maps (the net's)
    progress: bool = True  #: progress bar of the fit
    optimizer: dict[str, Any] = field(default_factory=dict)  #: further OptimizeConfig settings of the fit

    def __post_init__(self) -> None:
        check_fields([
            ("budget_s", self.budget_s > 0, "seconds > 0", self.budget_s),
            ("camera_distance", self.camera_distance > 0, "a distance > 0", self.camera_distance),
            ("search_size", isinstance(self.search_size, int) and self.search_size >= 4, "an int >= 4",
             self.search_size),
            ("distances", bool(self.distances) and all(d > 0 for d in self.distances), "distances > 0",
             self.distances),
            ("elevations", bool(self.elevations) and all(0 < e <= 90 for e in self.elevations),
             "degrees in (0, 90]", self.elevations),
            ("camera_elevations", all(0 < e <= 90 for e in self.camera_elevations), "degrees in (0, 90]",
             self.camera_elevations),
            ("azimuths", isinstance(self.azimuths, int) and self.azimuths >= 4, "an int >= 4", self.azimuths),
            ("lr", self.lr > 0, "a learning rate > 0", self.lr),
            ("prior_falloff", self.prior_falloff >= 0, "an exponent >= 0", self.prior_falloff),
            ("trust_pose", self.trust_pose > 0, "a fraction > 0", self.trust_pose),
            ("trust_exposure_stops", self.trust_exposure_stops > 0, "stops > 0", self.trust_exposure_stops),
            ("calibrate_after", isinstance(self.calibrate_after, int) and self.calibrate_after >= 0,
             "an int >= 0", self.calibrate_after),
            ("dark_level", self.dark_level >= 0, "a level >= 0", self.dark_level),
            ("max_saturated", 0 < self.max_saturated <= 1, "a fraction in (0, 1]", self.max_saturated),
            ("clip_level", 0 < self.clip_level, "a level > 0", self.clip_level),
            ("max_search_error", self.max_search_error > 0, "an error > 0", self.max_search_error),
            ("distribution", self.distribution in DISTRIBUTIONS, f"one of {DISTRIBUTIONS}", self.distribution),
            ("optimizer", isinstance(self.optimizer, dict), "a dict of OptimizeConfig fields", self.optimizer),
        ], owner="RefineConfig")
        self.distances = tuple(float(d) for d in self.distances)
        self.elevations = tuple(float(e) for e in self.elevations)
        self.camera_elevations = tuple(float(e) for e in self.camera_elevations)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RefineConfig:
        """Build from a dict; unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)


@dataclass
class RefineResult:
    """What :func:`refine` returns."""

    maps: torch.Tensor  #: (1, 10, H, W) refined maps (the net's where nothing could be refined)
    lights: list[dict[str, Any]]  #: per photo: camera, light, gain (RGB), search error, used (bool), note
    spec: CaptureSpec | None  #: the estimated capture of the photos used (after the fit), None: none used
    fit: OptimizeResult | None  #: the optimiser's result (steps, stop reason, calibration), None: not run
    error_before: list[float | None]  #: per photo, display RMSE of the net's maps under the estimated lights
    error_after: list[float | None]  #: the same for the refined maps (None: a dropped photo)
    notes: list[str] = field(default_factory=list)  #: dropped photos, stop notes
    seconds: float = 0.0  #: wall time

    @property
    def stop_reason(self) -> str:
        """The fit's stop reason ("" when it did not run)."""
        return self.fit.stop_reason if self.fit is not None else ""

    @property
    def steps(self) -> int:
        """The fit's steps (0 when it did not run)."""
        return self.fit.steps if self.fit is not None else 0

    def summary(self) -> dict[str, Any]:
        """JSON-ready: the estimated lights, steps, stop reason, per-photo errors before and after, the blend of the
        net's and the fit's maps the validation chose (0: the net's, 1: the fit's; None: not validated), notes."""
        r4 = lambda v: None if v is None else round(float(v), 5)  # noqa: E731
        return {"lights": self.lights, "steps": self.steps, "stop_reason": self.stop_reason,
                "rerender_rmse_before": [r4(v) for v in self.error_before],
                "rerender_rmse_after": [r4(v) for v in self.error_after],
                "calibration": self.fit.calibration if self.fit is not None else None,
                "blend": self.fit.shrink if self.fit is not None else None,
                "seconds": round(self.seconds, 3), "notes": list(self.notes)}


# ----------------------------------------------------------------------------- the light search
def _unit(elevation_deg: torch.Tensor, azimuth: torch.Tensor) -> torch.Tensor:
    """Unit vectors ``(..., 3)`` at elevations (degrees) and azimuths (radians)."""
    e = torch.deg2rad(elevation_deg)
    return torch.stack([e.cos() * azimuth.cos(), e.cos() * azimuth.sin(), e.sin()], dim=-1)


def _hemisphere(elevations: tuple[float, ...], azimuths: int, distances: tuple[float, ...]) -> torch.Tensor:
    """``(C, 3)`` positions: every elevation x azimuth x distance, plus the zenith at each distance."""
    el = torch.tensor(elevations, dtype=torch.float32)
    az = torch.arange(azimuths, dtype=torch.float32) * (2 * math.pi / azimuths)
    dirs = _unit(el[:, None].expand(-1, azimuths), az[None].expand(len(elevations), -1)).reshape(-1, 3)
    dirs = torch.cat([dirs, torch.tensor([[0.0, 0.0, 1.0]])])
    dist = torch.tensor(distances, dtype=torch.float32)
    return (dirs[None] * dist[:, None, None]).reshape(-1, 3)


def _scores(maps_s: torch.Tensor, pos: torch.Tensor, photo: torch.Tensor, mask: torch.Tensor,
            light: torch.Tensor, view: torch.Tensor, ambient: torch.Tensor,
            distribution: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Display error ``(C,)``, RGB gain ``(C, 3)`` and RGB ambient ``(C, 3)`` of each hypothesis ``(C, 3)``.

    Per hypothesis and channel the photo is fitted as ``gain x render + ambient x fill`` (linear
    least squares, both >= 0; ``fill`` the maps under a unit light at the zenith, ``ambient`` ``(3, M)``)
    and scored by the mean absolute difference of the displayed values (``x^(1/2.2)``: robust to
    the noise of dark texels). ``maps_s`` ``(1, 10, 1, M)``, ``pos`` ``(3, 1, M)``, ``photo``
    ``(3, M)``, ``mask`` ``(M,)`` bool (usable texels).
    """
    errs, gains, ambs = [], [], []
    w = mask.to(photo)[None, None]  # (1, 1, M)
    b = ambient[None]  # (1, 3, M)
    p = photo[None]
    for i in range(0, light.shape[0], 256):  # chunks: (1, C, 3, 1, M) intermediates stay small
        lt, vw = light[i:i + 256], view[i:i + 256]
        ones = torch.ones(1, lt.shape[0], 3)
        r = brdf_torch.render(maps_s, pos, point(lt)[None], point(vw)[None], ones, None, None,
                              distance_falloff=True, light_z_division=False, include_diffuse=True,
                              normalize_normals=True, distribution=distribution)[0, :, :, 0]  # (C, 3, M)
        rr, rb, bb = (w * r * r).sum(-1), (w * r * b).sum(-1), (w * b * b).sum(-1)
        rp, bp = (w * r * p).sum(-1), (w * b * p).sum(-1)
        det = (rr * bb - rb * rb).clamp_min(1e-12)
        g = (rp * bb - bp * rb) / det
        a = (bp * rr - rp * rb) / det
        alone = (a < 0) | (bb <= 1e-12)  # no ambient (or no fill basis): the light alone
        g = torch.where(alone, rp / rr.clamp_min(1e-12), g)
        a = a.clamp_min(0.0)
        fit = g[..., None] * r + a[..., None] * b
        err = ((gamma_encode(fit) - gamma_encode(p)).abs() * w).sum(dim=(1, 2)) / (3 * w.sum().clamp_min(1))
        bad = (g <= 0).any(dim=-1) | ~torch.isfinite(err)  # a light that must be negative explains nothing
        errs.append(torch.where(bad, torch.full_like(err, math.inf), err))
        gains.append(g.clamp_min(0.0))
        ambs.append(a)
    return torch.cat(errs), torch.cat(gains), torch.cat(ambs)


def estimate_lights(photos: torch.Tensor, maps: torch.Tensor, config: RefineConfig | None = None,
                    usable: torch.Tensor | None = None) -> list[dict[str, Any]]:
    """Each photo's camera, light and RGB gain under ``maps``, by a grid search (module docstring).

    Args:
        photos: ``(N, 3, H, W)`` linear rectified photos, photo 0 a flash photo.
        maps: ``(1, 10, H', W')`` maps the hypotheses render (the net's).
        config: the search grids (:class:`RefineConfig`).
        usable: ``(N, 1, H, W)`` bool, False at texels that do not count (clipped); None: all.

    Returns:
        per photo ``{"camera": [x, y, z], "light": [x, y, z], "gain": [r, g, b], "search_error": e}``,
        ``e`` the mean absolute log error of the best hypothesis (``inf``: none rendered the photo).
    """
    cfg = config or RefineConfig()
    s = cfg.search_size
    small = F.interpolate(photos.float(), size=(s, s), mode="area")
    maps_s = F.interpolate(maps.float(), size=(s, s), mode="area")
    mask = torch.ones(photos.shape[0], s * s, dtype=torch.bool)
    if usable is not None:
        mask = F.interpolate(usable.float(), size=(s, s), mode="area").reshape(photos.shape[0], -1) > 0.999
    maps_s = maps_s.reshape(1, 10, 1, -1)
    pos = texel_positions(s, s).reshape(3, 1, -1)
    d0 = cfg.camera_distance
    fill = _fill(maps_s, pos, d0, cfg.distribution) if cfg.ambient else torch.zeros(3, s * s)

    def best(k: int, light: torch.Tensor, view: torch.Tensor) -> tuple[float, torch.Tensor, torch.Tensor,
                                                                      torch.Tensor, torch.Tensor]:
        err, gain, amb = _scores(maps_s, pos, small[k].reshape(3, -1), mask[k], light, view, fill, cfg.distribution)
        i = int(torch.argmin(err))
        return float(err[i]), light[i], view[i], gain[i], amb[i]

    out = []
    # Photo 0: a flash at its camera; the camera's offset and distance searched.
    grid = torch.linspace(-0.9, 0.9, 10)
    xy = torch.stack(torch.meshgrid(grid, grid, indexing="ij"), dim=-1).reshape(-1, 2)
    cams = torch.cat([torch.cat([xy, torch.full((xy.shape[0], 1), d)], dim=1)
                      for d in (*cfg.distances, d0)])
    first = best(0, cams, cams)
    out.append(first)
    v0 = first[2]
    lights = _hemisphere(cfg.elevations, cfg.azimuths, (*cfg.distances,))
    cam_dirs = _hemisphere(cfg.camera_elevations, 12, (1.0,)) if cfg.camera_elevations else torch.zeros(0, 3)
    cam_dirs = torch.cat([cam_dirs, torch.tensor([[0.0, 0.0, 1.0]])])
    dist0 = float(v0.norm())
    for k in range(1, photos.shape[0]):
        top = torch.tensor([0.0, 0.0, dist0])
        light = best(k, lights, top.expand_as(lights))[1]
        cams = cam_dirs * dist0
        # the light found, or the photo's own flash (light at the camera), from each camera
        view_a = best(k, torch.cat([light.expand_as(cams), cams]), torch.cat([cams, cams]))[2]
        again = best(k, lights, view_a.expand_as(lights))
        flash = best(k, view_a[None], view_a[None])  # the flash from that camera
        out.append(again if again[0] <= flash[0] else flash)
    return [{"camera": [round(float(v), 5) for v in view], "light": [round(float(v), 5) for v in light],
             "gain": [round(float(v), 6) for v in gain], "ambient": [round(float(v), 6) for v in amb],
             "search_error": err}
            for err, light, view, gain, amb in out]


def _fill(maps_s: torch.Tensor, pos: torch.Tensor, camera_distance: float, distribution: str) -> torch.Tensor:
    """``(3, M)`` the maps under a unit light at the zenith, far (no fall-off), seen from above: the ambient basis."""
    zenith = torch.tensor([[[0.0, 0.0, 1.0, 0.0]]])
    view = torch.tensor([[[0.0, 0.0, camera_distance, 1.0]]])
    return brdf_torch.render(maps_s, pos, zenith, view, torch.ones(1, 1, 3), None, None, distance_falloff=False,
                             light_z_division=False, include_diffuse=True, normalize_normals=True,
                             distribution=distribution)[0, 0, :, 0]


# ----------------------------------------------------------------------------- the refinement
def _screen(photos: torch.Tensor, usable: torch.Tensor, cfg: RefineConfig) -> list[str | None]:
    """Per photo None (usable) or why it holds no measurement."""
    out: list[str | None] = []
    for k in range(photos.shape[0]):
        top = float(torch.quantile(photos[k].amax(dim=0).flatten(), 0.99))
        clipped = 1.0 - float(usable[k].float().mean())
        if top < cfg.dark_level:
            out.append(f"photo {k} is (nearly) black (99th percentile {top:.4f} < dark_level {cfg.dark_level})")
        elif clipped > cfg.max_saturated:
            out.append(f"photo {k} is {100 * clipped:.0f} % clipped (> max_saturated {cfg.max_saturated})")
        else:
            out.append(None)
    return out


def _spec(estimates: list[dict[str, Any]]) -> CaptureSpec:
    """The capture the estimates state: rectified linear photos, isotropic point lights, a zenith fill."""
    def extras(e: dict[str, Any]) -> tuple[LightSpec, ...]:
        amb = e.get("ambient") or [0.0, 0.0, 0.0]
        return (LightSpec((0.0, 0.0, FILL_HEIGHT), tuple(amb)),) if max(amb) > 0 else ()

    return CaptureSpec(tuple(ImageSpec(f"{k:03d}.exr", "linear_exr", True, CameraSpec(tuple(e["camera"])),
                                       LightSpec(tuple(e["light"]), tuple(e["gain"])), extras(e))
                             for k, e in enumerate(estimates)))


def estimated_capture(photos: torch.Tensor, maps: torch.Tensor, config: RefineConfig | None = None
                      ) -> tuple[CaptureSpec, list[dict[str, Any]]]:
    """The capture of ``photos`` as :func:`refine` starts it: each photo's camera, light, RGB gain and room fill
    estimated under ``maps`` (:func:`estimate_lights`, texels at or above ``clip_level`` left out).

    Args:
        photos: ``(N, 3, H, W)`` linear rectified photos, photo 0 a flash photo.
        maps: ``(1, 10, H', W')`` maps the hypotheses render.
        config: :class:`RefineConfig` (None: defaults).

    Returns:
        ``(spec, estimates)``: a rectified :class:`~mi_svbrdf.io.calibrated_photos.CaptureSpec` of the N photos
        (its photo ``k`` is ``photos[k]``) and :func:`estimate_lights`'s per-photo dicts.

    Examples:
        >>> from mi_svbrdf.data import procedural
        >>> spec, est = estimated_capture(torch.rand(2, 3, 16, 16) * 0.3, procedural.generate("tiles", 0, 16)[None],
        ...                               RefineConfig(search_size=8, progress=False))
        >>> len(spec.images), sorted(est[1])[:3]
        (2, ['ambient', 'camera', 'gain'])
    """
    cfg = config or RefineConfig()
    photos = photos.detach().float().cpu().clamp_min(0.0)
    usable = (photos < cfg.clip_level).all(dim=1, keepdim=True)
    estimates = estimate_lights(photos, maps.detach().float().cpu(), cfg, usable)
    return _spec(estimates), estimates


def _errors(maps: torch.Tensor, spec: CaptureSpec, photos: torch.Tensor, usable: torch.Tensor,
            distribution: str) -> list[float]:
    """Per photo display RMSE of ``maps`` rendered under ``spec`` against ``photos``, over usable texels."""
    h, w = photos.shape[-2:]
    m = maps.float() if maps.shape[-2:] == (h, w) else resize_maps_to(maps.float(), (h, w))
    pos = texel_positions(h, w)
    flags = {"light_z_division": False, "include_diffuse": True, "normalize_normals": True,
             "distribution": distribution}
    out = []
    with torch.no_grad():
        for k, im in enumerate(spec.images):
            view = point(torch.tensor([[im.camera.position]]))
            r = brdf_torch.render(m, pos, point(torch.tensor([[im.light.position]])), view,
                                  torch.tensor([[im.light.intensity]]), None, None, distance_falloff=True, **flags)[0, 0]
            for e in im.extra_lights:
                r = r + brdf_torch.render(m, pos, point(torch.tensor([[e.position]])), view,
                                          torch.tensor([[e.intensity]]), None, None, distance_falloff=False,
                                          **flags)[0, 0]
            sel = usable[k].expand(3, h, w)
            diff = display(r)[sel] - display(photos[k].float())[sel]
            out.append(float(diff.square().mean().sqrt()) if diff.numel() else math.nan)
    return out


def refine(photos: torch.Tensor, maps: torch.Tensor, *, config: RefineConfig | None = None) -> RefineResult:
    """Refine ``maps`` (a net's) against uncalibrated ``photos``, estimating each photo's light.

    Args:
        photos: ``(N, 3, H, W)`` or ``(1, N, 3, H, W)`` linear rectified photos as the net saw
            them; photo 0 a flash photo (module docstring).
        maps: ``(1, 10, H, W)`` the net's maps for them (resized to the photos' size if needed).
        config: :class:`RefineConfig` (None: defaults).

    Returns:
        :class:`RefineResult`: the maps, per-photo lights and errors before and after, notes.

    Raises:
        ValueError: photos or maps of the wrong shape, or non-finite values.

    Examples:
        >>> import torch
        >>> from mi_svbrdf.data import procedural
        >>> maps = procedural.generate("stone", 0, 16)[None]
        >>> res = refine(torch.rand(1, 3, 3, 16, 16) * 0.3, maps, config=RefineConfig(budget_s=2.0, progress=False))
        >>> len(res.error_before), res.summary()["stop_reason"] in ("converged", "budget", "iterations")
        (3, True)
    """
    t0 = time.perf_counter()
    cfg = config or RefineConfig()
    if isinstance(photos, torch.Tensor) and photos.dim() == 5 and photos.shape[0] == 1:
        photos = photos[0]
    if not isinstance(photos, torch.Tensor) or photos.dim() != 4 or photos.shape[1] != 3:
        got = tuple(photos.shape) if isinstance(photos, torch.Tensor) else type(photos).__name__
        raise ValueError(f"photos: expected shape (N, 3, H, W) or (1, N, 3, H, W), got {got}")
    if not bool(torch.isfinite(photos).all()):
        raise ValueError("photos: expected finite values, got NaN or Inf")
    check_maps(maps, "maps")
    if maps.shape[0] != 1:
        raise ValueError(f"maps: expected one material (1, 10, H, W), got {tuple(maps.shape)}")
    photos = photos.detach().float().cpu().clamp_min(0.0)
    n, _, h, w = photos.shape
    maps = maps.detach().float().cpu()
    if maps.shape[-2:] != (h, w):
        maps = resize_maps_to(maps, (h, w))
    usable = (photos < cfg.clip_level).all(dim=1, keepdim=True)
    reasons = _screen(photos, usable, cfg)
    estimates = estimate_lights(photos, maps, cfg, usable)
    notes: list[str] = []
    for k, e in enumerate(estimates):
        if reasons[k] is None and not e["search_error"] <= cfg.max_search_error:
            reasons[k] = (f"photo {k}: no light explains it under the net's maps (search error "
                          f"{e['search_error']:.3f} > max_search_error {cfg.max_search_error})")
        e["used"] = reasons[k] is None
        e["search_error"] = round(float(e["search_error"]), 5) if math.isfinite(e["search_error"]) else None
        if reasons[k] is not None:
            e["note"] = reasons[k]
            notes.append(f"{reasons[k]}: dropped from the refinement")
    keep = [k for k in range(n) if reasons[k] is None]
    before: list[float | None] = [None] * n
    after: list[float | None] = [None] * n
    if 0 not in keep:
        notes.append("photo 0 (the flash photo that pins the lights' scale) is unusable: the net's maps are kept")
        return RefineResult(maps, estimates, None, None, before, after, notes, time.perf_counter() - t0)
    spec = _spec([estimates[k] for k in keep])
    for k, err in zip(keep, _errors(maps, spec, photos[keep], usable[keep], cfg.distribution)):
        before[k] = err
    left = cfg.budget_s - (time.perf_counter() - t0)
    opt = OptimizeConfig.from_dict({
        "iterations": 100_000, "lr": cfg.lr, "prior_falloff": cfg.prior_falloff,
        "calibrate": "on", "calibrate_after": cfg.calibrate_after,
        "trust_pose": cfg.trust_pose, "trust_exposure_stops": cfg.trust_exposure_stops,
        "distribution": cfg.distribution, "progress": cfg.progress,
        "validate_photo": cfg.validate, "validate_max_images": max(2, len(keep)), **cfg.optimizer,
        "budget_s": max(left, 1e-3)})
    fit = optimize(spec, photos[keep], usable[keep], config=opt, init_maps=maps)
    final = fit.calibrated_spec or spec
    for j, k in enumerate(keep):
        im = final.images[j]
        estimates[k].update(camera=[round(v, 5) for v in im.camera.position],
                            light=[round(v, 5) for v in im.light.position],
                            gain=[round(v, 6) for v in im.light.intensity],
                            ambient=[round(v, 6) for v in im.extra_lights[0].intensity] if im.extra_lights
                            else [0.0, 0.0, 0.0])
    for k, err in zip(keep, _errors(fit.maps, final, photos[keep], usable[keep], cfg.distribution)):
        after[k] = err
    notes += stop_notes(fit, opt)
    return RefineResult(fit.maps, estimates, final, fit, before, after, notes, time.perf_counter() - t0)
