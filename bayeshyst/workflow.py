"""The whole study on one dataset: compare, diagnose, compensate (``bayeshyst report``).

:func:`run_report` is what a user's report is made of, in the order an engineer would
do it by hand:

1. **model selection per frequency** — :func:`~bayeshyst.selection.compare_models`
   fits every model to every frequency's records, to all records jointly and (when
   there are several frequencies) to all-but-one frequency, and ranks them by
   cycle-wise PSIS-LOO;
2. **residual diagnosis** of the best *parametric* model over all frequencies (the
   Gaussian-process models have no physical structure to add an effect to, and no
   inverse) — :func:`~bayeshyst.diagnosis.diagnose` finds what its residual still
   holds, adds the effect, refits and keeps it only if held-out elpd improves;
3. **uncertainty-aware feedforward** with the model the diagnosis ended with —
   :func:`~bayeshyst.inverse.compensate.compensate` designs nominal, posterior-mean and
   robust commands from that posterior and scores them per frequency with bands;
4. **model-averaged feedforward** per frequency — the parametric models that
   frequency's comparison keeps, each with its per-frequency posterior (read back with
   :func:`~bayeshyst.inference.saved.load_fit`) and its stacking weight, designed over
   as one mixture (:func:`~bayeshyst.inverse.averaged.design_averaged`), next to the
   heaviest model alone.

Every stage samples with the same :class:`~bayeshyst.inference.settings.SamplerSettings`
(``ReportSettings.sampler``). Each fit checkpoints under ``out_dir/compare/checkpoints``,
named by what it fits (:func:`~bayeshyst.selection.tasks.fit_identity`): the
diagnosis' base fit *is* the comparison's joint fit of the chosen model and is read
back, not sampled again, and an interrupted report resumes where it stopped. Writing the files
(HTML, ``summary.json``, netCDF) is :func:`bayeshyst.outputs.report_outputs.write_report_outputs`.
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnosis import DiagnosisResult, diagnose
from bayeshyst.diagnosis.loop import DiagnosisFit
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.calibration import Calibration
from bayeshyst.inference.fit import FitResult, calibrate_fit
from bayeshyst.inference.residual import RESIDUAL_DRAWS, ResidualBlocks
from bayeshyst.inference.saved import load_fit
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.averaged import AveragedResult, WeightedPosterior, design_averaged
from bayeshyst.inverse.compensate import CompensationResult, compensate
from bayeshyst.inverse.feedforward import Draws
from bayeshyst.inverse.references import command_limits, design_references, virtual_plant
from bayeshyst.likelihoods import get_likelihood
from bayeshyst.selection import (
    ComparisonResult,
    check_models,
    compare_models,
    stacking_weights,
)
from bayeshyst.selection.results import cycles_at
from bayeshyst.selection.tasks import build_spec, is_parametric
from bayeshyst.tables import TableRecord, frame
from bayeshyst.workers import process_pool, resolve_jobs

__all__ = ["DEFAULT_MODELS", "ReportResult", "ReportSettings", "choose_model",
           "run_report"]

_log = logging.getLogger(__name__)

#: Models compared when the user names none: the two classic phenomenological families,
#: a rate-dependent PI, and the Gaussian-process peer.
DEFAULT_MODELS = ("pi_play", "bouc_wen", "pi_play+second_order", "gp_memory")
#: stacking weights below this are numerical dust, not a model the comparison keeps
WEIGHT_FLOOR = 0.01


@dataclass(frozen=True)
class ReportSettings:
    """Budgets and options of every stage of :func:`run_report`.

    Attributes
    ----------
    likelihood : str
        Observation model of every parametric fit (``gaussian``, ``student_t``, ``ar1``).
    sampler : SamplerSettings
        How every fit (comparison, diagnosis, and so the feedforward's posterior) is
        sampled; its seed is the report's seed (also of the feedforward's draws), its
        progress flag shows the diagnosis fits' progress bars (the comparison prints a
        line per fit instead). Its checkpoint is ignored: fits checkpoint under
        ``out_dir``.
    lofo : bool
        Run the leave-one-frequency-out fits of the comparison.
    max_refits : int
        Exact leave-one-cycle-out refits per fit for cycles with Pareto k > 0.7.
    gp_n_train : int
        Training subset of the Gaussian-process models.
    effects : tuple of str or None
        Candidate effects of the diagnosis (None: all).
    max_rounds, max_candidates : int
        Diagnosis: most effects added; fired effects sampled per round beyond those the
        screen judged.
    screen : bool
        Diagnosis: screen the fired candidates from their MAP first
        (:mod:`bayeshyst.diagnosis.screen`); off by default.
    budget_doublings : int
        Diagnosis: times an unconverged fit is sampled again with twice the steps before
        a candidate resting on it is not decided (the base fit too: then it is no longer
        the comparison's joint fit, which the comparison's table still reports).
    design_draws : int
        Posterior draws the posterior-aware feedforward commands are designed on.
    robust_quantile : float
        Quantile of ``|error|`` over draws the robust command minimises.
    n_jobs : int or None
        Processes of the comparison's fits, the diagnosis' candidate fits and the
        feedforward's references (default: one per core; the numbers do not depend on
        it).
    calibration : bool
        Check the final model's predictive on held-out cycles (one more posterior run
        without the last cycle of every record) for the report's uncertainty analysis.
    averaged : bool
        Design the model-averaged feedforward per frequency (stage 4 of the module
        docstring).
    """

    likelihood: str = "gaussian"
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    lofo: bool = True
    max_refits: int = 5
    gp_n_train: int = 1000
    effects: tuple[str, ...] | None = None
    max_rounds: int = 6
    max_candidates: int = 2
    screen: bool = False
    budget_doublings: int = 1
    design_draws: int = 24
    robust_quantile: float = 0.9
    n_jobs: int | None = None
    calibration: bool = True
    averaged: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.sampler, SamplerSettings):
            raise ParameterError(f"sampler must be a SamplerSettings, got "
                                 f"{type(self.sampler).__name__}")
        for name in ("max_rounds", "max_candidates", "design_draws", "gp_n_train"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ParameterError(f"{name} must be a positive integer, got {v!r}")
        for name in ("max_refits", "budget_doublings"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ParameterError(f"{name} must be an integer >= 0, got {v!r}")
        if not 0.0 < self.robust_quantile < 1.0:
            raise ParameterError(f"robust_quantile must be in (0, 1), got "
                                 f"{self.robust_quantile!r}")
        get_likelihood(self.likelihood)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings: every field, the sampler's dict, ``effects`` as a list or None."""
        d = asdict(self)
        d["sampler"] = self.sampler.to_dict()
        d["effects"] = None if self.effects is None else list(self.effects)
        return d


