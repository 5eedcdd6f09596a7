"""Posterior-aware feedforward: commands designed from posterior draws, with predicted bands.

Three commands for one reference ``y_d`` (MODELS.md §8):

* **nominal** -- the exact inverse of one parameter vector (the MAP);
* **posterior** -- the command whose *posterior-mean* output meets ``y_d`` (all design
  draws' states carried together, :func:`~bayeshyst.inverse.numerical.invert`);
* **robust** -- the command minimising a chosen quantile over draws of ``|y - y_d|``.

Each is then *predicted* on a separate set of posterior draws (not the ones it was
designed on, so the band is not flattered by the design): the pointwise output band
and the distribution of the tracking error that a plant drawn from the posterior
would show.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.posterior import record_covariates
from bayeshyst.inference.residual import ResidualBlocks
from bayeshyst.inverse.numerical import Inversion, invert
from bayeshyst.models.base import HysteresisModel
from bayeshyst.tables import TableRecord, frame

__all__ = [
    "BAND",
    "DISCREPANCY_TRANSFER",
    "Draws",
    "Feedforward",
    "PredictionError",
    "check_transfer_probability",
    "design_feedforward",
    "predict_outputs",
    "predict_record",
    "tracking_percent",
]

#: Probability of the predicted bands (5-95 %).
BAND = 0.9
#: Most fixed-point rounds of a design against a model with a discrepancy.
DISCREPANCY_ROUNDS = 4
#: Prior probability that a discrepancy learned on the identification loops holds along
#: a new input's paths, when no record with such paths measures it: even odds.
DISCREPANCY_TRANSFER = 0.5


@dataclass(frozen=True)
class Draws:
    """Parameter vectors of a model with their observation offsets (and discrepancy).

    Attributes
    ----------
    theta : dict
        ``name -> array (S, *shape)``, the model's parameters.
    offset : ndarray, shape (S,)
        Observation offsets added to the model output (zeros without one).
    discrepancy : Discrepancy, optional
        The fit's model-discrepancy term; its basis is evaluated on each command.
    delta : ndarray, shape (S, m), optional
        Each draw's discrepancy coefficients (``s * xi``).
    """

    theta: dict[str, np.ndarray]
    offset: np.ndarray
    discrepancy: Any = None
    delta: np.ndarray | None = None

    @classmethod
    def of(cls, post: Any, z: np.ndarray) -> Draws:
        """The draws of a posterior's points ``z`` (W, ndim).

        The model's parameters, the offsets and (with one) the discrepancy's coefficients:
        the discrepancy is a function of the input's history alone, so it transfers to a
        command.
        """
        theta, offset = post.model_draws(z)
        return cls(theta, offset, post.discrepancy, post.discrepancy_coefficients(z))

    def delta_on(self, u: np.ndarray, frequency_hz: float | None) -> np.ndarray | float:
        """The discrepancy ``(S, N)`` of every draw along the command ``u``; 0 without one."""
        if self.discrepancy is None or self.delta is None:
            return 0.0
        return self.delta @ self.discrepancy.basis(u, frequency_hz).T

    @property
    def size(self) -> int:
        """Number of draws ``S``."""
        return int(self.offset.size)


@dataclass(frozen=True)
class PredictionError(TableRecord):
    """What a measurement adds to a prediction draw's output on a new input.

    Two things: the residual the fit leaves unexplained, resampled onto the input
    (:class:`~bayeshyst.inference.residual.ResidualBlocks`), and -- with a model
    discrepancy -- whether ``delta`` holds along the new input at all. ``delta`` is
    learned on the identification loops; a feedforward command runs other paths (minor
    loops, another amplitude), and on the bundled virtual actuator the command designed
    with ``delta`` tracked 2-5x worse than its band said (2 of 16 cases inside), while a
    leave-one-frequency-out check showed ``delta`` transferring well between the
    training frequencies (held-out residual 0.24 µm against 0.17 µm in-sample at 50 and
    100 Hz): what fails is the transfer to new *paths*, which records of one path
    cannot measure. So the prediction is a mixture of two hypotheses:

    * **transfers** (probability :attr:`transfer`): the draw keeps its ``delta`` and
      its measurement adds the residual of model + ``delta``;
    * **does not transfer**: the draw drops ``delta`` and adds the residual of the
      model alone -- the command's misfit along its paths is then a fresh draw of the
      model's misfit, unrelated to the ``delta`` it was designed against.

    With no record to weigh them the odds are even (:data:`DISCREPANCY_TRANSFER`); a
    validation record with the command's paths measures the transfer instead
    (:meth:`measured`: its residual, every draw keeping ``delta``). Without a
    discrepancy this is the residual alone.

    Attributes
    ----------
    residual : ResidualBlocks
        About the mean prediction (model + ``delta`` with a discrepancy).
    without : ResidualBlocks or None
        About the mean of the model alone; None when the transfer is not in question
        (no discrepancy, or measured).
    transfer : float
        Probability that ``delta`` holds along a new input, in [0, 1].
    """

    residual: ResidualBlocks
    without: ResidualBlocks | None = None
    transfer: float = 1.0

    def __post_init__(self) -> None:
        check_transfer_probability(self.transfer)

    @classmethod
    def of(cls, post: Any, z: np.ndarray, *,
           transfer: float = DISCREPANCY_TRANSFER) -> PredictionError:
        """From a posterior's training residual about the draws ``z`` (S, ndim)."""
        residual = ResidualBlocks.of(post, z)
        if post.discrepancy is None:
            return cls(residual)
        return cls(residual, ResidualBlocks.of(post, z, discrepancy=False), float(transfer))

    @classmethod
    def measured(cls, residual: ResidualBlocks) -> PredictionError:
        """A residual measured on records with the new input's paths (the transfer known)."""
        return cls(residual)

    @property
    def mixed(self) -> bool:
        """Whether some draws drop the discrepancy."""
        return self.without is not None and self.transfer < 1.0

    def split(self, draws: Draws) -> list[tuple[Draws, ResidualBlocks]]:
        """The draws as predicted on a new input, each part with the residual it takes.

        The first ``round(transfer * S)`` draws keep ``delta`` (the draws come in a
        random order) with the residual of model + ``delta``; the others drop it and
        take the model-alone residual. Empty parts are left out.
        """
        if not self.mixed or draws.delta is None:
            return [(draws, self.residual)]
        keep = round(self.transfer * draws.size)
        mixed = self.hedged(draws)
        parts = [(_take_draws(mixed, slice(0, keep)), self.residual),
                 (_take_draws(mixed, slice(keep, draws.size)), self.without)]
        return [(d, r) for d, r in parts if d.size]

    def hedged(self, draws: Draws) -> Draws:
        """The draws with ``delta`` dropped from the share that it does not hold for.

        The first ``round(transfer * S)`` draws keep ``delta``, the others have it set to
        zero (the draws come in a random order): the robust command minimises its error
        quantile over these, hedging over both hypotheses as the band it is scored by
        does. Unchanged when the transfer is not in question.
        """
        if not self.mixed or draws.delta is None:
            return draws
        delta = draws.delta.copy()
        delta[round(self.transfer * draws.size):] = 0.0
        return Draws(draws.theta, draws.offset, draws.discrepancy, delta)

    def apply(self, draws: Draws, n_samples: int, frequency_hz: float | None,
              rng: np.random.Generator) -> tuple[Draws, np.ndarray]:
        """The draws as predicted on a new input and each one's residual ``(S, N)``.

        As :meth:`split`, the parts joined again in the draws' order.
        """
        parts = self.split(draws)
        res = np.concatenate([r.sample(d.size, n_samples, frequency_hz, rng)
                              for d, r in parts])
        if len(parts) == 1:
            return parts[0][0], res
        delta = np.concatenate([d.delta for d, _ in parts])
        return Draws(draws.theta, draws.offset, draws.discrepancy, delta), res

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the residual(s) and the transfer probability."""
        out = {"residual": self.residual.to_dict(),
               "discrepancy_transfer": (None if self.without is None else self.transfer)}
        if self.without is not None:
            out["residual_without_discrepancy"] = self.without.to_dict()
        return out

    def to_dataframe(self) -> Any:
        """One row per hypothesis and frequency: its probability and the residual's RMS."""
        parts = [("model + discrepancy", self.transfer if self.without is not None else 1.0,
                  self.residual)]
        if self.without is not None:
            parts.append(("model alone", 1.0 - self.transfer, self.without))
        return frame([{"hypothesis": name, "probability": p, **row}
                      for name, p, blocks in parts for row in blocks.to_dict()["rows"]])

    def __str__(self) -> str:
        if self.without is None:
            return f"PredictionError({self.residual})"
        return (f"PredictionError(discrepancy holds with probability {self.transfer:g}; "
                f"with it {self.residual}; without it {self.without})")


