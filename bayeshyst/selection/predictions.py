"""Each compared model's predicted loop per frequency, with its band (for the report).

:func:`predicted_loops` reads back every parametric model's per-frequency posterior that
a comparison saved (:func:`~bayeshyst.inference.saved.load_fit`) and predicts that
frequency's first record with posterior draws: the mean output and its central band,
noise-free (the parameters' uncertainty; the noise is the likelihood's). The report
overlays them on the measured loop, one panel per frequency.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import frequency_label
from bayeshyst.inference.saved import load_fit
from bayeshyst.selection.results import ComparisonResult
from bayeshyst.tables import TableRecord, frame

__all__ = ["FrequencyLoops", "ModelLoop", "predicted_loops"]


@dataclass(frozen=True)
class ModelLoop:
    """One model's prediction of one record.

    Attributes
    ----------
    model : str
    mean, lo, hi : ndarray, shape (N,)
        Posterior-mean output and the band's ends (output unit, noise-free).
    nrmse_percent : float
        RMS of ``mean - y`` over the scored samples, % of the measured peak-to-peak.
    converged : bool
        Whether that fit converged.
    """

    model: str
    mean: np.ndarray = field(repr=False)
    lo: np.ndarray = field(repr=False)
    hi: np.ndarray = field(repr=False)
    nrmse_percent: float
    converged: bool


@dataclass(frozen=True)
class FrequencyLoops(TableRecord):
    """The measured loop at one frequency and every model's predicted one.

    Attributes
    ----------
    frequency_hz : float
    record : str
        The record predicted (the frequency's first).
    t, u, y : ndarray, shape (N,)
        Its times (s), input and measured output.
    scored : ndarray of bool, shape (N,)
        Samples after its warm-up.
    models : tuple of ModelLoop
        In the comparison's ranking order (best first).
    best : str or None
        The comparison's best model there (possibly a GP, which has no loop here).
    prob : float
        The band's central probability.
    """

    frequency_hz: float
    record: str
    t: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    scored: np.ndarray = field(repr=False)
    models: tuple[ModelLoop, ...]
    best: str | None
    prob: float = 0.9

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no arrays)."""
        return {"frequency_hz": self.frequency_hz, "record": self.record, "best": self.best,
                "models": [{"model": m.model, "nrmse_percent": m.nrmse_percent,
                            "converged": m.converged} for m in self.models]}

    def to_dataframe(self) -> Any:
        """One row per model: its NRMSE on this record."""
        return frame([{"frequency_hz": self.frequency_hz, "record": self.record,
                       "model": m.model, "nrmse_percent": m.nrmse_percent,
                       "converged": m.converged} for m in self.models])

    def __str__(self) -> str:
        return (f"{frequency_label(self.frequency_hz)} ({self.record}): "
                + ", ".join(f"{m.model} {m.nrmse_percent:.3g} %" for m in self.models))


def predicted_loops(comparison: ComparisonResult, data: Dataset, *, n_draws: int = 100,
                    prob: float = 0.9, seed: int = 0) -> tuple[FrequencyLoops, ...]:
    """Every parametric model's predicted loop at each frequency (module docstring).

    Parameters
    ----------
    comparison : ComparisonResult
        With its tasks' saved posteriors (``compare_models(out_dir=...)``); models
        without one (a GP, a failed fit) are left out of the overlay.
    data : Dataset
        The compared records.
    n_draws : int
        Posterior draws per model.
    prob : float
        Central probability of the band.
    seed : int
        Seeds the choice of draws.

    Returns
    -------
    tuple of FrequencyLoops
        One per frequency with a record and at least one saved posterior.
    """
    groups = data.by_frequency()
    out = []
    for fc in comparison.per_frequency:
        if fc.frequency_hz is None or fc.frequency_hz not in groups:
            continue
        rec = groups[fc.frequency_hz][0]
        loops = []
        for score in fc.scores:
            task = comparison.fit_of(score.model, fc.frequency_hz)
            if task is None or task.netcdf is None:
                continue
            saved = load_fit(task.netcdf)
            names = [r.name for r in saved.data]
            if rec.name not in names:
                continue
            z = saved.draws(min(n_draws, saved.n_draws), seed=seed)
            pred = saved.posterior.predict(z)[names.index(rec.name)]
            pred = pred[np.all(np.isfinite(pred), axis=1)]
            if pred.shape[0] == 0:
                continue
            mean = pred.mean(axis=0)
            lo, hi = np.quantile(pred, [(1 - prob) / 2, (1 + prob) / 2], axis=0)
            sc = rec.scored_mask
            nrmse = 100.0 * float(np.sqrt(np.mean((mean[sc] - rec.y[sc]) ** 2))) / (
                float(np.ptp(rec.y[sc])) or 1.0)
            loops.append(ModelLoop(score.model, mean, lo, hi, nrmse, bool(task.converged)))
        if loops:
            out.append(FrequencyLoops(float(fc.frequency_hz), rec.name, rec.t, rec.u, rec.y,
                                      rec.scored_mask, tuple(loops), fc.best, prob))
    return tuple(out)