@dataclass(frozen=True)
class ReportResult(TableRecord):
    """Everything :func:`run_report` found.

    Attributes
    ----------
    data : Dataset
    comparison : ComparisonResult
    chosen_model : str or None
        The parametric model diagnosed and compensated (best by joint PSIS-LOO among the
        parametric models that fitted); None when none did.
    diagnosis : DiagnosisResult or None
    compensation : CompensationResult or None
        Designed from the diagnosis' final model.
    calibration : Calibration or None
        The leave-cycles-out calibration check of the diagnosis' final fit (None when
        ``settings.calibration`` is off or no parametric model fitted).
    averaged : AveragedResult or None
        The model-averaged feedforward per frequency (None when ``settings.averaged`` is
        off or no record has a frequency).
    settings : ReportSettings
    seed : int
        The report's seed (``settings.sampler.seed``).
    warnings : tuple of str
        Plain-language cautions of the run as a whole (each stage keeps its own too).
    runtime_s : dict of str to float
        Wall time per stage (s), in the stages' order, and ``total``, the run's. The
        calibration check runs alongside the feedforward stages when more than one
        process is allowed, so the stages may add up to more than the total.
    """

    data: Dataset
    comparison: ComparisonResult
    chosen_model: str | None
    diagnosis: DiagnosisResult | None
    compensation: CompensationResult | None
    settings: ReportSettings
    seed: int
    calibration: Calibration | None = None
    warnings: tuple[str, ...] = ()
    runtime_s: dict[str, float] = field(default_factory=dict)
    averaged: AveragedResult | None = None

    def to_dataframe(self) -> Any:
        """One row per frequency of the study.

        The comparison's best model, the feedforward's realised error with its band, and
        the model-averaged design's models and error.
        """
        comp = {} if self.compensation is None else {
            r.frequency_hz: r for r in self.compensation.rows}
        avg = {} if self.averaged is None else {r.frequency_hz: r for r in self.averaged.rows}
        rows = []
        for fc in self.comparison.per_frequency:
            # a band group has no frequency, hence no feedforward design of its own
            c, a = ((None, None) if fc.band is not None
                    else (comp.get(fc.frequency_hz), avg.get(fc.frequency_hz)))
            rows.append({
                "frequency": fc.label, "best": fc.best, "best_lofo": fc.best_lofo,
                "compensated_with": self.chosen_model,
                "tracking_nrmse_percent": None if c is None else c.posterior_nrmse_percent,
                "predicted_band_percent": None if c is None else c.predicted_band_percent,
                "averaged_models": None if a is None else a.models,
                "averaged_nrmse_percent": None if a is None else a.averaged_nrmse_percent})
        return frame(rows)

    @property
    def final_fit(self) -> FitResult | None:
        """The posterior the feedforward was designed from."""
        return None if self.diagnosis is None else self.diagnosis.final.fit

    def __str__(self) -> str:
        parts = [str(self.comparison)]
        if self.chosen_model is not None:
            parts.append(f"diagnosed and compensated: {self.chosen_model}")
        if self.diagnosis is not None:
            parts.append(str(self.diagnosis))
        if self.calibration is not None:
            parts.append(str(self.calibration))
        if self.compensation is not None:
            parts.append(str(self.compensation))
        if self.averaged is not None:
            parts.append(str(self.averaged))
        parts += [f"warning: {w}" for w in self.warnings]
        stages = {k: v for k, v in self.runtime_s.items() if k != "total"}
        total = self.runtime_s.get("total", sum(stages.values()))
        parts.append(f"total {total:.1f} s (" + ", ".join(
            f"{k} {v:.1f} s" for k, v in stages.items()) + ")")
        return "\n\n".join(parts)


