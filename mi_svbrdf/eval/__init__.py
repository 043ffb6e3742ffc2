"""Evaluation of the recovery methods on the held-out benchmark: ``mi-svbrdf evaluate``.

* :mod:`~mi_svbrdf.eval.methods` -- the one method registry (:func:`make_method`): every method
  behind ``method(inputs (B, N, 3, H, W), captures) -> maps (B, 10, H, W)``, timed, with peak memory;
* :mod:`~mi_svbrdf.eval.harness` -- datasets of materials with photos (held-out, foreign captures,
  a folder of 2019 test strips, failure cases), and the one loop that runs a method on them and
  scores it (:func:`run_and_score`);
* :mod:`~mi_svbrdf.eval.runner` -- methods x N x budgets over the held-out set, the foreign captures,
  strips and failure cases, one CSV row per material, resumable;
* :mod:`~mi_svbrdf.eval.stability` -- valid outputs, noise / permutation / repeat changes and the
  stability table;
* :mod:`~mi_svbrdf.eval.report` -- Markdown summary (the sets side by side, the gap per method),
  CSVs and the charts (a)-(e);
* :mod:`~mi_svbrdf.eval.accuracy` -- a network's held-out accuracy (the bundled weights' manifest figures);
* :mod:`~mi_svbrdf.eval.measured_comparison`, :mod:`~mi_svbrdf.eval.measured_report` -- a material against a
  measured BRDF (``mi-svbrdf calibrate``): factors, errors, plots and summary;
* :mod:`~mi_svbrdf.eval.studies` -- the studies beside the pipeline, each with its report: ablations, another
  output BRDF model, real-style checks, the held-out large-scale benchmark;
* :mod:`~mi_svbrdf.eval.baseline`, :mod:`~mi_svbrdf.eval.failure_cases` -- the trivial baseline
  and the failure-case captures;
* :mod:`~mi_svbrdf.cli.evaluate` -- the subcommand.

Examples:
    >>> from mi_svbrdf.eval import pareto_front
    >>> pareto_front([1.0, 2.0, 3.0], [0.5, 0.6, 0.1])
    [True, False, True]
"""
from __future__ import annotations

from mi_svbrdf.eval.harness import Dataset, load_foreign, load_strips, run_and_score
from mi_svbrdf.eval.methods import METHODS, Measured, Method, make_method, measure
from mi_svbrdf.eval.report import (
    aggregate,
    compare_sets,
    degradation,
    images_to_match,
    method_gaps,
    pareto_front,
    write_evaluation_report,
)
from mi_svbrdf.eval.runner import (
    SETS,
    EvalConfig,
    plan,
    quick_config,
    read_rows,
    run_evaluation,
)

__all__ = ["METHODS", "SETS", "Dataset", "EvalConfig", "Measured", "Method", "aggregate", "compare_sets",
           "degradation", "images_to_match", "load_foreign", "load_strips", "make_method", "measure", "method_gaps",
           "pareto_front", "plan", "quick_config", "read_rows", "run_and_score", "run_evaluation", "write_evaluation_report"]
