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
**without** it (leave one photo out: the multi-image and fused nets run on the other N - 1). For each
candidate and held photo, the photo's light and camera are estimated under that candidate's maps as
``--refine`` starts (:func:`mi_svbrdf.optim.refine.estimated_capture`, from photo 0 and photo ``k``), or
taken from a known capture (``spec``: the benchmark's true lights); the maps re-render the photo, its
exposure is fitted on the photo itself, robust to clipped renders
(:class:`mi_svbrdf.optim.scoring.HeldOutScorer`, ``exposure="held"``), and the error is the display-space
RMSE (gamma 2.2). A candidate's score is its mean over the held photos.

**The choice** (:func:`choose`): the lowest score, except that among candidates within :data:`TIE`
(relative) of the lowest the simplest is kept (``single < multi < fused < refined``): a more complex
candidate has to explain the photos clearly better. The refined candidate is scored by the refinement's
own held-out photo (:func:`with_refinement`): the base candidate's score times the ratio of the
refinement's validation error at the blend it chose to that at the net's maps (blend 0).

Examples:
    >>> choose({"single": 0.100, "multi": 0.099, "fused": 0.090})
    ('fused', 'fused: the lowest display RMSE on the held photos')
    >>> choose({"single": 0.100, "multi": 0.0985, "fused": 0.120})[0]  # within 2 % of the lowest: the simplest
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

from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.nets.fusion import NET_CANDIDATES, net_candidates
from mi_svbrdf.optim.fit import resize_maps_to
from mi_svbrdf.optim.refine import RefineConfig, estimated_capture
from mi_svbrdf.optim.scoring import HeldOutScorer

__all__ = ["CANDIDATES", "LIGHTS", "MAX_FOLDS", "TIE", "Judgement", "choose", "held_photos", "judge",
           "judge_photos", "photo_error", "with_refinement"]

#: The candidates, simplest first: a near-tie goes to the earliest.
CANDIDATES = (*NET_CANDIDATES, "refined")
#: Near-tie: a candidate whose score is at most ``(1 + TIE)`` times the lowest counts as tied with it.
TIE = 0.02
#: Held photos judged at most (each costs one run of the nets without it, per candidate that saw it).
MAX_FOLDS = 4
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
                f"{self.lights} lights: {scores}; within {100 * self.tie:g} % of the lowest, the simplest)")

    def summary(self) -> dict[str, Any]:
        """JSON-ready (``summary.json``'s ``choice``); photos are numbered from 1 as the user gave them."""
        r5 = lambda v: None if v is None or not math.isfinite(v) else round(float(v), 5)  # noqa: E731
        return {"choice": self.choice, "why": self.why, "scores": {c: r5(v) for c, v in self.scores.items()},
                "per_photo": {c: [r5(e) for e in v] for c, v in self.per_photo.items()},
                "held_photos": [k + 1 for k in self.held],
                "best_per_photo": {str(k + 1): c for k, c in self.best_per_photo().items()},
                "lights": self.lights, "tie": self.tie, "rule": "lowest score; within the tie of it, the simplest "
                "(" + " < ".join(CANDIDATES) + ")", "notes": list(self.notes)}


def choose(scores: Mapping[str, float | None], tie: float = TIE) -> tuple[str, str]:
    """The candidate kept and why: the lowest score, or the simplest within ``tie`` (relative) of it.

    Args:
        scores: per candidate (names of :data:`CANDIDATES`), a score (lower is better) or None (not scored).
        tie: the near-tie margin, >= 0.

    Raises:
        ValueError: no finite score, an unknown candidate, or a negative ``tie``.
    """
    if tie < 0:
        raise ValueError(f"tie: expected a margin >= 0, got {tie!r}")
    unknown = [c for c in scores if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"scores: expected candidates among {CANDIDATES}, got {unknown}")
    valid = {c: float(v) for c, v in scores.items() if v is not None and math.isfinite(float(v))}
    if not valid:
        raise ValueError(f"scores: expected at least one finite score, got {dict(scores)}")
    best = min(valid, key=valid.__getitem__)
    near = [c for c in CANDIDATES if c in valid and valid[c] <= valid[best] * (1.0 + tie)]
    choice = near[0]
    if choice == best:
        return choice, f"{choice}: the lowest display RMSE on the held photos"
    return choice, (f"{choice}: within {100 * tie:g} % of the lowest ({best}, {valid[best]:.4f} against "
                    f"{valid[choice]:.4f}), and simpler")


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


