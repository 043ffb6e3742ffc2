"""The choice by evidence: which maps a capture of N >= 2 photos keeps, judged on its own photos.

No fixed blend of the single-image and multi-image nets is right on every material, so ``capture`` lets
the photos choose among the **candidates** (:data:`CANDIDATES`, simplest first):

* ``single``: the single-image net on the flash photo (photo 0);
* ``multi``: the multi-image net alone on all N photos (the fused net's branch before the fusion);
* ``fused``: the fused multi-image net (:mod:`mi_svbrdf.nets.fusion`);
* ``refined``: where it validates, a short refinement of the best of them (:func:`mi_svbrdf.optim.refine.refine`).

**How each is scored** (:func:`judge`). Every candidate is judged on photos it never saw: the held photos
are photos 1..N-1 (at most ``folds`` of them, evenly spaced: :func:`held_photos`), which the single-image
net never reads; for the nets that read every photo, photo ``k`` is scored on the maps that net makes
**without** it (leave one photo out: the multi-image and fused nets run on the other N - 1). Photo ``k``'s
light and camera are estimated as ``--refine`` starts (:func:`mi_svbrdf.optim.refine.estimated_capture`, from
photo 0 and photo ``k``), then polished by a few gradient steps on the light, camera, gain and room fill
(:func:`polish_light`: the search's grid alone can leave the highlight a grid step away), under the fused net's
maps from all N photos, the best-informed (``lights_from``; with several starts, the search runs under each's maps
and the light kept is the one under which the first's explain the photo best). Every candidate is then scored
under that one light (a few light parameters, the same for all: lights chosen per candidate let a candidate's
errors hide in its light, and picked the single net's maps too often on the held-out set). With a known capture (``spec``: the
benchmark's true lights) its lights are used instead. The photo's exposure is fitted on the photo itself,
robust to clipped renders
(:class:`mi_svbrdf.optim.scoring.HeldOutScorer`, ``exposure="held"``), and the error is the display-space
RMSE (gamma 2.2). A candidate's score is its mean over the held photos.

**The choice** (:func:`choose`): the candidates are ranked by what they take from the capture
(:data:`LEVELS`): the single-image net one photo; the multi-image and fused nets every photo (one level:
the lower of the two wins); the refinement every photo and a fit of the maps to them. A level replaces the
choice below it only with a score lower by more than :data:`TIE` (relative): a candidate that takes more
from the photos has to explain them clearly better, and near-ties go to the simplest. The refined candidate is scored by the refinement's
own held-out photo (:func:`with_refinement`): the base candidate's score times the ratio of the
refinement's validation error at the blend it chose to that at the net's maps (blend 0).

Examples:
    >>> choose({"single": 0.100, "multi": 0.099, "fused": 0.090})
    ('fused', "fused: 0.0900, clearly below single's 0.1000 (more than 2 %)")
    >>> choose({"single": 0.100, "multi": 0.0985, "fused": 0.120})[0]  # within 2 % of the single net's: simpler
    'single'
    >>> held_photos(10, 4), held_photos(3, 4)
    ([1, 4, 6, 9], [1, 2])
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.render import render
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, ImageSpec, LightSpec
from mi_svbrdf.nets.fusion import NET_CANDIDATES, net_candidates
from mi_svbrdf.optim.fit import resize_maps_to
from mi_svbrdf.optim.refine import FILL_HEIGHT, RefineConfig, estimated_capture
from mi_svbrdf.optim.scoring import HeldOutScorer

__all__ = ["CANDIDATES", "LEVELS", "LIGHTS", "LIGHTS_FROM", "MAX_FOLDS", "POLISH_STEPS", "TIE", "Judgement", "choose", "estimated_pair",
           "held_photos", "judge", "judge_photos", "photo_error", "polish_light", "with_refinement"]

#: The candidates, by what they take from the capture (:data:`LEVELS`); an exact tie goes to the earliest.
CANDIDATES = (*NET_CANDIDATES, "refined")
#: What each candidate takes from the capture, least first (:func:`choose`): one photo; every photo; every photo
#: and a fit of the maps to them.
LEVELS = {"single": 0, "multi": 1, "fused": 1, "refined": 2}
#: The levels' names in :func:`choose`'s reasons.
LEVEL_NAMES = {0: "single-image net", 1: "multi-image nets", 2: "refinement"}
#: Near-tie: a candidate of a higher level replaces the kept one only with ``score * (1 + TIE) < kept score``.
TIE = 0.02
#: Held photos judged at most (each costs one run of the nets without it, per candidate that saw it).
MAX_FOLDS = 4
#: Gradient steps of :func:`polish_light` on each estimated light (0: the light search's grid alone).
POLISH_STEPS = 20
#: Texels per side :func:`polish_light` renders at.
POLISH_SIZE = 32
#: The starts of each held photo's light search (:func:`judge`): the fused net's maps from all N photos. Starting
#: also from the other candidates' maps (the best light under the fused net's maps kept) found lights a little
#: nearer the truth on the held-out set but chose no better on either set (docs/benchmarks/more_photos_choice.md),
#: at three times the searches.
LIGHTS_FROM: tuple[str, ...] = ("fused",)
#: Where the held photos' lights come from: estimated from the photos (``capture``) or a known capture's.
LIGHTS = ("estimated", "true")


@dataclass
class Judgement:
    """What :func:`judge` decided, and on what evidence."""

    choice: str  #: the candidate kept
    why: str  #: one clause: why it
    scores: dict[str, float | None]  #: per candidate, its mean display RMSE on the held photos (None: not scored)
    per_photo: dict[str, list[float]]  #: per candidate, its error on each held photo (in the order of ``held``)
    held: list[int]  #: the held photos, 0-based
    lights: str = "estimated"  #: one of :data:`LIGHTS`
    tie: float = TIE  #: the near-tie margin used
    notes: list[str] = field(default_factory=list)  #: e.g. how the refined candidate was scored
    #: per held photo, the start (:data:`LIGHTS_FROM`) whose light search gave the light kept (estimated lights)
    light_start: list[str] = field(default_factory=list)
    #: per start: per held photo its light search's ``fit`` (the first start's maps' error under it; NaN, None in
    #: the summary, with one start), ``light`` (the position found) and ``errors`` (per candidate) under it
    by_start: dict[str, dict[str, Any]] = field(default_factory=dict)

    def best_per_photo(self) -> dict[int, str]:
        """Per held photo (0-based), the candidate that explains it best (lowest error)."""
        out = {}
        for i, k in enumerate(self.held):
            errs = {c: v[i] for c, v in self.per_photo.items() if i < len(v) and math.isfinite(v[i])}
            if errs:
                out[k] = min(errs, key=errs.__getitem__)
        return out

    def line(self) -> str:
        """One line: the choice and each candidate's score."""
        scores = ", ".join(f"{c} {v:.4f}" for c, v in self.scores.items() if v is not None)
        photos = ", ".join(str(k + 1) for k in self.held)
        return (f"choice by the photos' own evidence: {self.choice} (display RMSE on held photo(s) {photos}, "
                f"{self.lights} lights: {scores}; a net that reads more photos must score lower by over "
                f"{100 * self.tie:g} %)")

    def summary(self) -> dict[str, Any]:
        """JSON-ready (``summary.json``'s ``choice``); photos are numbered from 1 as the user gave them."""
        r5 = lambda v: None if v is None or not math.isfinite(v) else round(float(v), 5)  # noqa: E731
        return {"choice": self.choice, "why": self.why, "scores": {c: r5(v) for c, v in self.scores.items()},
                "per_photo": {c: [r5(e) for e in v] for c, v in self.per_photo.items()},
                "held_photos": [k + 1 for k in self.held],
                "best_per_photo": {str(k + 1): c for k, c in self.best_per_photo().items()},
                "lights": self.lights, "tie": self.tie, "rule": "the lowest score of each level (single < multi = fused "
                "< refined); a higher level replaces the choice only below it by more than the tie",
                "notes": list(self.notes), "light_start": list(self.light_start),
                "by_start": {c: {"fit": [r5(e) for e in r["fit"]], "light": [[r5(v) for v in p] for p in r["light"]],
                                 "errors": {d: [r5(e) for e in v] for d, v in r["errors"].items()}}
                             for c, r in self.by_start.items()}}