def choose_model(comparison: ComparisonResult) -> tuple[str | None, list[str]]:
    """The parametric model to diagnose: the best by joint PSIS-LOO that fitted.

    Returns
    -------
    model : str or None
        None when no parametric model fitted.
    notes : list of str
        Why another model than the overall best was taken, in words.
    """
    notes = []
    ranking = [s for s in comparison.overall.scores if s.error is None]
    parametric = [s for s in ranking if is_parametric(build_spec(s.model))]
    if not parametric:
        return None, ["no parametric model fitted all frequencies jointly, so there is no "
                      "model to diagnose or to invert"]
    chosen = parametric[0]
    if ranking and ranking[0].model != chosen.model:
        best = ranking[0]
        notes.append(
            f"{best.model} ranks first over all frequencies, but a Gaussian-process model "
            f"has no physical structure to add an effect to and no inverse: the diagnosis "
            f"and the feedforward use the best parametric model, {chosen.model} "
            f"(elpd {chosen.elpd_loo - best.elpd_loo:+.1f} ± {chosen.delta_se:.1f} "
            f"relative to it)")
    return chosen.model, notes


def _stage(progress: bool, text: str) -> None:
    _log.info("%s", text)
    if progress:
        print(f"bayeshyst report: {text}", file=sys.stderr, flush=True)


