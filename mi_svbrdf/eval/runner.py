"""Run methods x N x budgets over the held-out benchmark, the foreign captures (and strips, failure cases), one CSV row at a time.

A **row** (:func:`run_row`) is one method on one material with N photos (and a budget for the
optimiser-based methods), run and scored by :func:`~mi_svbrdf.eval.harness.run_and_score`: the
metrics of :func:`mi_svbrdf.core.metrics.evaluate_maps` against the ground truth under the fixed
evaluation lights, the wall time and peak memory of :func:`~mi_svbrdf.eval.methods.measure`, and
the optimiser's steps and recoveries. Rows are keyed by ``(dataset, material, method, n, budget_s)``;
after each row the whole CSV is rewritten atomically (temp file + rename), so an interrupted run
keeps every finished row and a second run with the same ``out`` skips them (resumable).

Datasets (``EvalConfig.sets``): ``"heldout"`` (:class:`mi_svbrdf.data.heldout.HeldOutSet`, material m
of class ``CLASS_ORDER[m % 9]``, seed :data:`mi_svbrdf.data.heldout.HELD_OUT_SEED`; always run: the
reference of every comparison), ``"foreign"`` (:class:`mi_svbrdf.data.foreign.ForeignSet`: every
capture parameter outside training's, same size, materials and N as the held-out set unless
``foreign_materials`` says otherwise; every job, as on the held-out set), ``"strips"`` (a folder of
the thesis's 2019 test strips, ``EvalConfig.strips``: resized to ``size``, uncalibrated, so only
the methods that need no calibration run: trivial on photo 0 under the nominal 2019 flash, single,
multi, and uncalibrated, which estimates every photo's light from the photos (its use case: photos
nobody calibrated); optimize and refine, which read every photo's camera and light, are skipped),
and per failure case ``"case:NAME"`` and ``"clean:NAME"`` (its clean twin) at the case's N and the
smallest budget.

Which rows (:func:`plan`): trivial and multi at every N of ``n_images``; single at N = 1;
optimize at every N of ``n_images + optimizer_n`` and every budget of ``budgets``; refine at
every N of ``n_images`` and every budget of ``refine_budgets``; uncalibrated at every N of
``n_images`` and every budget of ``uncalibrated_budgets``. The stability table
(:mod:`~mi_svbrdf.eval.stability`, ``stability.csv``) follows, on the first held-out materials. Then, unless
``EvalConfig.real_checks`` is off, the real-style checks (:mod:`~mi_svbrdf.eval.studies.real_checks`: the nets on
the example photos and on clipped flash highlights, ``real_checks.json`` and two figures) at ``size``.

**The estimate** (:func:`measured_estimate`): the first pending row of each method, N, budget and size
(:func:`timing_key`) runs first and is timed (run, scored, written); the time left is then the sum over
the other rows of the timed row of the same method and budget at the nearest N (scaled by the pixel
count at another size), the stability table's calls priced the same way, and measured constants for
the real-style checks and the report (:data:`REAL_CHECKS_S`, :data:`REPORT_S`). The log gives it with
its parts, and at the end the time the rows, the stability table and the checks took.
"""
from __future__ import annotations

import csv
import inspect
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core.device import resolve_device
from mi_svbrdf.core.metrics import METRIC_KEYS, eval_lights
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import from_dict
from mi_svbrdf.data import foreign
from mi_svbrdf.data.heldout import HELD_OUT_SEED, HeldOutSet
from mi_svbrdf.eval import stability
from mi_svbrdf.eval.harness import (
    Dataset,
    case_datasets,
    load_foreign,
    load_heldout,
    load_strips,
    run_and_score,
)
from mi_svbrdf.eval.methods import (
    BUDGET_METHODS,
    METHODS,
    NEEDS_CALIBRATION,
    NET_METHODS,
    START_NET_METHODS,
    Method,
    available_nets,
    make_method,
)
from mi_svbrdf.eval.studies.real_checks import JSON_NAME as REAL_CHECKS_JSON
from mi_svbrdf.eval.studies.real_checks import real_checks as run_real_checks
from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES

#: CSV columns, in order.
COLUMNS: tuple[str, ...] = ("dataset", "material", "class", "method", "n", "budget_s", "seconds", "peak_mb",
                            "steps", "recoveries", "stop_reason", "net", *METRIC_KEYS)