def choose(scores: Mapping[str, float | None], tie: float = TIE) -> tuple[str, str]:
    """The candidate kept and why: the simplest that no more complex candidate beats by more than ``tie``.

    Candidates are ranked by what they take from the capture (:data:`LEVELS`): the single-image net reads one
    photo; the multi-image and fused nets read every photo (one level: both map the same N photos, nothing fitted
    to them); the refinement also fits the maps to the photos. Within a level the lowest score wins; a level
    replaces the choice of the levels below only when ``score * (1 + tie)`` is below the kept one's: a candidate
    that takes more from the photos has to explain them clearly better.

    Args:
        scores: per candidate (names of :data:`CANDIDATES`), a score (lower is better) or None (not scored).
        tie: the near-tie margin (relative), >= 0.

    Raises:
        ValueError: no finite score, an unknown candidate, or a negative ``tie``.

    Examples:
        >>> choose({"single": 0.100, "multi": 0.0899, "fused": 0.0900})[0]  # one level: the lower
        'multi'
        >>> choose({"single": 0.100, "multi": 0.0995, "fused": 0.0990})[1]
        'single: the multi-image nets (fused 0.0990) not clearly below it (0.1000, tie 2 %)'
    """
    if tie < 0:
        raise ValueError(f"tie: expected a margin >= 0, got {tie!r}")
    unknown = [c for c in scores if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"scores: expected candidates among {CANDIDATES}, got {unknown}")
    valid = {c: float(v) for c, v in scores.items() if v is not None and math.isfinite(float(v))}
    if not valid:
        raise ValueError(f"scores: expected at least one finite score, got {dict(scores)}")
    kept: str | None = None
    why = ""
    for level in sorted(set(LEVELS.values())):
        here = [c for c in CANDIDATES if c in valid and LEVELS[c] == level]
        if not here:
            continue
        best = min(here, key=valid.__getitem__)  # CANDIDATES order breaks an exact tie
        if kept is None:
            kept, why = best, f"{best}: the lowest display RMSE on the held photos"
        elif valid[best] * (1.0 + tie) < valid[kept]:
            why = (f"{best}: {valid[best]:.4f}, clearly below {kept}'s {valid[kept]:.4f} "
                   f"(more than {100 * tie:g} %)")
            kept = best
        else:
            why = (f"{kept}: the {LEVEL_NAMES[level]} ({best} {valid[best]:.4f}) not clearly below it "
                   f"({valid[kept]:.4f}, tie {100 * tie:g} %)")
    assert kept is not None
    return kept, why


