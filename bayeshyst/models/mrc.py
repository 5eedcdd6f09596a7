"""MRC electromechanical model of a piezo actuator (review Eq. 38–44, MODELS.md §4)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models._kernels.mrc import mrc_batch
from bayeshyst.models.base import (
    HysteresisModel,
    check_count,
    check_signal,
    data_scales,
    kernel_buffers,
    sample_period,
)
from bayeshyst.models.pi import default_thresholds
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["MRCElectromechanical"]


@register
@dataclass(frozen=True)
class MRCElectromechanical(HysteresisModel):
    """Electromechanical piezo model with MRC charge–voltage hysteresis (Eq. 38–44).

    Physical model (review Eq. 40–44, ``F_ext = 0``)::

        m x'' + c x' + k x = T_F u_p,   u = u_h + u_p,   q = C u_p + T_q x,
        u_h = H[q] = sum_i V_i,  V_i = (q - q_bi) / C_i  clamped to +-v_i  (Eq. 38–39)

    where each MRC element (capacitor ``C_i`` saturating at ``v_i``, its overflow
    charge ``q_bi`` the slider) is an elasto-slide element on charge. The model is
    voltage driven: at every instant ``u = H[C u_p + T_q x] + u_p`` is solved for
    ``u_p`` (monotone, bracketed Newton), and the sliders are committed only after the
    solve. Output ``y = x``.

    Parameters
    ----------
    n_elements : int
        Number of MRC (elasto-slide) elements.
    step : float
        Largest ``lam h`` of an RK4 sub-step, ``lam`` the fastest rate of the mechanics;
        smaller is more accurate (error ~ step^4).
    max_substeps : int
        Most RK4 sub-steps per sample interval; a parameter vector needing more (natural
        frequency far above the sampling rate, where the mechanics is quasi-static
        anyway) is reported as a failed simulation rather than run for minutes.

    Notes
    -----
    **Sampled parametrisation.** Outputs are invariant under two gauges: rescaling
    charge (``C, T_q, C_i, q_bi`` by ``a``) and force (``m, c, k, T_F`` by ``b``). With
    ``x = gain xi`` and ``Q = q / C`` the model becomes ::

        xi'' / w_n^2 + 2 zeta xi' / w_n + xi = u_p,    Q = u_p + (coupling / gain) x,
        u = sum_i rho_i clamp(Q - Qb_i, -delta_i, delta_i) + u_p,

    with parameters ``f_n = w_n / 2 pi = sqrt(k/m) / 2 pi`` (Hz), ``zeta = c / (2
    sqrt(k m))``, ``gain = T_F / k`` (output unit/V: the slope once every element
    saturates), ``coupling = T_F T_q / (k C) >= 0`` (the electrical back-coupling
    stiffness relative to ``k``), ``rho_i = C / C_i >= 0`` and the slip deflections
    ``delta_i = C_i v_i / C`` (V of ``Q``), fixed over the data's input span like the
    Maxwell-slip thresholds (``ParamSpace.free("delta")`` samples them). The mapping back
    to ``(m, c, k, T_F, T_q, C, C_i, v_i)`` for a chosen gauge is
    :meth:`physical_parameters`. The output is linear in ``gain``.

    Statically (``x = gain u_p``) the model is ``u = sum_i rho_i E_{delta_i}[Q] + Q / (1 +
    coupling)``, a stop-type Maxwell-slip from ``Q`` to ``u``: the loop in ``(u, x)`` is
    its inverse, counter-clockwise, flat after a reversal (slope ``gain / (1 + (1 +
    coupling) sum rho)``) and steepening to ``gain`` as elements saturate.

    **Integration.** RK4 in time with the input linearly interpolated between samples,
    ``ceil(dt lam / step)`` sub-steps per sample, ``lam = 2 pi f_n max(sqrt(1 + coupling),
    2 zeta)`` (see :mod:`bayeshyst.models._kernels.mrc`). With the default ``step = 0.1``
    the integration error is ~2e-7 of the stroke (checked against ``lsim``); the cost is
    proportional to ``f_n / f_s / step``.

    State ``[xi, xi', Qb_1..Qb_n, u_prev, t_prev]`` (``xi`` in V, ``xi'`` in V/s).
    Relaxed initial state: static equilibrium at ``u_0`` with unloaded elements
    (``u_p = xi = u_0``, ``xi' = 0``, ``Qb_i = (1 + coupling) u_0``), ``t_prev = -inf``
    (the first sample only solves the loop; the mechanics starts moving after it).
    """

    name: ClassVar[str] = "mrc"
    equation: ClassVar[str] = "review Eq. 38-44"
    rate_dependent: ClassVar[bool] = True
    n_elements: int = 5
    step: float = 0.1
    max_substeps: int = 2000

    def __post_init__(self) -> None:
        check_count(self.n_elements, "n_elements")
        if not (isinstance(self.step, int | float) and 0.0 < self.step <= 1.0):
            raise ModelError(f"step must be in (0, 1] (RK4 accuracy), got {self.step!r}")
        check_count(self.max_substeps, "max_substeps")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``f_n``, ``zeta``, ``gain``, ``coupling``, ``rho`` (n,) and the fixed ``delta`` (n,).

        Priors scaled from ``data``: ``f_n`` log-normal with median a quarter of the
        sampling rate (resolvable but not assumed; 1 kHz without time stamps), ``zeta``
        log-normal with median 0.3, ``gain ~ Normal(g, |g|)``, half-normal ``coupling`` and
        ``rho``; ``delta`` over the input span as the Maxwell-slip thresholds. ``data`` as in
        :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        n = self.n_elements
        gu = sc.gain_unit
        # a piezo stack resonates in the kHz range; with data, centre the prior at a
        # quarter of the sampling rate so the resonance is resolvable but not assumed
        f_med = 0.25 / sample_period(data, 2.5e-4)
        return ParamSpace(
            (
                Param("f_n", LogNormal.from_median(f_med, 0.75), unit="Hz",
                      description="natural frequency sqrt(k/m) / 2 pi"),
                Param("zeta", LogNormal.from_median(0.3, 0.75),
                      description="damping ratio c / (2 sqrt(k m))"),
                Param("gain", Normal(sc.gain, abs(sc.gain)), unit=gu,
                      description="T_F / k: output per u_p (slope with saturated elements)"),
                Param("coupling", HalfNormal(1.0),
                      description="back-coupling stiffness T_F T_q / (k C)"),
                Param("rho", HalfNormal(1.0 / n), shape=(n,),
                      description="element stiffness ratios C / C_i"),
            ),
            fixed={"delta": default_thresholds(n, sc)},
            fixed_params=(
                Param("delta", Uniform(0.0, 2.0 * sc.u_span), shape=(n,), unit=sc.u_unit,
                      description="slip deflections C_i v_i / C (fixed over the input span)"),
            ),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        n = self.n_elements
        s = np.empty((theta["f_n"].shape[0], n + 4))
        s[:, 0] = u0
        s[:, 1] = 0.0
        s[:, 2:2 + n] = ((1.0 + theta["coupling"]) * u0)[:, None]
        s[:, 2 + n] = u0
        s[:, 3 + n] = -np.inf
        return s

    def _simulate(self, u, t, theta, state0, n_rec):
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ParameterError("t must be strictly increasing for the MRC model")
        # NaN rows (walkers that failed earlier) are left to the kernel, which flags them
        if np.any(state0[:, -1] >= t[0]):
            raise ParameterError(f"t[0] = {t[0]} is not after the state's last sample time")
        y, state, failed = kernel_buffers(state0, u.shape[0])
        rec = np.empty((state.shape[0], 3, n_rec))
        mrc_batch(u, t, theta["f_n"], theta["zeta"], theta["gain"], theta["coupling"],
                  theta["rho"], theta["delta"], state, y, failed, float(self.step),
                  int(self.max_substeps), rec)
        state[failed] = np.nan
        return y, state, failed, rec

    def _run(self, u, t, theta, state0):
        y, state, failed, _ = self._simulate(u, t, theta, state0, 0)
        return y, state, failed

    def diagnose(self, u: Any, t: Any, theta: Mapping[str, Any], *,
                 state0: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Simulate once and return the internal electrical signals per sample.

        Parameters
        ----------
        u, t : array_like, shape (N,)
            Input (V) and times (s).
        theta : mapping
            One parameter vector.
        state0 : ndarray, shape (n_elements + 4,), optional
            State before the first sample; default relaxed at ``u[0]``.

        Returns
        -------
        dict
            ``y`` (output unit), ``u_p`` (V, transducer voltage), ``u_h`` (V, MRC
            voltage ``u - u_p``), ``Q`` (V, charge / C) and ``residual`` (V, the
            algebraic-loop residual ``Q + H(Q) - (u + coupling xi)`` of the committed
            solve at each sample), all shape (N,).
        """
        u, t = check_signal(u, t)
        tb, _ = self._batch_theta(theta, batched=False)
        s0 = (self._initial_state(tb, float(u[0])) if state0 is None
              else np.ascontiguousarray(np.asarray(state0, dtype=np.float64)[None, :]))
        y, _, failed, rec = self._simulate(u, t, tb, s0, u.shape[0])
        if failed[0]:
            raise SimulationError(f"{self.name}: simulation failed for theta={dict(theta)}")
        return {"y": y[0], "u_p": rec[0, 0], "u_h": u - rec[0, 0], "Q": rec[0, 1],
                "residual": rec[0, 2]}

    def physical_parameters(self, theta: Mapping[str, Any], *, C: float = 1.0,
                            k: float = 1.0) -> dict[str, Any]:
        """``m, c, k, T_F, T_q, C, C_i, v_i`` for the gauge ``(C, k)``.

        Parameters
        ----------
        theta : mapping
            One parameter vector of this model.
        C : float
            Capacitance in parallel with the transducer (F), the charge gauge.
        k : float
            Actuator stiffness (N per output unit), the force gauge.

        Returns
        -------
        dict
            ``m`` (N s^2 per output unit), ``c`` (N s per output unit), ``k``, ``T_F``
            (N/V), ``T_q`` (C per output unit), ``C`` (F), ``C_i`` (F, inf for
            ``rho_i = 0``), ``v_i`` (V, saturation voltages).
        """
        if not (C > 0 and k > 0):
            raise ParameterError(f"gauges C and k must be positive, got C={C}, k={k}")
        w = 2.0 * math.pi * float(theta["f_n"])
        gain = float(theta["gain"])
        rho = np.asarray(theta["rho"], float)
        with np.errstate(divide="ignore"):
            c_i = np.where(rho > 0, C / rho, np.inf)
        return {"m": k / w**2, "c": 2.0 * float(theta["zeta"]) * k / w, "k": k,
                "T_F": gain * k,
                "T_q": float(theta["coupling"]) * C / gain if gain != 0 else math.nan,
                "C": C, "C_i": c_i, "v_i": rho * np.asarray(theta["delta"], float)}
