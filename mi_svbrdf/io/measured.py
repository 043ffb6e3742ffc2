"""Measured-BRDF files: MERL binary tables and tabulated CSV files, read and written.

The files hold one homogeneous, isotropic BRDF (1/sr, **no cosine**, linear RGB); the readers return
the models of :mod:`mi_svbrdf.core.brdf_measured` (:class:`~mi_svbrdf.core.brdf_measured.MerlBRDF`,
:class:`~mi_svbrdf.core.brdf_measured.TabulatedBRDF`), whose lookups are documented there.

**MERL binary** (Matusik et al. 2003, the ``.binary`` files of the MERL 100):

- header: three little-endian int32, the table's dimensions ``n_θh, n_θd, n_φd = 90, 90, 180``;
- then ``3 · 90 · 90 · 180`` little-endian float64: every red value, then every green, then every
  blue; within a channel in C order ``(θ_h, θ_d, φ_d)``, i.e. entry ``φ + 180 (d + 90 h)``;
- stored value × channel scale = BRDF, scales ``(1/1500, 1.15/1500, 1.66/1500)`` for R, G, B;
  a negative stored value means *no data* (MERL marks unmeasured entries so).

The angles are Rusinkiewicz's half/difference angles on MERL's square-root θ_h grid
(:mod:`mi_svbrdf.core.brdf_measured`).

**Tabulated CSV** (other instruments, e.g. a gonioreflectometer's export)::

    # comment lines start with '#'; one optional header line (a first field that is not a number)
    theta_i,phi_i,theta_o,phi_o,r,g,b
    10,0,0,0,0.21,0.19,0.17
    10,0,2.5,180,0.23,0.20,0.18

Angles in degrees (θ from the normal, in [0, 90]; φ any value, taken modulo 360), values the BRDF
(1/sr, no cosine; finite and ≥ 0), linear RGB, comma-separated.

Examples:
    >>> import math, tempfile, pathlib, torch
    >>> from mi_svbrdf.core.brdf_measured import merl_table
    >>> lambert = lambda wi, wo: torch.full(wi.shape[:-1] + (3,), 0.5 / math.pi, dtype=torch.float64)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "lambert.binary"
    >>> write_merl(path, merl_table(lambert))
    >>> brdf = read_merl(path)
    >>> wi = torch.tensor([[0.3, 0.1, 0.95]]); wo = torch.tensor([[-0.5, 0.2, 0.84]])
    >>> f, valid = brdf.lookup(wi, wo)
    >>> [round(float(v) * math.pi, 6) for v in f[0]], bool(valid[0])
    ([0.5, 0.5, 0.5], True)
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.core.brdf_measured import MERL_DIMS, MeasuredBRDF, MerlBRDF, TabulatedBRDF
from mi_svbrdf.io.atomic import atomic_path

#: Stored value × scale = BRDF, per channel R, G, B.
MERL_SCALES: tuple[float, float, float] = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: Header (3 int32) + data (3 channels of float64) of a MERL file, in bytes.
MERL_BYTES = 12 + 8 * 3 * MERL_DIMS[0] * MERL_DIMS[1] * MERL_DIMS[2]
#: Columns of the tabulated CSV format.
CSV_COLUMNS: tuple[str, ...] = ("theta_i", "phi_i", "theta_o", "phi_o", "r", "g", "b")


# ----------------------------------------------------------------------------------------------- MERL binary


def write_merl(path: str | os.PathLike, table: torch.Tensor | np.ndarray) -> None:
    """Write a ``(3, 90, 90, 180)`` BRDF table (negative = no data) as a MERL ``.binary`` file, atomically.

    Values are divided by :data:`MERL_SCALES`; entries without data are written as -1.
    """
    table = torch.as_tensor(table, dtype=torch.float64)
    if tuple(table.shape) != (3, *MERL_DIMS):
        raise ValueError(f"table: expected shape (3, 90, 90, 180) (RGB, theta_h, theta_d, phi_d), got {tuple(table.shape)}")
    if torch.isnan(table).any() or torch.isinf(table).any():
        raise ValueError("table: contains NaN or Inf (mark entries without data with a negative value)")
    scales = torch.tensor(MERL_SCALES, dtype=torch.float64).view(3, 1, 1, 1)
    stored = torch.where(table >= 0, table / scales, torch.full((), -1.0, dtype=torch.float64))
    header = np.array(MERL_DIMS, dtype="<i4").tobytes()
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        fh.write(stored.numpy().astype("<f8").tobytes())


def read_merl(path: str | os.PathLike, interpolation: str = "linear") -> MerlBRDF:
    """Read a MERL ``.binary`` file (see the module docstring for the format).

    Args:
        path: the file.
        interpolation: of the returned table's lookup, ``"linear"`` or ``"nearest"``.

    Returns:
        A :class:`MerlBRDF` with the values in BRDF units (scales applied).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: a truncated or over-long file, dimensions other than
            90 x 90 x 180, NaN or Inf values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected a MERL .binary BRDF file, got no such file")
    size = path.stat().st_size
    if size < 12:
        raise ValueError(f"{path}: expected a MERL header of three int32 dimensions (90, 90, 180), "
                         f"got a file of {size} bytes")
    with open(path, "rb") as fh:
        dims = tuple(int(v) for v in np.frombuffer(fh.read(12), dtype="<i4"))
        if dims != MERL_DIMS:
            raise ValueError(f"{path}: expected MERL dimensions 90 x 90 x 180 (theta_h, theta_d, phi_d), "
                             f"got {dims[0]} x {dims[1]} x {dims[2]} (not a MERL file, or another table layout)")
        if size != MERL_BYTES:
            what = "truncated" if size < MERL_BYTES else "trailing bytes after the table"
            raise ValueError(f"{path}: expected {MERL_BYTES} bytes (12-byte header + 3 x 90 x 90 x 180 float64), "
                             f"got {size} ({what})")
        data = np.frombuffer(fh.read(), dtype="<f8")
    finite = np.isfinite(data)
    if not finite.all():
        raise ValueError(f"{path}: expected finite values, got {int(np.isnan(data).sum())} NaN and "
                         f"{int(np.isinf(data).sum())} Inf")
    stored = torch.from_numpy(data.astype(np.float64)).reshape(3, *MERL_DIMS)
    scales = torch.tensor(MERL_SCALES, dtype=torch.float64).view(3, 1, 1, 1)
    table = torch.where(stored >= 0, stored * scales, torch.full((), -1.0, dtype=torch.float64))
    return MerlBRDF(table, name=str(path), interpolation=interpolation)



