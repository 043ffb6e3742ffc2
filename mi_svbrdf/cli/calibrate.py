"""``mi-svbrdf calibrate``: compare a recovered material with a measured BRDF and correct its scale (thesis ch. 6.2)."""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from mi_svbrdf.cli.common import (
    add_command,
    float_between,
    int_at_least,
    material_from_spec,
    material_outputs,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core import conoscopic as CN
from mi_svbrdf.core.brdf_measured import MerlBRDF
from mi_svbrdf.eval import measured_comparison as C
from mi_svbrdf.eval.measured_report import REPORT_FILES, write_measured_report
from mi_svbrdf.io import material_io
from mi_svbrdf.io.measured import read_measured
from mi_svbrdf.optim import fit_measured as FM

DESCRIPTION = """\
Compare a material recovered by mi-svbrdf (capture, optimize, ...) with a measurement of the same
sample by a gonioreflectometer, as the thesis's ch. 6.2 does:

  1. the maps are averaged over --mask (default: the whole sample) into one BRDF: the mean of
     every texel's reflected light (reflectance average; the parameter average is reported beside
     it, with how much it differs);
  2. both BRDFs are evaluated as f * cos(theta_o) (the cosine-weighted BRDF, 1/sr) at each
     --incidences angle over the outgoing hemisphere (a polar grid up to --theta-max) and in the
     plane of incidence;
  3. per colour channel: the factor (measured ~ factor x ours; by default the scale minimising the
     solid-angle weighted |factor*ours - measured|, see --factor-method), the absolute error
     sum w|o-m|/sum w and the relative error sum w|o-m|/sum w|m|, before and after the correction
     (one global factor, or --correction per-incidence);
  4. our model is fitted to the measurement directly with the rendering loss (--no-fit: skip):
     the error that remains is what our model cannot represent of this material.

--measured reads a MERL .binary file (90 x 90 x 180 half/difference table) or a .csv with the
columns theta_i,phi_i,theta_o,phi_o,r,g,b (degrees; the BRDF in 1/sr, no cosine; isotropic); see
mi_svbrdf/io/measured.py for both formats.

No measurement at hand? --write-synthetic writes one instead of comparing: a MERL file (-o, a
.binary name) "measured" from MATERIAL, the BRDF of its averaged parameters (over --mask) x --scale
(one number or R,G,B), in the material's BRDF model. The examples write the tiles' x 1.5 and
compare the tiles with it: calibrate compares with the texels' averaged reflectance, which differs
from the averaged parameters' BRDF on a textured sample (grout, bumps), so it finds a factor near
1.7 and a corrected error near 10 %, not 1.5 and 0 (a homogeneous material gives exactly the scale:
tests/test_calibrate.py).
"""
OUTPUTS = """\
Writes to -o/--out:
  report.json               factor, abs_error, rel_error, abs_error_corrected, rel_error_corrected
                            (RGB lists), the maps' BRDF model (distribution: ggx or beckmann),
                            per-incidence figures, the averaging difference, the direct fit
  summary.md                the same as tables, with the plots
  conoscopic.png            per incidence: measured | ours | relative error | absolute error
  conoscopic_corrected.png  the same with ours x factor
  inplane.png               the in-plane slices: measured, ours, ours x factor
  errors.png                factor, absolute and relative error per channel, before/after correction
  material/                 with --apply: the material with the global factor applied (PNG, 16-bit)
With --write-synthetic, -o names the one file written instead: a MERL .binary (35 MB).
"""
EXAMPLES = (("mi-svbrdf calibrate example:tiles --write-synthetic --scale 1.5 -o tiles_x1.5.binary && "
             "mi-svbrdf calibrate example:tiles --measured tiles_x1.5.binary -o out/calibrate --apply"),
            ("mi-svbrdf capture example -o out/capture && "
             "mi-svbrdf calibrate out/capture --measured tiles_x1.5.binary -o out/calibrate-capture"))
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new comparison replaces a previous one's.
OWNED = (*REPORT_FILES, *material_outputs("material"))


def _incidences(text: str) -> tuple[float, ...]:
    """``"10,22,45"`` -> angles (an argparse type)."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        values = ()
    if not values or any(not 0.0 <= v < 90.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated angles in [0, 90) degrees, got {text!r}")
    return values


#: Above this relative difference between the texels' averaged reflectance and the BRDF of their averaged parameters
#: (any channel), calibrate says which one it compared and the factor against the other.
PARAMETERS_DIFFER = 0.02


def _scale(text: str) -> tuple[float, ...]:
    """``"1.5"`` or ``"1.5,1.4,1.3"`` -> positive scales (an argparse type)."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in (1, 3) or not all(math.isfinite(v) and v > 0.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected one positive number or three (R,G,B), got {text!r}")
    return values