KEY = ("dataset", "material", "method", "n", "budget_s")
CSV_NAME = "results.csv"
#: Evaluation sets, in report order ("heldout" is always run: the reference of the gaps).
SETS: tuple[str, ...] = ("heldout", "foreign", "strips")


@dataclass
class EvalConfig:
    """What :func:`run_evaluation` runs; :meth:`from_dict` rejects unknown keys."""

    size: int = 256  #: H = W of the held-out maps and photos
    materials: int = 16  #: held-out materials (classes in turn)
    n_images: tuple[int, ...] = tuple(range(1, 11))  #: N for trivial, multi, optimize, refine, uncalibrated
    optimizer_n: tuple[int, ...] = (20, 50)  #: extra N for the optimiser only
    #: optimiser budgets, seconds. The fit stops on convergence (256^2: 3-6 s at N <= 10, 17 s at
    #: N = 50), so a budget above that is a cap: 1 and 3 s show the fit cut short (its schedule
    #: compressed), 30 s the converged fit.
    budgets: tuple[float, ...] = (1.0, 3.0, 30.0)
    refine_budgets: tuple[float, ...] = (3.0, 30.0)  #: refinement budgets, seconds (as budgets)
    #: budgets of the uncalibrated refinement (optim.refine: the light search, then the fit), seconds. Each row
    #: costs about its whole budget (the self-calibrating fit seldom converges before 30 s at 256^2), so 30 s
    #: would add about 3 h to a full run: 3 s (cut short, paired with refine at 3 s) and 10 s instead.
    uncalibrated_budgets: tuple[float, ...] = (3.0, 10.0)
    methods: tuple[str, ...] = METHODS  #: methods to run (those needing absent weights are skipped)
    lights: int = 9  #: evaluation lights of the re-rendering metrics
    gallery_materials: int = 2  #: materials shown in the gallery (their predictions are saved)
    gallery_n: int = 5  #: N of the gallery's predictions (clipped to the largest N run)
    reference_n: int = 5  #: N of the multi net the optimiser must match (chart c)
    seconds_per_row: float = 1.5  #: estimated overhead per row at 256^2 (metrics, nets), for the estimate
    warm_up: bool = True  #: one untimed call of each method first (imports, JIT) so no row pays one-time costs
    stability_materials: int = 2  #: held-out materials of the stability table (stability.csv; 0: none)
    stability_n: int | None = None  #: photos per material in the stability table (None: min(3, largest N); off when that is 1)
    stability_trials: int = 2  #: 1/255-noise perturbations per method and material
    sets: tuple[str, ...] = ("heldout", "foreign")  #: evaluation sets (SETS); "strips" is added with strips
    foreign_materials: int | None = None  #: materials of the foreign set (None: as materials)
    strips: str | None = None  #: folder of 2019 test strips (the "strips" set), None: none
    device: str = "cpu"  #: where photos and captures go before each call (core.device.resolve_device)
    real_checks: bool = True  #: run the real-style checks (eval.real_checks; skipped when real_checks.json exists)
    symmetries: int = DEFAULT_SYMMETRIES  #: the nets' symmetry ensemble (nets.ensemble; 1: the net alone), as predict runs them

    def __post_init__(self) -> None:
        self.n_images = tuple(int(n) for n in self.n_images)
        self.optimizer_n = tuple(int(n) for n in self.optimizer_n)
        self.budgets = tuple(float(b) for b in self.budgets)
        self.refine_budgets = tuple(float(b) for b in self.refine_budgets)
        self.uncalibrated_budgets = tuple(float(b) for b in self.uncalibrated_budgets)
        self.methods = tuple(self.methods)
        if not (isinstance(self.size, int) and self.size >= 16):
            raise ValueError(f"size: expected an int >= 16, got {self.size!r}")
        if not (isinstance(self.materials, int) and self.materials >= 1):
            raise ValueError(f"materials: expected an int >= 1, got {self.materials!r}")
        if not self.n_images or not all(1 <= n <= 50 for n in self.n_images + self.optimizer_n):
            raise ValueError(f"n_images, optimizer_n: expected N in [1, 50], got {self.n_images}, {self.optimizer_n}")
        if not all(b > 0 for b in self.budgets + self.refine_budgets + self.uncalibrated_budgets) or not self.budgets:
            raise ValueError(f"budgets, refine_budgets, uncalibrated_budgets: expected seconds > 0, got "
                             f"{self.budgets}, {self.refine_budgets}, {self.uncalibrated_budgets}")
        if "uncalibrated" in self.methods and not self.uncalibrated_budgets:
            raise ValueError("uncalibrated_budgets: expected a budget with 'uncalibrated' in methods, got ()")
        if self.stability_n is None:  # a permutation needs two photos
            self.stability_n = min(3, self.max_n)
            if self.stability_n < 2:
                self.stability_materials = 0
        if self.stability_materials and not 2 <= self.stability_n <= self.max_n:
            raise ValueError(f"stability_n: expected 2 <= N <= {self.max_n} (the largest N), got {self.stability_n}")
        if not (isinstance(self.stability_trials, int) and self.stability_trials >= 1):
            raise ValueError(f"stability_trials: expected an int >= 1, got {self.stability_trials!r}")
        bad = [m for m in self.methods if m not in METHODS]
        if bad or not self.methods:
            raise ValueError(f"methods: expected some of {METHODS}, got {self.methods}")
        self.sets = tuple(self.sets)
        if self.strips is not None:
            self.strips = str(self.strips)
            if "strips" not in self.sets:
                self.sets += ("strips",)
        if any(s not in SETS for s in self.sets) or "heldout" not in self.sets or len(set(self.sets)) != len(self.sets):
            raise ValueError(f"sets: expected distinct names among {SETS} including 'heldout', got {self.sets}")
        if "strips" in self.sets and not self.strips:
            raise ValueError(f"strips: expected a folder of strips with 'strips' in sets, got {self.strips!r}")
        self.sets = tuple(s for s in SETS if s in self.sets)
        if self.foreign_materials is not None and not (isinstance(self.foreign_materials, int)
                                                       and self.foreign_materials >= 1):
            raise ValueError(f"foreign_materials: expected None or an int >= 1, got {self.foreign_materials!r}")
        self.device = str(resolve_device(self.device))
        if isinstance(self.symmetries, bool) or not (isinstance(self.symmetries, int) and 1 <= self.symmetries <= 8):
            raise ValueError(f"symmetries: expected an int in [1, 8], got {self.symmetries!r}")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EvalConfig:
        """Build from a dict; unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)

    @property
    def max_n(self) -> int:
        """The largest N of any row."""
        return max(self.n_images + self.optimizer_n)


def quick_config(**overrides: Any) -> EvalConfig:
    """``--quick``: 4 materials at 128^2, N in {1, 3}, one 4 s budget (about 10 minutes on 2 cores with an empty cache; it prints its estimate first)."""
    base = dict(size=128, materials=4, n_images=(1, 3), optimizer_n=(), budgets=(4.0,), refine_budgets=(4.0,),
                uncalibrated_budgets=(4.0,), gallery_n=3, reference_n=3, stability_materials=1, stability_trials=1)
    return EvalConfig.from_dict({**base, **overrides})


@dataclass(frozen=True)
class Job:
    """One method at one N (and budget), run on every material."""

    method: str
    n: int
    budget_s: float | None


def plan(config: EvalConfig, nets: Sequence[str]) -> list[Job]:
    """The jobs of ``config`` (see the module docstring), skipping net methods without weights."""
    jobs: list[Job] = []
    for m in config.methods:
        if m in ("single", "multi") and m not in nets or m in START_NET_METHODS and not nets:
            continue
        if m == "single":
            jobs.append(Job(m, 1, None))
        elif m in ("trivial", "multi"):
            jobs += [Job(m, n, None) for n in config.n_images]
        elif m == "optimize":
            jobs += [Job(m, n, b) for n in sorted(set(config.n_images + config.optimizer_n)) for b in config.budgets]
        elif m == "refine":
            jobs += [Job(m, n, b) for n in config.n_images for b in config.refine_budgets]
        else:
            jobs += [Job(m, n, b) for n in config.n_images for b in config.uncalibrated_budgets]
    return jobs


def case_jobs(jobs: Sequence[Job], n_case: int) -> list[Job]:
    """The jobs run on a failure case with ``n_case`` photos: each method once, at N = n_case
    (1 for the single net) and its smallest budget."""
    out = []
    for method in dict.fromkeys(j.method for j in jobs):
        budgets = [j.budget_s for j in jobs if j.method == method and j.budget_s is not None]
        out.append(Job(method, 1 if method == "single" else n_case, min(budgets) if budgets else None))
    return out


def row_key(row: dict[str, Any]) -> tuple[str, ...]:
    """The identity of a row (strings, as read back from the CSV)."""
    return tuple(_fmt(row[k]) for k in KEY)


def _fmt(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def read_rows(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a results CSV (numbers parsed), [] if the file does not exist."""
    path = Path(path)
    if not path.is_file():
        return []
    rows = []
    with path.open(newline="", encoding="utf-8") as f:
        for raw in csv.DictReader(f):
            if any(raw.get(k) is None for k in COLUMNS):
                continue  # a truncated line
            row: dict[str, Any] = dict(raw)
            for k in ("material", "n", "steps", "recoveries"):
                row[k] = int(raw[k]) if raw[k] else 0
            for k in ("seconds", "peak_mb", *METRIC_KEYS):
                row[k] = float(raw[k]) if raw[k] else math.nan
            row["budget_s"] = float(raw["budget_s"]) if raw["budget_s"] else None
            rows.append(row)
    return rows


