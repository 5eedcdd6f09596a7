"""A feedforward command from a saved fit, without refitting (``bayeshyst invert``).

:func:`design_command` takes a posterior read back with
:func:`~bayeshyst.inference.saved.load_fit` and a reference trajectory and returns the
command with what the posterior predicts it does: the output's 90 % band sample by
sample and the tracking NRMSE's 90 % range, from posterior draws held out from the
design. The objectives are those of ``bayeshyst compensate``:

* ``nominal`` -- the inverse of the MAP model;
* ``mean`` -- the posterior-mean output follows the reference;
* ``robust`` -- the ``q``-quantile over draws of ``|y - y_d|`` is smallest.

With a discrepancy in the fit the command is designed against model + discrepancy
(:func:`~bayeshyst.inverse.feedforward.design_feedforward`); the robust one hedges over
whether the discrepancy holds along the command, the two hypotheses its band mixes
(:meth:`~bayeshyst.inverse.feedforward.PredictionError.hedged`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.inference.residual import RESIDUAL_DRAWS
from bayeshyst.inference.saved import SavedFit
from bayeshyst.inverse.feedforward import (
    BAND,
    DISCREPANCY_TRANSFER,
    Draws,
    PredictionError,
    design_feedforward,
)
from bayeshyst.inverse.references import U_MARGIN, Reference, command_limits
from bayeshyst.models.compose import model_spec
from bayeshyst.tables import TableRecord

__all__ = ["OBJECTIVES", "CommandDesign", "design_command"]

#: what ``--objective`` chooses
OBJECTIVES = ("nominal", "mean", "robust")


@dataclass(frozen=True)
class CommandDesign(TableRecord):
    """A command for one reference and what the posterior predicts it does.

    Attributes
    ----------
    model : str
        The fitted model's spec string.
    objective : str
        ``"nominal"``, ``"mean"`` or ``"robust"``.
    reference : str
        The reference's name (its file).
    t, y_d, u : ndarray, shape (N,)
        Times (s), reference (output unit), command (input unit).
    y_mean, y_lo, y_hi : ndarray, shape (N,)
        Predicted output under ``u``: the mean over the prediction draws (noise-free,
        discrepancy included when the fit has one) and the 90 % band of a measurement
        (each draw plus the fit's residual resampled in whole cycles).
    predicted_band_percent : (float, float)
        90 % range of the predicted tracking NRMSE of a measurement (% of the
        reference's stroke): parameters, discrepancy and the fit's residual.
    model_error_percent : float
        The inverter's own check: max ``|model output - y_d|`` (design draws' mean, or
        the MAP's) in % of stroke.
    n_saturated : int
        Samples where the command hit ``u_limits``.
    u_limits : (float, float)
        The admissible command range (the fit's data input range widened by 25 % of its
        span at each end, input unit).
    n_design_draws, n_predict_draws : int
    fit_converged : bool
        Whether the fit's sampler converged (a command from an unconverged posterior is
        a warning, not a result).
    warnings : tuple of str
    """

    model: str
    objective: str
    reference: str
    t: np.ndarray = field(repr=False)
    y_d: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    y_mean: np.ndarray = field(repr=False)
    y_lo: np.ndarray = field(repr=False)
    y_hi: np.ndarray = field(repr=False)
    predicted_band_percent: tuple[float, float]
    model_error_percent: float
    n_saturated: int
    u_limits: tuple[float, float]
    n_design_draws: int
    n_predict_draws: int
    fit_converged: bool
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the trajectories are in :meth:`to_dataframe`)."""
        return {"model": self.model, "objective": self.objective,
                "reference": self.reference, "n_samples": int(self.t.size),
                "predicted_band_percent": list(self.predicted_band_percent),
                "model_error_percent": self.model_error_percent,
                "n_saturated": self.n_saturated, "u_limits": list(self.u_limits),
                "u_range": [float(self.u.min()), float(self.u.max())],
                "n_design_draws": self.n_design_draws,
                "n_predict_draws": self.n_predict_draws,
                "fit_converged": self.fit_converged, "warnings": list(self.warnings)}

    def to_dataframe(self) -> Any:
        """Columns ``t, u, y_d, y_mean, y_lo, y_hi`` (pandas), one row per sample."""
        import pandas as pd

        return pd.DataFrame({"t": self.t, "u": self.u, "y_d": self.y_d, "y_mean": self.y_mean,
                             "y_lo": self.y_lo, "y_hi": self.y_hi})

    def __str__(self) -> str:
        lo, hi = self.predicted_band_percent
        lines = [f"{self.objective} command for {self.reference} from {self.model}: "
                 f"{self.t.size} samples, u in [{self.u.min():.4g}, {self.u.max():.4g}]; "
                 f"predicted tracking NRMSE 90 % range [{lo:.3g}, {hi:.3g}] % of stroke; "
                 f"inverter's own error {self.model_error_percent:.2g} %"]
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def design_command(fit: SavedFit, reference: Reference, *, objective: str = "mean",
                   n_design_draws: int = 24, n_predict_draws: int = 100,
                   quantile: float = 0.9, u_margin: float = U_MARGIN,
                   seed: int = 0,
                   discrepancy_transfer: float = DISCREPANCY_TRANSFER) -> CommandDesign:
    """The command that makes the saved fit's model follow ``reference``.

    Parameters
    ----------
    fit : SavedFit
        From :func:`~bayeshyst.inference.saved.load_fit`.
    reference : Reference
        The trajectory (output unit; e.g. :func:`~bayeshyst.inverse.references.
        load_reference`).
    objective : {"nominal", "mean", "robust"}
    n_design_draws, n_predict_draws : int
        Posterior draws the command is designed on (``mean``/``robust``) and, disjoint
        from them, the draws its band is predicted from.
    quantile : float
        ``q`` of the robust objective, in (0, 1).
    u_margin : float
        Command limits: the fit's input range widened by this fraction of its span.
    seed : int
        Seeds the choice of draws: same seed, same command.
    discrepancy_transfer : float
        With a discrepancy: the probability that it holds along the reference's paths,
        in [0, 1] (default 0.5; :class:`~bayeshyst.inverse.feedforward.PredictionError`).

    Returns
    -------
    CommandDesign

    Raises
    ------
    ParameterError
        For an unknown objective, bad counts, or more draws asked for than stored.
    """
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    for name, value in (("n_design_draws", n_design_draws), ("n_predict_draws", n_predict_draws)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ParameterError(f"{name} must be a positive integer, got {value!r}")
    if not 0.0 < quantile < 1.0:
        raise ParameterError(f"quantile must be in (0, 1), got {quantile}")
    post = fit.posterior
    n_design = 0 if objective == "nominal" else n_design_draws
    if n_design + n_predict_draws > fit.n_draws:
        raise ParameterError(f"{fit.path}: {fit.n_draws} stored draws, {n_design} design + "
                             f"{n_predict_draws} prediction draws asked for")
    z = fit.draws(n_design + n_predict_draws, seed=seed)
    z = z[np.random.default_rng(seed).permutation(z.shape[0])]
    predict = Draws.of(post, z[n_design:])
    design = Draws.of(post, fit.map_z[None, :] if objective == "nominal" else z[:n_design])
    t, y_d, mask, stroke = reference.t, reference.y_d, reference.scored, reference.stroke
    limits = command_limits(post.data, u_margin)
    # the band predicts a measured error: the fit's unexplained residual, resampled in
    # whole cycles, is added to every prediction draw (see inference.residual)
    errors = PredictionError.of(post, z[n_design:][: RESIDUAL_DRAWS],
                                transfer=discrepancy_transfer)
    predict, resid = errors.apply(predict, t.size, reference.frequency_hz,
                                  np.random.default_rng([seed, 1]))
    # a model that reads a measured column is designed at the reference's values of it
    # (the conditions the command will run at); without them, at nominal conditions
    needed = tuple(post.model.covariates)
    given = reference.covariates or {}
    missing = [c for c in needed if c not in given]
    covariates = None if missing or not needed else {c: given[c] for c in needed}
    if objective == "robust":  # hedged over whether the discrepancy holds, as its band
        design = errors.hedged(design)
    ff = design_feedforward(post.model, y_d, t, design, predict, label=objective,
                            objective="quantile" if objective == "robust" else "mean",
                            quantile=quantile, u_limits=limits, periodic=reference.periodic,
                            scored=mask, frequency_hz=reference.frequency_hz, residual=resid,
                            covariates=covariates)
    lo, hi = ff.band()
    ok = np.all(np.isfinite(ff.predicted), axis=1)
    band = np.quantile(ff.error_distribution(y_d, stroke, mask), [(1 - BAND) / 2, (1 + BAND) / 2])
    warnings = list(fit.warnings)
    if missing:
        warnings.append(f"the model reads the measured column(s) {missing}, which the "
                        f"reference {reference.kind} does not give (its columns: "
                        f"{sorted(given) or 'none'}): the command is designed for the "
                        "fitted data's mean conditions")
    y_all = np.concatenate([r.y for r in post.data])
    outside = (y_d < y_all.min()) | (y_d > y_all.max())
    if outside.any():
        warnings.append(f"the reference leaves the fitted data's output range "
                        f"[{y_all.min():.4g}, {y_all.max():.4g}] at {int(outside.sum())} of "
                        f"{y_d.size} samples: the model extrapolates there")
    inv = ff.inversion  # a designed command always has its inversion
    if inv.n_saturated:
        warnings.append(f"the command saturates at the limits [{limits[0]:.4g}, "
                        f"{limits[1]:.4g}] at {inv.n_saturated} samples: the reference is "
                        "out of the actuator's reach there")
    if int(ok.sum()) < predict.size:
        warnings.append(f"{predict.size - int(ok.sum())} of {predict.size} prediction draws "
                        "failed to simulate under the command (left out of the band)")
    return CommandDesign(
        model=model_spec(post.model), objective=objective, reference=reference.kind,
        t=t, y_d=y_d, u=ff.u, y_mean=np.mean(ff.predicted[ok], axis=0), y_lo=lo, y_hi=hi,
        predicted_band_percent=(float(band[0]), float(band[1])),
        model_error_percent=float(100.0 * inv.max_error / stroke),
        n_saturated=int(inv.n_saturated), u_limits=limits,
        n_design_draws=design.size, n_predict_draws=predict.size,
        fit_converged=fit.converged, warnings=tuple(warnings))
