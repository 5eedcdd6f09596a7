"""Prandtl–Ishlinskii models with play and stop operators, and the exact play-PI inverse.

Review Eq. 11–14 and 20; inverse after Kuhnen (2003), review ref. [52]; MODELS.md §1–2.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.models._kernels.operators import pi_play_batch, pi_stop_batch, stop_operator
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.registry import register
from bayeshyst.params import Normal, Param, ParamSpace, Uniform

__all__ = [
    "LinearInWeights",
    "PIInverse",
    "PrandtlIshlinskii",
    "PrandtlIshlinskiiStop",
    "check_count",
    "default_thresholds",
    "operator_space",
    "play_pi_inverse",
    "stop_response",
]


def default_thresholds(n: int, scales: DataScales) -> np.ndarray:
    """Thresholds ``r_i = i * span / (2 (n + 1))``, ``i = 1..n`` (V).

    The review's ``r_i = i max|u| / (n + 1)`` for a symmetric input, written with the
    peak-to-peak span so that unipolar drives (0–150 V) are covered the same way: no
    operator is wider than half the span, so every one of them takes part in a full
    cycle.
    """
    return np.arange(1, n + 1) * scales.u_span / (2.0 * (n + 1))


def operator_space(n: int, scales: DataScales, *, linear: str) -> ParamSpace:
    """The parameters every PI-type model shares: weights ``p0``, ``w`` (n,), thresholds ``r``.

    The weights have priors scaled to the secant gain; the thresholds ``r`` are fixed by
    :func:`default_thresholds`.
    """
    g = scales.gain
    gu = scales.gain_unit
    span = scales.u_span
    return ParamSpace(
        (
            Param("p0", Normal(g, abs(g)), unit=gu, description=f"weight of the {linear} term"),
            Param("w", Normal(0.0, abs(g)), shape=(n,), unit=gu,
                  description="operator weights"),
        ),
        fixed={"r": default_thresholds(n, scales)},
        fixed_params=(
            Param("r", Uniform(0.0, span), shape=(n,), unit=scales.u_unit,
                  description="operator thresholds (fixed over the data's input span)"),
        ),
    )


class LinearInWeights(LinearInParams):
    """PI-type models: linear in ``[p0, w]`` for fixed thresholds and shape parameters.

    Column 0 of :meth:`regressors` is ``u``, column ``i`` operator ``i``'s output.
    """

    linear_params: ClassVar[tuple[str, ...]] = ("p0", "w")


@register
@dataclass(frozen=True)
class PrandtlIshlinskii(LinearInWeights, HysteresisModel):
    r"""Prandtl–Ishlinskii model with play (backlash) operators.

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w_i F_{r_i}[u]_k,
               \quad F_r[u]_k = \max(u_k - r, \min(u_k + r, F_r[u]_{k-1}))

    (review Eq. 11–12 and 20). The loop is counter-clockwise for positive weights and
    monotone while ``p0 > 0`` and every partial sum ``p0 + w_1 + ... + w_i > 0``; then
    :meth:`inverse` is exact.

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.

    Notes
    -----
    Parameters: ``p0`` (output unit/V), ``w`` (n,) (output unit/V), and the thresholds
    ``r`` (n,) (V), fixed by default at ``i * span / (2 (n + 1))`` of the data's input
    span (``ParamSpace.free("r")`` samples them; they must stay increasing for the
    inverse). Initial state: every operator relaxed at the first input,
    ``F_{r_i}[u]_{-1} = u_0`` (so ``play + stop = u`` with a zero stop state).
    """

    name: ClassVar[str] = "pi_play"
    equation: ClassVar[str] = "review Eq. 11-12, 20"
    has_inverse: ClassVar[bool] = True
    n_operators: int = 10

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Weights ``p0``, ``w`` (n,) and fixed thresholds ``r`` (n,): :func:`operator_space`."""
        return operator_space(self.n_operators, data_scales(data), linear="linear (p0 u)")

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return np.full((theta["w"].shape[0], self.n_operators), u0)

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        pi_play_batch(u, theta["p0"], theta["w"], theta["r"], state, y)
        return y, state, failed

    def inverse_theta(self, theta: Mapping[str, Any]) -> PIInverse:
        """The exact inverse (review ref. [52]) as play- and stop-PI parameters."""
        return play_pi_inverse(theta["p0"], theta["w"], theta["r"])

    def inverse(self, y: Any, t: Any, theta: Mapping[str, Any], *,
                state0: np.ndarray | None = None, u_prev: float | None = None) -> np.ndarray:
        """Input ``u`` (N,) that drives the model to output ``y`` (N,).

        Parameters
        ----------
        y : array_like, shape (N,)
            Desired output.
        t : array_like, shape (N,)
            Times (s), unused (rate-independent).
        theta : mapping
            Forward parameters; must be invertible (see class notes).
        state0 : ndarray, shape (n,), optional
            The *forward* model's state before the first sample (e.g. the final state
            of an earlier :meth:`run`); default relaxed at the input that gives
            ``y[0]``.
        u_prev : float, optional
            The forward input at that instant; required with ``state0``.
        """
        inv = self.inverse_theta(theta)
        y = np.ascontiguousarray(y, dtype=float)
        if state0 is None:
            s0 = None
        elif u_prev is None:
            raise ParameterError("inverse with state0 needs u_prev, the input at that state")
        else:
            s0 = inv.state_from_forward(state0, u_prev)
        return PrandtlIshlinskii(self.n_operators).simulate(y, t, inv.play_theta, state0=s0)