def write_synthetic(args: argparse.Namespace) -> int:
    """``calibrate MATERIAL --write-synthetic [--scale S] -o FILE.binary``: a synthetic MERL measurement of MATERIAL."""
    t0 = time.perf_counter()
    if args.measured:
        raise ValueError(f"--measured: expected none with --write-synthetic (it writes a measurement), got "
                         f"{args.measured!r}")
    if args.apply:
        raise ValueError("--apply: expected none with --write-synthetic (it compares nothing), got --apply")
    out = Path(args.out)
    if out.suffix.lower() != ".binary":
        raise ValueError(f"-o/--out: expected a MERL file name ending in .binary with --write-synthetic, got {out}")
    if out.is_dir():
        raise ValueError(f"-o/--out: expected a file name with --write-synthetic, got the folder {out}")
    maps = material_from_spec(args.material, arg="MATERIAL_DIR")
    mask = C.read_mask(args.mask, maps.shape[2], maps.shape[3]) if args.mask else None
    model = material_io.read_distribution(args.material) if Path(args.material).is_dir() else "ggx"
    scale = args.scale if args.scale is not None else (1.0,)
    out.parent.mkdir(parents=True, exist_ok=True)
    C.write_synthetic_merl(maps, out, scale=scale if len(scale) == 3 else scale[0], mask=mask, distribution=model)
    region = f" over {args.mask}" if args.mask else ""
    print(f"wrote {out} ({out.stat().st_size / 1e6:.0f} MB, {time.perf_counter() - t0:.1f} s): a synthetic MERL "
          f"measurement of {args.material}, the {model} BRDF of its averaged parameters{region} x "
          f"{'/'.join(f'{v:g}' for v in scale)}")
    return 0


def run_cli(args: argparse.Namespace) -> int:
    """The ``calibrate`` command (or, with ``--write-synthetic``, :func:`write_synthetic`)."""
    if args.write_synthetic:
        return write_synthetic(args)
    if args.scale is not None:
        raise ValueError("--scale: expected only with --write-synthetic (the scale of the measurement it writes), "
                         f"got --scale {','.join(f'{v:g}' for v in args.scale)} without it")
    if not args.measured:
        raise ValueError("--measured: expected a measured BRDF file (MERL .binary or .csv) to compare with, got "
                         "none (no measurement at hand: --write-synthetic writes one)")
    t0 = time.perf_counter()
    out = Path(args.out)
    maps = material_from_spec(args.material, arg="MATERIAL_DIR")
    kwargs: dict[str, Any] = {}
    if args.interpolation and not args.measured.lower().endswith(".csv"):
        kwargs["interpolation"] = args.interpolation
    measured = read_measured(args.measured, **kwargs)
    mask = C.read_mask(args.mask, maps.shape[2], maps.shape[3]) if args.mask else None
    grid = CN.conoscopic_grid(args.incidences, theta_max_deg=args.theta_max)
    # a material folder's BRDF model (material.json; ggx otherwise): a Beckmann fit is compared as Beckmann
    model = material_io.read_distribution(args.material) if Path(args.material).is_dir() else "ggx"
    material = C.average_material(maps, mask, max_texels=args.max_texels, distribution=model)
    cmp = C.compare(measured, material, grid=grid, factor_method=args.factor_method, correction=args.correction)
    fit = None if args.no_fit else FM.fit_measured(measured, preset=args.fit_preset, grid=grid)
    replace_outputs(args, out, OWNED, keep=[args.material, args.measured, *([args.mask] if args.mask else [])])
    applied = None
    if args.apply:
        corrected, info = C.correct_material(maps, cmp.factor)
        folder = out / "material"
        material_io.write_material(folder, corrected, fmt="png", bit_depth=16, distribution=model)
        again = C.compare(measured, C.average_material(corrected, mask, max_texels=args.max_texels,
                                                       distribution=model), grid=grid,
                          factor_method=args.factor_method, correction="global")
        summary = again.figures()
        applied = {"folder": "material", **info, "rel_error": summary["rel_error"],
                   "abs_error": summary["abs_error"], "factor_after": summary["factor"]}
    kind = "merl" if isinstance(measured, MerlBRDF) else "csv"
    report = write_measured_report(out, cmp, measured={"file": str(args.measured), "format": kind}, material=str(args.material),
                          mask=str(args.mask) if args.mask else None, fit=fit, applied=applied)

    def pct(values: list[float]) -> str:
        return "/".join(f"{100 * v:.1f}%" for v in values)

    print(f"factor (measured ~ factor x ours, {args.factor_method}) R/G/B: "
          + "/".join(f"{v:.4g}" for v in report["factor"]))
    print(f"relative error {pct(report['rel_error'])} -> {pct(report['rel_error_corrected'])} "
          f"after the {args.correction} correction")
    averaging = report["averaging"]
    if max(averaging["parameters_vs_reflectance"]) > PARAMETERS_DIFFER:  # a textured sample: say which BRDF was compared
        print(f"compared with the texels' averaged reflectance (what an instrument sees), which differs from the BRDF "
              f"of their averaged parameters by {pct(averaging['parameters_vs_reflectance'])} on this textured sample; "
              f"against that BRDF (what --write-synthetic writes, times its --scale) the factor would be "
              + "/".join(f"{v:.4g}" for v in averaging["with_parameter_average"]["factor"]))
    if fit is not None:
        print(f"our model fitted to the measurement directly: relative error {pct(report['direct_fit']['rel_error'])}")
    if applied:
        print(f"corrected material in {out / 'material'}: relative error {pct(applied['rel_error'])}")
    print(f"wrote {out}/: {', '.join(report['files'])} ({time.perf_counter() - t0:.1f} s)")
    return 0


