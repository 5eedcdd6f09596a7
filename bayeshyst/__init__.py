"""bayeshyst: Bayesian identification of hysteresis in piezoelectric actuators.

Models of the review's families (Preisach, Prandtl–Ishlinskii, Maxwell-slip, Duhem,
Bouc–Wen, Hammerstein blocks, creep) with declared parameters and priors, a likelihood
over measured loops, emcee posteriors, per-frequency model selection and
uncertainty-aware inverse compensation.
"""

from __future__ import annotations

from bayeshyst import models
from bayeshyst.data import Dataset, Record, load
from bayeshyst.errors import DataError, ModelError, ParameterError, SimulationError
from bayeshyst.params import Param, ParamSpace

__version__ = "0.1.0.dev0"

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
]