@dataclass(frozen=True)
class PIInverse:
    """Parameters of the inverse of a play-PI (Kuhnen 2003; MODELS.md §2).

    Attributes
    ----------
    p0 : float
        ``w'_0 = 1 / p0`` (V per output unit).
    w : ndarray, shape (n,)
        ``w'_i = -w_i / ((p0 + ... + w_i)(p0 + ... + w_{i-1}))``.
    r : ndarray, shape (n,)
        ``r'_i = sum_{j <= i} w_j (r_i - r_j)`` (output unit).
    forward_w : ndarray, shape (n + 1,)
        ``[p0, w_1, ..., w_n]``, kept for mapping initial states.
    """

    p0: float
    w: np.ndarray
    r: np.ndarray
    forward_w: np.ndarray

    @property
    def play_theta(self) -> dict[str, Any]:
        """Theta of a ``pi_play`` model that computes ``u`` from ``y``."""
        return {"p0": self.p0, "w": self.w, "r": self.r}

    @property
    def stop_theta(self) -> dict[str, Any]:
        """The same inverse written with stop operators (a ``pi_stop`` model).

        With ``F = y - E``: ``u = (w'_0 + sum w'_i) y - sum w'_i E_{r'_i}[y]``.
        """
        return {"p0": self.p0 + float(self.w.sum()), "w": -self.w, "r": self.r}

    def state_from_forward(self, v: Any, u_prev: float) -> np.ndarray:
        """Inverse play states from forward play states (MODELS.md §2).

        ``v'_i = sum_{j<=i} w_j v_i + sum_{j>i} w_j v_j`` with ``v_0 = u_prev``, the
        input before the first sample (the zero-threshold operator is the input).

        Parameters
        ----------
        v : array_like, shape (n,)
            Forward play-operator outputs.
        u_prev : float
            The forward input at the same instant (V).
        """
        v = np.asarray(v, dtype=float).ravel()
        wf = self.forward_w
        n = wf.size - 1
        if v.size != n:
            raise ParameterError(f"forward state has {v.size} entries, expected {n}")
        vv = np.concatenate([[float(u_prev)], v])
        out = np.empty(n)
        for i in range(1, n + 1):
            out[i - 1] = wf[: i + 1].sum() * vv[i] + (wf[i + 1:] * vv[i + 1:]).sum()
        return out

    def __str__(self) -> str:
        return (f"PIInverse(p0'={self.p0:.6g}, w'={np.array2string(self.w, precision=4)}, "
                f"r'={np.array2string(self.r, precision=4)})")