def held_photos(n: int, folds: int = MAX_FOLDS) -> list[int]:
    """The photos judged (0-based): 1..n-1, or ``folds`` of them evenly spaced (the first and the last kept)."""
    if n < 2:
        raise ValueError(f"n: expected 2 photos or more (photo 0 is every candidate's), got {n}")
    if folds < 1:
        raise ValueError(f"folds: expected at least 1 held photo, got {folds}")
    if n - 1 <= folds:
        return list(range(1, n))
    if folds == 1:
        return [n - 1]
    return sorted({round(1 + i * (n - 2) / (folds - 1)) for i in range(folds)})


def polish_light(maps: torch.Tensor, photo: torch.Tensor, image: ImageSpec, *, steps: int = POLISH_STEPS,
                 size: int = POLISH_SIZE, clip: float = 0.99, distribution: str = "ggx") -> ImageSpec:
    """``image``'s light, camera, RGB gain and zenith fill moved by Adam steps to explain ``photo`` under ``maps``.

    The loss is the light search's (:func:`mi_svbrdf.optim.refine.estimate_lights`): the mean absolute
    difference of the gamma-encoded photo and render over the texels the photo does not clip, at ``size``
    texels per side; the light and camera stay above the sample.

    Args:
        maps: ``(1, 10, H, W)`` the maps rendered (fixed).
        photo: ``(3, H', W')`` the linear photo.
        image: its estimated :class:`~mi_svbrdf.io.calibrated_photos.ImageSpec` (a flash, at most one fill light).
        steps: Adam steps (0: ``image`` as it is); size: texels per side; clip: a texel at or above it is clipped.
        distribution: the maps' BRDF model.

    Returns:
        The polished :class:`~mi_svbrdf.io.calibrated_photos.ImageSpec`.

    Examples:
        >>> from mi_svbrdf.data import procedural
        >>> maps = procedural.generate("tiles", 0, 16)[None]
        >>> photo = render(maps, torch.tensor([[[1.0, 0.5, 1.5]]]), torch.tensor([[[0.0, 0.0, 2.0]]]),
        ...                distance_falloff=True)[0, 0]
        >>> start = ImageSpec("1.exr", "linear_exr", True, CameraSpec((0.0, 0.0, 2.0)), LightSpec((1.3, 0.3, 1.3), (1.0, 1.0, 1.0)))
        >>> moved = polish_light(maps, photo, start, steps=30, size=16)
        >>> bool(sum((a - b) ** 2 for a, b in zip(moved.light.position, (1.0, 0.5, 1.5))) < 0.1)
        True
    """
    if steps <= 0:
        return image
    m = F.interpolate(maps.detach().float().cpu(), size=(size, size), mode="area")
    p = F.interpolate(photo.detach().float().cpu()[None], size=(size, size), mode="area")[0]
    ok = (p < clip).all(dim=0, keepdim=True).to(p)
    target = gamma_encode(p)
    light = torch.tensor(image.light.position, dtype=torch.float32, requires_grad=True)
    view = torch.tensor(image.camera.position, dtype=torch.float32, requires_grad=True)
    log_gain = torch.tensor(image.light.intensity, dtype=torch.float32).clamp_min(1e-6).log().requires_grad_()
    fill0 = image.extra_lights[0].intensity if image.extra_lights else (0.0, 0.0, 0.0)
    log_fill = torch.tensor(fill0, dtype=torch.float32).clamp_min(1e-4).log().requires_grad_()
    fill_at = torch.tensor([[[0.0, 0.0, FILL_HEIGHT]]])
    opt = torch.optim.Adam([{"params": [light, view], "lr": 0.03}, {"params": [log_gain, log_fill], "lr": 0.05}])
    for _ in range(steps):
        opt.zero_grad()
        r = render(m, light[None, None], view[None, None], intensity=log_gain.exp()[None, None], distance_falloff=True,
                   distribution=distribution, backend="torch")[0, 0]
        r = r + render(m, fill_at, view[None, None], intensity=log_fill.exp()[None, None], distribution=distribution,
                       backend="torch")[0, 0]
        loss = ((gamma_encode(r.clamp_min(0.0)) - target).abs() * ok).sum() / (3 * ok.sum().clamp_min(1.0))
        loss.backward()
        opt.step()
        with torch.no_grad():
            light[2].clamp_(min=0.05)
            view[2].clamp_(min=0.05)
    fill = tuple(float(v) for v in log_fill.detach().exp())
    return ImageSpec(image.file, image.encoding, image.rectified,
                     CameraSpec(tuple(float(v) for v in view.detach()), image.camera.fov_deg),
                     LightSpec(tuple(float(v) for v in light.detach()), tuple(float(v) for v in log_gain.detach().exp())),
                     (LightSpec((0.0, 0.0, FILL_HEIGHT), fill),))


