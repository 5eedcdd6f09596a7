"""Inverse models and feedforward compensation (MODELS.md §8).

* :mod:`~bayeshyst.inverse.analytic` -- closed-form inverses (play-PI, modified
  Bouc–Wen Eq. 55, Bouc–Wen [93], Duhem [84]) and data for direct-inverse identification
  (stop-PI, GP, clockwise-relay Preisach); :mod:`~bayeshyst.inverse.closed_form` -- the
  nominal command of ``compensate`` from a closed form;
* :mod:`~bayeshyst.inverse.numerical` -- any model or composition, sample by sample
  through its one-step map, for one parameter vector or many posterior draws at once
  (posterior-mean or robust quantile objective); linear dynamics after the hysteresis
  by stable deconvolution (:mod:`~bayeshyst.inverse.lti`);
* :mod:`~bayeshyst.inverse.feedforward` -- nominal, posterior-aware and robust commands
  with predicted output bands and tracking-error distributions;
* :mod:`~bayeshyst.inverse.references` -- reference trajectories, command limits and
  the virtual plant a design is run on;
* :mod:`~bayeshyst.inverse.compensate` -- the per-frequency evaluation behind
  ``bayeshyst compensate``;
* :mod:`~bayeshyst.inverse.averaged` -- one command designed over several models'
  posteriors weighted by their stacking weights (the report's model-averaged design).
"""

from bayeshyst.inverse.analytic import analytic_inverse, swap_input_output
from bayeshyst.inverse.closed_form import closed_form_feedforward
from bayeshyst.inverse.compensate import CompensationResult, CompensationRow, compensate
from bayeshyst.inverse.feedforward import (
    Draws,
    Feedforward,
    design_feedforward,
    predict_outputs,
    tracking_percent,
)
from bayeshyst.inverse.lti import LTIInverse, deconvolve
from bayeshyst.inverse.numerical import Inversion, Member, invert, invert_pooled
from bayeshyst.inverse.references import Reference, load_reference, reference_signal

__all__ = [
    "CompensationResult",
    "CompensationRow",
    "Draws",
    "Feedforward",
    "Inversion",
    "LTIInverse",
    "Member",
    "Reference",
    "analytic_inverse",
    "closed_form_feedforward",
    "compensate",
    "deconvolve",
    "design_feedforward",
    "invert",
    "invert_pooled",
    "load_reference",
    "predict_outputs",
    "reference_signal",
    "swap_input_output",
    "tracking_percent",
]
