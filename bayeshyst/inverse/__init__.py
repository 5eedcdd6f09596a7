"""Inverse models and feedforward compensation (MODELS.md §8).

* :mod:`~bayeshyst.inverse.analytic` -- closed-form inverses (play-PI, modified
  Bouc–Wen Eq. 55) and data for direct-inverse identification (stop-PI, GP);
* :mod:`~bayeshyst.inverse.numerical` -- any model or composition, sample by sample
  through its one-step map, for one parameter vector or many posterior draws at once
  (posterior-mean or robust quantile objective); linear dynamics after the hysteresis
  by stable deconvolution (:mod:`~bayeshyst.inverse.lti`);
* :mod:`~bayeshyst.inverse.feedforward` -- nominal, posterior-aware and robust commands
  with predicted output bands and tracking-error distributions;
* :mod:`~bayeshyst.inverse.compensate` -- the per-frequency evaluation behind
  ``bayeshyst compensate``.
"""

from bayeshyst.inverse.analytic import analytic_inverse, swap_input_output
from bayeshyst.inverse.compensate import (
    CompensationResult,
    CompensationRow,
    Reference,
    compensate,
    load_reference,
    reference_signal,
)
from bayeshyst.inverse.feedforward import (
    Draws,
    Feedforward,
    design_feedforward,
    predict_outputs,
    tracking_percent,
)
from bayeshyst.inverse.lti import LTIInverse, deconvolve
from bayeshyst.inverse.numerical import Inversion, Member, invert, invert_pooled

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