# ----------------------------------------------------------------------------------------------- tabulated CSV


def read_tabulated_csv(path: str | os.PathLike, **kwargs: object) -> TabulatedBRDF:
    """Read the tabulated CSV format (see the module docstring) into a :class:`TabulatedBRDF`.

    Args:
        path: the ``.csv`` file.
        **kwargs: passed on to :class:`TabulatedBRDF` (``neighbours``, ``max_gap``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file and line: a row without 7 numbers, NaN/Inf, angles outside
            [0, 90], negative values, no data rows.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected a tabulated BRDF .csv file, got no such file")
    rows: list[list[float]] = []
    header_seen = False
    with open(path, newline="", encoding="utf-8") as fh:
        for lineno, fields in enumerate(csv.reader(fh), start=1):
            fields = [f.strip() for f in fields]
            if not fields or not any(fields) or fields[0].startswith("#"):
                continue
            try:
                float(fields[0])
            except ValueError:
                if header_seen or rows:
                    raise ValueError(f"{path}:{lineno}: expected 7 numbers ({', '.join(CSV_COLUMNS)}), "
                                     f"got {','.join(fields)!r}") from None
                header_seen = True
                continue
            if len(fields) != len(CSV_COLUMNS):
                raise ValueError(f"{path}:{lineno}: expected 7 values ({', '.join(CSV_COLUMNS)}), got {len(fields)}")
            try:
                row = [float(f) for f in fields]
            except ValueError:
                raise ValueError(f"{path}:{lineno}: expected 7 numbers ({', '.join(CSV_COLUMNS)}), "
                                 f"got {','.join(fields)!r}") from None
            if not all(math.isfinite(v) for v in row):
                raise ValueError(f"{path}:{lineno}: expected finite numbers, got {','.join(fields)!r} (NaN or Inf)")
            rows.append(row)
    if not rows:
        raise ValueError(f"{path}: expected rows of {', '.join(CSV_COLUMNS)}, got no data rows")
    a = np.asarray(rows, dtype=np.float64)
    try:
        return TabulatedBRDF(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4:7], name=str(path), **kwargs)  # type: ignore[arg-type]
    except ValueError as err:
        raise ValueError(str(err)) from None


def write_tabulated_csv(path: str | os.PathLike, theta_i: np.ndarray, phi_i: np.ndarray, theta_o: np.ndarray,
                        phi_o: np.ndarray, values: np.ndarray, comment: str = "") -> None:
    """Write measurements in the tabulated CSV format (angles in degrees; values the BRDF, ``(N, 3)``), atomically."""
    cols = [np.asarray(c, dtype=np.float64).reshape(-1) for c in (theta_i, phi_i, theta_o, phi_o)]
    values = np.asarray(values, dtype=np.float64)
    if any(c.shape != cols[0].shape for c in cols) or values.shape != (cols[0].shape[0], 3):
        raise ValueError(f"values: expected (N, 3) with N = {cols[0].shape[0]} like the angles, got {values.shape}")
    lines = [f"# {line}" for line in comment.splitlines()] if comment else []
    lines.append(",".join(CSV_COLUMNS))
    for row in zip(*cols, *values.T):
        lines.append(",".join(f"{v:.10g}" for v in row))
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")



def read_measured(path: str | os.PathLike, **kwargs: object) -> MeasuredBRDF:
    """A measured BRDF file: ``.csv`` -> :func:`read_tabulated_csv`, anything else -> :func:`read_merl`."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_tabulated_csv(path, **kwargs)
    return read_merl(path, **kwargs)  # type: ignore[arg-type]
