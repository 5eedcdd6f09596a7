"""Close the loop on measured data, from the residual to the augmented model's error.

The chain is residual → missing effect → augmented model → error before and after.

- :mod:`~bayeshyst.diagnosis.stats`: score (LM) tests with AR(p)-whitened regressions,
  Breusch–Godfrey, Holm;
- :mod:`~bayeshyst.diagnosis.effects`: the candidate effects, each with its score
  regressors, its augmentation block and its physical reading;
- :mod:`~bayeshyst.diagnosis.residual`: a fit's residual and every effect's test on it;
- :mod:`~bayeshyst.diagnosis.loop`: :func:`diagnose`, the loop with its two gates
  (test fires, held-out elpd improves).
"""

from bayeshyst.diagnosis.catalogue import EFFECTS, get_effect
from bayeshyst.diagnosis.effects import Effect
from bayeshyst.diagnosis.loop import (
    DiagnosisFit,
    DiagnosisResult,
    DiagnosisSettings,
    DiagnosisStep,
    diagnose,
)
from bayeshyst.diagnosis.residual import EffectTest, ResidualAnalysis, analyse_residual

__all__ = [
    "EFFECTS",
    "DiagnosisFit",
    "DiagnosisResult",
    "DiagnosisSettings",
    "DiagnosisStep",
    "Effect",
    "EffectTest",
    "ResidualAnalysis",
    "analyse_residual",
    "diagnose",
    "get_effect",
]
