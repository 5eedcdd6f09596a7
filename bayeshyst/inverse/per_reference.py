"""One reference of a feedforward evaluation: four commands, their plant runs and bands.

:func:`evaluate_reference` is what :func:`~bayeshyst.inverse.compensate.compensate`
does for each frequency of the data. It reads its arguments only and draws its
randomness from ``numpy.random.default_rng([seed, k, ...])`` with the reference's index
``k``, so the references are independent tasks: ``compensate`` runs them in a process
pool, with the same result as one after the other. The plants it runs the commands on
are picklable objects for that reason (:class:`VirtualPlant`, :class:`PosteriorPlant`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.virtual import VirtualActuator
from bayeshyst.errors import DataError
from bayeshyst.inverse.closed_form import closed_form_feedforward
from bayeshyst.inverse.feedforward import (
    BAND,
    Draws,
    Feedforward,
    PredictionError,
    design_feedforward,
    predict_outputs,
    tracking_percent,
)
from bayeshyst.inverse.references import Reference
from bayeshyst.models.base import HysteresisModel
from bayeshyst.tables import TableRecord, frame
from bayeshyst.threads import single_threaded_blas

__all__ = ["CompensationRow", "PosteriorPlant", "VirtualPlant", "evaluate_reference"]


@dataclass(frozen=True)
class VirtualPlant:
    """The virtual actuator that generated the data, measured with its sensor noise.

    Attributes
    ----------
    actuator : VirtualActuator
    """

    actuator: VirtualActuator

    def __call__(self, t: np.ndarray, u: np.ndarray, frequency_hz: float | None,
                 rng: np.random.Generator) -> np.ndarray:
        """Measured outputs ``(1, N)`` of the actuator driven by ``u`` (N,) at ``t`` (N,) (s).

        ``frequency_hz`` is not used (the actuator has its own dynamics); ``rng`` draws
        the sensor noise.
        """
        return self.actuator.simulate(t, u, rng=rng)[None, :]


@dataclass(frozen=True)
class PosteriorPlant:
    """Held-out posterior draws standing in for the plant, each with a resampled residual.

    Attributes
    ----------
    model : HysteresisModel
    plants : Draws
        The held-out draws, one plant each.
    errors : PredictionError
        What a measurement adds to each plant's output (and whether a discrepancy holds).
    """

    model: HysteresisModel
    plants: Draws
    errors: PredictionError

    def __call__(self, t: np.ndarray, u: np.ndarray, frequency_hz: float | None,
                 rng: np.random.Generator) -> np.ndarray:
        """Measured outputs ``(P, N)`` of every plant driven by ``u`` (N,) at ``t`` (N,) (s).

        ``frequency_hz`` is the reference's (where the residual and the discrepancy are
        taken); ``rng`` draws the residual.
        """
        drawn, resid = self.errors.apply(self.plants, t.size, frequency_hz, rng)
        return predict_outputs(self.model, u, t, drawn, frequency_hz) + resid


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


def _interval(values: np.ndarray) -> tuple[float, float]:
    """Central :data:`BAND` interval of ``values``."""
    lo, hi = np.quantile(values, [(1 - BAND) / 2, (1 + BAND) / 2])
    return float(lo), float(hi)


def _scaled_input(records: Dataset) -> tuple[float, float]:
    """``(a, b)`` of the least-squares line ``y = a + b u`` through the measured loops."""
    u = np.concatenate([r.u[r.scored] for r in records])
    y = np.concatenate([r.y[r.scored] for r in records])
    b, a = np.polyfit(u, y, 1)
    if not b != 0:
        raise DataError(f"{records.name}: output does not change with the input")
    return float(a), float(b)


def evaluate_reference(model: HysteresisModel, ref: Reference, group: Dataset,
                       nominal: Draws, design: Draws, predict: Draws,
                       run_plant: VirtualPlant | PosteriorPlant,
                       u_limits: tuple[float, float], q: float, virtual: bool,
                       errors: PredictionError, key: tuple[int, int],
                       nominal_inverse: str = "numerical") -> CompensationRow:
    """Design the four commands for one reference, run them on the plant, score them.

    Parameters
    ----------
    model : HysteresisModel
        The fitted model.
    ref : Reference
        The reference trajectory (``t`` (N,) (s), ``y_d`` (N,) (output unit), scored
        mask, stroke).
    group : Dataset
        The measured records at the reference's frequency (the uncompensated command's
        straight line is fitted to them).
    nominal, design, predict : Draws
        The MAP, the design draws and the held-out prediction draws.
    run_plant : VirtualPlant or PosteriorPlant
        ``(t, u, frequency_hz, rng) -> (P, N)`` measured plant outputs.
    u_limits : (float, float)
        Command limits (input unit).
    q : float
        Quantile of ``|error|`` the robust command minimises, in (0, 1).
    virtual : bool
        Whether the plant is the virtual actuator (else posterior draws).
    errors : PredictionError
        What a measurement adds to a prediction draw's output.
    key : (int, int)
        ``(seed, k)``: the reference's random streams are
        ``default_rng([seed, k, 0])`` (residuals) and ``default_rng([seed, k, 1])``
        (the plant's noise), whatever process runs it.
    nominal_inverse : {"numerical", "closed_form"}
        How the nominal command inverts the MAP.

    Returns
    -------
    CompensationRow
    """
    # single-threaded BLAS, as in a pool's worker: the products are small, and one
    # configuration everywhere keeps a serial run's bits those of a parallel one
    with single_threaded_blas():
        return _evaluate(model, ref, group, nominal, design, predict, run_plant, u_limits,
                         q, virtual, errors, key, nominal_inverse)


def _evaluate(model: HysteresisModel, ref: Reference, group: Dataset, nominal: Draws,
              design: Draws, predict: Draws, run_plant: VirtualPlant | PosteriorPlant,
              u_limits: tuple[float, float], q: float, virtual: bool,
              errors: PredictionError, key: tuple[int, int],
              nominal_inverse: str) -> CompensationRow:
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