def check_transfer_probability(value: Any) -> float:
    """``value`` as a discrepancy-transfer probability in [0, 1], else ParameterError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not 0.0 <= value <= 1.0:
        raise ParameterError(f"discrepancy_transfer must be a probability in [0, 1], got "
                             f"{value!r}")
    return float(value)


def _take_draws(draws: Draws, rows: slice) -> Draws:
    """The draws ``rows`` of ``draws`` (parameters, offsets, discrepancy coefficients)."""
    return Draws({k: np.asarray(v)[rows] for k, v in draws.theta.items()},
                 draws.offset[rows], draws.discrepancy,
                 None if draws.delta is None else draws.delta[rows])


def predict_outputs(model: HysteresisModel, u: np.ndarray, t: np.ndarray,
                    draws: Draws, frequency_hz: float | None = None,
                    covariates: Mapping[str, Any] | None = None) -> np.ndarray:
    """Noise-free outputs ``(S, N)`` of every draw driven by ``u`` from rest (failed: NaN).

    With a discrepancy in ``draws`` it is added, evaluated along ``u`` at
    ``frequency_hz`` (the reference's). ``covariates`` (``column -> (N,)``) are the
    measured columns a column-reading model runs at (None: nominal conditions).
    """
    return (model.run_batch(u, t, draws.theta, covariates=covariates).y
            + draws.offset[:, None] + draws.delta_on(u, frequency_hz))


def predict_record(model: HysteresisModel, rec: Any, draws: Draws) -> np.ndarray:
    """Outputs ``(S_ok, N)`` of the draws that simulate record ``rec`` from its own input.

    Failed draws are left out; DataError naming the record when none simulates it. A
    model that reads a measured column runs at the record's own column.
    """
    pred = predict_outputs(model, rec.u, rec.t, draws, rec.frequency_hz,
                           record_covariates(model, rec))
    ok = np.all(np.isfinite(pred), axis=1)
    if not ok.any():
        raise DataError(f"{rec.name}: no posterior draw simulates this record")
    return pred[ok]


def tracking_percent(y: np.ndarray, y_d: np.ndarray, stroke: float,
                     mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """RMS and max of ``y - y_d`` in % of ``stroke``, per row of ``y`` (..., N).

    Parameters
    ----------
    y : ndarray, shape (N,) or (S, N)
        Outputs.
    y_d : ndarray, shape (N,)
        Reference.
    stroke : float
        Peak-to-peak output the percentages refer to (> 0).
    mask : ndarray of bool, shape (N,), optional
        Samples scored (e.g. after the warm-up cycle); default all.
    """
    if not stroke > 0:
        raise ParameterError(f"stroke must be positive, got {stroke}")
    e = np.asarray(y, float) - np.asarray(y_d, float)
    if mask is not None:
        e = e[..., mask]
    return (100.0 * np.sqrt(np.mean(e ** 2, axis=-1)) / stroke,
            100.0 * np.max(np.abs(e), axis=-1) / stroke)


@dataclass(frozen=True)
class Feedforward:
    """A feedforward command and what the posterior predicts it does.

    Attributes
    ----------
    label : str
        ``"uncompensated"``, ``"nominal"``, ``"posterior"`` or ``"robust"``.
    u : ndarray, shape (N,)
        The command (input unit).
    predicted : ndarray, shape (P, N)
        Outputs of the prediction draws under ``u`` (noise-free, output unit).
    inversion : Inversion or None
        How the command was found (None for the scaled input).
    residual : ndarray, shape (P, N), optional
        What each prediction draw's *measurement* adds to its noise-free output: the
        fit's unexplained residual resampled onto the command
        (:class:`~bayeshyst.inference.residual.ResidualBlocks`). None: the bands are those
        of the noise-free output (parameters and discrepancy only).
    """

    label: str
    u: np.ndarray
    predicted: np.ndarray
    inversion: Inversion | None = None
    residual: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.residual is not None and np.shape(self.residual) != np.shape(self.predicted):
            raise ParameterError(f"Feedforward({self.label}): residual of shape "
                                 f"{np.shape(self.residual)} for predictions of shape "
                                 f"{np.shape(self.predicted)}")

    @property
    def measured(self) -> np.ndarray:
        """Predicted measurements ``(P, N)``: the outputs plus the residual (if any)."""
        return self.predicted if self.residual is None else self.predicted + self.residual

    def band(self, prob: float = BAND) -> tuple[np.ndarray, np.ndarray]:
        """Pointwise central ``prob`` band ``(lo, hi)`` of the predicted measurement, (N,)."""
        y = self.measured
        ok = np.all(np.isfinite(y), axis=1)
        lo, hi = np.quantile(y[ok], [(1 - prob) / 2, (1 + prob) / 2], axis=0)
        return lo, hi

    def error_distribution(self, y_d: np.ndarray, stroke: float,
                           mask: np.ndarray | None = None, *,
                           residual: bool = True) -> np.ndarray:
        """Predicted tracking NRMSE (% of stroke) of every prediction draw, shape (P,).

        With ``residual`` (default) the error a measurement would show (outputs plus the
        resampled residual); without, the noise-free outputs' error alone.
        """
        y = self.measured if residual else self.predicted
        ok = np.all(np.isfinite(y), axis=1)
        return tracking_percent(y[ok], y_d, stroke, mask)[0]

    def __str__(self) -> str:
        inv = "" if self.inversion is None else f", {self.inversion}"
        return f"Feedforward({self.label}, {self.u.size} samples{inv})"


def design_feedforward(model: HysteresisModel, y_d: Any, t: Any, design: Draws,
                       predict: Draws, *, label: str, objective: str = "mean",
                       quantile: float = 0.9,
                       u_limits: tuple[float, float] = (-np.inf, np.inf),
                       periodic: bool = False, scored: Any = None,
                       frequency_hz: float | None = None,
                       residual: np.ndarray | None = None,
                       covariates: Mapping[str, Any] | None = None) -> Feedforward:
    """Design a command on ``design`` draws and predict it on ``predict`` draws.

    Parameters
    ----------
    model : HysteresisModel
    y_d, t : array_like, shape (N,)
        Reference (output unit) and times (s).
    design : Draws
        One draw (the nominal inverse) or many (posterior-aware).
    predict : Draws
        Draws the command's outputs are predicted on (held out from ``design``).
    label : str
        Name of the command in reports.
    objective, quantile, u_limits, periodic, scored
        As :func:`~bayeshyst.inverse.numerical.invert`.
    frequency_hz : float, optional
        The reference's frequency (where the draws' discrepancy is evaluated).
    residual : ndarray, shape (P, N), optional
        The residual each prediction draw's measurement adds
        (:meth:`~bayeshyst.inference.residual.ResidualBlocks.sample`); see
        :class:`Feedforward`.
    covariates : mapping of str to array_like (N,), optional
        Measured columns along the reference for a model that reads them (designed and
        predicted at those conditions); None: nominal conditions.

    Returns
    -------
    Feedforward
    """
    t = np.asarray(t, float)
    inv = invert(model, y_d, t, design.theta, objective=objective, quantile=quantile,
                 u_limits=u_limits, offset=design.offset, periodic=periodic, scored=scored,
                 covariates=covariates)
    if design.discrepancy is not None and design.delta is not None:
        # the discrepancy depends on the command: a fixed-point iteration, each
        # round inverting the model with the discrepancy along the current command as a
        # known per-sample offset. It converges where the discrepancy's slope in u is
        # below the model's; where it is not (a large, wiggly discrepancy) it need not,
        # so every round is scored by the forward error of model + discrepancy and the
        # best command kept -- the model-only design included, so the result is never
        # worse, under the model with its discrepancy, than ignoring it
        y_target = np.asarray(y_d, float)
        mask = (np.ones(t.size, dtype=bool) if scored is None
                else np.asarray(scored, dtype=bool))

        def forward_error(u: np.ndarray) -> float:
            y = predict_outputs(model, u, t, design, frequency_hz, covariates)
            ok = np.all(np.isfinite(y), axis=1)
            if not ok.any():
                return np.inf
            # rms over the scored samples: the rounds are ranked by how well they track
            # overall, not by their single worst sample
            return float(np.sqrt(np.mean(((np.mean(y[ok], axis=0) - y_target)[mask]) ** 2)))

        best_err, best = forward_error(inv.u), inv
        u = inv.u
        for _ in range(DISCREPANCY_ROUNDS):
            extra = design.offset[:, None] + design.delta_on(u, frequency_hz)
            new = invert(model, y_d, t, design.theta, objective=objective,
                         quantile=quantile, u_limits=u_limits, offset=extra,
                         periodic=periodic, scored=scored, covariates=covariates)
            err = forward_error(new.u)
            if err < best_err:
                best_err, best = err, new
            step = float(np.max(np.abs(new.u - u)))
            u = new.u
            if step <= 1e-6 * (float(np.ptp(u)) or 1.0):
                break
        inv = best
    return Feedforward(label, inv.u,
                       predict_outputs(model, inv.u, t, predict, frequency_hz, covariates),
                       inv, residual)

