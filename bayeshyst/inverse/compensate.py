"""Feedforward compensation evaluated per excitation frequency (``bayeshyst compensate``).

For every frequency in the data a reference trajectory at that frequency is tracked by
four commands -- the scaled input (no compensation), the nominal inverse of the MAP,
the posterior-aware inverse and its robust variant (:mod:`bayeshyst.inverse.feedforward`)
-- and each is run on a **plant**:

* the virtual actuator that generated the data, when the records carry its truth (the
  sidecar of every bundled dataset does): the real test of a model;
* otherwise posterior draws held out from both the design and the prediction draws,
  each standing in for the plant (the first is *the* plant of the report, the others
  measure how often the predicted band holds). This says how well the model's own
  uncertainty is propagated, not how well the model fits the actuator; every output
  says which plant was used.

Errors are RMS and max of ``y - y_d`` in % of the reference's stroke, over the cycles
after the warm-up cycle(s) (the first cycle starts from the relaxed state and carries
the transient of the dynamics). ``y`` is a *measurement*: the virtual actuator runs
with its sensor noise, and the predicted bands add to every prediction draw the fit's
own unexplained residual, resampled in whole cycles
(:class:`~bayeshyst.inference.residual.ResidualBlocks`) -- parameters, discrepancy and
residual, the tracking band's budget (``parameter_band_percent``,
``model_band_percent``, ``predicted_band_percent``). With a discrepancy, whether it
holds along the commands' paths is part of the band: a share of the prediction draws
drops it and takes the model's own residual
(:class:`~bayeshyst.inverse.feedforward.PredictionError`, ``discrepancy_transfer``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.data.virtual import VirtualActuator
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.fit import FitResult, fit_model
from bayeshyst.inference.residual import (
    MIN_SAMPLES,
    RESIDUAL_DRAWS,
    ResidualBlocks,
    cycle_samples,
)
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.closed_form import NOMINAL_INVERSES, check_closed_form
from bayeshyst.inverse.feedforward import (
    BAND,
    DISCREPANCY_TRANSFER,
    Draws,
    PredictionError,
    check_transfer_probability,
    predict_record,
)
from bayeshyst.inverse.per_reference import (
    CompensationRow,
    PosteriorPlant,
    VirtualPlant,
    evaluate_reference,
)
from bayeshyst.inverse.references import (
    U_MARGIN,
    Reference,
    command_limits,
    design_references,
    virtual_plant,
)
from bayeshyst.models import get as get_model
from bayeshyst.models.base import HysteresisModel
from bayeshyst.tables import TableRecord, frame
from bayeshyst.workers import process_pool, resolve_jobs

__all__ = ["CompensationResult", "CompensationRow", "compensate"]

_log = logging.getLogger(__name__)

# ------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class CompensationResult(TableRecord):
    """Feedforward compensation of one model, per frequency.

    Attributes
    ----------
    model : str
    plant : str
        What the commands were evaluated on, in words.
    plant_kind : str
        ``"virtual actuator"`` or ``"posterior draw"``.
    rows : tuple of CompensationRow
        Ascending frequency.
    statements : tuple of str
        Plain-language findings (error growing with frequency, bands missed).
    converged : bool
        Whether the fit behind the design converged.
    settings : dict
    """

    model: str
    plant: str
    plant_kind: str
    rows: tuple[CompensationRow, ...]
    statements: tuple[str, ...]
    converged: bool
    settings: dict[str, Any]

    def to_dataframe(self) -> Any:
        """One row per frequency: every command's realised error and the bands."""
        return frame([{"model": self.model, **r.to_dict()} for r in self.rows],
                     drop=("mean_over_plants",))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary; ``per_frequency`` is the list of row dicts."""
        return {"model": self.model, "plant": self.plant, "plant_kind": self.plant_kind,
                "converged": self.converged, "per_frequency": [r.to_dict() for r in self.rows],
                "statements": list(self.statements), "settings": dict(self.settings)}

    def __str__(self) -> str:
        head = (f"feedforward compensation with {self.model} (tracking NRMSE, % of stroke); "
                f"plant: {self.plant}")
        return "\n".join([head, *(str(r) for r in self.rows), *self.statements])


# ------------------------------------------------------------------------------ driver

def _validation_residual(post: Any, z: np.ndarray, validation: Dataset) -> ResidualBlocks:
    """Residual of records the posterior was not fitted on, about its mean prediction."""
    if not len(validation):
        raise DataError("validation: no record to take a residual from")
    draws = Draws.of(post, z)
    series, freqs, cycles = [], [], []
    for rec in validation:
        pred = predict_record(post.model, rec, draws)
        resid = (rec.y - np.mean(pred, axis=0))[rec.scored]
        if resid.size < MIN_SAMPLES:
            raise DataError(f"validation {rec.name}: {resid.size} scored samples; a residual "
                            f"needs at least {MIN_SAMPLES}")
        series.append(resid)
        freqs.append(rec.frequency_hz)
        cycles.append(cycle_samples(rec))
    return ResidualBlocks.from_series(series, freqs, cycles)


def _split_draws(fit: FitResult, sizes: tuple[int, ...], seed: int) -> list[Draws]:
    """Disjoint sets of posterior draws (design, prediction, plants) as model draws."""
    post = fit.posterior
    z = fit.sampling.draws(sum(sizes), seed=seed)
    if z.shape[0] < sum(sizes):
        raise ParameterError(f"the posterior holds {z.shape[0]} draws, {sum(sizes)} needed "
                             "(design + prediction + plants); sample longer")
    z = z[np.random.default_rng(seed).permutation(z.shape[0])]
    out, start = [], 0
    for size in sizes:
        out.append(Draws.of(post, z[start:start + size]))
        start += size
    return out


def _trend_statements(rows: list[CompensationRow], model: str,
                      rate_dependent: bool, errors: PredictionError | None = None
                      ) -> list[str]:
    out = []
    if errors is not None and errors.mixed:
        out.append(f"With a discrepancy the bands mix two cases: that what it learned on the "
                   f"identification loops holds along the command (probability "
                   f"{errors.transfer:g}), and that it does not (the command's misfit is then "
                   "the model's own). Nothing in the identification data tells them apart "
                   "on paths those loops never showed (minor loops of a narrower reference); "
                   "a validation record with such paths (--validation) measures it and "
                   "narrows the bands.")
    elif errors is not None and errors.without is not None:
        out.append("With a discrepancy and discrepancy_transfer=1 the bands assume that what "
                   "it learned on the identification loops holds along the command; a "
                   "command that drives paths those loops never showed can err by more.")
    freq = [r for r in rows if r.frequency_hz is not None]
    if len(freq) >= 2:
        first, last = freq[0], freq[-1]
        lo, hi = last.model_band_percent
        # growth beyond what the posterior itself predicts: at the top frequency the
        # posterior command's error leaves the band of the model alone (parameters and
        # discrepancy, noise-free), and exceeds the lowest frequency's by more than that
        # band's width. (The band with the residual may hold it: the fit's residual
        # already shows the misfit at that frequency, which is the point.)
        if (last.posterior_nrmse_percent > hi
                and last.posterior_nrmse_percent - first.posterior_nrmse_percent > hi - lo):
            advice = ("its rate dependence does not match the plant's" if rate_dependent else
                      "a composition with linear dynamics "
                      f"('{model}+second_order') or a rate-dependent model should help")
            out.append(f"The tracking error of {model} grows with frequency "
                       f"({first.posterior_nrmse_percent:.3g} % at {first.frequency_hz:g} Hz "
                       f"to {last.posterior_nrmse_percent:.3g} % at {last.frequency_hz:g} Hz, "
                       f"beyond the model's own predicted band [{lo:.3g}, {hi:.3g}] %; the "
                       f"fit's residual: {first.residual_rms_percent:.3g} % to "
                       f"{last.residual_rms_percent:.3g} %): the model misses rate-dependent "
                       f"dynamics; {advice}.")
    for r in rows:
        if not r.realised_inside_band:
            lo, hi = r.predicted_band_percent
            out.append(f"At {r.label} the realised error {r.posterior_nrmse_percent:.3g} % lies "
                       f"outside the predicted 90 % band [{lo:.3g}, {hi:.3g}] %: the model's "
                       "uncertainty does not cover the plant there.")
        if r.n_saturated:
            out.append(f"At {r.label} {r.n_saturated} command samples hit the command limits: "
                       "the reference is out of the actuator's reach there.")
    return out


def compensate(
    data: Dataset | Record,
    model: HysteresisModel | str,
    *,
    fit: FitResult | None = None,
    plant: VirtualActuator | str | None = None,
    reference: str | Reference = "sine",
    cycles: int = 2,
    warmup_cycles: int = 1,
    n_design_draws: int = 24,
    n_predict_draws: int = 100,
    n_plants: int = 50,
    robust_quantile: float = 0.9,
    u_margin: float = U_MARGIN,
    likelihood: str = "gaussian",
    sampler: SamplerSettings | None = None,
    discrepancy: str | None = None,
    validation: Dataset | Record | None = None,
    nominal_inverse: str = "numerical",
    discrepancy_transfer: float = DISCREPANCY_TRANSFER,
    n_jobs: int | None = None,
) -> CompensationResult:
    """Design feedforward from the posterior of ``model`` and evaluate it per frequency.

    Parameters
    ----------
    data : Dataset or Record
        Measured loops; each frequency in them gets a reference at that frequency.
    model : HysteresisModel or str
        Model or spec string (``"pi_play+second_order"``).
    fit : FitResult, optional
        A posterior of ``model`` given ``data`` already sampled (its model must be
        ``model``); default: sampled here with ``likelihood`` and ``sampler``.
    plant : VirtualActuator, "posterior" or None
        What the commands are run on. None: the virtual actuator named by the records'
        ``truth`` metadata if any, else held-out posterior draws.
    reference : {"sine", "triangle"} or Reference
        Built-in shape (spanning the central 80 % of the data's output range, at every
        frequency of the data and its sampling rate) or one trajectory (from
        :func:`load_reference`), evaluated once.
    cycles, warmup_cycles : int
        Scored cycles of a built-in reference and unscored cycles before them.
    n_design_draws : int
        Posterior draws the posterior-aware commands are designed on.
    n_predict_draws : int
        Held-out draws the bands are predicted from.
    n_plants : int
        Held-out draws used as plants when no virtual actuator is available.
    robust_quantile : float
        Quantile of ``|error|`` the robust command minimises.
    u_margin : float
        Command limits: the data's input range widened by this fraction of its span
        at each end.
    likelihood : str
        As :func:`~bayeshyst.inference.fit.fit_model` (ignored with ``fit``).
    sampler : SamplerSettings, optional
        How the fit is sampled (default :class:`SamplerSettings`, the defaults of every
        command; ignored with ``fit`` but for its seed). ``sampler.seed`` seeds the fit,
        the choice of draws and the residual series; a virtual plant's sensor noise at
        the ``k``-th reference is drawn from ``numpy.random.default_rng([seed, k, 1])``
        (the same for every command): same seed, same result.
    validation : Dataset or Record, optional
        Measured records the model was *not* fitted on, driven along paths like the
        commands' (minor loops, another amplitude): the bands then resample their
        residual -- measurement minus the posterior's mean prediction from their own
        input -- instead of the training residual, so that they carry the error a
        command shows on paths the identification data never drove. Default: the
        training residual.
    discrepancy : {"none", "hsgp"}, optional
        Fit with a model discrepancy (ignored with ``fit``, which carries its own): the
        commands are then designed against model + discrepancy and the bands predicted
        from both (:func:`~bayeshyst.inverse.feedforward.design_feedforward`).
    nominal_inverse : {"numerical", "closed_form"}
        How the nominal command inverts the MAP: per-sample root finding (default), or
        the model's closed-form inverse where it has one (``has_inverse``: ``pi_play``,
        ``mbw``, ``bouc_wen``, ``bouc_wen_asym``, ``duhem``;
        :mod:`~bayeshyst.inverse.closed_form`), not with a discrepancy.
    discrepancy_transfer : float
        With a discrepancy and no ``validation``: the probability that the discrepancy
        learned on the identification loops holds along the commands' paths (default
        0.5, even odds); the bands mix the two cases
        (:class:`~bayeshyst.inverse.feedforward.PredictionError`). 1 trusts it
        everywhere -- right only when the commands run the identification data's
        paths. Ignored without a discrepancy and with ``validation`` (which measures it).
    n_jobs : int, optional
        Worker processes the references are evaluated in (:mod:`bayeshyst.workers`);
        default one per core, 1 evaluates them one after the other in this process. The
        result does not depend on it: every reference draws from its own random
        streams, and workers and this process compute with the same (serial) kernels
        and single-threaded BLAS.

    Returns
    -------
    CompensationResult
    """
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if isinstance(validation, Record):
        validation = Dataset((validation,), name=validation.name)
    sampler = SamplerSettings() if sampler is None else sampler
    if not isinstance(sampler, SamplerSettings):
        raise ParameterError(f"sampler must be a SamplerSettings, got {type(sampler).__name__}")
    seed = sampler.seed
    for name, value, low in (("cycles", cycles, 1), ("warmup_cycles", warmup_cycles, 0),
                             ("n_design_draws", n_design_draws, 1),
                             ("n_predict_draws", n_predict_draws, 10),
                             ("n_plants", n_plants, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ParameterError(f"{name} must be an integer >= {low}, got {value!r}")
    if not (math.isfinite(u_margin) and u_margin >= 0):
        raise ParameterError(f"u_margin must be >= 0, got {u_margin}")
    if not 0.0 < robust_quantile < 1.0:
        raise ParameterError(f"robust_quantile must be in (0, 1), got {robust_quantile}")
    # before the fit, not after it
    check_transfer_probability(discrepancy_transfer)
    if nominal_inverse not in NOMINAL_INVERSES:
        raise ParameterError(f"nominal_inverse must be one of {NOMINAL_INVERSES}, "
                             f"got {nominal_inverse!r}")
    if nominal_inverse == "closed_form":
        # refused before the fit, not after it
        check_closed_form(get_model(model) if isinstance(model, str) else model)
    if fit is not None:
        wanted = get_model(model) if isinstance(model, str) else model
        if wanted.name != fit.posterior.model.name:
            raise ParameterError(f"fit is a posterior of {fit.posterior.model.name!r}, not of "
                                 f"the model asked for, {wanted.name!r}")
    else:
        fit = fit_model(data, model, likelihood, sampler=sampler, discrepancy=discrepancy)
    post = fit.posterior
    model = post.model
    if plant is None:
        plant = virtual_plant(data) or "posterior"
    elif isinstance(plant, str) and plant != "posterior":
        raise ParameterError(f"plant must be a VirtualActuator, 'posterior' or None, "
                             f"got {plant!r}")
    virtual = isinstance(plant, VirtualActuator)
    sizes = (n_design_draws, n_predict_draws) + (() if virtual else (n_plants,))
    design, predict, *rest = _split_draws(fit, sizes, seed)
    nominal = Draws.of(post, fit.sampling.start.z)
    if nominal_inverse == "closed_form":
        check_closed_form(model, nominal)
    # what the fit leaves unexplained: the training residual about the posterior mean,
    # resampled onto every command so that the bands predict a measured error (and,
    # with a discrepancy, whether it holds along the commands: see PredictionError)
    z_mean = fit.sampling.draws(RESIDUAL_DRAWS, seed=seed)
    errors = (PredictionError.of(post, z_mean, transfer=discrepancy_transfer)
              if validation is None
              else PredictionError.measured(_validation_residual(post, z_mean, validation)))
    if virtual:
        plant_text = (f"virtual actuator ({', '.join(plant.effects)}), the simulator that "
                      "generated the data, measured with its sensor noise")
        run_plant: VirtualPlant | PosteriorPlant = VirtualPlant(plant)
    else:
        plants = rest[0]
        plant_text = (f"{plants.size} posterior draws of {model.name} held out from design "
                      "and prediction, each with a resampled residual (no ground truth: "
                      "this measures how the model's uncertainty propagates, not how well "
                      "it fits the actuator)")
        run_plant = PosteriorPlant(model, plants, errors)
    u_limits = command_limits(data, u_margin)
    refs = design_references(data, reference, cycles=cycles, warmup_cycles=warmup_cycles)
    tasks = [(model, ref, group, nominal, design, predict, run_plant, u_limits,
              robust_quantile, virtual, errors, (seed, k), nominal_inverse)
             for k, (ref, group) in enumerate(refs)]
    n_workers = resolve_jobs(n_jobs, len(tasks))
    if n_workers == 1:
        rows = [evaluate_reference(*task) for task in tasks]
    else:
        # the references are independent (each draws from its own streams): one task
        # each, the rows back in reference order
        with process_pool(n_workers) as pool:
            rows = list(pool.map(evaluate_reference, *zip(*tasks, strict=True)))
    for row in rows:
        _log.info("%s: realised tracking NRMSE %.3g %% (posterior command), band "
                  "[%.3g, %.3g] %%", row.label, row.posterior_nrmse_percent,
                  *row.predicted_band_percent)
    statements = _trend_statements(rows, model.name, model.rate_dependent, errors)
    settings = {"reference": reference.kind if isinstance(reference, Reference) else reference,
                "cycles": cycles, "warmup_cycles": warmup_cycles,
                "n_design_draws": n_design_draws, "n_predict_draws": n_predict_draws,
                "n_plants": 0 if virtual else n_plants, "robust_quantile": robust_quantile,
                "band": BAND, "u_limits": list(u_limits), "seed": seed,
                "residual_from": ("training records" if validation is None else
                                  "validation records: "
                                  + ", ".join(r.name for r in validation)),
                "percent_of": "peak-to-peak of the reference",
                "nominal_inverse": nominal_inverse,
                "discrepancy_transfer": errors.transfer if errors.without is not None else None}
    return CompensationResult(model.name, plant_text,
                              "virtual actuator" if virtual else "posterior draw",
                              tuple(rows), tuple(statements), bool(fit.converged), settings)