def write_rows(path: str | os.PathLike, rows: Sequence[dict[str, Any]]) -> None:
    """Write ``rows`` as CSV atomically (temp file, then rename)."""
    with atomic_path(path, fsync=False) as tmp:
        with tmp.open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: _fmt(r.get(k)) for k in COLUMNS})


#: Wall time of an uncalibrated refinement (optim.refine: search and fit) over its budget: at 256^2 (N = 3 and 10,
#: budgets 3-30 s, 2 held-out materials) its fit stopped on the budget in 5 of the 6 fitted rows and took
#: 0.95-1.3 x the budget (the net's time excluded); a sample whose flash photo is unusable keeps the net's maps at once.
UNCALIBRATED_TYPICAL = 1.05


def estimate_seconds(jobs: Sequence[Job], materials: int, config: EvalConfig) -> tuple[float, float]:
    """Rough duration of ``jobs`` on ``materials`` materials: (typical, at most).

    Both add a per-row overhead (metrics, nets). *At most* charges each optimiser row its whole
    budget x 1.5 (measured at 128^2 with a 4 s budget: the wall time exceeds the budget by
    35-80 %). *Typical* charges it the convergence stop's time instead when that comes first:
    ``(2.5 + 0.3 N) s x (size / 256)^2``, fitted to ``benchmarks/bench_optimize.py`` at 256^2
    (2.5-4.5 s at N <= 5, 5.1-6.0 s at N = 10, 8.3-9.3 s at N = 20, 16.6-18.1 s at N = 50). An
    uncalibrated refinement row is charged its whole budget (:data:`UNCALIBRATED_TYPICAL` x it): its
    light search and self-calibrating fit share the budget and the fit seldom converges before it.
    """
    scale = (config.size / 256) ** 2
    overhead = config.seconds_per_row * scale

    def typical_fit(job: Job) -> float:
        budget = job.budget_s or 0.0
        if job.method == "uncalibrated":
            return UNCALIBRATED_TYPICAL * budget
        return min(1.5 * budget, (2.5 + 0.3 * job.n) * scale)

    worst = sum(1.5 * (j.budget_s or 0.0) + overhead for j in jobs)
    typical = sum(typical_fit(j) + overhead for j in jobs)
    return materials * typical, materials * worst