def run_report(
    data: Dataset | Record,
    models: tuple[str, ...] | str = DEFAULT_MODELS,
    *,
    settings: ReportSettings | None = None,
    out_dir: str | Path | None = None,
    progress: bool = False,
    on_fit: Callable[[DiagnosisFit], None] | None = None,
    validation: Dataset | Record | None = None,
) -> ReportResult:
    """Compare ``models`` per frequency, diagnose the best parametric one, design feedforward.

    Parameters
    ----------
    data : Dataset or Record
        Measured loops; records grouped by ``frequency_hz``, multisine and broadband
        records by band (see :func:`~bayeshyst.selection.compare_models`).
    models : tuple of str or comma-separated str
        Model specs to compare (``"gp"``/``"gp_memory"`` take part in the comparison only).
    settings : ReportSettings, optional
        Budgets of every stage (default :class:`ReportSettings()`); ``settings.sampler``
        samples every fit, and its seed is the report's: same seed, same numbers.
    out_dir : path, optional
        Posteriors and resumable checkpoints of every fit go under it: every fit
        checkpoints in ``compare/checkpoints/`` (the diagnosis too, so its base fit
        reuses the comparison's joint fit of the same model).
    progress : bool
        One line per stage and per finished fit on stderr.
    on_fit : callable, optional
        Called with each diagnosis fit as it finishes.
    validation : Dataset or Record, optional
        Measured records not fitted on, driven like the feedforward commands: the
        feedforward stage's bands resample their residual
        (:func:`~bayeshyst.inverse.compensate.compensate`'s ``validation``); the
        model-averaged design keeps the training residual.

    Returns
    -------
    ReportResult
    """
    settings = ReportSettings() if settings is None else settings
    if not isinstance(settings, ReportSettings):
        raise ParameterError(f"settings must be a ReportSettings, got {type(settings).__name__}")
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if not isinstance(data, Dataset):
        raise DataError(f"data must be a Dataset or Record, got {type(data).__name__}")
    names = check_models(models)
    if out_dir is None:
        # the model-averaged design reads the comparison's per-frequency posteriors back
        # from its files: without an out_dir they go to a folder removed at the end
        with tempfile.TemporaryDirectory(prefix="bayeshyst-report-") as tmp:
            return _run_report(data, names, settings, Path(tmp), progress, on_fit,
                               validation)
    return _run_report(data, names, settings, Path(out_dir), progress, on_fit, validation)


def _timed_calibration(fit: FitResult, sampler: SamplerSettings
                       ) -> tuple[Calibration, float]:
    """The fit's calibration check (:func:`calibrate_fit`) and its wall time (s)."""
    t0 = time.perf_counter()
    calibration = calibrate_fit(fit, sampler).calibration
    return calibration, time.perf_counter() - t0


