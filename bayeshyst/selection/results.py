"""The records of a model comparison: one model's scores, a frequency's ranking, the result.

:func:`~bayeshyst.selection.compare.compare_models` returns a :class:`ComparisonResult`;
each :class:`FrequencyComparison` holds the models ranked at one excitation frequency
(by :func:`~bayeshyst.selection.ranking.rank_by_elpd`), one :class:`ModelScore` each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.data.groups import Band, group_label
from bayeshyst.errors import ParameterError
from bayeshyst.selection.ranking import paired_difference
from bayeshyst.selection.tasks import TaskResult
from bayeshyst.tables import TableRecord, frame

__all__ = ["ComparisonResult", "FrequencyComparison", "ModelScore", "cycles_at"]


def cycles_at(task: TaskResult, freq: Any, joint: bool) -> np.ndarray:
    """Mask (n_cycles,) of a task's scored cycles in the group ``freq``.

    ``freq`` is a group key (:mod:`bayeshyst.data.groups`): a frequency, a
    :class:`~bayeshyst.data.groups.Band`, or None for the unknown group. All cycles
    with ``joint``.
    """
    if joint:
        return np.ones(task.pointwise.size, dtype=bool)
    if task.unit_group:
        return np.array([g == freq for g in task.unit_group], dtype=bool)
    # a result without group keys: its cycles are told apart by frequency only
    if freq is None:
        return np.isnan(task.unit_frequency)
    return task.unit_frequency == freq


@dataclass(frozen=True)
class ModelScore(TableRecord):
    """One model at one frequency (or over all frequencies).

    Attributes
    ----------
    model : str
    elpd_loo, se : float
        PSIS-LOO (exact refits for bad cycles; exact LOO for GP models) summed over the
        cycles, and its standard error.
    p_loo : float
        Effective number of parameters (NaN for GP models).
    delta_elpd, delta_se : float
        ``elpd_loo`` below the best model's, and the se of that paired difference.
    weight : float
        Stacking weight among the models at this frequency.
    elpd_waic, waic_se : float
        WAIC (NaN for GP models).
    elpd_lofo, lofo_se : float
        Log predictive density of these cycles by the model fitted to the **other**
        frequencies (NaN when there is a single frequency or LOFO was not run).
    lofo_nrmse_percent : float
        Tracking error of that extrapolated prediction (% of the measured stroke).
    elpd_joint : float
        elpd of these cycles by PSIS-LOO of the model fitted to all frequencies.
    bic : float
        At the MAP (NaN for GP models); lower is better.
    nrmse_percent, max_error_percent : float
        Posterior-mean prediction error of the model fitted here (% of stroke).
    n_params : int
        Free parameters including noise and offset (GP: hyperparameters).
    converged : bool
        Every fit behind this row converged (sampler R-hat/ESS or GP optimiser).
    max_pareto_k : float
        Over the cycles not refitted exactly (NaN for GP models).
    n_refits : int
    n_cycles : int
    warnings : tuple of str
    error : str or None
        The fit failed; its scores are NaN and it is ranked last.
    """

    model: str
    elpd_loo: float
    se: float
    p_loo: float
    delta_elpd: float
    delta_se: float
    weight: float
    elpd_waic: float
    waic_se: float
    elpd_lofo: float
    lofo_se: float
    lofo_nrmse_percent: float
    elpd_joint: float
    bic: float
    nrmse_percent: float
    max_error_percent: float
    n_params: int
    converged: bool
    max_pareto_k: float
    n_refits: int
    n_cycles: int
    warnings: tuple[str, ...] = ()
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN becomes ``None``)."""
        out: dict[str, Any] = {}
        for k, v in self.__dict__.items():
            if isinstance(v, float) and not math.isfinite(v):
                v = None
            out[k] = list(v) if isinstance(v, tuple) else v
        return out

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])


