"""``python -m mi_svbrdf.cli ...``: the same as ``mi-svbrdf ...``."""
from __future__ import annotations

from mi_svbrdf.cli import main

raise SystemExit(main())
