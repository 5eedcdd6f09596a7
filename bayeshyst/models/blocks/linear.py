"""Linear dynamics after a hysteresis model: ARX and exact second order (review Eq. 56–57)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.blocks import arx_batch, arx_polynomials, second_order_batch
from bayeshyst.models.base import check_count, kernel_buffers
from bayeshyst.models.blocks.base import (
    EffectBlock,
    param_columns,
    register_block,
    time_scales,
)
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["ARX", "SecondOrder"]


# -------------------------------------------------------------------------------- ARX


@register_block
@dataclass(frozen=True)
class ARX(EffectBlock):
    """ARX linear dynamics ``A(q^-1) y_k = B(q^-1) w_{k-nk}`` (review Eq. 56–57).

    ``A = 1 + a_1 q^-1 + ... + a_na q^-na``, ``B = b_0 + ... + b_{nb-1} q^-(nb-1)``;
    the noise term ``e`` of Eq. 56 belongs to the likelihood, not here.

    Parameters
    ----------
    na : int
        Order of ``A`` (0 for a finite impulse response).
    nb : int
        Number of ``B`` coefficients (>= 1).
    nk : int
        Input delay in samples.

    Notes
    -----
    Parametrised so that **every draw is stable with unit DC gain**:

    * ``kappa`` (na,) in (-1, 1): reflection coefficients, mapped to ``A`` by the
      step-up recursion ``a^(m)_i = a^(m-1)_i + kappa_m a^(m-1)_(m-i)``,
      ``a^(m)_m = kappa_m``. ``A`` has all roots inside the unit circle iff every
      ``|kappa_m| < 1`` (Schur–Cohn), and every stable ``A`` has exactly one such
      ``kappa``, so no stable filter is lost and no unstable one is proposed.
    * ``beta`` (nb - 1,): shares of the static gain on the lagged inputs,
      ``b = A(1) [1 - sum(beta), beta_1, ..., beta_{nb-1}]``, so ``B(1) / A(1) = 1``.
      A free ``B`` would multiply the hysteresis gain by ``B(1)/A(1)``: only their
      product is identifiable, and the posterior would be a ridge.

    Priors: ``kappa`` uniform on (-1, 1), no preferred pole location (the logit
    transform lets the sampler approach the unit circle, where the poles of slow
    dynamics sampled fast lie); ``beta ~ Normal(0, 0.5)``. Coefficients are per sample:
    the block assumes the data's uniform rate and ignores ``t``. State: the last ``na``
    outputs and ``nk + nb - 1`` inputs, oldest first.
    """

    name: ClassVar[str] = "arx"
    affine: ClassVar[bool] = True
    needs_preview: ClassVar[bool] = True
    equation: ClassVar[str] = "review Eq. 56-57"
    na: int = 2
    nb: int = 2
    nk: int = 0

    def __post_init__(self) -> None:
        check_count(self.na, "ARX na", minimum=0)
        check_count(self.nb, "ARX nb", minimum=1)
        check_count(self.nk, "ARX nk", minimum=0)

    @property
    def state_size(self) -> int:
        """``na + nk + nb - 1``: the last ``na`` outputs and ``nk + nb - 1`` inputs."""
        return self.na + self.nk + self.nb - 1

    def param_space(self, data: Any = None) -> ParamSpace:
        """Reflection coefficients ``kappa`` (na,) and gain shares ``beta`` (nb - 1,).

        Each is declared only when non-empty; priors as in the class Notes (they do not
        depend on ``data``).
        """
        params = []
        if self.na:
            params.append(Param("kappa", Uniform(-1.0, 1.0), shape=(self.na,), unit="1",
                                description="reflection coefficients of A (stable iff |k|<1)"))
        if self.nb > 1:
            params.append(Param("beta", Normal(0.0, 0.5), shape=(self.nb - 1,), unit="1",
                                description="shares of the unit DC gain on lagged inputs"))
        return ParamSpace(tuple(params))

    def polynomials(self, theta: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """``(a, b)`` of one parameter vector: ``a`` (na + 1,) with ``a_0 = 1``, ``b`` (nb,).

        Raises ParameterError if a reflection coefficient is outside (-1, 1).
        """
        tb, _ = self._batch_theta(theta, batched=False)
        a, b = np.empty(self.na + 1), np.empty(self.nb)
        kappa, beta = param_columns(tb, "kappa", 1)[0], param_columns(tb, "beta", 1)[0]
        if not arx_polynomials(kappa, beta, a, b):
            raise ParameterError(f"ARX: reflection coefficients must lie in (-1, 1): {theta}")
        return a, b

    def _initial_state(self, theta, w0, t0):
        # unit DC gain: the settled output equals the held input
        return np.repeat(np.asarray(w0, float)[:, None], self.state_size, axis=1)

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        width = w.shape[0]
        arx_batch(w, param_columns(theta, "kappa", width), param_columns(theta, "beta", width),
                  self.nk, st, out, failed)
        return out, st, failed


# ----------------------------------------------------------------------- second order


@register_block
@dataclass(frozen=True)
class SecondOrder(EffectBlock):
    """Second-order dynamics ``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)``, ``wn = 2 pi f_n``.

    Discretised exactly for the chosen hold of the input between samples, by the
    matrix exponential in closed form for under-, critically and over-damped ``zeta``
    (MODELS.md §7). Any sampling, uniform or not, is exact: the discretisation is cached
    per distinct step and recomputed when the step changes.

    Parameters
    ----------
    hold : {"foh", "zoh"}, default "foh"
        ``"foh"``: the input is linear between samples (first-order hold), as a sampled
        smooth drive is; the output at ``t_k`` depends on ``w_k``. ``"zoh"``: the input
        is held, so the output at ``t_k`` depends on inputs up to ``w_{k-1}`` only (a
        strictly proper map whose one-sample lag is an artefact of the hold: at 100
        samples per period it delays the loop by 3.6 degrees, which model comparison
        would then mistake for dynamics).

    Notes
    -----
    Parameters: ``f_n`` (Hz), log-normal prior with median ``fs / 20`` (a tenth of the
    data's Nyquist frequency; ``fs = 10 kHz`` without data) and a factor-e spread, so
    about 1 % of the prior lies above Nyquist; ``zeta`` (1), log-normal with median 0.3
    (piezo stages are lightly damped; 11 % prior mass is over-damped). ``G(0) = 1``.
    State: ``[y, dy/dt, w_prev, t_prev, h_ref]``.
    """

    name: ClassVar[str] = "second_order"
    affine: ClassVar[bool] = True
    needs_preview: ClassVar[bool] = True
    equation: ClassVar[str] = "wn^2/(s^2 + 2 zeta wn s + wn^2), exact FOH or ZOH"

    hold: str = "foh"

    def __post_init__(self) -> None:
        if self.hold not in ("foh", "zoh"):
            raise ModelError(f"SecondOrder.hold: expected 'foh' or 'zoh', got {self.hold!r}")

    @property
    def state_size(self) -> int:
        """5: ``[y, dy/dt, w_prev, t_prev, h_ref]``."""
        return 5

    def param_space(self, data: Any = None) -> ParamSpace:
        """``f_n`` (Hz) and ``zeta`` with the priors of the class Notes.

        The median of ``f_n`` is ``fs / 20`` for the sampling rate ``fs`` of ``data``
        (Record, Dataset or None; 10 kHz without data).
        """
        fs = time_scales(data).fs
        return ParamSpace((
            Param("f_n", LogNormal.from_median(fs / 20.0, 1.0), unit="Hz",
                  description="natural frequency (prior median a tenth of Nyquist)"),
            Param("zeta", LogNormal.from_median(0.3, 1.0), unit="1",
                  description="damping ratio"),
        ))

    def _initial_state(self, theta, w0, t0):
        s = np.zeros((w0.shape[0], 5))
        s[:, 0] = w0
        s[:, 2] = w0
        s[:, 3] = t0
        s[:, 4] = np.nan
        return s

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        # an f_n near the float limit overflows to inf here; the kernel refuses a
        # non-finite wn and flags the walker failed (counted), so no warning is due
        with np.errstate(over="ignore"):
            wn = 2.0 * np.pi * np.ascontiguousarray(theta["f_n"], dtype=np.float64)
        second_order_batch(w, t, wn, np.ascontiguousarray(theta["zeta"]), self.hold == "foh",
                           st, out, failed)
        return out, st, failed
