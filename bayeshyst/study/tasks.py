"""One fit of a study: (dataset, model, likelihood, excitation frequency, seed).

A task is named by what its result depends on — the data it fits (sample values, not
the file name), the model spec, the likelihood, the frequency, the seed, every scoring
setting and the sampler's fingerprint
(:meth:`~bayeshyst.inference.settings.SamplerSettings.fingerprint`: moves, walkers,
budget, convergence criteria) — hashed into :attr:`StudyTask.digest`. Its result is stored under
that name, so a re-run finds what is already done and an edit of the study (another
``max_steps``, a changed file) makes new tasks instead of reusing stale results.

:func:`execute` is what a Dask worker runs. It is a plain function of picklable
arguments that returns a picklable :class:`FitOutcome` (scores and the posterior's
netCDF bytes), so the workers need not share a file system with the client; when they
do, the sampler's checkpoint under the study's ``work/`` folder lets a fit that was
interrupted (a killed worker, a stopped study) continue where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import tempfile
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.selection.tasks import (
    CompareSettings,
    TaskResult,
    TaskSpec,
    derived_seed,
    run_task,
    slug,
)

__all__ = ["TASK_FORMAT", "FitOutcome", "StudyTask", "data_digest", "execute",
           "settings_fingerprint", "slug"]

TASK_FORMAT = 2
"""Version of what a task's name covers; bump it when a result's meaning changes
(2: the structured sampler, settings as a SamplerSettings fingerprint)."""


def settings_fingerprint(settings: CompareSettings) -> dict[str, Any]:
    """JSON-ready :class:`CompareSettings` as far as a result depends on them.

    That is the scoring fields and the sampler's fingerprint (not its checkpoint or
    progress bar).
    """
    out: dict[str, Any] = {f.name: getattr(settings, f.name) for f in fields(settings)
                           if f.name != "sampler"}
    out["sampler"] = settings.sampler.fingerprint()
    return out


def data_digest(data: Dataset) -> str:
    """SHA-256 of the values a fit reads: each record's t, u, y, warm-up and frequency."""
    h = hashlib.sha256()
    for rec in data:
        for arr in (rec.t, rec.u, rec.y):
            h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
        h.update(repr((rec.warmup, rec.frequency_hz)).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class StudyTask:
    """One fit of a study.

    Attributes
    ----------
    dataset : str
        The dataset's label in the study.
    model : str
        Model spec (``"gp"``/``"gp_memory"`` for the Gaussian-process model).
    likelihood : str
    frequency_hz : float or None
        The excitation frequency whose records are fitted (None: records without one).
    seed : int
        The study's seed; the fit derives its own from it, the dataset and the task.
    data_sha256 : str
        :func:`data_digest` of the records fitted.
    settings : CompareSettings
        Sampler and scoring settings, ``likelihood`` included.
    """

    dataset: str
    model: str
    likelihood: str
    frequency_hz: float | None
    seed: int
    data_sha256: str
    settings: CompareSettings

    @property
    def spec(self) -> TaskSpec:
        """The comparison task this fit is: the model on the records at one frequency.

        The records without a frequency (the study's "unknown" group) are fitted all
        together, whatever band a multisine or broadband one covers: the study groups
        by frequency only, and hands each task exactly its group's records.
        """
        if self.frequency_hz is None:
            return TaskSpec(self.model, "joint")
        return TaskSpec(self.model, "frequency", self.frequency_hz, True)

    @property
    def digest(self) -> str:
        """Hash of everything the result depends on (see the module docstring)."""
        what = {"format": TASK_FORMAT, "data": self.data_sha256, "model": self.model,
                "likelihood": self.likelihood, "frequency_hz": self.frequency_hz,
                "seed": self.seed, "dataset": self.dataset,
                "settings": settings_fingerprint(self.settings)}
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()

    @property
    def name(self) -> str:
        """File-name-safe, readable, unique name of the task.

        ``<dataset>__<model>__<f>__<lik>__s<seed>-<hash>``, ``<hash>`` the first 12 hex
        digits of :attr:`digest`.
        """
        f = "unknown" if self.frequency_hz is None else f"{self.frequency_hz:g}Hz"
        model = self.spec.key.split("__")[0]
        return (f"{slug(self.dataset)}__{model}__{f}__{self.likelihood}__s{self.seed}"
                f"-{self.digest[:12]}")

    @property
    def fit_seed(self) -> int:
        """The seed handed to the fit, derived from the study seed, dataset and likelihood.

        The same study seed, dataset and likelihood give the same numbers, whichever
        worker runs the task and in which order.
        """
        return derived_seed(self.seed, f"{self.dataset}|{self.likelihood}")

    def label(self) -> str:
        """``"actuator-a · bouc_wen · 10 Hz · gaussian · seed 0"`` for progress lines."""
        f = "unknown f" if self.frequency_hz is None else f"{self.frequency_hz:g} Hz"
        return f"{self.dataset} · {self.model} · {f} · {self.likelihood} · seed {self.seed}"


@dataclass(frozen=True)
class FitOutcome:
    """What a worker sends back.

    Attributes
    ----------
    task : StudyTask
    result : TaskResult
        Scores; ``result.netcdf`` is None (the bytes travel in ``netcdf``).
    netcdf : bytes or None
        The posterior as a netCDF file (parametric models).
    worker : str
        ``host:pid`` of the process that ran the fit.
    notes : tuple of str
        What the worker could not do as planned (no shared work folder).
    """

    task: StudyTask
    result: TaskResult
    netcdf: bytes | None
    worker: str
    notes: tuple[str, ...] = ()


def _work_dir(requested: str | None) -> tuple[Path, bool, tuple[str, ...]]:
    """The folder of the fit's checkpoint and posterior.

    It is ``requested`` when this worker can write it (a shared file system: the
    checkpoint survives the worker), otherwise a private temporary folder (removed after
    the fit).
    """
    if requested is not None:
        try:
            Path(requested).mkdir(parents=True, exist_ok=True)
            return Path(requested), False, ()
        except OSError as exc:
            note = (f"work folder {requested} not writable on this worker ({exc.strerror}); "
                    f"the fit ran without a resumable checkpoint")
            return Path(tempfile.mkdtemp(prefix="bayeshyst-fit-")), True, (note,)
    return Path(tempfile.mkdtemp(prefix="bayeshyst-fit-")), True, ()


def execute(task: StudyTask, data: Dataset, work_dir: str | None = None) -> FitOutcome:
    """Run one study fit (what a Dask worker calls).

    Parameters
    ----------
    task : StudyTask
    data : Dataset
        The records of ``task.dataset`` at ``task.frequency_hz``.
    work_dir : str, optional
        Folder for the sampler checkpoint and the posterior file; a re-run of an
        interrupted fit with the same folder resumes from the checkpoint.

    Returns
    -------
    FitOutcome
        A fit that fails (bad data for the model, a failed simulation) is returned
        with ``result.error`` set; it does not raise.
    """
    from bayeshyst.models import kernel_parallelism

    where, private, notes = _work_dir(work_dir)
    # one worker per core: a fit's kernels run serially, so that the fits do not fight
    # for the cores (and a study's numbers do not depend on how threads were split)
    try:
        with kernel_parallelism(None):
            result = run_task(data, task.spec, task.settings, task.fit_seed, where)
        blob = Path(result.netcdf).read_bytes() if result.netcdf else None
    finally:
        if private:
            shutil.rmtree(where, ignore_errors=True)
    return FitOutcome(task, replace(result, netcdf=None), blob,
                      f"{socket.gethostname()}:{os.getpid()}", notes)
