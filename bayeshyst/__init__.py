"""bayeshyst: Bayesian identification of hysteresis in piezoelectric actuators.

Models of the review's families (Preisach, Prandtl–Ishlinskii, Maxwell-slip, Duhem,
Bouc–Wen, Hammerstein blocks, creep) with declared parameters and priors, a likelihood
over measured loops, emcee posteriors, per-frequency model selection and
uncertainty-aware inverse compensation.
"""

from __future__ import annotations

import importlib
from typing import Any

from bayeshyst import models
from bayeshyst._version import __version__
from bayeshyst.data import Dataset, Record, load
from bayeshyst.errors import DataError, ModelError, ParameterError, SimulationError
from bayeshyst.params import Param, ParamSpace

#: the verbs a user types in the CLI (data first, then model) and their records, loaded
#: on first use (PEP 562): ``import bayeshyst`` stays light, ``bayeshyst.fit(...)`` works.
#: name -> (module, attribute)
_LAZY: dict[str, tuple[str, str]] = {
    # verbs
    "fit": ("bayeshyst.inference.fit", "fit_model"),
    "compare": ("bayeshyst.selection.compare", "compare_models"),
    "diagnose": ("bayeshyst.diagnosis.loop", "diagnose"),
    "compensate": ("bayeshyst.inverse.compensate", "compensate"),
    "report": ("bayeshyst.workflow", "run_report"),
    "predict": ("bayeshyst.inference.predict", "predict"),
    # records and settings they take and return
    "Posterior": ("bayeshyst.inference.posterior", "Posterior"),
    "SamplerSettings": ("bayeshyst.inference.settings", "SamplerSettings"),
    "FitResult": ("bayeshyst.inference.fit", "FitResult"),
    "ComparisonResult": ("bayeshyst.selection.results", "ComparisonResult"),
    "DiagnosisResult": ("bayeshyst.diagnosis.loop", "DiagnosisResult"),
    "CompensationResult": ("bayeshyst.inverse.compensate", "CompensationResult"),
    "ReportResult": ("bayeshyst.workflow", "ReportResult"),
    "ReportSettings": ("bayeshyst.workflow", "ReportSettings"),
    "SavedFit": ("bayeshyst.inference.saved", "SavedFit"),
    "PredictionResult": ("bayeshyst.inference.predictive", "PredictionResult"),
    "InitialCondition": ("bayeshyst.inference.predictive", "InitialCondition"),
    # a fit written by fit/compare/diagnose/report, read back with its draws
    "load_fit": ("bayeshyst.inference.saved", "load_fit"),
    # the same functions under their long names, and the two inference steps
    "fit_model": ("bayeshyst.inference.fit", "fit_model"),
    "compare_models": ("bayeshyst.selection.compare", "compare_models"),
    "run_report": ("bayeshyst.workflow", "run_report"),
    "find_map": ("bayeshyst.inference.optimize", "find_map"),
    "sample_posterior": ("bayeshyst.inference.sampling", "sample_posterior"),
}

__all__ = [
    "DataError",
    "Dataset",
    "ModelError",
    "Param",
    "ParamSpace",
    "ParameterError",
    "Record",
    "SimulationError",
    "__version__",
    "load",
    "models",
    *sorted(_LAZY),
]


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'bayeshyst' has no attribute {name!r}")
    module, attribute = _LAZY[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