#: Seconds of the steps after the rows that no row's timing covers: the real-style checks and writing the
#: report with its charts (the upper end of timings with one torch thread on a loaded 2-core CPU, the same at
#: 128^2 and 256^2 since the nets see their 256^2 input either way; docs/design-notes.md).
REAL_CHECKS_S, REPORT_S = 6.0, 6.0

#: ``(method, N, budget_s, H)``: rows of one key take about the same time (:func:`timing_key`).
TimingKey = tuple[str, int, float | None, int]


def timing_key(job: Job, data: Dataset) -> TimingKey:
    """The key of ``job`` on ``data``'s materials: method, N, budget and the photos' height."""
    return job.method, job.n, job.budget_s, int(data.inputs.shape[-2])


def timing_rows_first(todo: Sequence[tuple[Job, Dataset, int]]
                      ) -> tuple[list[tuple[Job, Dataset, int]], list[tuple[Job, Dataset, int]]]:
    """Split ``todo`` into the first pending row of each :func:`timing_key` (run first and timed: the
    estimate's measurements) and the rest (in their order)."""
    first: list[tuple[Job, Dataset, int]] = []
    rest: list[tuple[Job, Dataset, int]] = []
    seen: set[TimingKey] = set()
    for item in todo:
        key = timing_key(item[0], item[1])
        (rest if key in seen else first).append(item)
        seen.add(key)
    return first, rest


