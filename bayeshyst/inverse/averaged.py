"""Model-averaged feedforward: one command designed over several models' posteriors.

At one excitation frequency the model comparison leaves a set of models with stacking
weights (Yao et al. 2018): the predictive mixture that scores best on held-out cycles.
Designing the command on one model's posterior ignores the others even where they win.
:func:`design_averaged` pools the members' posterior draws **in proportion to their
weights** and inverts the pool as one (:func:`~bayeshyst.inverse.numerical.invert_pooled`):

* the *averaged* command makes the mixture's mean output follow the reference;
* the *robust* command minimises the mixture's ``q``-quantile of ``|y - y_d|``;
* the predicted 90 % band of the tracking NRMSE is taken over held-out draws of the
  mixture (drawn in the same proportions, disjoint from the design draws).

Both commands are then run on the plant: the virtual actuator that generated the data
when there is one, else held-out mixture draws standing in for it (which measures how
the mixture's uncertainty propagates, not how well it fits the actuator).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.data.virtual import VirtualActuator
from bayeshyst.errors import ParameterError
from bayeshyst.inference.residual import ResidualBlocks
from bayeshyst.inverse.feedforward import BAND, Draws, predict_outputs, tracking_percent
from bayeshyst.inverse.numerical import Member, invert_pooled
from bayeshyst.inverse.references import Reference
from bayeshyst.models.base import HysteresisModel
from bayeshyst.tables import TableRecord, frame

__all__ = ["POSTERIOR_WORDS", "AveragedDesign", "AveragedResult", "WeightedPosterior",
           "allocate_draws", "design_averaged"]


@dataclass(frozen=True)
class WeightedPosterior:
    """One member of a model-averaged design.

    Attributes
    ----------
    label : str
        How the member is named in the outputs (its model spec).
    model : HysteresisModel
    draws : Draws
        Its posterior draws at this frequency (no discrepancy: ``draws.delta`` None).
    weight : float
        Its weight in the average (> 0; the members' weights are renormalised).
    residual : ResidualBlocks, optional
        What its fit leaves unexplained, added to its prediction draws (and plants) so
        that the band predicts a measured error; None: noise-free outputs only.
    """

    label: str
    model: HysteresisModel
    draws: Draws
    weight: float
    residual: ResidualBlocks | None = None


def allocate_draws(weights: Sequence[float], total: int) -> list[int]:
    """Split ``total`` draws over members in proportion to ``weights`` (each >= 1).

    Largest-remainder rounding of ``total * w / sum(w)``, then every member gets at
    least one draw (taken from the largest allocations), so the counts sum to
    ``max(total, len(weights))``.
    """
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise ParameterError(f"weights must be positive and finite, got {list(weights)}")
    total = max(int(total), w.size)
    share = total * w / w.sum()
    n = np.floor(share).astype(int)
    for i in np.argsort(-(share - n), kind="stable")[: total - int(n.sum())]:
        n[i] += 1
    while np.any(n < 1):
        n[int(np.argmin(n))] += 1
        n[int(np.argmax(n))] -= 1
    return [int(v) for v in n]


def _take(d: Draws, idx: np.ndarray) -> Draws:
    return Draws({k: np.asarray(v)[idx] for k, v in d.theta.items()}, d.offset[idx])


@dataclass(frozen=True)
class AveragedDesign(TableRecord):
    """The model-averaged design at one frequency, and how it tracked.

    Attributes
    ----------
    frequency_hz : float or None
    models : tuple of str
        The members, in order.
    weights : tuple of float
        Their renormalised weights.
    design_draws : tuple of int
        Draws of each member the commands were designed on.
    averaged_nrmse_percent, robust_nrmse_percent : float
        Realised tracking NRMSE (% of the reference's stroke, scored cycles) of the
        averaged and the robust command on the plant (the mean over plants when the
        plants are held-out draws).
    averaged_max_percent : float
        Largest realised error of the averaged command (% of stroke).
    predicted_band_percent : (float, float)
        The mixture's predicted 90 % range of the averaged command's NRMSE.
    realised_inside_band : bool
    plants_inside_band : float or None
        With held-out draws as plants: the fraction whose NRMSE lies in the band.
    model_error_percent : float
        The inverter's own check: max ``|mixture mean - y_d|`` over scored samples.
    single_model : str
        The member of largest weight, whose own posterior-mean command is the baseline.
    single_nrmse_percent : float
        That command's realised NRMSE on the same plant (equal to the averaged one with
        a single member).
    curves : dict of str to ndarray
        ``t``, ``y_d``, ``scored`` and each command ``u_<label>`` with the plant's output
        ``y_<label>`` (the first plant's), for ``averaged``, ``robust`` (and ``single``);
        not in :meth:`to_dict`.
    """

    frequency_hz: float | None
    models: tuple[str, ...]
    weights: tuple[float, ...]
    design_draws: tuple[int, ...]
    averaged_nrmse_percent: float
    averaged_max_percent: float
    robust_nrmse_percent: float
    predicted_band_percent: tuple[float, float]
    realised_inside_band: bool
    plants_inside_band: float | None
    model_error_percent: float
    single_model: str
    single_nrmse_percent: float
    curves: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def label(self) -> str:
        """``"10 Hz"`` or ``"reference"`` for a reference without a frequency."""
        return "reference" if self.frequency_hz is None else f"{self.frequency_hz:g} Hz"

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict` (models and weights as ``;``-joined text)."""
        return frame([self.to_dict()])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready row."""
        out = {k: v for k, v in self.__dict__.items() if k != "curves"}
        out["models"], out["weights"] = list(self.models), list(self.weights)
        out["design_draws"] = list(self.design_draws)
        out["predicted_band_percent"] = list(self.predicted_band_percent)
        return out

    def __str__(self) -> str:
        lo, hi = self.predicted_band_percent
        members = ", ".join(f"{m} {w:.2f}" for m, w in zip(self.models, self.weights,
                                                            strict=True))
        inside = "inside" if self.realised_inside_band else "OUTSIDE"
        return (f"{self.label:>10}  averaged {self.averaged_nrmse_percent:7.3f}  robust "
                f"{self.robust_nrmse_percent:7.3f}  band [{lo:.3f}, {hi:.3f}] {inside}  "
                f"({self.single_model} alone {self.single_nrmse_percent:.3f})  over {members}")


#: which fit of each member supplied its draws, in words
POSTERIOR_WORDS = {
    "auto": "a rate-independent model's posterior given that frequency, a rate-dependent "
            "model's joint posterior",
    "joint": "each model's joint posterior (all frequencies)",
    "frequency": "each model's posterior given that frequency's records",
}


@dataclass(frozen=True)
class AveragedResult(TableRecord):
    """Model-averaged designs per frequency, and the frequencies or models left out.

    Attributes
    ----------
    rows : tuple of AveragedDesign
    plant : str
        What the commands were run on, in words.
    notes : tuple of str
        Members left out (a GP has no inverse, an unconverged fit, no saved posterior)
        and frequencies without a design, with the reason.
    posteriors : str
        Which fit of each member supplied its draws (``"joint"``: all frequencies,
        ``"frequency"``: that frequency's records, ``"auto"``: the latter for a
        rate-independent model, the former for a rate-dependent one).
    """

    rows: tuple[AveragedDesign, ...]
    plant: str
    notes: tuple[str, ...] = ()
    posteriors: str = "auto"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"plant": self.plant, "posteriors": self.posteriors,
                "per_frequency": [r.to_dict() for r in self.rows], "notes": list(self.notes)}

    def to_dataframe(self) -> Any:
        """One row per frequency (pandas); models and weights as ``;``-joined text."""
        import pandas as pd

        rows = []
        for r in self.rows:
            d = r.to_dict()
            d["models"] = "; ".join(r.models)
            d["weights"] = "; ".join(f"{w:.4g}" for w in r.weights)
            d["design_draws"] = "; ".join(str(n) for n in r.design_draws)
            d["band_lo"], d["band_hi"] = d.pop("predicted_band_percent")
            rows.append(d)
        return pd.DataFrame(rows)

    def __str__(self) -> str:
        head = (f"model-averaged feedforward (tracking NRMSE, % of stroke; the models at each "
                f"frequency's stacking weights, {POSTERIOR_WORDS.get(self.posteriors, '')}); "
                f"plant: {self.plant}")
        return "\n".join([head, *(str(r) for r in self.rows),
                          *(f"note: {n}" for n in self.notes)])


def design_averaged(members: Sequence[WeightedPosterior], reference: Reference, *,
                    plant: VirtualActuator | None, u_limits: tuple[float, float],
                    n_design_draws: int = 24, n_predict_draws: int = 100,
                    n_plants: int = 50, robust_quantile: float = 0.9,
                    seed: int = 0) -> AveragedDesign:
    """Design the averaged and robust commands over ``members`` and run them on the plant.

    Parameters
    ----------
    members : sequence of WeightedPosterior
        At least one; weights are renormalised to sum to 1.
    reference : Reference
        The trajectory to follow (output unit), with its scored samples.
    plant : VirtualActuator or None
        Run the commands on it (with its sensor noise, if it has any: a measurement);
        None: on ``n_plants`` held-out mixture draws, each with its member's residual.
    u_limits : (float, float)
        Admissible command range (input unit).
    n_design_draws, n_predict_draws, n_plants : int
        Mixture draws the commands are designed on, the band is predicted from, and (no
        plant) that stand in for the plant; each split over the members by weight.
    robust_quantile : float
        ``q`` the robust command minimises.
    seed : int
        Seeds the choice of draws: same seed, same result.

    Returns
    -------
    AveragedDesign

    Raises
    ------
    ParameterError
        For no members, a member with a discrepancy, too few draws of a member, or bad
        counts.
    """
    members = list(members)
    if not members or not all(isinstance(m, WeightedPosterior) for m in members):
        raise ParameterError("members must be a non-empty sequence of WeightedPosterior")
    for name, value in (("n_design_draws", n_design_draws), ("n_predict_draws", n_predict_draws),
                        ("n_plants", n_plants)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ParameterError(f"{name} must be a positive integer, got {value!r}")
    bad = [m.label for m in members if m.draws.delta is not None]
    if bad:
        raise ParameterError(f"{bad}: a model-averaged design takes members without a "
                             "discrepancy")
    weights = np.array([m.weight for m in members], dtype=float)
    if not (np.all(np.isfinite(weights)) and np.all(weights > 0)):
        raise ParameterError(f"weights must be positive and finite, got {weights.tolist()}")
    weights = weights / weights.sum()
    counts = {"design": allocate_draws(weights, n_design_draws),
              "predict": allocate_draws(weights, n_predict_draws),
              "plants": allocate_draws(weights, n_plants) if plant is None else
              [0] * len(members)}
    rng = np.random.default_rng(seed)
    split: dict[str, list[Draws]] = {k: [] for k in counts}
    for i, m in enumerate(members):
        need = sum(c[i] for c in counts.values())
        if m.draws.size < need:
            raise ParameterError(f"{m.label}: {m.draws.size} posterior draws, {need} needed "
                                 "(design + prediction + plants at its weight)")
        order = rng.permutation(m.draws.size)
        start = 0
        for k, c in counts.items():
            split[k].append(_take(m.draws, order[start:start + c[i]]))
            start += c[i]
    t, y_d, mask, stroke = reference.t, reference.y_d, reference.scored, reference.stroke
    common = {"u_limits": u_limits, "periodic": reference.periodic, "scored": mask}
    design = [Member(m.model, d.theta, d.offset) for m, d in zip(members, split["design"],
                                                                  strict=True)]
    averaged = invert_pooled(design, y_d, t, objective="mean", **common)
    robust = invert_pooled(design, y_d, t, objective="quantile", quantile=robust_quantile,
                           **common)
    top = int(np.argmax(weights))
    commands = {"averaged": averaged, "robust": robust}
    if len(members) > 1:
        # the baseline: the heaviest member alone, on as many of its draws (design and
        # prediction ones: never the plants')
        own = split["design"][top], split["predict"][top]
        pool = Draws({k: np.concatenate([np.asarray(d.theta[k]) for d in own])
                      for k in own[0].theta}, np.concatenate([d.offset for d in own]))
        alone = _take(pool, np.arange(min(n_design_draws, pool.size)))
        commands["single"] = invert_pooled([Member(members[top].model, alone.theta,
                                                   alone.offset)], y_d, t, objective="mean",
                                           **common)

    f = reference.frequency_hz

    def residuals(parts: list[Draws], stream: int) -> list[np.ndarray | float]:
        # one residual series per draw, fixed per role and shared by the commands
        r = np.random.default_rng([seed, stream])
        return [0.0 if m.residual is None or not d.size else
                m.residual.sample(d.size, t.size, f, r)
                for m, d in zip(members, parts, strict=True)]

    def mixture(u: np.ndarray, parts: list[Draws], noise: list[np.ndarray | float]
                ) -> np.ndarray:
        out = np.concatenate([predict_outputs(m.model, u, t, d, f) + e
                              for m, d, e in zip(members, parts, noise, strict=True)
                              if d.size])
        return out[np.all(np.isfinite(out), axis=1)]

    noise = {"predict": residuals(split["predict"], 1), "plants": residuals(split["plants"], 2)}
    predicted = tracking_percent(mixture(averaged.u, split["predict"], noise["predict"]), y_d,
                                 stroke, mask)[0]
    lo, hi = (float(v) for v in np.quantile(predicted, [(1 - BAND) / 2, (1 + BAND) / 2]))
    realised = {}
    curves: dict[str, np.ndarray] = {"t": t, "y_d": y_d, "scored": mask}
    for label, inv in commands.items():
        y = (plant.simulate(t, inv.u, rng=np.random.default_rng([seed, 3]))[None, :]
             if plant is not None else mixture(inv.u, split["plants"], noise["plants"]))
        realised[label] = tracking_percent(y, y_d, stroke, mask)
        curves[f"u_{label}"], curves[f"y_{label}"] = inv.u, y[0]
    nrmse, mx = realised["averaged"]
    inside = (nrmse >= lo) & (nrmse <= hi)
    return AveragedDesign(
        frequency_hz=reference.frequency_hz, models=tuple(m.label for m in members),
        weights=tuple(float(w) for w in weights), design_draws=tuple(counts["design"]),
        averaged_nrmse_percent=float(np.mean(nrmse)), averaged_max_percent=float(np.max(mx)),
        robust_nrmse_percent=float(np.mean(realised["robust"][0])),
        predicted_band_percent=(lo, hi),
        realised_inside_band=bool(lo <= float(np.mean(nrmse)) <= hi),
        plants_inside_band=None if plant is not None else float(np.mean(inside)),
        model_error_percent=float(100.0 * averaged.max_error / stroke),
        single_model=members[top].label,
        single_nrmse_percent=float(np.mean(realised.get("single", realised["averaged"])[0])),
        curves=curves)