def estimated_pair(maps: torch.Tensor, photos: torch.Tensor, k: int, *, config: RefineConfig | None = None,
                   distribution: str = "ggx", polish: int = POLISH_STEPS) -> CaptureSpec:
    """Photo 0's and photo ``k``'s light and camera estimated under ``maps`` as ``--refine`` starts
    (:func:`mi_svbrdf.optim.refine.estimated_capture`), photo ``k``'s then polished (:func:`polish_light`).

    Args:
        maps: ``(1, 10, H, W)`` maps; photos: ``(N, 3, H, W)`` linear photos, photo 0 the flash photo.
        k: the held photo, ``1 <= k < N``; config: the light search's settings; distribution: the maps' model.
        polish: :func:`polish_light`'s steps (0: the search's grid alone).

    Returns:
        The capture of the two photos ``photos[[0, k]]``.
    """
    n = photos.shape[0]
    if not 1 <= k < n:
        raise ValueError(f"k: expected a held photo in [1, {n}), got {k}")
    cfg = config or RefineConfig(distribution=distribution, progress=False)
    pair = photos[[0, k]].detach().float().cpu().clamp_min(0.0)
    spec, _ = estimated_capture(pair, maps, cfg)
    if polish <= 0:
        return spec
    return CaptureSpec((spec.images[0], polish_light(maps, pair[1], spec.images[1], steps=polish, clip=cfg.clip_level,
                                                     distribution=distribution)))


