"""``python -m mi_svbrdf.cli.example_photos``: re-make the bundled example photos in ``mi_svbrdf/assets/``."""
from __future__ import annotations

import argparse
from pathlib import Path

from mi_svbrdf.assets import ASSETS_DIR
from mi_svbrdf.data import example_photos


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mi_svbrdf.cli.example_photos", description=example_photos.__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--out", type=Path, default=ASSETS_DIR, help="output folder (default: the package's assets/)")
    parser.add_argument("--size", type=int, default=example_photos.SIZE, help=f"photo side (default: {example_photos.SIZE})")
    args = parser.parse_args(argv)
    for path in example_photos.write_examples(args.out, args.size):
        print(f"wrote {path} ({path.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