@dataclass(frozen=True)
class FrequencyComparison(TableRecord):
    """The ranking in one group: an excitation frequency or a band.

    ``frequency_hz`` is the group's frequency; ``band`` its band for a group of
    multisine or broadband records (``frequency_hz`` None then). With both None it
    ranks all groups jointly when ``joint`` is True, and the records of the unknown
    group otherwise.

    ``scores`` are ranked by ``elpd_loo`` (failed fits last); ``best`` is the first;
    ``best_lofo`` the model with the highest leave-one-frequency-out elpd.
    """

    frequency_hz: float | None
    scores: tuple[ModelScore, ...]
    best: str | None
    best_lofo: str | None
    joint: bool = False
    band: Band | None = None

    @property
    def key(self) -> Any:
        """The group key (:mod:`bayeshyst.data.groups`): the frequency, the band or None."""
        return self.band if self.band is not None else self.frequency_hz

    @property
    def label(self) -> str:
        """``"10 Hz"``, ``"band 5-150 Hz"``, ``"all"`` or ``"unknown"``."""
        return "all" if self.joint else group_label(self.key)

    def score(self, model: str) -> ModelScore:
        """The row of ``model``."""
        for s in self.scores:
            if s.model == model:
                return s
        raise ParameterError(f"no model {model!r} at {self.label}; have "
                             f"{[s.model for s in self.scores]}")

    def to_dataframe(self) -> Any:
        """One row per model (the ranking's order): its scores at this frequency."""
        return frame([{"frequency": self.label, **s.to_dict()} for s in self.scores])

    def to_dict(self) -> dict[str, Any]:
        """The ``per_frequency`` entry of ``summary.json``."""
        return {
            "frequency_hz": self.frequency_hz,
            "group": self.label,
            "band_hz": None if self.band is None else self.band.to_list(),
            "best": self.best,
            "best_lofo": self.best_lofo,
            "ranking": [s.to_dict() for s in self.scores],
        }

    def __str__(self) -> str:
        def f(x: float, fmt: str = ".1f") -> str:
            return "—" if not math.isfinite(x) else format(x, fmt)

        head = (f"{'model':<26} {'elpd_loo':>10} {'se':>7} {'Δelpd':>9} {'Δse':>7} "
                f"{'weight':>6} {'elpd_lofo':>10} {'NRMSE%':>7} {'max%':>7} {'k':>3} "
                f"{'conv':>4}")
        lines = [f"── {self.label}: best {self.best}"
                 + (f"; best out of frequency {self.best_lofo}" if self.best_lofo else ""),
                 head]
        for s in self.scores:
            if s.error:
                lines.append(f"{s.model:<26} failed: {s.error}")
                continue
            lines.append(
                f"{s.model:<26} {f(s.elpd_loo):>10} {f(s.se):>7} {f(s.delta_elpd):>9} "
                f"{f(s.delta_se):>7} {f(s.weight, '.2f'):>6} {f(s.elpd_lofo):>10} "
                f"{f(s.nrmse_percent, '.3f'):>7} {f(s.max_error_percent, '.3f'):>7} "
                f"{s.n_params:>3} {'yes' if s.converged else 'NO':>4}")
        return "\n".join(lines)


