"""Hysteresis models: one module per family, a registry of names.

``bayeshyst.models.get("pi_play", n_operators=12)`` builds a model;
``bayeshyst.models.names()`` lists what is registered.
"""

from __future__ import annotations

# importing the family modules registers their models
from bayeshyst.models import (  # noqa: F401  (importing registers the models)
    bipolar,
    bouc_wen,
    bouc_wen_variants,
    compose,
    conditioned,
    duhem,
    fractional,
    hammerstein,
    maxwell,
    maxwell_variants,
    modified_bouc_wen,
    mrc,
    mrc_fractional,
    pi,
    pi_operators,
    pi_variants,
    pi_weighted,
    preisach,
    preisach_clockwise,
    preisach_variants,
)
from bayeshyst.models._kernels import (
    kernel_parallelism,
    kernels_yield_while,
    serial_kernels_in_this_thread,
)
from bayeshyst.models.base import DataScales, HysteresisModel, Trajectory, data_scales
from bayeshyst.models.bipolar import Butterfly, ButterflyBoucWen
from bayeshyst.models.bouc_wen import AsymmetricBoucWen, BoucWen
from bayeshyst.models.bouc_wen_variants import (
    AsymmetricBoucWenSgn,
    BoucWenOscillator,
    FrequencyFactorBoucWen,
)
from bayeshyst.models.compose import Composite, model_spec
from bayeshyst.models.conditioned import Conditioned
from bayeshyst.models.duhem import Duhem, ImprovedDuhem
from bayeshyst.models.fractional import FractionalDuhem
from bayeshyst.models.hammerstein import CreepVibration, FractionalHammerstein
from bayeshyst.models.maxwell import MaxwellSlip
from bayeshyst.models.maxwell_variants import AsymmetricMaxwellSlip, DistributedMaxwellSlip
from bayeshyst.models.modified_bouc_wen import ModifiedBoucWen
from bayeshyst.models.mrc import MRCElectromechanical
from bayeshyst.models.mrc_fractional import FractionalMRC
from bayeshyst.models.pi import (
    PIInverse,
    PrandtlIshlinskii,
    PrandtlIshlinskiiStop,
    play_pi_inverse,
)
from bayeshyst.models.pi_operators import (
    DeadZonePrandtlIshlinskii,
    OneSidePlayPrandtlIshlinskii,
    RateDependentOneSidePlayPI,
    RightLeftPrandtlIshlinskii,
)
from bayeshyst.models.pi_variants import (
    AsymmetricPrandtlIshlinskii,
    GeneralizedPrandtlIshlinskii,
    RateDependentPrandtlIshlinskii,
)
from bayeshyst.models.pi_weighted import CovariatePI, PolynomialInputPI, RateWeightedPI
from bayeshyst.models.preisach import Preisach, PreisachDensity
from bayeshyst.models.preisach_clockwise import PreisachClockwise
from bayeshyst.models.preisach_variants import (
    DiagonalPreisach,
    PreisachDensityRate,
    PreisachRate,
)
from bayeshyst.models.registry import get, model_class, names, register

__all__ = [
    "AsymmetricBoucWen",
    "AsymmetricBoucWenSgn",
    "AsymmetricMaxwellSlip",
    "AsymmetricPrandtlIshlinskii",
    "BoucWen",
    "BoucWenOscillator",
    "Butterfly",
    "ButterflyBoucWen",
    "Composite",
    "Conditioned",
    "CovariatePI",
    "CreepVibration",
    "DataScales",
    "DeadZonePrandtlIshlinskii",
    "DiagonalPreisach",
    "DistributedMaxwellSlip",
    "Duhem",
    "FractionalDuhem",
    "FractionalHammerstein",
    "FractionalMRC",
    "FrequencyFactorBoucWen",
    "GeneralizedPrandtlIshlinskii",
    "HysteresisModel",
    "ImprovedDuhem",
    "MRCElectromechanical",
    "MaxwellSlip",
    "ModifiedBoucWen",
    "OneSidePlayPrandtlIshlinskii",
    "PIInverse",
    "PolynomialInputPI",
    "PrandtlIshlinskii",
    "PrandtlIshlinskiiStop",
    "Preisach",
    "PreisachClockwise",
    "PreisachDensity",
    "PreisachDensityRate",
    "PreisachRate",
    "RateDependentOneSidePlayPI",
    "RateDependentPrandtlIshlinskii",
    "RateWeightedPI",
    "RightLeftPrandtlIshlinskii",
    "Trajectory",
    "data_scales",
    "get",
    "kernel_parallelism",
    "kernels_yield_while",
    "model_class",
    "model_spec",
    "names",
    "play_pi_inverse",
    "register",
    "serial_kernels_in_this_thread",
]