def row_seconds(measured: dict[TimingKey, float], job: Job, size: int, config: EvalConfig) -> float:
    """Wall seconds of one row of ``job`` at ``size``^2 from the rows timed in this run: the same method
    and budget at the nearest N (the same size preferred, another one scaled by the pixel count); without
    such a row, :func:`estimate_seconds`'s typical figure."""
    same = [(key[3] != size, abs(key[1] - job.n), seconds * (size / key[3]) ** 2)
            for key, seconds in measured.items() if key[0] == job.method and key[2] == job.budget_s]
    if same:
        return min(same)[2]
    return estimate_seconds([job], 1, replace(config, size=size))[0]


@dataclass
class Estimate:
    """Seconds left after the timed rows: the other rows, the stability table, the real-style checks, the
    report (written by the caller after :func:`run_evaluation`); ``worst_rows``: the rows if every optimiser
    fit ran to 1.5 x its budget."""

    rows: float
    stability: float
    real_checks: float
    report: float
    worst_rows: float

    @property
    def total(self) -> float:
        """Every part, seconds."""
        return self.rows + self.stability + self.real_checks + self.report


def measured_estimate(rest: Sequence[tuple[Job, Dataset, int]], measured: dict[TimingKey, float],
                      stability_methods: Sequence[Job], config: EvalConfig, real_checks: bool) -> Estimate:
    """The time left, from the rows timed in this run (:func:`row_seconds`).

    Args:
        rest: the rows still to run.
        measured: wall seconds of the timed rows (run, scored, written) by :func:`timing_key`.
        stability_methods: the stability table's jobs when it is still to run ([] otherwise): each runs
            ``4 + stability_trials`` times per material (scored, repeat, unperturbed, trials, permutation).
        config: sizes, budgets, stability settings.
        real_checks: whether the real-style checks are still to run.
    """
    rows = worst = 0.0
    for job, data, _ in rest:
        seconds = row_seconds(measured, job, int(data.inputs.shape[-2]), config)
        rows += seconds
        worst += max(seconds, 1.5 * (job.budget_s or 0.0))
    calls = min(config.stability_materials, config.materials) * (4 + config.stability_trials)
    stab = sum(calls * row_seconds(measured, job, config.size, config) for job in stability_methods)
    return Estimate(rows=rows, stability=stab, real_checks=REAL_CHECKS_S if real_checks else 0.0,
                    report=REPORT_S, worst_rows=worst)


def _per_method(measured: dict[TimingKey, float]) -> str:
    """``"trivial 0.02 s, multi 0.10-0.21 s, optimize 4 s 1.1-2.3 s"``: the timed rows' range per method."""
    spans: dict[str, list[float]] = {}
    for (method, _, budget, _), seconds in measured.items():
        spans.setdefault(f"{method} {budget:g} s" if budget is not None else method, []).append(seconds)
    return ", ".join(f"{name} {min(v):.2f} s" + (f"-{max(v):.2f} s" if max(v) > min(v) * 1.05 else "")
                     for name, v in spans.items())


def heldout_dataset(config: EvalConfig, progress: bool = True) -> Dataset:
    """The held-out benchmark of ``config`` (cached by :class:`~mi_svbrdf.data.heldout.HeldOutSet`)."""
    return load_heldout(HeldOutSet(size=config.size, materials=config.materials, n_images=config.max_n), progress)


def foreign_dataset(config: EvalConfig, progress: bool = True) -> Dataset:
    """The foreign captures of ``config`` (cached by :class:`~mi_svbrdf.data.foreign.ForeignSet`): the
    held-out set's size and N, ``foreign_materials`` (default: as many as the held-out set) materials."""
    fs = foreign.ForeignSet(size=config.size, materials=config.foreign_materials or config.materials,
                            n_images=config.max_n)
    return load_foreign(fs, progress)


def set_datasets(config: EvalConfig, progress: bool = True) -> list[Dataset]:
    """The datasets of ``config.sets``, in :data:`SETS` order (the held-out set first)."""
    out = []
    for name in config.sets:
        if name == "heldout":
            out.append(heldout_dataset(config, progress))
        elif name == "foreign":
            out.append(foreign_dataset(config, progress))
        else:
            out.append(load_strips(config.strips, size=config.size))
    return out