def photo_error(maps: torch.Tensor, photos: torch.Tensor, k: int, *, spec: CaptureSpec | None = None,
                config: RefineConfig | None = None, distribution: str = "ggx", polish: int = POLISH_STEPS) -> float:
    """Display RMSE of photo ``k`` re-rendered under ``maps``, its exposure fitted robustly on itself.

    Args:
        maps: ``(1, 10, H', W')`` maps (resized to the photos' size when they differ).
        photos: ``(N, 3, H, W)`` linear rectified photos, photo 0 the flash photo.
        k: the photo scored, ``1 <= k < N``.
        spec: the capture of the photos: all N images (a known capture), or the two of ``photos[[0, k]]``
            (:func:`estimated_pair`); None: estimated under ``maps`` (:func:`estimated_pair`).
        config, distribution, polish: as :func:`estimated_pair`.

    Returns:
        The RMSE of the gamma-encoded (2.2) photo and re-rendering
        (:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`, ``exposure="held"``).
    """
    n = photos.shape[0]
    if not 1 <= k < n:
        raise ValueError(f"k: expected a held photo in [1, {n}), got {k}")
    pair = photos[[0, k]].detach().float().cpu().clamp_min(0.0)
    maps = maps.detach().float().cpu()
    if maps.shape[-2:] != pair.shape[-2:]:
        maps = resize_maps_to(maps, tuple(pair.shape[-2:]))
    if spec is None:
        spec = estimated_pair(maps, photos, k, config=config, distribution=distribution, polish=polish)
    elif len(spec.images) == n:
        spec = spec.subset([0, k])
    elif len(spec.images) != 2:
        raise ValueError(f"spec: expected the capture of the {n} photos or of photos 0 and {k}, got "
                         f"{len(spec.images)} images")
    scorer = HeldOutScorer(spec, pair, fit=[0], held=[1], distribution=distribution, backend="torch",
                           exposure="held")
    return scorer(maps)


