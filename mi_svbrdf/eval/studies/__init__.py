"""Studies beside the evaluation pipeline, each with its report next to it.

* :mod:`~mi_svbrdf.eval.studies.ablations` -- the thesis's ablations at equal compute (``mi-svbrdf ablations``);
* :mod:`~mi_svbrdf.eval.studies.output_model` -- another output BRDF model: GGX -> Beckmann next to GGX -> GGX;
* :mod:`~mi_svbrdf.eval.studies.real_checks` -- the nets on the bundled example photos and on clipped flash
  highlights (run by ``mi-svbrdf evaluate`` unless turned off);
* :mod:`~mi_svbrdf.eval.studies.large_scale` -- the held-out large-scale benchmark of the by-example net and the
  exemplar-influence check.
"""
