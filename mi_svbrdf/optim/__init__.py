"""The classical method: calibrated multi-image optimisation (thesis ch. 4.4.2).

* :mod:`~mi_svbrdf.optim.fit` -- :func:`optimize`, its config, initialisation and multi-start;
* :mod:`~mi_svbrdf.optim.select` -- the map model and recipe chosen per capture by leave-one-photo-out validation;
* :mod:`~mi_svbrdf.optim.loop` -- the Adam loop, schedule and convergence stop;
* :mod:`~mi_svbrdf.optim.params` -- maps <-> unconstrained variables, and the map models (tied or fixed maps);
* :mod:`~mi_svbrdf.optim.forward` -- the forward models (texel path, Mitsuba path);
* :mod:`~mi_svbrdf.optim.fused_loss` -- the fused Dr.Jit objective of the texel path;
* :mod:`~mi_svbrdf.optim.mitsuba_forward` -- perspective photos through Mitsuba;
* :mod:`~mi_svbrdf.optim.selfcal` -- self-calibration of gains, flash offset and poses;
* :mod:`~mi_svbrdf.optim.refine` -- a net's maps refined against uncalibrated photos (lights estimated);
* :mod:`~mi_svbrdf.optim.fit_measured` -- our model fitted to a measured BRDF.
"""
from __future__ import annotations

from mi_svbrdf.optim.fit import METHODS, OptimizeConfig, OptimizeResult, initial_maps, method_config, optimize
from mi_svbrdf.optim.select import select_and_fit

__all__ = ["METHODS", "OptimizeConfig", "OptimizeResult", "initial_maps", "method_config", "optimize", "select_and_fit"]