def dataset_jobs(jobs: Sequence[Job], data: Dataset) -> list[Job]:
    """The jobs run on ``data``: every job on a calibrated set (held-out, foreign); on an uncalibrated
    one (strips) those needing no calibration (not :data:`~mi_svbrdf.eval.methods.NEEDS_CALIBRATION`:
    optimize, refine; uncalibrated runs); :func:`case_jobs` on a failure case; always N <= the dataset's
    photos."""
    n_max = data.inputs.shape[1]
    if data.name.startswith(("case:", "clean:")):
        chosen = case_jobs(jobs, n_max)
    elif data.calibrated:
        chosen = list(jobs)
    else:
        chosen = [j for j in jobs if j.method not in NEEDS_CALIBRATION]
    return [j for j in chosen if j.n <= n_max]


def _prediction_path(out: Path, row: dict[str, Any]) -> Path:
    budget = f"_{row['budget_s']:g}s" if row["budget_s"] is not None else ""
    return out / "predictions" / f"{row['dataset'].replace(':', '_')}_m{row['material']}_{row['method']}" \
                                 f"_n{row['n']}{budget}.pt"


def check_settings(out: Path, config: EvalConfig) -> None:
    """Record in ``out/settings.json`` what makes rows comparable (size, lights, held-out seed); a
    resumed run must match it (more materials, N or budgets are fine: rows are per material).
    """
    settings: dict[str, Any] = {"size": config.size, "lights": config.lights, "heldout_seed": HELD_OUT_SEED,
                                "foreign_seed": foreign.FOREIGN_SEED, "foreign_version": foreign.VERSION,
                                "symmetries": config.symmetries}
    if config.strips:
        settings["strips"] = str(Path(config.strips).resolve())
    path = out / "settings.json"
    if path.is_file():
        old = json.loads(path.read_text())
        old.setdefault("symmetries", 1)  # runs from before the symmetry ensemble ran the nets alone
        # a key only one side has (an older run without the foreign set, a run without strips) is fine
        if any(old[k] != settings[k] for k in old.keys() & settings.keys()):
            raise ValueError(f"{path}: expected the settings of the run being resumed {old}, got {settings} "
                             "(use another --out)")
        if old.keys() >= settings.keys():
            return
        settings = {**old, **settings}
    write_json(path, settings, indent=None, fsync=False)


def warm_up(names: Sequence[str], data: Dataset, weights_dir: str | os.PathLike | None) -> None:
    """One untimed call of each method on a 16^2 corner of material 0 with 2 photos (0.2 s budgets).

    The first call in a process pays one-time costs (imports of the optimiser's dependencies,
    Dr.Jit and PyTorch kernel compilation) that would otherwise be charged to whichever row runs
    first.
    """
    n = min(2, data.inputs.shape[1])
    inputs = data.inputs[:1, :n, :, :16, :16]
    captures = data.captures.take(0).images(slice(0, n))
    for name in names:
        make_method(name, weights_dir=weights_dir, budget_s=0.2 if name in BUDGET_METHODS else None)(inputs, captures)


def run_row(method: Method, job: Job, data: Dataset, material: int, lights: Any,
            device: torch.device | str | None = None) -> tuple[dict[str, Any], torch.Tensor]:
    """One row: ``method`` (built for ``job``) on ``material`` of ``data`` with ``job.n`` photos, timed
    and scored (:func:`~mi_svbrdf.eval.harness.run_and_score`, photos on ``device``); returns the row and the maps."""
    res, metrics = run_and_score(method, data, job.n, lights, material, device=device)
    row = {"dataset": data.name, "material": material, "class": data.classes[material % len(data.classes)],
           "method": job.method, "n": job.n, "budget_s": job.budget_s, "seconds": res.seconds,
           "peak_mb": res.peak_mb, "steps": res.info.get("steps", 0), "recoveries": res.info.get("recoveries", 0),
           "stop_reason": res.info.get("stop_reason", ""), "net": res.info.get("net", ""), **metrics}
    return row, res.maps


