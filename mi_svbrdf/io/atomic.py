"""Atomic writes: every file mi_svbrdf writes goes to a temporary name and is renamed over the target.

A crash or Ctrl-C never leaves a half-written result, checkpoint or manifest: readers see either
the old file or the new one. :func:`clear_owned` removes a previous run's outputs from a folder
before a command writes its new ones, so that a folder never mixes two runs.

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.io.atomic import write_json
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "summary.json"
    >>> write_json(path, {"loss": 0.5})
    >>> path.read_text()
    '{\\n  "loss": 0.5\\n}\\n'
"""
from __future__ import annotations

import json
import math
import os
import re
import secrets
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["atomic_path", "clear_owned", "dumps_json", "json_safe", "owned_files", "write_json", "write_text",
           "written_outputs"]
#: The characters that make a pattern of :func:`clear_owned` a glob pattern rather than a file name.
_GLOB = re.compile(r"[*?\[]")


@contextmanager
def atomic_path(path: str | os.PathLike, *, fsync: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``, else delete it.

    The temporary name is ``.<stem>.tmp<8 hex digits><suffix>`` in the same folder (same
    file system, so ``os.replace`` is atomic; the suffix tells writers the format). The rename
    alone guarantees that a killed process never leaves a half-written ``path``; ``fsync=True``
    also flushes the data to disk first, against an operating-system crash (milliseconds per
    file: bulk writers whose readers validate files, like dataset shards, turn it off).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{secrets.token_hex(4)}{path.suffix}")
    try:
        yield tmp
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str, *, fsync: bool = True) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path, fsync=fsync) as tmp:
        tmp.write_text(text, encoding="utf-8")


def json_safe(value: Any) -> Any:
    """``value`` with every NaN and infinite float replaced by None, recursively through dicts, lists and tuples
    (tuples become lists): strict JSON, which has no NaN (JavaScript's ``JSON.parse``, ``jq`` and most languages
    refuse ``NaN`` and ``Infinity``). A number that is not a plain float but converts to one (a NumPy scalar)
    is treated the same way.

    Examples:
        >>> json_safe({"a": float("nan"), "b": [1.0, float("inf")], "c": "x"})
        {'a': None, 'b': [1.0, None], 'c': 'x'}
    """
    if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if type(value).__module__ == "numpy" and hasattr(value, "item") and getattr(value, "ndim", None) == 0:
        return json_safe(value.item())  # a NumPy scalar: the Python number it holds
    return value


def dumps_json(data: Any, *, indent: int | None = 2, **kwargs: Any) -> str:
    """``data`` as strict JSON text: every NaN or infinite float becomes ``null`` (:func:`json_safe`), and
    ``json.dumps`` runs with ``allow_nan=False`` so nothing non-strict can slip out (a value it cannot write
    raises instead). Every JSON text mi_svbrdf writes or prints goes through here.

    Args:
        data: dicts, lists, tuples, strings, numbers, booleans and None.
        indent: as ``json.dumps`` (None: one line).
        kwargs: passed to ``json.dumps`` (``sort_keys``, ``default``, ...).

    Examples:
        >>> dumps_json({"se": float("nan"), "mean": 0.5}, indent=None)
        '{"se": null, "mean": 0.5}'
    """
    return json.dumps(json_safe(data), indent=indent, allow_nan=False, **kwargs)


def write_json(path: str | os.PathLike, data: Any, *, indent: int | None = 2, fsync: bool = True) -> None:
    """Write ``data`` as strict JSON (``indent``, trailing newline) to ``path`` atomically.

    A NaN or infinite float is written as ``null`` (:func:`dumps_json`): the file parses in any JSON reader.
    """
    write_text(path, dumps_json(data, indent=indent) + "\n", fsync=fsync)


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies under it (both resolved)."""
    return path == folder or folder in path.parents


def owned_files(out: str | os.PathLike, patterns: Iterable[str], *,
                keep: Iterable[str | os.PathLike] = ()) -> list[Path]:
    """The files of the folder ``out`` that match ``patterns`` (what :func:`clear_owned` would remove).

    Args:
        out: a folder (none: no files).
        patterns: files relative to ``out``: names or glob patterns (``"summary.json"``,
            ``"renders/[0-9][0-9][0-9].png"``), and for each the temporary files of an interrupted atomic
            write of it.
        keep: paths never listed, nor anything under them.

    Returns:
        The matching files, sorted.
    """
    out = Path(out)
    if not out.is_dir():
        return []
    kept = [Path(k).resolve() for k in keep]
    found: set[Path] = set()
    for pattern in patterns:
        rel = Path(pattern)
        tmp = rel.with_name(f".{rel.stem}.tmp*{rel.suffix}")  # what atomic_path leaves when killed
        for path in [*out.glob(pattern), *out.glob(str(tmp))]:
            if path.is_file() or path.is_symlink():
                if not any(_inside(path.resolve(), k) or _inside(path.absolute(), k) for k in kept):
                    found.add(path)
    return sorted(found)


def written_outputs(out: str | os.PathLike, patterns: Iterable[str]) -> list[str]:
    """Of ``patterns`` (relative to the folder ``out``), those that name a file there: a plain name when that
    file exists, a glob pattern when it matches at least one (what a command wrote, from what it may write).

    Examples:
        >>> import tempfile, pathlib
        >>> out = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (out / "a.png").write_text("x")
        >>> written_outputs(out, ["a.png", "a.exr", "[0-9][0-9][0-9].png"])
        ['a.png']
    """
    out = Path(out)
    return sorted({p for p in patterns
                   if (any(f.is_file() for f in out.glob(p)) if _GLOB.search(p) else (out / p).is_file())})


def clear_owned(out: str | os.PathLike, patterns: Iterable[str], *,
                keep: Iterable[str | os.PathLike] = ()) -> list[Path]:
    """Remove from the folder ``out`` the files a command owns there, left by a previous run.

    Args:
        out: the command's output folder (nothing happens when it does not exist).
        patterns: the owned files, relative to ``out``: names or glob patterns
            (``"summary.json"``, ``"renders/[0-9][0-9][0-9].png"``). Only files matching them are
            removed (and the temporary files of an interrupted atomic write of them); a folder
            left empty by the removal is removed too. Unrelated files stay.
        keep: paths never removed, nor anything under them (the command's inputs, which may lie
            in ``out``).

    Returns:
        The removed files, sorted.
    """
    out = Path(out)
    removed = owned_files(out, patterns, keep=keep)
    for path in removed:
        path.unlink(missing_ok=True)
    root = out.resolve()
    for folder in sorted({p.parent for p in removed}, key=lambda p: len(p.parts), reverse=True):
        while folder.resolve() != root and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
            folder = folder.parent
    return removed
