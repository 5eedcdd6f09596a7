"""Inference: posteriors, the MAP, the structured emcee sampler and its settings.

The names a user needs are importable from here (``from bayeshyst.inference import
Posterior, SamplerSettings, sample_posterior, fit_model``); they are loaded on first use
(PEP 562), so importing one submodule does not import the others.
"""

from __future__ import annotations

import importlib
from typing import Any

#: public name -> the submodule that defines it
_EXPORTS = {
    "ConvergenceReport": "convergence",
    "FitResult": "fit",
    "LinearStructure": "linear",
    "MAPResult": "optimize",
    "Posterior": "posterior",
    "Prediction": "protocols",
    "Predictor": "protocols",
    "SamplerSettings": "settings",
    "SavedFit": "saved",
    "SamplingResult": "sampling_result",
    "SamplingTarget": "protocols",
    "calibrate_fit": "fit",
    "conjugate_posterior": "conjugate",
    "find_map": "optimize",
    "fit_model": "fit",
    "load_fit": "saved",
    "sample_posterior": "sampling",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'bayeshyst.inference' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"bayeshyst.inference.{_EXPORTS[name]}"), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
