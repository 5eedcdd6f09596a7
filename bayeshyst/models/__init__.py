"""Hysteresis models: one module per family, a registry of names.

``bayeshyst.models.get("pi_play", n_operators=12)`` builds a model;
``bayeshyst.models.names()`` lists what is registered.
"""

from __future__ import annotations

# importing the family modules registers their models
from bayeshyst.models import (  # noqa: F401  (importing registers the models)
    bouc_wen,
    compose,
    duhem,
    fractional,
    maxwell,
    maxwell_variants,
    mrc,
    pi,
    pi_variants,
    preisach,
)
from bayeshyst.models._kernels import kernel_parallelism, serial_kernels_in_this_thread
from bayeshyst.models.base import DataScales, HysteresisModel, Trajectory, data_scales
from bayeshyst.models.bouc_wen import (
    AsymmetricBoucWen,
    BoucWen,
    BoucWenOscillator,
    ModifiedBoucWen,
)
from bayeshyst.models.compose import Composite, model_spec
from bayeshyst.models.duhem import Duhem, ImprovedDuhem
from bayeshyst.models.fractional import FractionalDuhem
from bayeshyst.models.maxwell import MaxwellSlip
from bayeshyst.models.maxwell_variants import AsymmetricMaxwellSlip, DistributedMaxwellSlip
from bayeshyst.models.mrc import MRCElectromechanical
from bayeshyst.models.pi import (
    PIInverse,
    PrandtlIshlinskii,
    PrandtlIshlinskiiStop,
    play_pi_inverse,
)
from bayeshyst.models.pi_variants import (
    AsymmetricPrandtlIshlinskii,
    GeneralizedPrandtlIshlinskii,
    RateDependentPrandtlIshlinskii,
)
from bayeshyst.models.preisach import Preisach, PreisachDensity
from bayeshyst.models.registry import get, model_class, names, register

__all__ = [
    "AsymmetricBoucWen",
    "AsymmetricMaxwellSlip",
    "AsymmetricPrandtlIshlinskii",
    "BoucWen",
    "BoucWenOscillator",
    "Composite",
    "DataScales",
    "DistributedMaxwellSlip",
    "Duhem",
    "FractionalDuhem",
    "GeneralizedPrandtlIshlinskii",
    "HysteresisModel",
    "ImprovedDuhem",
    "MRCElectromechanical",
    "MaxwellSlip",
    "ModifiedBoucWen",
    "PIInverse",
    "PrandtlIshlinskii",
    "PrandtlIshlinskiiStop",
    "Preisach",
    "PreisachDensity",
    "RateDependentPrandtlIshlinskii",
    "Trajectory",
    "data_scales",
    "get",
    "kernel_parallelism",
    "model_class",
    "model_spec",
    "names",
    "play_pi_inverse",
    "register",
    "serial_kernels_in_this_thread",
]
