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
from bayeshyst.data import Dataset, Record, load
from bayeshyst.errors import DataError, ModelError, ParameterError, SimulationError
from bayeshyst.params import Param, ParamSpace

__version__ = "0.1.0.dev0"

#: the verbs and their records, loaded on first use (PEP 562): ``import bayeshyst``
#: stays light, ``bayeshyst.fit_model(...)`` works
_LAZY = {
    "Posterior": "bayeshyst.inference.posterior",
    "SamplerSettings": "bayeshyst.inference.settings",
    "compare_models": "bayeshyst.selection",
    "compensate": "bayeshyst.inverse",
    "diagnose": "bayeshyst.diagnosis",
    "find_map": "bayeshyst.inference.optimize",
    "fit_model": "bayeshyst.inference.fit",
    "sample_posterior": "bayeshyst.inference.sampling",
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
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
