"""The README's picture: the contact sheet that ``mi-svbrdf capture example`` writes, as it writes it.

Runs ``capture example`` into a temporary folder and copies its ``contact_sheet.png`` (the bundled flash
photo | normal | diffuse | roughness | specular | the material relit under three lights, each labelled with
where its light is) to ``docs/images/capture_example.png``. ``tests/test_docs_figures.py`` checks that the
picture's labels are the ones capture writes now and that the README's caption names them.

Run: ``python benchmarks/readme_figure.py [-o docs/images/capture_example.png]``.
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from mi_svbrdf import cli

ROOT = Path(__file__).resolve().parent.parent
#: Where the README's picture lives.
FIGURE = ROOT / "docs" / "images" / "capture_example.png"


def main(argv: list[str] | None = None) -> int:
    """Write the figure; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--out", type=Path, default=FIGURE, help="the picture written (default: the README's)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="readme_figure_") as tmp:
        if cli.main(["capture", "example", "--frames", "0", "-o", tmp]) != 0:
            raise SystemExit("mi-svbrdf capture example: failed")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(tmp) / "contact_sheet.png", args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
