"""Candidate physical effects: each with its score regressors, its augmentation and its
physical reading.

Every effect is tested by the *score* of the block that would add it: the regressors
are the derivatives of the augmented model's output with respect to the block's
parameters at the values where the block does nothing (``eta = 0``), evaluated on the
fitted model's output ``w``. The test and the augmentation are therefore the same
hypothesis: when a test fires, the block it names is the first-order explanation of
the residual, and refitting with that block is the natural next model.

============== ======================================= =========================== ==========
effect         regressors (per record, on ``w``)       augmentation                source
============== ======================================= =========================== ==========
creep          ``x_j - w``, ``tau_j x_j' = w - x_j``    ``+creep`` (log-spaced lags) MODELS §7
rate_dependence ``dw/dt``, ``d2w/dt2``                  ``+second_order``           Eq. 56–57
asymmetry      ``h x^2``, ``x = (w - c) / h``           ``+asym_output(order=2)``   MODELS §6
drift          ``s w``, ``s``, ``s = (t - t0) / T``     ``+drift``                  MODELS §7
delay          ``-(w_k - w_{k-1}) / dt``                ``+delay``                  MODELS §7
colored_noise  ``e_{t-1}`` (Breusch–Godfrey)           AR(1) likelihood            —
============== ======================================= =========================== ==========

The creep, drift, asymmetry and delay regressors are computed by running the block
itself on ``w`` (exactly linear in its parameters, or — for the delay — its one-sided
derivative at ``d = 0``, exact under linear interpolation), so they cannot drift from
the block they stand for. Second-order dynamics at ``f_n -> inf`` has no finite null
value; its expansion ``G(s) = 1 - (2 zeta / w_n) s - ((1 - 4 zeta^2) / w_n^2) s^2 +
O(s^3)`` gives the two derivative regressors. A pure delay's expansion is ``1 - d s +
d^2 s^2 / 2``: one regressor fits it, so the smaller model (delay) wins the Bayes factor
unless the second derivative carries real weight (dynamics).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, SimulationError
from bayeshyst.models.base import HysteresisModel
from bayeshyst.models.blocks import AsymmetricOutput, Creep, Delay, Drift, SecondOrder
from bayeshyst.models.blocks.base import EffectBlock, time_scales
from bayeshyst.models.compose import Composite

__all__ = [
    "EFFECTS",
    "Asymmetry",
    "ColoredNoise",
    "CreepEffect",
    "DelayEffect",
    "DriftEffect",
    "Effect",
    "RateDependence",
    "RecordSignals",
    "get_effect",
]


@dataclass(frozen=True)
class RecordSignals:
    """One record as the diagnosis sees it.

    Attributes
    ----------
    name : str
    t : ndarray, shape (N,)
        Times (s), whole record (warm-up included).
    u : ndarray, shape (N,)
        Input (V).
    w : ndarray, shape (N,)
        Posterior-mean output of the fitted model *without* the observation offset
        (output unit): what an appended block would receive.
    s0 : int
        First scored sample.
    frequency_hz : float or None
    """

    name: str
    t: np.ndarray
    u: np.ndarray
    w: np.ndarray
    s0: int
    frequency_hz: float | None


def _blocks(model: HysteresisModel) -> tuple[EffectBlock, ...]:
    return model.blocks if isinstance(model, Composite) else ()


class Effect(ABC):
    """A physical effect the fitted model may lack.

    Class attributes
    ----------------
    name : str
        Name in results (``"creep"``); the list :data:`EFFECTS` is in reporting order.
    description : str
        What it is physically, one line.
    evidence_label : str
        Axis label of the evidence plot's explaining variable.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    evidence_label: ClassVar[str] = ""
    #: block names that already provide the effect (the test is then skipped)
    provided_by: ClassVar[tuple[str, ...]] = ()

    def not_applicable(self, model: HysteresisModel, likelihood: str) -> str | None:
        """Why the effect cannot be added to this model (None if it can)."""
        have = [b.name for b in _blocks(model) if b.name in self.provided_by]
        return f"the model already has '{have[0]}'" if have else None

    @abstractmethod
    def regressors(self, rec: RecordSignals, data: Any) -> np.ndarray:
        """Score regressors (N, k) on the whole record (the caller keeps the scored part)."""

    def evidence_axis(self, rec: RecordSignals) -> np.ndarray:
        """The explaining variable of the evidence plot (N,)."""
        return rec.t - rec.t[0]

    @abstractmethod
    def augment(self, model: HysteresisModel, likelihood: str, coef: np.ndarray,
                data: Any) -> tuple[HysteresisModel, str, str]:
        """(augmented model, likelihood, spec suffix) given the test's coefficients."""

    def initial(self, coef: np.ndarray, estimates: Mapping[str, float]) -> dict[str, Any]:
        """The added parameters at the test's estimate (``"creep.c"``, ``"noise.phi"``):
        a warm start for the augmented fit (the score coefficients of a block that is
        linear in its parameters *are* those parameters to first order)."""
        return {}

    def interpret(self, coef: np.ndarray, cov: np.ndarray, data: Any) -> dict[str, float]:
        """Physical reading of the test's coefficients ``coef`` (k,) with covariance
        ``cov`` (k, k) (rough, first-order)."""
        return {}


