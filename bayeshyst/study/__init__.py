"""Studies over datasets × models × likelihoods × frequencies × seeds, on Dask.

``bayeshyst study STUDY.toml`` (or :func:`run_study`) fits every model to the records of
every excitation frequency of every dataset, one Dask task per fit, stores each result
as it completes under a name hashed from its inputs (so a study resumes), and ends with
the table of every fit and model selection per frequency across datasets.
"""

from __future__ import annotations

from bayeshyst.study.run import StudyResult, plan_study, run_study
from bayeshyst.study.spec import MEASURED_LOADERS, DatasetSpec, Study, load_dataset, read_study
from bayeshyst.study.summary import DatasetRanking, FrequencySummary, summarise
from bayeshyst.study.tasks import StudyTask, execute

__all__ = [
    "MEASURED_LOADERS",
    "DatasetRanking",
    "DatasetSpec",
    "FrequencySummary",
    "Study",
    "StudyResult",
    "StudyTask",
    "execute",
    "load_dataset",
    "plan_study",
    "read_study",
    "run_study",
    "summarise",
]