@dataclass(frozen=True)
class ComparisonResult(TableRecord):
    """Everything :func:`compare_models` found.

    Attributes
    ----------
    models : tuple of str
    per_frequency : tuple of FrequencyComparison
        Sorted by frequency (unknown last).
    overall : FrequencyComparison
        All frequencies jointly (joint fits; ``elpd_lofo`` is the sum over frequencies).
    tasks : tuple of TaskResult
        Every fit that ran, with its own warnings, runtime and saved posterior.
    settings : dict
    runtime_s : float
    """

    models: tuple[str, ...]
    per_frequency: tuple[FrequencyComparison, ...]
    overall: FrequencyComparison
    tasks: tuple[TaskResult, ...]
    settings: dict[str, Any] = field(default_factory=dict)
    runtime_s: float = 0.0

    def fit_of(self, model: str, frequency_hz: Any = None, *,
               joint: bool = False) -> TaskResult | None:
        """The successful fit of ``model`` behind the ranking in one group.

        ``frequency_hz`` is the group's key (a frequency, a
        :class:`~bayeshyst.data.groups.Band` or None: :attr:`FrequencyComparison.key`).
        The fit to that group's records; the joint fit (all records) with ``joint``
        or when the data have one group, as the comparison ranks them. None if that
        fit failed or did not run.
        """
        joint = joint or len(self.per_frequency) == 1
        for t in self.tasks:
            if t.ok and t.spec.model == model and (
                    t.spec.scope == "joint" if joint else
                    (t.spec.scope == "frequency" and t.spec.group_key == frequency_hz)):
                return t
        return None

    def difference(self, a: str, b: str, frequency_hz: float | None = None, *,
                   joint: bool = False) -> tuple[float, float]:
        """``elpd_loo(a) - elpd_loo(b)`` and its paired standard error at one frequency.

        Parameters
        ----------
        a, b : str
            Model specs of this comparison.
        frequency_hz : float, Band or None
            The group's key (``None``: records of the unknown group, or all groups
            with ``joint=True``).
        joint : bool
            Compare the joint fits over all frequencies.
        """
        fits = {m: t for m in (a, b)
                if (t := self.fit_of(m, frequency_hz, joint=joint)) is not None}
        missing = [m for m in (a, b) if m not in fits]
        if missing:
            raise ParameterError(f"no successful fit of {missing} at "
                                 f"{'all frequencies' if joint else frequency_hz}")
        pw = [fits[m].pointwise[cycles_at(fits[m], frequency_hz, joint)] for m in (a, b)]
        return paired_difference(pw[0], pw[1])

    def to_dataframe(self) -> Any:
        """One row per (frequency, model), the joint ranking (frequency "all") last."""
        return frame([{"frequency": fc.label, **s.to_dict()}
                      for fc in (*self.per_frequency, self.overall) for s in fc.scores])

    def winners(self) -> dict[str, str | None]:
        """Best model by ``elpd_loo`` at each frequency label."""
        return {fc.label: fc.best for fc in self.per_frequency}

    @property
    def failed(self) -> tuple[TaskResult, ...]:
        """Tasks that raised (recorded, not fatal)."""
        return tuple(t for t in self.tasks if not t.ok)

    def to_dict(self) -> dict[str, Any]:
        """The model-selection part of ``summary.json``."""
        return {
            "models": list(self.models),
            "per_frequency": [fc.to_dict() for fc in self.per_frequency],
            "overall": self.overall.to_dict(),
            "winners": self.winners(),
            "failed_fits": [t.error for t in self.failed],
            "fits": [{"key": t.spec.key, "model": t.spec.model, "scope": t.spec.scope,
                      "frequency_hz": t.spec.frequency_hz,
                      "group": group_label(t.spec.group_key) if t.spec.group else "all",
                      "band_hz": None if t.spec.band is None else t.spec.band.to_list(),
                      "converged": t.converged,
                      "runtime_s": round(t.runtime_s, 2), "n_refits": t.n_refits,
                      "n_moment_matched": t.n_moment_matched,
                      "failed_simulations": t.failed_simulations,
                      "move_acceptance": {k: round(v, 4) for k, v in
                                          t.move_acceptance.items()},
                      "posterior": t.netcdf,
                      "warnings": list(t.warnings), "error": t.error}
                     for t in self.tasks],
            "settings": self.settings,
            "runtime_s": round(self.runtime_s, 2),
        }

    def __str__(self) -> str:
        blocks = [str(fc) for fc in self.per_frequency] + [str(self.overall)]
        tail = [f"{len(self.tasks)} fits in {self.runtime_s:.1f} s"]
        tail += [f"failed: {t.error}" for t in self.failed]
        return "\n\n".join(blocks) + "\n\n" + "\n".join(tail)