def _run_report(data: Dataset, names: tuple[str, ...], s: ReportSettings, out: Path,
                progress: bool, on_fit: Callable[[DiagnosisFit], None] | None,
                validation: Dataset | Record | None = None) -> ReportResult:
    times: dict[str, float] = {}
    start = time.perf_counter()
    sampler = s.sampler.replace(checkpoint=None)
    seed = sampler.seed
    # the comparison's fits checkpoint here (run_task: <out_dir>/checkpoints), and so do
    # the diagnosis' fits: its base fit has the comparison's joint fit's identity
    checkpoints = out / "compare" / "checkpoints"

    _stage(progress, f"1/5 comparing {', '.join(names)} per frequency")
    t0 = time.perf_counter()
    comparison = compare_models(
        data, names, likelihood=s.likelihood, sampler=sampler, lofo=s.lofo,
        max_refits=s.max_refits, gp_n_train=s.gp_n_train, n_jobs=s.n_jobs,
        out_dir=out / "compare", progress=progress)
    times["compare"] = time.perf_counter() - t0

    chosen, warnings = choose_model(comparison)
    diagnosis = compensation = calibration = averaged = None
    if chosen is not None:
        _stage(progress, f"2/5 diagnosing the residual of {chosen}")
        t0 = time.perf_counter()
        diagnosis = diagnose(
            data, chosen, s.likelihood, effects=s.effects, max_rounds=s.max_rounds,
            max_candidates=s.max_candidates, sampler=sampler, max_refits=s.max_refits,
            budget_doublings=s.budget_doublings, checkpoint_dir=checkpoints, on_fit=on_fit,
            n_jobs=s.n_jobs, screen=s.screen)
        times["diagnose"] = time.perf_counter() - t0
        final = diagnosis.final
    with ExitStack() as stack:
        pending = None
        if chosen is not None:
            if s.calibration:
                _stage(progress, f"3/5 checking {final.label}'s predictive on held-out cycles")
                if resolve_jobs(s.n_jobs) > 1:
                    # the check is one more posterior run, independent of the feedforward:
                    # it runs in a worker of its own while the feedforward's references
                    # run here (the same numbers: a worker's serial kernels give the bits
                    # of the parallel ones)
                    pool = stack.enter_context(process_pool(1))
                    pending = pool.submit(_timed_calibration, final.fit, sampler)
                else:
                    calibration, times["calibrate"] = _timed_calibration(final.fit, sampler)
            _stage(progress, f"4/5 designing feedforward with {final.label}")
            t0 = time.perf_counter()
            compensation = compensate(data, final.model, fit=final.fit,
                                      n_design_draws=s.design_draws,
                                      robust_quantile=s.robust_quantile, sampler=sampler,
                                      validation=validation, n_jobs=s.n_jobs)
            times["compensate"] = time.perf_counter() - t0
        if s.averaged and any(f is not None for f in data.by_frequency()):
            _stage(progress, "5/5 designing model-averaged feedforward per frequency")
            t0 = time.perf_counter()
            averaged = model_averaged_design(data, comparison, s)
            times["averaged"] = time.perf_counter() - t0
        if pending is not None:
            calibration, times["calibrate"] = pending.result()
    order = ("compare", "diagnose", "calibrate", "compensate", "averaged")
    times = {k: times[k] for k in order if k in times}
    times["total"] = time.perf_counter() - start
    if calibration is not None:
        warnings += [f"{diagnosis.final_model} (final model): {w}" for w in calibration.warnings]
    return ReportResult(data, comparison, chosen, diagnosis, compensation, s, int(seed),
                        calibration, tuple(warnings), times, averaged)


#: which posterior of each member the model-averaged design uses
AVERAGED_POSTERIORS = ("auto", "joint", "frequency")


def _member_task(comparison: ComparisonResult, model: str, frequency_hz: float,
                 posteriors: str) -> Any:
    """The successful fit whose draws ``model`` brings to ``frequency_hz``'s design.

    ``"joint"``: the fit to all records; ``"frequency"``: the fit to that frequency's
    records (the joint one when the data have one frequency, as the comparison ranks);
    ``"auto"``: the frequency's fit for a rate-independent model, the joint fit for a
    rate-dependent one. None if there is none.
    """
    if posteriors == "auto":
        posteriors = "joint" if build_spec(model).rate_dependent else "frequency"
    return comparison.fit_of(model, frequency_hz, joint=posteriors == "joint")