def add_parser(subparsers: Any) -> None:
    """Register ``mi-svbrdf calibrate``."""
    p = add_command(subparsers, "calibrate", help="compare a material with a measured BRDF (MERL or CSV): "
                                                  "conoscopic maps, factor and errors, a corrected material",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("material", metavar="MATERIAL_DIR",
                   help="material folder (or a thesis strip .png, or example:NAME)")
    p.add_argument("--measured", metavar="FILE", help="MERL .binary or tabulated .csv BRDF (required unless "
                                                       "--write-synthetic)")
    p.add_argument("--mask", metavar="MASK.png", help="white = the homogeneous region measured (default: all)")
    p.add_argument("--incidences", type=_incidences, default=CN.DEFAULT_INCIDENCES, metavar="A,B,...",
                   help="incidence angles in degrees (default: 10,22,45,60,69)")
    p.add_argument("-o", "--out", required=True, help="output folder (created); with --write-synthetic the .binary "
                                                      "file written")
    p.add_argument("--write-synthetic", action="store_true",
                   help="instead of comparing, write a synthetic MERL measurement of MATERIAL to -o: the BRDF of "
                        "its averaged parameters (over --mask) x --scale (the comparison's options are unused)")
    p.add_argument("--scale", type=_scale, default=None, metavar="S|R,G,B",
                   help="with --write-synthetic: measured = scale x ours (default 1)")
    p.add_argument("--apply", action="store_true", help="also write OUT/material: the material with the global factor")
    p.add_argument("--correction", choices=C.CORRECTIONS, default="global",
                   help="factors of the corrected errors: one global (default) or one per incidence")
    p.add_argument("--factor-method", choices=CN.FACTOR_METHODS, default="l1",
                   help="l1: minimise the weighted absolute error (default); energy: ratio of sums; lsq: least squares")
    p.add_argument("--theta-max", type=float_between(0.0, 90.0, open_ends=True, unit="an angle"), default=80.0,
                   help="outer theta_o of the conoscopic grid (degrees, default 80)")
    p.add_argument("--max-texels", type=int_at_least(1), default=1024,
                   help="texels of the reflectance average (default 1024)")
    p.add_argument("--interpolation", choices=("linear", "nearest"), default=None,
                   help="MERL lookup: trilinear (default) or the reference reader's truncation")
    p.add_argument("--no-fit", action="store_true", help="skip the direct fit of our model to the measurement")
    p.add_argument("--fit-preset", choices=("2018", "2019"), default="2018", help="rendering-loss preset of the fit")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED, _out_file=lambda args: args.write_synthetic)


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.cli.calibrate``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    sys.exit(main())