def stop_response(u: Any, r: float) -> np.ndarray:
    """Output (N,) of one stop operator of threshold ``r`` driven by ``u``, from 0.

    ``e_k = min(r, max(-r, e_(k-1) + u_k - u_(k-1)))``, ``e_0 = 0`` (review Eq. 20;
    the kernel the stop-type PI models run).

    Parameters
    ----------
    u : array_like, shape (N,)
        Input (input unit).
    r : float
        Threshold (input unit), > 0.
    """
    u = np.ascontiguousarray(u, dtype=float)
    out = np.empty(u.size)
    if u.size:
        stop_operator(u, float(r), 0.0, float(u[0]), out)
    return out


def play_pi_inverse(p0: float, w: Any, r: Any) -> PIInverse:
    """Exact inverse of ``y = p0 u + sum w_i F_{r_i}[u]`` (review ref. [52]).

    Parameters
    ----------
    p0 : float
        Linear weight, > 0.
    w : array_like, shape (n,)
        Operator weights; every partial sum ``p0 + w_1 + ... + w_i`` must be > 0.
    r : array_like, shape (n,)
        Thresholds, strictly increasing and > 0 (V).

    Raises
    ------
    ParameterError
        If the model is not invertible (a partial sum <= 0, thresholds not increasing).
    """
    w = np.asarray(w, dtype=float).ravel()
    r = np.asarray(r, dtype=float).ravel()
    if w.shape != r.shape:
        raise ParameterError(f"w and r must have equal length, got {w.size} and {r.size}")
    if not r[0] > 0 or np.any(np.diff(r) <= 0):
        raise ParameterError(f"thresholds must be positive and strictly increasing, got {r}")
    wf = np.concatenate([[float(p0)], w])
    partial = np.cumsum(wf)
    bad = np.flatnonzero(partial <= 0)
    if bad.size:
        i = int(bad[0])
        raise ParameterError(
            f"play-PI is not invertible: partial sum p0 + w_1..w_{i} = {partial[i]:.6g} <= 0 "
            "(the loop folds back; the inverse does not exist)"
        )
    rf = np.concatenate([[0.0], r])
    w_inv = -w / (partial[1:] * partial[:-1])
    r_inv = np.array([np.sum(wf[: i + 1] * (rf[i] - rf[: i + 1])) for i in range(1, r.size + 1)])
    return PIInverse(1.0 / float(p0), w_inv, r_inv, wf)


@register
@dataclass(frozen=True)
class PrandtlIshlinskiiStop(LinearInWeights, HysteresisModel):
    r"""Prandtl–Ishlinskii model with stop (elastic-plastic) operators.

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w_i E_{r_i}[u]_k,
               \quad E_r[u]_k = \min(r, \max(-r, E_r[u]_{k-1} + u_k - u_{k-1}))

    (review Eq. 13–14, 20 with ``E`` for ``F``). Stop operators run clockwise, so with
    positive weights this model describes clockwise loops: fitted with the displacement
    as input and the voltage as output it is a direct inverse (review ref. [57]); the
    exact inverse of a play-PI is one (:attr:`PIInverse.stop_theta`).

    Parameters
    ----------
    n_operators : int
        Number of stop operators.

    Notes
    -----
    State: the ``n`` stop outputs and the previous input (stop operators integrate
    input increments). Initial state: zero stop outputs, previous input ``u_0``.
    """

    name: ClassVar[str] = "pi_stop"
    equation: ClassVar[str] = "review Eq. 13-14, 20"
    n_operators: int = 10

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Weights ``p0``, ``w`` (n,) and fixed thresholds ``r`` (n,): :func:`operator_space`."""
        return operator_space(self.n_operators, data_scales(data), linear="linear (p0 u)")

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = np.zeros((theta["w"].shape[0], self.n_operators + 1))
        s[:, -1] = u0
        return s

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        pi_stop_batch(u, theta["p0"], theta["w"], theta["r"], state, y)
        return y, state, failed