def model_averaged_design(data: Dataset, comparison: ComparisonResult,
                          settings: ReportSettings, *,
                          posteriors: str = "auto") -> AveragedResult:
    """Per frequency, one feedforward design over the models the comparison keeps.

    The members at a frequency are the parametric models whose fit converged and whose
    posterior was saved, weighted by their **stacking weights among themselves** at that
    frequency (the same held-out cycle densities the comparison stacks; a GP, which has
    no inverse, may hold the comparison's weight, and the design then says so), those of
    weight at least :data:`WEIGHT_FLOOR` kept; each brings its posterior draws
    (:func:`~bayeshyst.inference.saved.load_fit`). An unconverged fit or a missing file
    leaves a member out with a note, as does a frequency left with no member.

    The draws are, by default (``"auto"``), a
    rate-independent model's posterior given that frequency's records and a
    rate-dependent model's **joint** posterior (all frequencies). A command carries
    harmonics of the reference's frequency, and a rate-dependent model fitted to one
    frequency is identified at that frequency alone; a rate-independent model responds
    to the path, not its timing, and its own frequency's fit is the local one. On the
    bundled virtual actuator (benchmarks/RESULTS.md): at 200 Hz
    ``pi_play(5)+second_order``'s per-frequency posterior designed a command tracking at
    11.6 % NRMSE, its joint posterior at 2.1 %; at 1 Hz ``pi_play(5)``'s per-frequency
    posterior at 1.9 %, its joint one at 3.6 %.

    Parameters
    ----------
    data : Dataset
        The report's records (the references, command limits and plant come from them
        as in :func:`~bayeshyst.inverse.compensate.compensate`).
    comparison : ComparisonResult
        Its tasks must carry their saved posteriors (``compare_models(out_dir=...)``).
    settings : ReportSettings
        ``design_draws``, ``robust_quantile`` and the sampler's seed.
    posteriors : {"auto", "joint", "frequency"}
        Which fit of each member supplies its draws (see above).

    Returns
    -------
    AveragedResult
    """
    if posteriors not in AVERAGED_POSTERIORS:
        raise ParameterError(f"posteriors must be one of {AVERAGED_POSTERIORS}, got "
                             f"{posteriors!r}")
    plant = virtual_plant(data)
    plant_text = ("virtual actuator (" + ", ".join(plant.effects) + "), measured with its "
                  "sensor noise"
                  if plant is not None else "held-out draws of the mixture (no ground truth)")
    u_limits = command_limits(data)
    refs = {ref.frequency_hz: ref for ref, _ in design_references(data, "sine")}
    rows, notes = [], []
    for fc in comparison.per_frequency:
        if fc.frequency_hz is None or fc.frequency_hz not in refs:
            continue
        candidates = []
        for score in fc.scores:
            if score.error:
                continue
            if not is_parametric(build_spec(score.model)):
                if score.weight >= WEIGHT_FLOOR:
                    notes.append(f"{fc.label}: {score.model} (stacking weight "
                                 f"{score.weight:.2f} in the comparison) has no inverse; the "
                                 "design weighs the parametric models by their stacking "
                                 "weights among themselves")
                continue
            scoring = comparison.fit_of(score.model, fc.frequency_hz)
            task = _member_task(comparison, score.model, fc.frequency_hz, posteriors)
            why = None
            if scoring is None or task is None or task.netcdf is None:
                why = "its posterior was not saved"
            elif not task.converged:
                why = "its fit did not converge"
            if why is not None:
                notes.append(f"{fc.label}: {score.model} left out of the average: {why}")
                continue
            candidates.append((score.model, scoring, task))
        members = []
        if candidates:
            # the stacking weights of the models that can be inverted, from the same
            # held-out cycle densities the comparison stacked
            single = len(comparison.per_frequency) == 1
            weights = stacking_weights(np.column_stack(
                [t.pointwise[cycles_at(t, fc.frequency_hz, single)] for _, t, _ in candidates]))
            for (model, _, task), w in zip(candidates, weights, strict=True):
                if w < WEIGHT_FLOOR:
                    continue
                saved = load_fit(task.netcdf)
                members.append(WeightedPosterior(
                    model, saved.model, Draws.of(saved.posterior, saved.z), float(w),
                    ResidualBlocks.of(saved.posterior, saved.draws(
                        min(RESIDUAL_DRAWS, saved.n_draws), seed=settings.sampler.seed))))
        if not members:
            notes.append(f"{fc.label}: no model-averaged design (no member left)")
            continue
        rows.append(design_averaged(
            members, refs[fc.frequency_hz], plant=plant, u_limits=u_limits,
            n_design_draws=settings.design_draws, robust_quantile=settings.robust_quantile,
            seed=settings.sampler.seed))
    return AveragedResult(tuple(rows), plant_text, tuple(notes), posteriors)
