"""The progress bar every module draws: :data:`tqdm`.

In Jupyter ``tqdm.auto`` picks the notebook widget, which needs ``ipywidgets``; without it every bar
prints ``TqdmWarning: IProgress not found`` and falls back to text. Here the widget is used only where
``ipywidgets`` is installed, and tqdm's text bar everywhere else (terminals, files, notebooks without
widgets), so no bar warns.

A bar is drawn only where someone watches it: on a terminal, or in a Jupyter kernel with the widget. Written to
a file or a pipe (a log, a CI job, ``2> out.txt``), a bar is kilobytes of carriage returns; there every bar is
off whatever ``disable`` said (``progress=True`` in the API means "where it can be seen", as the commands do).
``MI_SVBRDF_PROGRESS=1`` forces them on.

Examples:
    >>> from mi_svbrdf.core.progress import tqdm
    >>> sum(tqdm(range(3), disable=True))
    3
"""
from __future__ import annotations

import importlib.util
import os
import sys
from typing import Any

from tqdm import tqdm as text_tqdm

__all__ = ["seen", "text_tqdm", "tqdm"]


def seen(stream: Any = None) -> bool:
    """Whether a bar written to ``stream`` (default: stderr) can be seen: a terminal, a Jupyter kernel with
    ``ipywidgets``, or ``MI_SVBRDF_PROGRESS=1``."""
    if os.environ.get("MI_SVBRDF_PROGRESS") == "1":
        return True
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        if callable(isatty) and isatty():
            return True
    except (OSError, ValueError):  # a closed stream
        return False
    return "ipykernel" in sys.modules and importlib.util.find_spec("ipywidgets") is not None


def _bar_class() -> type[text_tqdm]:
    """``tqdm.auto.tqdm`` when ``ipywidgets`` is installed (the notebook widget in Jupyter), else tqdm's text bar."""
    if importlib.util.find_spec("ipywidgets") is None:
        return text_tqdm
    from tqdm.auto import tqdm as auto_tqdm

    return auto_tqdm


_Base = _bar_class()


class tqdm(_Base):  # type: ignore[misc,valid-type]  # noqa: N801 - tqdm's own name
    """The progress-bar class (tqdm's arguments); off where no one can see it (:func:`seen`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if not kwargs.get("disable", False) and not seen(kwargs.get("file")):
            kwargs["disable"] = True
        super().__init__(*args, **kwargs)