def _runnable(config: EvalConfig, weights_dir: str | os.PathLike | None, log: Callable[[str], None]) -> list[Job]:
    """The jobs of ``config`` whose weights exist; the skipped net methods are logged."""
    nets = available_nets(weights_dir) if any(m in NET_METHODS for m in config.methods) else []
    skipped = [m for m in config.methods if m in ("single", "multi") and m not in nets
               or m in START_NET_METHODS and not nets]
    if skipped:
        log(f"note: no network weights for {skipped} in {weights_dir or 'the bundled folder'}: skipped")
    return plan(config, nets)


def _pending(jobs: Sequence[Job], data: Sequence[Dataset], rows: Sequence[dict[str, Any]]
             ) -> list[tuple[Job, Dataset, int]]:
    """``(job, dataset, material)`` of every row not in ``rows`` yet (:func:`dataset_jobs` per dataset)."""
    done = {row_key(r) for r in rows}
    todo: list[tuple[Job, Dataset, int]] = []
    for ds in data:
        for job in dataset_jobs(jobs, ds):
            for m in range(ds.maps.shape[0]):
                key = row_key({"dataset": ds.name, "material": m, "method": job.method, "n": job.n,
                               "budget_s": job.budget_s})
                if key not in done:
                    todo.append((job, ds, m))
                    done.add(key)
    return todo


def _save_gallery(out: Path, heldout: Dataset, config: EvalConfig) -> None:
    """``out/gallery/heldout_mM.pt``: ground truth and photos of the gallery materials (once)."""
    (out / "gallery").mkdir(exist_ok=True)
    for m in range(min(config.gallery_materials, heldout.maps.shape[0])):
        path = out / "gallery" / f"heldout_m{m}.pt"
        if not path.exists():
            torch.save({"maps": heldout.maps[m:m + 1].clone(), "inputs": heldout.inputs[m:m + 1, :config.max_n].half(),
                        "class": heldout.classes[m]}, path)


def _make_method(name: str, weights_dir: str | os.PathLike | None, budget_s: float | None, device: str,
                 symmetries: int = DEFAULT_SYMMETRIES) -> Method:
    """:func:`~mi_svbrdf.eval.methods.make_method`, told the device when it takes one (methods that
    do not yet run where their photos are get CPU photos: ``device`` is then only honoured off the CPU
    by moving the photos, :func:`~mi_svbrdf.eval.harness.run_and_score`)."""
    kwargs: dict[str, Any] = {"weights_dir": weights_dir, "budget_s": budget_s}
    if name in NET_METHODS:
        kwargs["symmetries"] = symmetries
    if "device" in inspect.signature(make_method).parameters:
        kwargs["device"] = device
    return make_method(name, **kwargs)


def _run_pending(todo: Sequence[tuple[Job, Dataset, int]], rows: list[dict[str, Any]], out: Path,
                 config: EvalConfig, weights_dir: str | os.PathLike | None, bar: Any,
                 methods: dict[tuple[str, float | None], Method]) -> list[float]:
    """Run the pending rows in order, appending each to ``rows`` and rewriting ``out/results.csv``;
    the gallery materials' predictions at the gallery's N go to ``out/predictions/``. ``methods`` caches
    the methods built (net loading) across calls; ``bar`` (tqdm) advances per row. Returns each row's wall
    seconds (run, scored, written; building its method excluded)."""
    lights = eval_lights(config.lights)
    gallery_n = min(config.gallery_n, max(config.n_images))
    seconds = []
    for job, ds, m in todo:
        method = methods.get((job.method, job.budget_s))
        if method is None:
            method = methods[(job.method, job.budget_s)] = _make_method(job.method, weights_dir, job.budget_s,
                                                                        config.device, config.symmetries)
        start = time.perf_counter()
        row, maps = run_row(method, job, ds, m, lights, device=config.device)
        if ds.name == "heldout" and m < config.gallery_materials and job.n == (1 if job.method == "single"
                                                                               else gallery_n):
            path = _prediction_path(out, row)
            path.parent.mkdir(exist_ok=True)
            torch.save(maps.half(), path)
        rows.append(row)
        write_rows(out / CSV_NAME, rows)
        seconds.append(time.perf_counter() - start)
        bar.update(1)
    return seconds


