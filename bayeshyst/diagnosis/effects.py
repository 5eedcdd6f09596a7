"""Candidate physical effects, each with its score regressors, augmentation and physical reading.

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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.data import estimate_frequency
from bayeshyst.errors import DataError, SimulationError
from bayeshyst.models.base import HysteresisModel
from bayeshyst.models.blocks import AsymmetricOutput, Creep, Delay, Drift, SecondOrder
from bayeshyst.models.blocks.base import EffectBlock, time_scales
from bayeshyst.models.compose import Composite

__all__ = [
    "Asymmetry",
    "ColoredNoise",
    "CreepEffect",
    "DelayEffect",
    "DriftEffect",
    "Effect",
    "RateDependence",
    "RecordSignals",
    "insert_after_base",
    "shortest_half_period",
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

    def variants(self, sigs: Sequence[RecordSignals], data: Any, model: HysteresisModel
                 ) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """What is tested: ``(variant, regressors, evidence axis)`` on the stacked samples.

        One unnamed variant for an effect of the classic catalogue: its
        :meth:`regressors` and :meth:`evidence_axis` on every record's scored samples.
        Effects with several variants (which column, which change time) override it.
        """
        x = np.concatenate([self.regressors(s, data)[s.s0:] for s in sigs])
        ax = np.concatenate([self.evidence_axis(s)[s.s0:] for s in sigs])
        return [("", x, ax)]

    @abstractmethod
    def augment(self, model: HysteresisModel, likelihood: str, coef: np.ndarray,
                data: Any, variant: str = "") -> tuple[HysteresisModel, str, str]:
        """(augmented model, likelihood, spec suffix) given the test's coefficients.

        ``variant`` is the variant the test chose (:meth:`variants`; empty for most).
        """

    def initial(self, coef: np.ndarray, estimates: Mapping[str, float]) -> dict[str, Any]:
        """The added parameters at the test's estimate: a warm start for the augmented fit.

        Keys are full parameter names (``"creep.c"``, ``"noise.phi"``). The score
        coefficients of a block that is linear in its parameters *are* those parameters to
        first order.

        Parameters
        ----------
        coef : ndarray, shape (k,)
            The test's coefficients.
        estimates : mapping of str to float
            The test's physical reading (from :meth:`interpret`).
        """
        return {}

    def interpret(self, coef: np.ndarray, cov: np.ndarray, data: Any) -> dict[str, float]:
        """Physical reading of the test's coefficients (rough, first-order).

        ``coef`` (k,) are the coefficients and ``cov`` (k, k) their covariance.
        """
        return {}

    def interpret_variant(self, variant: str, coef: np.ndarray, cov: np.ndarray,
                          data: Any) -> dict[str, float]:
        """:meth:`interpret` for the variant the test chose (the same for most effects)."""
        return self.interpret(coef, cov, data)


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

    def augment(self, model, likelihood, coef, data, variant=""):
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
        """The :class:`~bayeshyst.models.blocks.Creep` block with ``n_terms`` log-spaced lags."""
        return Creep(n_terms=self.n_terms)

    def unit_thetas(self, block, data):
        """One regressor per lag: unit gains ``c = eye(n_terms)``, divisor 1 (exactly linear)."""
        return {"c": np.eye(self.n_terms)}, 1.0

    def initial(self, coef, estimates):
        """``creep.c`` at the score coefficients (the gain of each lag)."""
        return {"creep.c": np.asarray(coef, float)}

    def interpret(self, coef, cov, data):
        """Creep per decade of time, ``creep_per_decade_percent`` (%, rough).

        The sum of the lag gains spread over the decades the lags span plus the one the
        slowest lag takes to settle.
        """
        # y = w + sum c_j (x_j - w): the step response climbs by sum(c) over the decades
        # the lags span plus the one the slowest lag takes to settle (rough)
        tau = Creep(n_terms=self.n_terms).time_constants(data)
        decades = max(math.log10(tau[-1] / tau[0]), 1.0) if tau.size > 1 else 1.0
        return {"creep_per_decade_percent": float(100.0 * np.sum(coef) / (decades + 1.0))}


class DriftEffect(_BlockEffect):
    """Drift: a slow change of offset and gain over the record, unrelated to the input.

    Typically thermal. Regressors ``s w`` and ``s`` of
    :class:`~bayeshyst.models.blocks.Drift`.
    """

    name = "drift"
    description = "offset and gain change slowly over the record, unrelated to the input"
    evidence_label = "time since the record started (s)"
    provided_by = ("drift",)

    def block(self, data):
        """The :class:`~bayeshyst.models.blocks.Drift` block of order 1."""
        return Drift(order=1)

    def unit_thetas(self, block, data):
        """Two regressors: unit gain drift ``g`` and unit offset drift ``d``, divisor 1."""
        return {"g": np.array([[1.0], [0.0]]), "d": np.array([[0.0], [1.0]])}, 1.0

    def initial(self, coef, estimates):
        """``drift.g`` and ``drift.d`` at the score coefficients."""
        return {"drift.g": np.asarray(coef[:1], float), "drift.d": np.asarray(coef[1:], float)}

    def interpret(self, coef, cov, data):
        """Drift rates over the record duration ``T``.

        ``gain_drift_percent_per_s`` (% per s) and ``offset_drift_per_s`` (output unit per s).
        """
        ts = time_scales(data)
        return {"gain_drift_percent_per_s": float(100.0 * coef[0] / ts.duration),
                "offset_drift_per_s": float(coef[1] / ts.duration)}


class Asymmetry(_BlockEffect):
    """Asymmetry: the two halves of the stroke bend differently (an even output term).

    The bending goes beyond what the model's own asymmetry can do. Regressor ``h x^2`` of
    :class:`~bayeshyst.models.blocks.AsymmetricOutput`.
    """

    name = "asymmetry"
    description = "the loop bends differently in the two halves of the stroke"
    evidence_label = "normalised model output x = (w - c) / h"
    provided_by = ("asym_output",)
    _h: ClassVar[float] = 0.01  # a2 for the finite difference: exact (linear in a2)

    def block(self, data):
        """The :class:`~bayeshyst.models.blocks.AsymmetricOutput` block of order 2."""
        return AsymmetricOutput(order=2)

    def unit_thetas(self, block, data):
        """One regressor: ``a2 = 0.01`` divided by 0.01 (exact: the block is linear in ``a2``)."""
        return {"a2": np.array([self._h])}, self._h

    def spec(self, blk):
        """``asym_output(order=2)``: the spec names the order."""
        return "asym_output(order=2)"

    def augment(self, model, likelihood, coef, data, variant=""):
        """The output map right after the hysteresis model, before its linear blocks.

        A static nonlinearity followed by linear dynamics (creep, second-order, delay) is
        the Hammerstein structure of review Eq. 56–57; placed after them the map would
        make the composite non-affine and leave creep's gains, which the sampler draws
        exactly otherwise, to the ensemble moves (the micromanipulator's creep +
        asymmetry fit did not converge in 10 000 steps that way). Without affine blocks
        it is appended. The spec suffix is inserted after the base's spec by
        :func:`insert_after_base` when the map goes first.
        """
        blk = self.block(data)
        if isinstance(model, Composite) and model.blocks \
                and all(b.affine for b in model.blocks):
            return Composite(model.base, (blk, *model.blocks)), likelihood, f"+{self.spec(blk)}"
        return Composite(model, (blk,)), likelihood, f"+{self.spec(blk)}"

    def evidence_axis(self, rec):
        """Normalised model output ``x = (w - c) / h`` (N,).

        ``c`` and ``h`` are the centre and the half-span of ``w``.
        """
        lo, hi = float(np.min(rec.w)), float(np.max(rec.w))
        return (rec.w - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-300)

    def initial(self, coef, estimates):
        """``asym_output.a2`` at the score coefficient."""
        return {"asym_output.a2": float(coef[0])}

    def interpret(self, coef, cov, data):
        """The quadratic output coefficient ``a2``."""
        return {"a2": float(coef[0])}


def shortest_half_period(data: Any) -> float | None:
    """Half the shortest excitation period (s) over the records of ``data``.

    A record's period is ``1 / frequency_hz`` when it declares one, else
    :func:`~bayeshyst.data.estimate_frequency` by its input's reversals (noise-robust).
    None when no record has a period (no frequency and too few reversals).
    """
    records = list(data) if hasattr(data, "records") else [data]
    halves = []
    for rec in records:
        try:
            freq = rec.frequency_hz or estimate_frequency(rec, method="reversals")
        except DataError:  # too few turning points: this record has no period
            continue
        halves.append(0.5 / float(freq))
    return min(halves) if halves else None


def insert_after_base(spec: str, suffix: str) -> str:
    """``spec`` with ``suffix`` (``"+block(...)"``) right after its base model's spec.

    The base is what precedes the first ``+`` outside parentheses; a spec without one
    gets the suffix appended.
    """
    depth = 0
    for i, ch in enumerate(spec):
        depth += (ch == "(") - (ch == ")")
        if ch == "+" and depth == 0:
            return spec[:i] + suffix + spec[i:]
    return spec + suffix


class DelayEffect(_BlockEffect):
    """Delay: the sensor (or the amplifier) lags the drive by a constant time.

    Regressor ``dy/dd`` at ``d = 0``: minus the backward difference of ``w``.
    """

    name = "delay"
    description = "the measured output lags the drive by a constant time"
    evidence_label = "rate of the model output dw/dt (unit/s)"
    provided_by = ("delay",)

    def block(self, data, d_max: float | None = None):
        """The :class:`~bayeshyst.models.blocks.Delay` block with room for three times ``d_max``.

        Parameters
        ----------
        data : Record or Dataset
            Data whose sample interval ``dt`` (s) sizes the history.
        d_max : float or None
            Expected delay (s): the history holds ``max(10, ceil(3 d_max / dt))`` samples;
            10 samples when ``None``. The room never exceeds half the shortest excitation
            period (:func:`shortest_half_period`): a longer delay shifts the fastest
            record's loop by more than half a cycle, where its phase wraps and the
            posterior of ``d`` becomes multimodal (one mode per period) — that is not a
            delay the data can identify, whatever the score coefficient said.

        Returns
        -------
        Delay
        """
        dt = time_scales(data).dt
        room = 10 * dt if d_max is None else max(10 * dt, 3.0 * d_max)
        half = shortest_half_period(data)
        if half is not None:
            room = min(room, half)
        return Delay(max_delay_samples=max(1, math.ceil(room / dt - 1e-9)))

    def unit_thetas(self, block, data):
        """One regressor: ``d = dt / 4``, divided by itself.

        The block is exactly linear in ``d`` inside the first sample interval.
        """
        h = 0.25 * time_scales(data).dt  # inside the first interval: exactly linear
        return {"d": np.array([h])}, h

    def evidence_axis(self, rec):
        """Rate of the model output ``dw/dt`` (N,) (output unit per s)."""
        return np.gradient(rec.w, rec.t)

    def augment(self, model, likelihood, coef, data, variant=""):
        """Append a delay block sized to cover three times the estimated delay ``|coef[0]|``.

        Returns the composite, the unchanged likelihood and the spec suffix
        ``+delay(max_delay_samples=n)``.
        """
        # y ~ w + d * (-dw/dt): the coefficient estimates the delay; size the block's
        # history (and its prior) to cover three times it
        blk = self.block(data, d_max=abs(float(coef[0])) if coef.size else None)
        return (Composite(model, (blk,)), likelihood,
                f"+delay(max_delay_samples={blk.max_delay_samples})")

    def initial(self, coef, estimates):
        """``delay.d`` at the score coefficient (s)."""
        return {"delay.d": float(coef[0])}

    def interpret(self, coef, cov, data):
        """The delay ``delay_s`` (s): the score coefficient of ``-dw/dt``."""
        return {"delay_s": float(coef[0])}



class RateDependence(Effect):
    """Rate dependence: the loop changes with the speed of the drive.

    The cause is linear dynamics after the hysteresis (mass, stiffness, damping: the
    Hammerstein structure of review Eq. 56–57). Regressors ``dw/dt`` and ``d2w/dt2``;
    augmentation ``+second_order``.
    """

    name = "rate_dependence"
    description = "the loop changes with the speed of the drive (dynamics after the hysteresis)"
    evidence_label = "rate of the model output dw/dt (unit/s)"
    provided_by = ("second_order", "arx")

    def regressors(self, rec, data):
        """``dw/dt`` and ``d2w/dt2`` (N, 2) by finite differences over the record's times."""
        d1 = np.gradient(rec.w, rec.t)
        return np.column_stack([d1, np.gradient(d1, rec.t)])

    def evidence_axis(self, rec):
        """Rate of the model output ``dw/dt`` (N,) (output unit per s)."""
        return np.gradient(rec.w, rec.t)

    def augment(self, model, likelihood, coef, data, variant=""):
        """Append :class:`~bayeshyst.models.blocks.SecondOrder` (suffix ``+second_order``).

        The likelihood is unchanged.
        """
        return Composite(model, (SecondOrder(),)), likelihood, "+second_order"

    def initial(self, coef, estimates):
        """``second_order.f_n`` and ``second_order.zeta`` from the test's estimates.

        Empty without a natural frequency estimate; the damping ratio defaults to 0.3 and is
        kept at least 1e-3.
        """
        if "natural_frequency_hz" not in estimates:
            return {}
        return {"second_order.f_n": estimates["natural_frequency_hz"],
                "second_order.zeta": max(estimates.get("damping_ratio", 0.3), 1e-3)}

    def interpret(self, coef, cov, data):
        """Time constant, curvature z-score and, for a rising gain, the resonance.

        From ``G(s) ~ 1 - (2 zeta / wn) s - ((1 - 4 zeta^2) / wn^2) s^2`` (``zeta << 1/2``):
        ``first_order_time_s = -coef[0]`` (s) and ``curvature_z`` is ``coef[1]`` over its
        standard error. When ``coef[1] < 0`` (the gain rises with frequency, an underdamped
        resonance) ``natural_frequency_hz`` and ``damping_ratio`` follow from
        ``wn = 1 / sqrt(-coef[1])``; ``coef[1] >= 0`` is a lag without gain rise, which in
        band is a delay.
        """
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
    """Coloured noise: a serially correlated residual that no structural effect explains.

    The correlation remains after every structural effect has been accounted for; the
    likelihood becomes AR(1). Tested by Breusch–Godfrey.
    """

    name = "colored_noise"
    description = "the measurement noise is serially correlated (AR(1))"
    evidence_label = "previous residual e[t-1]"

    def not_applicable(self, model, likelihood):
        """Why not: the likelihood is already AR(1) (None otherwise)."""
        return "the likelihood is already AR(1)" if likelihood == "ar1" else None

    def regressors(self, rec, data):
        """Not used: raises TypeError (the effect is tested on the residual by ``lag_test``)."""
        raise TypeError("colored_noise is tested on the residual itself (lag_test)")

    def augment(self, model, likelihood, coef, data, variant=""):
        """The same model with the AR(1) likelihood; suffix ``" with likelihood ar1"``."""
        return model, "ar1", " with likelihood ar1"

    def initial(self, coef, estimates):
        """``noise.phi`` at the estimated lag-1 autocorrelation (0 if missing)."""
        return {"noise.phi": float(estimates.get("lag1_autocorrelation", 0.0))}

    def interpret(self, coef, cov, data):
        """The residual's lag-1 autocorrelation ``lag1_autocorrelation``, ``coef[0]``."""
        return {"lag1_autocorrelation": float(coef[0])}
