"""Hammerstein forms of review §10: additive cascaded dynamics [107], fractional order [111].

* :class:`CreepVibration` (effect block ``creep_vibration``): the dynamic part of the
  *additive cascaded* Hammerstein model of ref. [107], split into a low-frequency part
  (creep, a bank of first-order lags) and a high-frequency part (vibration, a second-order
  stage) that act **in parallel** on the hysteresis output and are added. With a play PI
  in front (``pi_play+creep_vibration``) it is [107]'s model; any hysteresis model can
  precede it.
* :class:`FractionalHammerstein` (model ``bouc_wen_fractional``): the fractional-order
  Hammerstein model of ref. [111] (Bouc–Wen static part, fractional-order transfer
  function as the dynamic part), which the review's summary names as the model that
  describes hysteresis and creep at once.

Both are built from the existing blocks' code (:class:`~bayeshyst.models.blocks.Creep`,
:class:`~bayeshyst.models.blocks.SecondOrder`,
:class:`~bayeshyst.models.blocks.FractionalCreep` and their kernels); nothing here is a
new time loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.models.base import HysteresisModel, LinearDesign, LinearInParams, data_scales
from bayeshyst.models.blocks import Creep, FractionalCreep, SecondOrder
from bayeshyst.models.blocks.base import EffectBlock, register_block, time_scales
from bayeshyst.models.bouc_wen import BoucWen
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Param, ParamSpace

__all__ = ["CreepVibration", "FractionalHammerstein"]


@register_block
@dataclass(frozen=True)
class CreepVibration(EffectBlock):
    r"""Additive cascaded dynamics of ref. [107]: creep and vibration in parallel (review §10).

    .. math::  y = \Big(1 - \sum_j c_j\Big) G_v[w] + \sum_j c_j L_j[w], \quad
               G_v(s) = \frac{\omega_n^2}{s^2 + 2\zeta\omega_n s + \omega_n^2}, \quad
               L_j(s) = \frac{1}{\tau_j s + 1}

    Which form: the review says only that [107]'s dynamic linear part "was divided into
    two parts: low frequency and high frequency, used to describe creep and vibration",
    in an *additive* cascade. We read it as the sum of a creep transfer function (the
    ``creep`` block's lags ``c_j / (τ_j s + 1)``) and a vibration transfer function
    carrying the rest of the unit static gain, ``(1 - Σc) G_v``: every part low-pass,
    ``G(0) = 1`` (the convention of every block: the hysteresis model keeps the gain),
    and the creep lags bypass the stage. That is what distinguishes it from the series
    cascade ``creep+second_order`` (``G_c G_v``), which differs from it by ``Σ c_j L_j
    (G_v - 1)`` -- negligible at creep frequencies, visible near and above the
    resonance, where the additive form keeps the creep's share unresonated. With all
    ``c = 0`` it is ``second_order``.

    Parameters
    ----------
    n_terms : int
        Number of creep lags (as :class:`~bayeshyst.models.blocks.Creep`).
    tau_min, tau_max : float, optional
        Range of the fixed, log-spaced creep time constants (s), as for ``creep``.
    hold : {"foh", "zoh"}
        Hold of the stage's input between samples, as for ``second_order``.

    Notes
    -----
    Parameters: the creep gains ``c`` (n_terms,) and fixed ``tau`` with the ``creep``
    block's priors; ``f_n`` (Hz) and ``zeta`` with the ``second_order`` block's priors.
    The lags are exact for a held input (ZOH), the stage for the chosen hold. State:
    the ``creep`` block's state then the ``second_order`` block's, ``[x_1 .. x_n, w_prev,
    t_prev, h_ref, y, dy/dt, w_prev, t_prev, h_ref]``. The output is affine in ``w``
    (sampled and inverted like the other linear blocks; its exact inverse is not causal).
    """

    name: ClassVar[str] = "creep_vibration"
    affine: ClassVar[bool] = True
    needs_preview: ClassVar[bool] = True
    equation: ClassVar[str] = ("ref. [107]: (1 - sum c) wn^2/(s^2 + 2 zeta wn s + wn^2) "
                               "+ sum c_j/(tau_j s + 1), additive")
    n_terms: int = 3
    tau_min: float | None = None
    tau_max: float | None = None
    hold: str = "foh"

    def __post_init__(self) -> None:
        # the parts check their own settings, with their own messages
        _ = self._parts

    @property
    def _parts(self) -> tuple[Creep, SecondOrder]:
        return Creep(self.n_terms, self.tau_min, self.tau_max), SecondOrder(self.hold)

    @property
    def state_size(self) -> int:
        """``n_terms + 8``: the creep lags' state, then the stage's."""
        creep, stage = self._parts
        return creep.state_size + stage.state_size

    def param_space(self, data: Any = None) -> ParamSpace:
        """Creep gains ``c``, fixed ``tau`` (s), and ``f_n`` (Hz), ``zeta`` of the stage.

        The priors of the ``creep`` and ``second_order`` blocks, scaled from ``data``.
        """
        creep, stage = self._parts
        return ParamSpace.concat([creep.param_space(data), stage.param_space(data)])

    def _initial_state(self, theta, w0, t0):
        creep, stage = self._parts
        return np.ascontiguousarray(np.concatenate(
            [creep._initial_state(theta, w0, t0), stage._initial_state(theta, w0, t0)],
            axis=1))

    def _apply(self, w, t, theta, state):
        creep, stage = self._parts
        n_c = creep.state_size
        lagged, s_c, f_c = creep._apply(w, t, theta, np.ascontiguousarray(state[:, :n_c]))
        vib, s_v, f_v = stage._apply(w, t, theta, np.ascontiguousarray(state[:, n_c:]))
        c = np.asarray(theta["c"], dtype=np.float64).reshape(w.shape[0], -1)
        rest = 1.0 - c.sum(axis=1)
        # creep writes w + sum c (x - w) = sum c x + (1 - sum c) w; swap w for G_v[w]
        out = lagged + rest[:, None] * (vib - w)
        failed = np.asarray(f_c, dtype=bool) | np.asarray(f_v, dtype=bool)
        out[failed] = np.nan
        return out, np.ascontiguousarray(np.concatenate([s_c, s_v], axis=1)), failed


@register
@dataclass(frozen=True)
class FractionalHammerstein(LinearInParams, HysteresisModel):
    r"""Fractional-order Hammerstein model: Bouc–Wen, then a fractional-order lag (ref. [111]).

    .. math::  w = k u - h \;\; \text{(review Eq. 47-48)}, \qquad
               y = G[w], \quad
               G(s) = 1 - g + \frac{g}{(\tau s)^\lambda + 1}
                    = \frac{1 + (1 - g)(\tau s)^\lambda}{1 + (\tau s)^\lambda}

    Which form: the review gives no equation for [111] -- a Bouc–Wen static part and "the
    fractional-order transfer function" as the dynamic part, which with the summary's
    remark (hysteresis and creep described together) we read as the general first-order
    fractional transfer function with unit static gain: a share ``g`` of the hysteresis
    output passes the fractional lag ``1 / ((τ s)^λ + 1)`` (power-law creep after a step,
    a loop that lowers, lags and widens with frequency), the rest is immediate.
    ``λ = 1`` is the integer-order lead-lag ``bouc_wen+creep(n_terms=1)`` exactly;
    ``g = 1`` the pure fractional lag. The fractional lag is the ``creep_fractional``
    block's diffusive approximation (its modes and kernel are reused: exact for any
    sampling, cost ``n_modes`` per sample), so the model equals the composition
    ``bouc_wen+creep_fractional``; registered on its own for the review's model, its
    equation and priors that reach rate-dependent time scales (``τ`` from the sampling
    period to the record length, not only creep times).

    Parameters
    ----------
    n_modes, per_decade : int, float
        The diffusive grid, as for :class:`~bayeshyst.models.blocks.FractionalCreep`.

    Notes
    -----
    Parameters: ``k, alpha, beta, gamma, n`` as :class:`BoucWen` (same priors);
    ``gain`` (1) and ``lam`` (1) with the ``creep_fractional`` priors
    (``Normal(0.05, 0.05)``, ``Uniform(0, 1)``); ``tau`` (s) ``LogNormal`` with median
    ``sqrt(dt T)`` (``dt`` the sampling period, ``T`` the longest record) and log-sd
    ``ln(T/dt)/4``, so that ±2 sd spans ``[dt, T]``. State: the Bouc–Wen state ``[h,
    u_prev]`` then the block's ``[x_1 .. x_m, w_prev, t_prev, h_ref]``; relaxed start at
    rest (``x_i = w(u_0)``). The output is linear in ``k``.
    """

    name: ClassVar[str] = "bouc_wen_fractional"
    equation: ClassVar[str] = ("review Eq. 47-48, ref. [111] (then 1 - g + g/((tau s)^lam + 1),"
                               " fractional order)")
    rate_dependent: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("k",)
    linear_affine: ClassVar[bool] = True
    n_modes: int = 41
    per_decade: float = 4.0

    def __post_init__(self) -> None:
        _ = self._block  # its own checks and messages

    @property
    def _block(self) -> FractionalCreep:
        return FractionalCreep(self.n_modes, self.per_decade)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Bouc–Wen's ``k, alpha, beta, gamma, n``, then ``gain``, ``tau`` (s), ``lam``.

        Priors as in the class Notes, scaled from ``data``.
        """
        ts = time_scales(data)
        span = max(ts.duration / ts.dt, math.e)
        block = self._block.param_space(data)
        tau = Param("tau", LogNormal.from_median(math.sqrt(ts.dt * ts.duration),
                                                 math.log(span) / 4.0), unit="s",
                    description="time constant of the fractional lag")
        bw = BoucWen()._space(data_scales(data))
        return ParamSpace((*bw.params, block["gain"], tau, block["lam"]))

    def _split(self, theta):
        return ({k: theta[k] for k in ("k", "alpha", "beta", "gamma", "n")},
                {k: theta[k] for k in ("gain", "tau", "lam")})

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        bw_theta, lag_theta = self._split(theta)
        bw = BoucWen()
        s_bw = bw._initial_state(bw_theta, u0)
        w0, _, _ = bw._run(np.array([float(u0)]), np.zeros(1), bw_theta, s_bw.copy())
        s_lag = self._block._initial_state(lag_theta, np.ascontiguousarray(w0[:, 0]), math.nan)
        return np.ascontiguousarray(np.concatenate([s_bw, s_lag], axis=1))

    def _run(self, u, t, theta, state0):
        state = np.asarray(state0, dtype=np.float64)
        if state.ndim != 2 or state.shape[1] != 2 + self._block.state_size:
            raise ParameterError(f"{self.name}: state must have {2 + self._block.state_size} "
                                 f"entries, got {state.shape}")
        if u.shape[0] > 1 and np.any(np.diff(t) <= 0):
            raise ParameterError(f"{self.name}: t must be strictly increasing")
        bw_theta, lag_theta = self._split(theta)
        w, s_bw, f_bw = BoucWen()._run(u, t, bw_theta, np.ascontiguousarray(state[:, :2]))
        y, s_lag, f_lag = self._block._apply(np.ascontiguousarray(np.nan_to_num(w)),
                                             np.ascontiguousarray(t, dtype=np.float64),
                                             lag_theta, np.ascontiguousarray(state[:, 2:]))
        failed = np.asarray(f_bw, dtype=bool) | np.asarray(f_lag, dtype=bool)
        y[failed] = np.nan
        return y, np.ascontiguousarray(np.concatenate([s_bw, s_lag], axis=1)), failed

    def linear_design(self, u: Any, t: Any, thetas: Mapping[str, Any],
                      names: tuple[str, ...] | None = None, *,
                      covariates: Mapping[str, Any] | None = None) -> LinearDesign:
        """``y = k G[u] - G[h]``: two simulations per walker (``k`` 0 and 1).

        See :meth:`LinearInParams.linear_design` (``covariates`` as there);
        ``G`` is linear, so the column is the difference of the two runs.
        """
        names = ("k",) if names is None else tuple(names)
        if names not in ((), ("k",)):
            raise ParameterError(f"{self.name}: only 'k' is linear, got {list(names)}")
        batch = {k: np.asarray(v, dtype=float) for k, v in thetas.items()}
        width = int(np.shape(batch["alpha"])[0])
        batch["k"] = np.zeros(width)
        const = self.run_batch(u, t, batch, covariates=covariates)
        if not names:
            return LinearDesign(names, np.zeros((1, const.y.shape[1], 0)), const.y,
                                const.failed)
        batch["k"] = np.ones(width)
        one = self.run_batch(u, t, batch, covariates=covariates)
        return LinearDesign(names, (one.y - const.y)[:, :, None], const.y,
                            const.failed | one.failed)