def judge(photos: torch.Tensor, candidates: Mapping[str, torch.Tensor],
          folds: Mapping[int, Mapping[str, torch.Tensor]] | None = None, *, spec: CaptureSpec | None = None,
          config: RefineConfig | None = None, distribution: str = "ggx", tie: float = TIE,
          held: Sequence[int] | None = None, polish: int = POLISH_STEPS,
          lights_from: str | Sequence[str] | None = LIGHTS_FROM) -> Judgement:
    """Score each candidate on the held photos and choose (module docstring).

    Args:
        photos: ``(N, 3, H, W)`` or ``(1, N, 3, H, W)`` linear photos, N >= 2, photo 0 the flash photo.
        candidates: per candidate, its ``(1, 10, H, W)`` maps from all N photos.
        folds: per held photo ``k``, the maps of the candidates that read photo ``k``, made without it
            (leave one out); a candidate missing there is scored with its maps from ``candidates`` (the
            single-image net's never read photo ``k``). None: no folds (every candidate its own maps).
        spec: the photos' known capture (the benchmark's true lights); None: lights estimated per candidate.
        config: the light search's settings; distribution: the maps' BRDF model; tie: the near-tie margin.
        held: the held photos (0-based; default: the keys of ``folds``, else :func:`held_photos`).
        polish: :func:`polish_light`'s steps on each estimated light.
        lights_from: the starts of each held photo's light search: candidates whose maps from all N photos
            (``candidates``) the light is searched under, in turn; the light kept is the one under which the
            first start's maps explain the photo best (the search's local minima: a light found under other maps
            can be the better one), and every candidate is scored under it. None (or no candidate given): under
            each candidate's maps in turn, each candidate keeping the light that explains the photo best under
            its own maps.

    Returns:
        :class:`Judgement`.

    Examples:
        >>> from mi_svbrdf.data import procedural
        >>> from mi_svbrdf.core.render import render
        >>> truth = procedural.generate("tiles", 0, 32)[None]
        >>> light = torch.tensor([[[0.0, 0.0, 2.0], [1.2, 0.5, 1.5]]])
        >>> view = torch.tensor([[[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]]])
        >>> photos = render(truth, light, view, distance_falloff=True)[0].clamp(0, 1)
        >>> flat = truth.clone(); flat[:, :3] = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
        >>> j = judge(photos, {"single": flat, "multi": truth}, config=RefineConfig(search_size=16, progress=False))
        >>> j.choice, j.held
        ('multi', [1])
    """
    if photos.dim() == 5 and photos.shape[0] == 1:
        photos = photos[0]
    if photos.dim() != 4 or photos.shape[1] != 3 or photos.shape[0] < 2:
        raise ValueError(f"photos: expected shape (N, 3, H, W) with N >= 2, got {tuple(photos.shape)}")
    if not candidates:
        raise ValueError("candidates: expected at least one candidate's maps, got none")
    folds = dict(folds or {})
    ks = list(held) if held is not None else (sorted(folds) or held_photos(photos.shape[0]))
    per_photo: dict[str, list[float]] = {c: [] for c in CANDIDATES if c in candidates}
    starts = [c for c in ((lights_from,) if isinstance(lights_from, str) else (lights_from or ())) if c in candidates]
    by_start: dict[str, dict[str, Any]] = {}
    light_start: list[str] = []
    for k in ks:
        maps = {c: folds.get(k, {}).get(c, candidates[c]) for c in per_photo}
        if spec is not None:
            for c in per_photo:
                per_photo[c].append(photo_error(maps[c], photos, k, spec=spec, distribution=distribution))
            continue
        if starts:  # one light for every candidate: searched from each start's maps, kept by the first's fit
            fit: dict[str, float] = {}
            for c in starts:
                pair = estimated_pair(candidates[c], photos, k, config=config, distribution=distribution,
                                      polish=polish)
                # the first start's maps under each start's light: needed only to pick among several
                fit[c] = (photo_error(candidates[starts[0]], photos, k, spec=pair, distribution=distribution)
                          if len(starts) > 1 else math.nan)
                record = by_start.setdefault(c, {"fit": [], "light": [], "errors": {d: [] for d in per_photo}})
                record["fit"].append(fit[c])
                record["light"].append(list(pair.images[1].light.position))
                for d in per_photo:
                    record["errors"][d].append(photo_error(maps[d], photos, k, spec=pair, distribution=distribution))
            kept = min(starts, key=lambda c: (not math.isfinite(fit[c]), fit[c]))
            light_start.append(kept)
            for c in per_photo:
                per_photo[c].append(by_start[kept]["errors"][c][-1])
            continue
        # every candidate under the lights found under each candidate's maps, keeping its best
        pairs = [estimated_pair(maps[c], photos, k, config=config, distribution=distribution, polish=polish)
                 for c in per_photo]
        for c in per_photo:
            per_photo[c].append(min(photo_error(maps[c], photos, k, spec=p, distribution=distribution)
                                    for p in pairs))
    scores: dict[str, float | None] = {}
    for c, errs in per_photo.items():
        finite = [e for e in errs if math.isfinite(e)]
        scores[c] = sum(finite) / len(finite) if finite and len(finite) == len(errs) else None
    choice, why = choose(scores, tie)
    return Judgement(choice, why, scores, per_photo, list(ks), "estimated" if spec is None else "true", tie,
                     light_start=light_start, by_start=by_start)


