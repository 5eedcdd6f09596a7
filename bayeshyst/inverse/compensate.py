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
from collections.abc import Mapping
from dataclasses import dataclass, field
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
from bayeshyst.inverse.closed_form import (
    NOMINAL_INVERSES,
    check_closed_form,
    closed_form_feedforward,
)
from bayeshyst.inverse.feedforward import (
    BAND,
    DISCREPANCY_TRANSFER,
    Draws,
    Feedforward,
    PredictionError,
    check_transfer_probability,
    design_feedforward,
    predict_outputs,
    predict_record,
    tracking_percent,
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

__all__ = ["CompensationResult", "CompensationRow", "compensate"]

_log = logging.getLogger(__name__)

# ------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class CompensationRow(TableRecord):
    """Tracking errors at one frequency (all in % of the reference's stroke).

    Attributes
    ----------
    frequency_hz : float or None
    reference : str
    uncompensated_nrmse_percent, uncompensated_max_percent : float
        The scaled input (a straight line fitted to the measured loop, inverted).
    nominal_nrmse_percent, nominal_max_percent : float
        The exact inverse of the MAP.
    posterior_nrmse_percent, posterior_max_percent : float
        The posterior-mean inverse.
    robust_nrmse_percent, robust_max_percent : float
        The robust inverse (smallest ``robust_quantile`` of ``|error|`` over draws).
    predicted_band_percent : (float, float)
        Central 90 % interval of the posterior command's tracking NRMSE predicted from
        held-out draws.
    nominal_predicted_band_percent : (float, float)
        The same for the nominal command.
    realised_inside_band : bool
        Whether the plant's NRMSE under the posterior command lies in that interval.
    output_coverage : float
        Fraction of scored samples where the plant's output lies in the predicted 90 %
        pointwise output band.
    plants_inside_band : float or None
        With posterior-draw plants: the fraction of held-out plants whose NRMSE lies in
        the band (≈ 0.9 when the uncertainty is propagated correctly).
    mean_over_plants : dict or None
        With posterior-draw plants: the mean NRMSE over plants of each command.
    n_saturated : int
        Samples where a designed command hit the command limits.
    model_error_percent : float
        Largest deviation of the model's own (posterior-mean) output from the reference
        under the posterior command: how exactly the inverse was computed.
    parameter_band_percent : (float, float)
        The 90 % NRMSE interval of the posterior command from the parameters alone
        (noise-free outputs, the discrepancy left out).
    model_band_percent : (float, float)
        The same from parameters and discrepancy (noise-free outputs); with
        ``parameter_band_percent`` and ``predicted_band_percent`` (parameters,
        discrepancy and the resampled residual) the tracking band's budget.
    residual_rms_percent : float
        RMS of the training residual resampled onto the command (% of stroke): what the
        fit leaves unexplained (sensor noise and unmodelled structure).
    curves : dict
        ``t``, ``y_d``, ``scored``, the commands ``u_<label>``, the plant outputs
        ``y_<label>`` (the first plant), the tracking NRMSE on every plant
        ``nrmse_<label>`` and the 90 % band ``band_lo``/``band_hi`` of the posterior
        command, for figures and paired comparisons (not in :meth:`to_dict`).
    """

    frequency_hz: float | None
    reference: str
    uncompensated_nrmse_percent: float
    uncompensated_max_percent: float
    nominal_nrmse_percent: float
    nominal_max_percent: float
    posterior_nrmse_percent: float
    posterior_max_percent: float
    robust_nrmse_percent: float
    robust_max_percent: float
    predicted_band_percent: tuple[float, float]
    nominal_predicted_band_percent: tuple[float, float]
    realised_inside_band: bool
    output_coverage: float
    plants_inside_band: float | None
    mean_over_plants: dict[str, float] | None
    n_saturated: int
    model_error_percent: float
    parameter_band_percent: tuple[float, float] = (0.0, 0.0)
    model_band_percent: tuple[float, float] = (0.0, 0.0)
    residual_rms_percent: float = 0.0
    curves: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict` (bands as ``_lo``/``_hi`` columns)."""
        return frame([self.to_dict()], drop=("mean_over_plants",))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (no curves)."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "curves"}
        out["predicted_band_percent"] = list(self.predicted_band_percent)
        out["nominal_predicted_band_percent"] = list(self.nominal_predicted_band_percent)
        out["model_band_percent"] = list(self.model_band_percent)
        out["parameter_band_percent"] = list(self.parameter_band_percent)
        return out

    @property
    def label(self) -> str:
        """``"10 Hz"`` or the reference name."""
        return self.reference if self.frequency_hz is None else f"{self.frequency_hz:g} Hz"

    def __str__(self) -> str:
        lo, hi = self.predicted_band_percent
        inside = "inside" if self.realised_inside_band else "OUTSIDE"
        return (f"{self.label:>10}  none {self.uncompensated_nrmse_percent:7.3f}  nominal "
                f"{self.nominal_nrmse_percent:7.3f}  posterior {self.posterior_nrmse_percent:7.3f}"
                f"  robust {self.robust_nrmse_percent:7.3f}  band [{lo:.3f}, {hi:.3f}] "
                f"{inside}")


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


def _interval(values: np.ndarray) -> tuple[float, float]:
    """Central :data:`BAND` interval of ``values``."""
    lo, hi = np.quantile(values, [(1 - BAND) / 2, (1 + BAND) / 2])
    return float(lo), float(hi)


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


def _scaled_input(records: Dataset) -> tuple[float, float]:
    """``(a, b)`` of the least-squares line ``y = a + b u`` through the measured loops."""
    u = np.concatenate([r.u[r.scored] for r in records])
    y = np.concatenate([r.y[r.scored] for r in records])
    b, a = np.polyfit(u, y, 1)
    if not b != 0:
        raise DataError(f"{records.name}: output does not change with the input")
    return float(a), float(b)


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
        def run_plant(t: np.ndarray, u: np.ndarray, f: float | None,
                      rng: np.random.Generator) -> np.ndarray:
            return plant.simulate(t, u, rng=rng)[None, :]
    else:
        plants = rest[0]
        plant_text = (f"{plants.size} posterior draws of {model.name} held out from design "
                      "and prediction, each with a resampled residual (no ground truth: "
                      "this measures how the model's uncertainty propagates, not how well "
                      "it fits the actuator)")
        def run_plant(t: np.ndarray, u: np.ndarray, f: float | None,
                      rng: np.random.Generator) -> np.ndarray:
            drawn, resid = errors.apply(plants, t.size, f, rng)
            return predict_outputs(model, u, t, drawn, f) + resid
    u_limits = command_limits(data, u_margin)
    refs = design_references(data, reference, cycles=cycles, warmup_cycles=warmup_cycles)
    rows = []
    for k, (ref, group) in enumerate(refs):
        rows.append(_evaluate(model, ref, group, nominal, design, predict, run_plant,
                              u_limits, robust_quantile, virtual, errors, (seed, k),
                              nominal_inverse))
        _log.info("%s: realised tracking NRMSE %.3g %% (posterior command), band "
                  "[%.3g, %.3g] %%", rows[-1].label, rows[-1].posterior_nrmse_percent,
                  *rows[-1].predicted_band_percent)
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


def _evaluate(model: HysteresisModel, ref: Reference, group: Dataset, nominal: Draws,
              design: Draws, predict: Draws, run_plant: Any, u_limits: tuple[float, float],
              q: float, virtual: bool, errors: PredictionError,
              key: tuple[int, int], nominal_inverse: str = "numerical") -> CompensationRow:
    t, y_d, mask, stroke = ref.t, ref.y_d, ref.scored, ref.stroke
    a, b = _scaled_input(group)
    u_scaled = (y_d - a) / b
    f = ref.frequency_hz
    # one residual series per prediction draw, shared by the four commands (and one
    # plant noise stream, below), so their errors differ by the commands alone
    # (with a discrepancy, a share of the prediction draws drops it: PredictionError)
    predict, resid = errors.apply(predict, t.size, f, np.random.default_rng([*key, 0]))
    commands: dict[str, Feedforward] = {
        "uncompensated": Feedforward("uncompensated", u_scaled,
                                     predict_outputs(model, u_scaled, t, predict, f),
                                     residual=resid),
    }
    common: Mapping[str, Any] = {"u_limits": u_limits, "periodic": ref.periodic,
                                 "scored": mask, "frequency_hz": f, "residual": resid}
    if nominal_inverse == "closed_form":
        commands["nominal"] = closed_form_feedforward(
            model, y_d, t, nominal, predict, label="nominal", u_limits=u_limits,
            scored=mask, frequency_hz=f, residual=resid)
    else:
        commands["nominal"] = design_feedforward(model, y_d, t, nominal, predict,
                                                 label="nominal", **common)
    commands["posterior"] = design_feedforward(model, y_d, t, design, predict,
                                               label="posterior", **common)
    # the robust command hedges over whether the discrepancy holds along it, as its band
    commands["robust"] = design_feedforward(model, y_d, t, errors.hedged(design), predict,
                                            label="robust", objective="quantile", quantile=q,
                                            **common)
    curves: dict[str, np.ndarray] = {"t": t, "y_d": y_d, "scored": mask}
    realised: dict[str, tuple[float, float]] = {}
    over_plants: dict[str, float] = {}
    for label, ff in commands.items():
        y_plant = run_plant(t, ff.u, f, np.random.default_rng([*key, 1]))
        nrmse, mx = tracking_percent(y_plant, y_d, stroke, mask)
        realised[label] = (float(nrmse[0]), float(mx[0]))
        over_plants[label] = float(np.mean(nrmse))
        curves[f"nrmse_{label}"] = nrmse
        curves[f"u_{label}"] = ff.u
        curves[f"y_{label}"] = y_plant[0]
        if label == "posterior":
            posterior_plants = nrmse
    post_ff = commands["posterior"]
    band_lo, band_hi = post_ff.band()
    curves["band_lo"], curves["band_hi"] = band_lo, band_hi
    lo, hi = np.quantile(post_ff.error_distribution(y_d, stroke, mask),
                         [(1 - BAND) / 2, (1 + BAND) / 2])
    nlo, nhi = np.quantile(commands["nominal"].error_distribution(y_d, stroke, mask),
                           [(1 - BAND) / 2, (1 + BAND) / 2])
    alone = (post_ff.predicted if predict.delta is None else
             predict_outputs(model, post_ff.u, t, Draws(predict.theta, predict.offset)))
    ok = np.all(np.isfinite(alone), axis=1)
    param_band = _interval(tracking_percent(alone[ok], y_d, stroke, mask)[0])
    model_band = _interval(post_ff.error_distribution(y_d, stroke, mask, residual=False))
    y_post = curves["y_posterior"]
    inside = (y_post >= band_lo) & (y_post <= band_hi)
    posterior_plants = curves["nrmse_posterior"]
    return CompensationRow(
        frequency_hz=ref.frequency_hz, reference=ref.kind,
        uncompensated_nrmse_percent=realised["uncompensated"][0],
        uncompensated_max_percent=realised["uncompensated"][1],
        nominal_nrmse_percent=realised["nominal"][0],
        nominal_max_percent=realised["nominal"][1],
        posterior_nrmse_percent=realised["posterior"][0],
        posterior_max_percent=realised["posterior"][1],
        robust_nrmse_percent=realised["robust"][0],
        robust_max_percent=realised["robust"][1],
        predicted_band_percent=(float(lo), float(hi)),
        nominal_predicted_band_percent=(float(nlo), float(nhi)),
        realised_inside_band=bool(lo <= realised["posterior"][0] <= hi),
        output_coverage=float(np.mean(inside[mask])),
        plants_inside_band=(None if virtual else
                            float(np.mean((posterior_plants >= lo) & (posterior_plants <= hi)))),
        mean_over_plants=None if virtual else over_plants,
        n_saturated=int(sum(ff.inversion.n_saturated for ff in commands.values()
                            if ff.inversion is not None)),
        # the inverter's own forward check: max |posterior-mean output - y_d| when scored
        model_error_percent=float(100.0 * post_ff.inversion.max_error / stroke),
        parameter_band_percent=param_band,
        model_band_percent=model_band,
        residual_rms_percent=float(100.0 * np.sqrt(np.mean(resid[:, mask] ** 2)) / stroke),
        curves=curves,
    )