class _BlockEffect(Effect):
    """An effect whose regressors come from running its block on ``w``."""

    def block(self, data: Any) -> EffectBlock:
        raise NotImplementedError

    #: parameter rows of the block that give one regressor each: name -> (k, *shape)
    def unit_thetas(self, block: EffectBlock, data: Any) -> tuple[dict[str, np.ndarray],
                                                                   float]:
        raise NotImplementedError

    def regressors(self, rec: RecordSignals, data: Any) -> np.ndarray:
        blk = self.block(data)
        thetas, h = self.unit_thetas(blk, data)
        fixed = blk.param_space(data).fixed
        k = next(iter(thetas.values())).shape[0]
        full = {**{n: np.repeat(np.asarray(v, float)[None], k, axis=0)
                   for n, v in fixed.items()}, **thetas}
        out = blk.apply_batch(rec.w, rec.t, full)
        if np.any(out.failed):
            raise SimulationError(f"{blk.name}: the block failed on the fitted output of "
                               f"record {rec.name!r}")
        return ((out.y - rec.w[None, :]) / h).T

    def augment(self, model, likelihood, coef, data):
        blk = self.block(data)
        return Composite(model, (blk,)), likelihood, f"+{self.spec(blk)}"

    def spec(self, blk: EffectBlock) -> str:
        return blk.name


class CreepEffect(_BlockEffect):
    """Creep: slow, logarithmic-in-time relaxation after every change of the drive.

    Regressors: the lags ``x_j - w`` of the block :class:`~bayeshyst.models.blocks.Creep`
    with its own log-spaced time constants (one per decade up to the record length).
    """

    name = "creep"
    description = "slow logarithmic relaxation after each change of the drive (creep)"
    evidence_label = "time since the record started (s)"
    provided_by = ("creep", "creep_fractional")
    n_terms: ClassVar[int] = 3

    def block(self, data):
        return Creep(n_terms=self.n_terms)

    def unit_thetas(self, block, data):
        return {"c": np.eye(self.n_terms)}, 1.0

    def initial(self, coef, estimates):
        return {"creep.c": np.asarray(coef, float)}

    def interpret(self, coef, cov, data):
        # y = w + sum c_j (x_j - w): the step response climbs by sum(c) over the decades
        # the lags span plus the one the slowest lag takes to settle (rough)
        tau = Creep(n_terms=self.n_terms).time_constants(data)
        decades = max(math.log10(tau[-1] / tau[0]), 1.0) if tau.size > 1 else 1.0
        return {"creep_per_decade_percent": float(100.0 * np.sum(coef) / (decades + 1.0))}


class DriftEffect(_BlockEffect):
    """Drift: a slow change of offset and gain over the record, unrelated to the input
    (thermal). Regressors ``s w`` and ``s`` of :class:`~bayeshyst.models.blocks.Drift`."""

    name = "drift"
    description = "offset and gain change slowly over the record, unrelated to the input"
    evidence_label = "time since the record started (s)"
    provided_by = ("drift",)

    def block(self, data):
        return Drift(order=1)

    def unit_thetas(self, block, data):
        return {"g": np.array([[1.0], [0.0]]), "d": np.array([[0.0], [1.0]])}, 1.0

    def initial(self, coef, estimates):
        return {"drift.g": np.asarray(coef[:1], float), "drift.d": np.asarray(coef[1:], float)}

    def interpret(self, coef, cov, data):
        ts = time_scales(data)
        return {"gain_drift_percent_per_s": float(100.0 * coef[0] / ts.duration),
                "offset_drift_per_s": float(coef[1] / ts.duration)}


class Asymmetry(_BlockEffect):
    """Asymmetry: the two halves of the stroke bend differently (an even term in the
    output), beyond what the model's own asymmetry can do. Regressor ``h x^2`` of
    :class:`~bayeshyst.models.blocks.AsymmetricOutput`."""

    name = "asymmetry"
    description = "the loop bends differently in the two halves of the stroke"
    evidence_label = "normalised model output x = (w - c) / h"
    provided_by = ("asym_output",)
    _h: ClassVar[float] = 0.01  # a2 for the finite difference: exact (linear in a2)

    def block(self, data):
        return AsymmetricOutput(order=2)

    def unit_thetas(self, block, data):
        return {"a2": np.array([self._h])}, self._h

    def spec(self, blk):
        return "asym_output(order=2)"

    def evidence_axis(self, rec):
        lo, hi = float(np.min(rec.w)), float(np.max(rec.w))
        return (rec.w - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-300)

    def initial(self, coef, estimates):
        return {"asym_output.a2": float(coef[0])}

    def interpret(self, coef, cov, data):
        return {"a2": float(coef[0])}