def photo_error(maps: torch.Tensor, photos: torch.Tensor, k: int, *, spec: CaptureSpec | None = None,
                config: RefineConfig | None = None, distribution: str = "ggx") -> float:
    """Display RMSE of photo ``k`` re-rendered under ``maps``, its exposure fitted robustly on itself.

    Args:
        maps: ``(1, 10, H', W')`` maps (resized to the photos' size when they differ).
        photos: ``(N, 3, H, W)`` linear rectified photos, photo 0 the flash photo.
        k: the photo scored, ``1 <= k < N``.
        spec: the photos' known capture (N images); None: photo 0's and photo ``k``'s light and camera are
            estimated under ``maps`` (:func:`mi_svbrdf.optim.refine.estimated_capture`).
        config: the light search's settings (:class:`~mi_svbrdf.optim.refine.RefineConfig`).
        distribution: the BRDF model of ``maps``.

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
        cfg = config or RefineConfig(distribution=distribution, progress=False)
        pair_spec, _ = estimated_capture(pair, maps, cfg)
    else:
        if len(spec.images) != n:
            raise ValueError(f"spec: expected the capture of the {n} photos, got {len(spec.images)} images")
        pair_spec = spec.subset([0, k])
    scorer = HeldOutScorer(pair_spec, pair, fit=[0], held=[1], distribution=distribution, backend="torch",
                           exposure="held")
    return scorer(maps)


def judge(photos: torch.Tensor, candidates: Mapping[str, torch.Tensor],
          folds: Mapping[int, Mapping[str, torch.Tensor]] | None = None, *, spec: CaptureSpec | None = None,
          config: RefineConfig | None = None, distribution: str = "ggx", tie: float = TIE,
          held: Sequence[int] | None = None) -> Judgement:
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
    for k in ks:
        for c in per_photo:
            maps = folds.get(k, {}).get(c, candidates[c])
            per_photo[c].append(photo_error(maps, photos, k, spec=spec, config=config, distribution=distribution))
    scores: dict[str, float | None] = {}
    for c, errs in per_photo.items():
        finite = [e for e in errs if math.isfinite(e)]
        scores[c] = sum(finite) / len(finite) if finite and len(finite) == len(errs) else None
    choice, why = choose(scores, tie)
    return Judgement(choice, why, scores, per_photo, list(ks), "estimated" if spec is None else "true", tie)


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
                         judgement.lights, judgement.tie, notes)
    scores["refined"] = base * vb / v0
    notes.append(f"refined: {judgement.choice}'s score x {vb:.4f} / {v0:.4f}, the refinement's held-out photo error "
                 f"at its blend {blend:g} over that at the start's maps")
    choice, why = choose(scores, judgement.tie)
    return Judgement(choice, why, scores, dict(judgement.per_photo), list(judgement.held), judgement.lights,
                     judgement.tie, notes)


def judge_photos(net: Any, photos: torch.Tensor, *, symmetries: int = 1, spec: CaptureSpec | None = None,
                 folds: int = MAX_FOLDS, config: RefineConfig | None = None, distribution: str = "ggx",
                 tie: float = TIE) -> tuple[dict[str, torch.Tensor], Judgement]:
    """The nets' candidates of ``photos`` and their :func:`judge`-ment, leave-one-out folds run here.

    Args:
        net: the fused multi-image net (:func:`mi_svbrdf.nets.fusion.net_candidates`).
        photos: ``(1, N, 3, H, W)`` or ``(N, 3, H, W)`` linear photos, N >= 2, photo 0 the flash photo.
        symmetries: the nets' symmetry ensemble; folds: the most held photos (:func:`held_photos`).
        spec, config, distribution, tie: as :func:`judge`.

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
                      spec=spec, config=config, distribution=distribution, tie=tie)
    return candidates, judgement
