"""The progress bar every module draws: :data:`tqdm`.

In Jupyter ``tqdm.auto`` picks the notebook widget, which needs ``ipywidgets``; without it every bar
prints ``TqdmWarning: IProgress not found`` and falls back to text. Here the widget is used only where
``ipywidgets`` is installed, and tqdm's text bar everywhere else (terminals, files, notebooks without
widgets), so no bar warns.

Examples:
    >>> from mi_svbrdf.core.progress import tqdm
    >>> sum(tqdm(range(3), disable=True))
    3
"""
from __future__ import annotations

import importlib.util

from tqdm import tqdm as text_tqdm

__all__ = ["text_tqdm", "tqdm"]


def _bar_class() -> type[text_tqdm]:
    """``tqdm.auto.tqdm`` when ``ipywidgets`` is installed (the notebook widget in Jupyter), else tqdm's text bar."""
    if importlib.util.find_spec("ipywidgets") is None:
        return text_tqdm
    from tqdm.auto import tqdm as auto_tqdm

    return auto_tqdm


#: The progress-bar class (tqdm's arguments).
tqdm = _bar_class()