def _stability_table(jobs: Sequence[Job], heldout: Dataset, out: Path, config: EvalConfig,
                     weights_dir: str | os.PathLike | None, log: Callable[[str], None]) -> None:
    """``out/stability.csv`` (:func:`~mi_svbrdf.eval.stability.run_stability`), unless written already."""
    if not config.stability_materials or (out / stability.CSV_NAME).is_file():
        return
    k = min(config.stability_materials, config.materials)
    methods = [(job.method, job.budget_s) for job in case_jobs(jobs, config.stability_n)]
    log(f"evaluate: stability table ({len(methods)} methods x {k} materials, N = {config.stability_n})")
    stability.run_stability(methods, heldout, config.stability_n, out, materials=k, weights_dir=weights_dir,
                            lights=eval_lights(config.lights), trials=config.stability_trials)


def run_evaluation(config: EvalConfig, out: str | os.PathLike, *, weights_dir: str | os.PathLike | None = None,
                   cases: Sequence[Any] = (), progress: bool = True,
                   log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Run every job on every material (and failure case), resuming from ``out/results.csv``.

    Args:
        config: what to run.
        out: the report folder (``results.csv``, ``predictions/``, ``gallery/``, ``stability.csv``,
            ``real_checks.json``).
        weights_dir: the nets' weights folder (None: bundled); net methods without weights are skipped.
        cases: failure cases (``Case`` objects: ``name``, ``maps (1, 10, H, W)``, ``inputs (1, N, 3, H, W)``,
            ``captures``, ``clean``), run at their N with every method (the smallest budget).
        progress: tqdm bar.
        log: where notes and the estimate go.

    Returns:
        Every row of ``out/results.csv`` (earlier ones included).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_settings(out, config)
    jobs = _runnable(config, weights_dir, log)
    data = set_datasets(config, progress) + case_datasets(cases)
    if "strips" in config.sets:
        skipped = [m for m in NEEDS_CALIBRATION if m in {j.method for j in jobs}]
        log(f"note: strips ({config.strips}): uncalibrated, {skipped or 'no methods'} skipped; trivial uses "
            "photo 0 under the nominal 2019 flash (light (0, 0, 2.197), camera (0, 0, 2.75), I = 13, e = 5)"
            + ("; uncalibrated estimates every photo's light" if "uncalibrated" in {j.method for j in jobs} else ""))
    rows = read_rows(out / CSV_NAME)
    todo = _pending(jobs, data, rows)
    timed, rest = timing_rows_first(todo)
    log(f"evaluate: {len(todo)} rows to run ({len(rows)} already done)"
        + (f"; timing the first row of each of the {len(timed)} method settings, then estimating the rest"
           if todo else ""))
    _save_gallery(out, data[0], config)
    if config.warm_up and todo:
        warm_up(sorted({t[0].method for t in todo}), data[0], weights_dir)
    methods: dict[tuple[str, float | None], Method] = {}
    with tqdm(total=len(todo), desc="evaluate", disable=not progress) as bar:
        seconds = _run_pending(timed, rows, out, config, weights_dir, bar, methods)
        measured = {timing_key(job, ds): s for (job, ds, _), s in zip(timed, seconds)}
        stab_jobs = (case_jobs(jobs, config.stability_n) if config.stability_materials
                     and not (out / stability.CSV_NAME).is_file() else [])
        real_pending = config.real_checks and not (out / REAL_CHECKS_JSON).is_file()
        est = measured_estimate(rest, measured, stab_jobs, config, real_pending)
        start = time.perf_counter()
        log(f"evaluate: estimated {est.total / 60:.1f} min left, from this run's timed rows at {config.size}^2 "
            f"({_per_method(measured) or 'none timed'}): {len(rest)} rows {est.rows / 60:.1f} min (at most "
            f"{est.worst_rows / 60:.1f} if every fit runs to 1.5 x its budget), stability table "
            f"{est.stability / 60:.1f} min, real-style checks {est.real_checks / 60:.1f} min, report "
            f"{est.report / 60:.1f} min")
        _run_pending(rest, rows, out, config, weights_dir, bar, methods)
    _stability_table(jobs, data[0], out, config, weights_dir, log)
    if config.real_checks and not (out / REAL_CHECKS_JSON).is_file():
        log(f"evaluate: real-style checks (the nets on the example photos and on clipped highlights, {config.size}^2)")
        run_real_checks(out, weights_dir, size=config.size, progress=False)
    log(f"evaluate: rows, stability table and real-style checks took {(time.perf_counter() - start) / 60:.1f} min "
        f"(estimated {(est.total - est.report) / 60:.1f}); writing the report")
    return rows