def with_refinement(judgement: Judgement, validation: Mapping[float, float] | None, blend: float | None
                    ) -> Judgement:
    """``judgement`` with the ``refined`` candidate added where the refinement validated, and chosen again.

    Args:
        judgement: the nets' judgement; the refinement started from its choice.
        validation: the refinement's held-out photo error per blend (``OptimizeResult.validation``: 0 the
            start's maps, 1 the fit's); None or without blend 0: not validated, the candidate is not scored.
        blend: the blend the refinement kept.

    Returns:
        A new :class:`Judgement`: ``refined`` scored as the base's score times
        ``validation[blend] / validation[0]`` (no per-photo errors), the choice made again
        (``refined`` is the most complex: it must beat the others beyond the tie).
    """
    base = judgement.scores.get(judgement.choice)
    scores = dict(judgement.scores)
    notes = list(judgement.notes)
    v0 = None if not validation else validation.get(0.0)
    vb = None if not validation or blend is None else validation.get(float(blend))
    if base is None or v0 is None or vb is None or not v0 > 0 or not math.isfinite(vb):
        scores["refined"] = None
        notes.append("refined: not scored (the refinement did not validate on a held-out photo)")
        return Judgement(judgement.choice, judgement.why, scores, dict(judgement.per_photo), list(judgement.held),
                         judgement.lights, judgement.tie, notes, list(judgement.light_start), dict(judgement.by_start))
    scores["refined"] = base * vb / v0
    notes.append(f"refined: {judgement.choice}'s score x {vb:.4f} / {v0:.4f}, the refinement's held-out photo error "
                 f"at its blend {blend:g} over that at the start's maps")
    choice, why = choose(scores, judgement.tie)
    return Judgement(choice, why, scores, dict(judgement.per_photo), list(judgement.held), judgement.lights,
                     judgement.tie, notes, list(judgement.light_start), dict(judgement.by_start))


def judge_photos(net: Any, photos: torch.Tensor, *, symmetries: int = 1, spec: CaptureSpec | None = None,
                 folds: int = MAX_FOLDS, config: RefineConfig | None = None, distribution: str = "ggx",
                 tie: float = TIE, polish: int = POLISH_STEPS, lights_from: str | Sequence[str] | None = LIGHTS_FROM
                 ) -> tuple[dict[str, torch.Tensor], Judgement]:
    """The nets' candidates of ``photos`` and their :func:`judge`-ment, leave-one-out folds run here.

    Args:
        net: the fused multi-image net (:func:`mi_svbrdf.nets.fusion.net_candidates`).
        photos: ``(1, N, 3, H, W)`` or ``(N, 3, H, W)`` linear photos, N >= 2, photo 0 the flash photo.
        symmetries: the nets' symmetry ensemble; folds: the most held photos (:func:`held_photos`).
        spec, config, distribution, tie, polish, lights_from: as :func:`judge`.

    Returns:
        ``(candidates, judgement)``: each candidate's ``(1, 10, H, W)`` maps from all N photos (on the
        photos' device) and the judgement.
    """
    if photos.dim() == 4:
        photos = photos[None]
    if photos.dim() != 5 or photos.shape[0] != 1 or photos.shape[1] < 2:
        raise ValueError(f"photos: expected shape (1, N, 3, H, W) with N >= 2, got {tuple(photos.shape)}")
    n = photos.shape[1]
    candidates = net_candidates(net, photos, symmetries)
    fold_maps: dict[int, dict[str, torch.Tensor]] = {}
    for k in held_photos(n, folds):
        others = [i for i in range(n) if i != k]
        without = net_candidates(net, photos[:, others], symmetries)
        fold_maps[k] = {c: without[c] for c in NET_CANDIDATES if c != "single"}
    judgement = judge(photos[0].cpu(), {c: m.cpu() for c, m in candidates.items()},
                      {k: {c: m.cpu() for c, m in f.items()} for k, f in fold_maps.items()},
                      spec=spec, config=config, distribution=distribution, tie=tie, polish=polish,
                      lights_from=lights_from)
    return candidates, judgement
