"""Model selection per excitation frequency.

- :func:`compare_models` — the comparison a user runs (:mod:`bayeshyst.selection.compare`),
  and its records (:mod:`bayeshyst.selection.results`);
- :mod:`bayeshyst.selection.tasks` — the public task layer: one fit of a comparison
  (:class:`TaskSpec` → :func:`run_task` → :class:`TaskResult`), its seed, its identity
  (which fits share a posterior) and its predictive scores, for callers that schedule
  fits themselves (the study, the diagnosis);
- :mod:`bayeshyst.selection.ranking` — the one ranking by pointwise elpd
  (:func:`rank_by_elpd`), its paired standard errors and stacking weights, used by the
  comparison and by the study summary alike.
"""

from __future__ import annotations

from bayeshyst.selection.compare import check_models, compare_models, split_top_level
from bayeshyst.selection.predictor import ParametricPredictor
from bayeshyst.selection.ranking import (
    RankedModel,
    paired_difference,
    rank_by_elpd,
    stacking_weights,
    total_and_se,
)
from bayeshyst.selection.results import ComparisonResult, FrequencyComparison, ModelScore
from bayeshyst.selection.tasks import (
    CompareSettings,
    LooScores,
    TaskResult,
    TaskSpec,
    derived_seed,
    fit_identity,
    fit_sampler,
    heldout_log_density,
    loo_scores,
    run_task,
    task_seed,
)

__all__ = [
    "CompareSettings",
    "ComparisonResult",
    "FrequencyComparison",
    "LooScores",
    "ModelScore",
    "ParametricPredictor",
    "RankedModel",
    "TaskResult",
    "TaskSpec",
    "check_models",
    "compare_models",
    "derived_seed",
    "fit_identity",
    "fit_sampler",
    "heldout_log_density",
    "loo_scores",
    "paired_difference",
    "rank_by_elpd",
    "run_task",
    "split_top_level",
    "stacking_weights",
    "task_seed",
    "total_and_se",
]