class DelayEffect(_BlockEffect):
    """Delay: the sensor (or the amplifier) lags the drive by a constant time.
    Regressor ``dy/dd`` at ``d = 0``: minus the backward difference of ``w``."""

    name = "delay"
    description = "the measured output lags the drive by a constant time"
    evidence_label = "rate of the model output dw/dt (unit/s)"
    provided_by = ("delay",)

    def block(self, data, d_max: float | None = None):
        dt = time_scales(data).dt
        n = 10 if d_max is None else max(10, math.ceil(3.0 * d_max / dt))
        return Delay(max_delay_samples=n)

    def unit_thetas(self, block, data):
        h = 0.25 * time_scales(data).dt  # inside the first interval: exactly linear
        return {"d": np.array([h])}, h

    def evidence_axis(self, rec):
        return np.gradient(rec.w, rec.t)

    def augment(self, model, likelihood, coef, data):
        # y ~ w + d * (-dw/dt): the coefficient estimates the delay; size the block's
        # history (and its prior) to cover three times it
        blk = self.block(data, d_max=abs(float(coef[0])) if coef.size else None)
        return (Composite(model, (blk,)), likelihood,
                f"+delay(max_delay_samples={blk.max_delay_samples})")

    def initial(self, coef, estimates):
        return {"delay.d": float(coef[0])}

    def interpret(self, coef, cov, data):
        return {"delay_s": float(coef[0])}



class RateDependence(Effect):
    """Rate dependence: the loop changes with the speed of the drive — linear dynamics
    after the hysteresis (mass, stiffness, damping: the Hammerstein structure of review
    Eq. 56–57). Regressors ``dw/dt`` and ``d2w/dt2``; augmentation ``+second_order``."""

    name = "rate_dependence"
    description = "the loop changes with the speed of the drive (dynamics after the hysteresis)"
    evidence_label = "rate of the model output dw/dt (unit/s)"
    provided_by = ("second_order", "arx")

    def regressors(self, rec, data):
        d1 = np.gradient(rec.w, rec.t)
        return np.column_stack([d1, np.gradient(d1, rec.t)])

    def evidence_axis(self, rec):
        return np.gradient(rec.w, rec.t)

    def augment(self, model, likelihood, coef, data):
        return Composite(model, (SecondOrder(),)), likelihood, "+second_order"

    def initial(self, coef, estimates):
        if "natural_frequency_hz" not in estimates:
            return {}
        return {"second_order.f_n": estimates["natural_frequency_hz"],
                "second_order.zeta": max(estimates.get("damping_ratio", 0.3), 1e-3)}

    def interpret(self, coef, cov, data):
        # G(s) ~ 1 - (2 zeta / wn) s - ((1 - 4 zeta^2) / wn^2) s^2 (zeta << 1/2)
        a, b = float(coef[0]), float(coef[1])
        se_b = math.sqrt(max(float(cov[1, 1]), 0.0)) if cov.shape == (2, 2) else math.nan
        # b < 0: the gain rises with frequency (an underdamped resonance, zeta < 1/2);
        # b >= 0: a lag without gain rise, which in band is a delay (see fired())
        out = {"first_order_time_s": -a, "curvature_z": b / se_b if se_b > 0 else math.nan}
        if b < 0:
            wn = 1.0 / math.sqrt(-b)
            out.update(natural_frequency_hz=wn / (2 * math.pi), damping_ratio=-a * wn / 2)
        return out


class ColoredNoise(Effect):
    """Coloured noise: the residual is serially correlated after every structural effect
    has been accounted for; the likelihood becomes AR(1). Tested by Breusch–Godfrey."""

    name = "colored_noise"
    description = "the measurement noise is serially correlated (AR(1))"
    evidence_label = "previous residual e[t-1]"

    def not_applicable(self, model, likelihood):
        return "the likelihood is already AR(1)" if likelihood == "ar1" else None

    def regressors(self, rec, data):
        raise TypeError("colored_noise is tested on the residual itself (lag_test)")

    def augment(self, model, likelihood, coef, data):
        return model, "ar1", " with likelihood ar1"

    def initial(self, coef, estimates):
        return {"noise.phi": float(estimates.get("lag1_autocorrelation", 0.0))}

    def interpret(self, coef, cov, data):
        return {"lag1_autocorrelation": float(coef[0])}


#: The candidate effects in reporting order.
EFFECTS: Mapping[str, Effect] = {e.name: e for e in (
    CreepEffect(), RateDependence(), Asymmetry(), DriftEffect(), DelayEffect(), ColoredNoise())}


def get_effect(name: str) -> Effect:
    """The effect called ``name``; ModelError listing the valid names."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise ModelError(f"unknown effect {name!r}; valid: {', '.join(EFFECTS)}") from None
