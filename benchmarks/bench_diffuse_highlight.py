"""Where the single-image net leaves the flash's highlight in the diffuse map, and what the check of
:mod:`mi_svbrdf.eval.diffuse_highlight` says: its measurements behind :data:`~mi_svbrdf.eval.diffuse_highlight.VISIBLE_STEP`.

The single-image net (``capture``'s path for one photo, its default 8 symmetries) runs on:

- **example**: the bundled flash photo;
- **real**: every photo of ``../shared/real/*`` (phone photos, the flash at the lens, rectified; each read alone
  as one flash photo), when the folder is there;
- **held-out** and **foreign**: the held-out set's single-flash photos and the foreign captures' first photos,
  whose true maps are known;
- **dark glossy (simulated)**: tufted dark leather (cushions, domed buttons, glossy) and flat black plastic,
  rendered with the flash photo's renderer (:func:`mi_svbrdf.core.flash.render_flash`) at 1x, 3x and 8x the
  flash's exposure (a phone's auto-exposure on a dark sample clips the highlight wider).

For each photo: the check's figures (the clipped spot's contrast in the displayed diffuse map, the largest
contrast of the same shape where the photo measured, their difference: the *excess*) and, where the true maps are
known, the **leak**: the predicted diffuse map's contrast at that spot minus the true one's (how much of the
contrast is the net's doing, in the same display units).

Run: ``python benchmarks/bench_diffuse_highlight.py [--out docs/benchmarks/diffuse_highlight]`` (about 6 min on 2
cores); writes ``OUT.md`` and ``OUT.json``.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.assets import EXAMPLE_FLASH
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.flash import FlashSetup, render_flash
from mi_svbrdf.data.foreign import ForeignSet
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.eval.diffuse_highlight import VISIBLE_STEP, displayed_diffuse, highlight_in_diffuse, spot_contrast
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.inference import predict_details

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT.parent / "shared" / "real"
#: Side of the simulated photos (the net's).
SIZE = 256
#: The simulated photos' flash exposures, times the authors' flash intensity.
EXPOSURES = (1, 3, 8)
#: A simulated photo the check warns about by a wide margin, also with the net alone (tests/test_diffuse_highlight.py
#: runs capture on it): (period, depth, roughness, seed, exposure) of :func:`tufted_leather`.
WARNED_CASE = (1.5, 0.15, 0.2, 12, 1)


def tufted_leather(period: float, depth: float, roughness: float, shift: tuple[float, float] = (0.0, 0.0),
                   seed: int = 0, size: int = SIZE) -> torch.Tensor:
    """Dark tufted leather: ``(1, 10, size, size)`` maps.

    Diamond-tufted cushions (``period`` diamonds per half-width, ``depth`` their height in half-widths) with a
    glossy domed button (radius 0.07, roughness 0.08, specular 0.9) at each tuft, leather of ``roughness`` and
    specular 0.12, a near-black diffuse albedo and a faint grain (``seed``).
    """
    ys, xs = torch.meshgrid(torch.linspace(1, -1, size), torch.linspace(-1, 1, size), indexing="ij")
    x, y = (xs - shift[0]) * period, (ys - shift[1]) * period
    u, v = math.pi * (x + y) / 2, math.pi * (x - y) / 2
    height = depth * (torch.sin(u).abs() * torch.sin(v).abs()).sqrt()
    gx, gy = torch.round((x + y) / 2), torch.round((x - y) / 2)
    cx, cy = (gx + gy) / period + shift[0], (gx - gy) / period + shift[1]
    r2 = (xs - cx) ** 2 + (ys - cy) ** 2
    button = r2 < 0.07 ** 2
    height = torch.where(button, 0.8 * torch.sqrt((0.07 ** 2 - r2).clamp_min(0.0)), height)
    grain = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(seed))
    height = height + 0.004 * torch.nn.functional.interpolate(grain, size=(size, size), mode="bicubic")[0, 0]
    dy, dx = torch.gradient(height, spacing=(-2 / size, 2 / size))
    normal = torch.stack([-dx, -dy, torch.ones_like(height)])
    normal = normal / normal.norm(dim=0, keepdim=True)
    diffuse = torch.tensor([0.02, 0.018, 0.016]).view(3, 1, 1).expand(3, size, size)
    return M.make_maps(normal[None], diffuse[None],
                       torch.where(button, 0.08, roughness).expand(1, size, size)[None],
                       torch.where(button, 0.9, 0.12).expand(3, size, size)[None])


def simulated() -> Iterator[tuple[str, torch.Tensor, torch.Tensor]]:
    """``(name, photo (1, 3, S, S) linear, true maps (1, 10, S, S))`` of the dark glossy samples."""
    for k, (period, depth, rough, gain) in enumerate(itertools.product((1.0, 1.5), (0.15, 0.3), (0.2, 0.35),
                                                                       EXPOSURES)):
        maps = tufted_leather(period, depth, rough, shift=(0.1, 0.05), seed=k)
        yield (f"leather {period:g}/half-width, depth {depth:g}, roughness {rough:g}, exposure x{gain}",
               render_flash(maps, FlashSetup(intensity=13.0 * gain)), maps)
    for rough, gain in itertools.product((0.15, 0.3), EXPOSURES):
        maps = M.constant_maps(1, SIZE, SIZE, diffuse=(0.02, 0.018, 0.016), roughness=rough, specular=0.3)
        yield f"flat black plastic, roughness {rough:g}, exposure x{gain}", render_flash(
            maps, FlashSetup(intensity=13.0 * gain)), maps


def cases() -> Iterator[tuple[str, str, Any, torch.Tensor | None]]:
    """``(group, name, photo: a path or (1, 3, H, W) linear, true maps or None)``."""
    yield "example", "example_flash.png", EXAMPLE_FLASH, None
    for photo in sorted(REAL.glob("*/**/0*.png")) if REAL.is_dir() else []:
        yield "real", photo.relative_to(REAL).as_posix(), photo, None
    held = HeldOutSet(size=SIZE, materials=32, n_images=1, preset="single_flash", cache=False)
    for m in range(held.materials):
        sample = held.material(m)
        yield "held-out", f"held-out {m} ({sample['info'].get('class', '?')})", sample["inputs"][0], sample["maps"]
    foreign = ForeignSet(size=SIZE, materials=16, n_images=1, cache=False)
    for m in range(foreign.materials):
        sample = foreign.material(m)
        yield "foreign", f"foreign {m} ({foreign.classes()[m]})", sample["inputs"][0], sample["maps"]
    for name, photo, maps in simulated():
        yield "dark glossy (simulated)", name, photo, maps


def measure(photo: Any, truth: torch.Tensor | None) -> dict[str, Any]:
    """The single net on ``photo``, the check on its maps, and the leak where ``truth`` is known."""
    result = predict_details(photo, kind="single")
    check = highlight_in_diffuse(result.photos[0, 0], result.maps)
    row = check.summary()
    row["leak"] = None
    if truth is not None and check.spot is not None:
        row["leak"] = round(check.contrast - spot_contrast(displayed_diffuse(truth[0]), check.spot), 4)
    return row


def why_the_step(rows: list[dict[str, Any]]) -> list[str]:
    """The paragraph that sets the margin against the measurements."""
    known = [r for r in rows if r["leak"] is not None and r["excess"] is not None]
    clean = [r["excess"] for r in known if r["leak"] < 0.1]
    real = [r["excess"] for r in rows if r["group"] in ("real", "example") and r["excess"] is not None]
    warned = [r for r in rows if r["left"]]
    leaks = [r for r in rows if r["leak"] is not None and r["leak"] >= VISIBLE_STEP]
    missed = [r["excess"] for r in leaks if not r["left"] and r["excess"] is not None]
    if not (clean and real and warned):
        return []
    return [f"Why {VISIBLE_STEP:g}: where the true maps are known and the net added less than 0.1 at the spot "
            f"({len(clean)} photos), the excess is at most {max(clean):+.3f}; on the real and example photos at most "
            f"{max(real):+.3f}. Every warned photo has a leak of at least {min(r['leak'] for r in warned):+.3f} "
            f"(a fifth of the display range: a step anyone sees); {sum(r['left'] for r in leaks)} of the "
            f"{len(leaks)} photos with a leak of {VISIBLE_STEP:g} or more are warned"
            + (f"; the others stand out less from what the photo measured elsewhere (excess "
               f"{min(missed):+.3f} to {max(missed):+.3f}): the material's own contrast, or the leak's, is near "
               "the margin." if missed else ".")]


def report(rows: list[dict[str, Any]]) -> str:
    """The Markdown page."""
    groups = list(dict.fromkeys(r["group"] for r in rows))
    summary = []
    for g in groups:
        mine = [r for r in rows if r["group"] == g]
        spots = [r for r in mine if r["excess"] is not None]
        left = [r for r in spots if r["left"]]
        kept = [r for r in spots if not r["left"]]
        leaks = [r for r in spots if r["leak"] is not None]
        summary.append([g, str(len(mine)), str(len(spots)), str(len(left)),
                        f"{max(r['excess'] for r in kept):+.3f}" if kept else "",
                        f"{min(r['excess'] for r in left):+.3f}" if left else "",
                        f"{sum(r['leak'] >= VISIBLE_STEP for r in leaks)}" if leaks else ""])
    lines = ["# A highlight left in the diffuse map: the check's measurements", "",
             "Written by `python benchmarks/bench_diffuse_highlight.py` (read its docstring for the photos). The "
             "check (`mi_svbrdf/eval/diffuse_highlight.py`, `capture`'s warning) compares, in the diffuse map as "
             "`diffuse.png` shows it (sRGB-encoded luminance, 0 black to 1 white), each clipped spot of the flash "
             "photo with its ring (its *contrast*) against the largest contrast of the same shape anywhere the photo "
             "measured; the *excess* is the difference, and the highlight is called left in the diffuse map when it "
             f"exceeds {VISIBLE_STEP:g}. The *leak* (true maps known) is the predicted diffuse map's contrast at the "
             "spot minus the true one's: what the net added there.", "",
             markdown_table(["photos", "count", "with a clipped spot compared", f"excess > {VISIBLE_STEP:g} (warned)",
                             "largest excess not warned", "smallest excess warned",
                             f"leak >= {VISIBLE_STEP:g}"], summary), "", *why_the_step(rows), "",
             "Every photo (excess and leak in display units; blank: no clipped spot, or nothing measured to compare "
             "with):", "",
             markdown_table(["group", "photo", "clipped cells", "contrast", "elsewhere", "excess", "leak", "warned"],
                            [[r["group"], r["name"], f"{r['clipped']:.3f}",
                              *("" if r[k] is None else f"{r[k]:+.3f}" for k in ("contrast", "elsewhere", "excess",
                                                                                  "leak")),
                              "yes" if r["left"] else ""] for r in rows]), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "diffuse_highlight",
                        help="OUT.md and OUT.json are written (default: docs/benchmarks/diffuse_highlight)")
    parser.add_argument("--report-only", action="store_true", help="write OUT.md again from OUT.json (no net run)")
    args = parser.parse_args(argv)
    if args.report_only:
        rows = json.loads(args.out.with_suffix(".json").read_text(encoding="utf-8"))["rows"]
        write_text(args.out.with_suffix(".md"), report(rows))
        print(f"wrote {args.out.with_suffix('.md')}")
        return 0
    rows, start = [], time.perf_counter()
    for group, name, photo, truth in cases():
        rows.append({"group": group, "name": name, **measure(photo, truth)})
        r = rows[-1]
        print(f"{group:24} {name:60} excess {r['excess']} leak {r['leak']} {'WARNED' if r['left'] else ''}",
              flush=True)
    write_json(args.out.with_suffix(".json"),
               {"visible_step": VISIBLE_STEP, "seconds": round(time.perf_counter() - start, 1), "rows": rows})
    write_text(args.out.with_suffix(".md"), report(rows))
    print(f"wrote {args.out.with_suffix('.md')} and .json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
