"""Markdown tables: one writer for every report and benchmark summary.

Examples:
    >>> print(markdown_table(["method", "error"], [["net", 0.0837], ["optimiser", "0.0512"]]))
    | method | error |
    |---|---|
    | net | 0.0837 |
    | optimiser | 0.0512 |
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["markdown_table"]


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table of ``rows`` under ``headers`` (cells written with ``str``).

    Raises:
        ValueError: a row whose length is not the headers'.
    """
    lines = ["| " + " | ".join(map(str, headers)) + " |", "|" + "---|" * len(headers)]
    for i, row in enumerate(rows):
        if len(row) != len(headers):
            raise ValueError(f"rows[{i}]: expected {len(headers)} cells like the headers, got {len(row)}")
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |")
    return "\n".join(lines)
