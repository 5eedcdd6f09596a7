"""Numerical inversion of any model and composition, for one or many parameter vectors.

The command ``u`` is found **sample by sample through the model's one-step map**
(MODELS.md §8): from the state after sample ``k - 1`` choose ``u_k`` so that the output at
``k`` meets the target, then advance the state with that ``u_k``. No algebraic loop (the
one-step map is evaluated, never solved implicitly inside the model) and no artificial
delay (``u_k`` is matched to ``y_k``, not ``y_{k+1}``). The one-step map of a hysteresis
model is non-decreasing in ``u_k``; :func:`~bayeshyst.inverse.rootfind.solve_increasing`
brackets and refines the root and checks monotonicity on the way.

A composition ``base + blocks`` is split into **stages**. Blocks whose exact inverse is
not causal (``needs_preview``: delay, ARX, second-order dynamics; see
:mod:`bayeshyst.inverse.lti`) are inverted over the whole known signal by stable
deconvolution, last block first; runs of other blocks are inverted sample by sample
with their own one-step maps; the base model with the blocks directly after it is the
first stage, the only one driven by the physical command.

**Many parameter vectors.** With ``S`` posterior draws the states of all draws are
carried together, and the one shared command ``u_k`` is chosen so that

* ``objective="mean"``: the posterior-mean output meets the target, or
* ``objective="quantile"``: the ``q``-quantile over draws of ``|y_k - y_d,k|`` is
  smallest (a robust command: it lies between the draws' individual inverses).

Later stages (dynamics after the hysteresis) are inverted per draw; the draws then ask
the first stage for slightly different intermediate signals, and for the posterior mean
the command is refined by correcting the reference with the remaining mean error until
it is below the tolerance (a fixed-point iteration that contracts as fast as the draws'
dynamics agree).

**Measured columns.** A model that reads a column (``pi_covariate``, ``conditioned(...)``,
an ``aux`` block) is inverted at the conditions given by ``covariates`` (the column
along the reference, e.g. the temperature the command will run at); without them it
runs at its nominal conditions, as its forward simulation does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from bayeshyst.errors import ParameterError, SimulationError
from bayeshyst.inverse.lti import deconvolve
from bayeshyst.inverse.rootfind import solve_increasing, solve_scalar
from bayeshyst.models.base import HysteresisModel, check_covariates
from bayeshyst.models.blocks import EffectBlock
from bayeshyst.models.compose import Composite, block_namespaces, leading_part
from bayeshyst.models.onestep import StepChain
from bayeshyst.params import ParamSpace

__all__ = ["OBJECTIVES", "Inversion", "Member", "invert", "invert_pooled"]

#: What the shared command is chosen to achieve across draws.
OBJECTIVES = ("mean", "quantile")

#: Residual accepted as zero, relative to the target's span.
FTOL_REL = 1e-10
#: Bracket width at which refinement stops, relative to the input scale.
XTOL_REL = 1e-13
#: Reference corrections for the posterior mean behind per-draw dynamics.
MAX_CORRECTIONS = 25
#: Golden-section iterations of the robust objective (bracket shrinks by 0.618 each).
GOLDEN_ITER = 80


@dataclass(frozen=True)
class Inversion:
    """A command designed by numerical inversion, with what it does on the model.

    Attributes
    ----------
    u : ndarray, shape (N,)
        The command (input unit).
    y : ndarray, shape (S, N)
        Output of every draw driven by ``u`` from rest (a forward simulation of the
        whole model, not the inverter's own bookkeeping); failed draws are NaN.
    objective : str
        ``"mean"`` or ``"quantile"``.
    quantile : float
        The quantile minimised by the robust objective.
    max_error : float
        Largest ``|mean_s y_s,k - y_d,k|`` over the scored samples (for
        ``objective="quantile"``: the largest ``q``-quantile of ``|y_s,k - y_d,k|``)
        (output unit).
    n_saturated : int
        Samples whose command reached a limit of ``u_limits`` (the target was out of
        reach; reported, never hidden).
    n_nonmonotone : int
        Samples where the one-step map was seen decreasing.
    n_failed_draws : int
        Draws whose simulation failed on the way (left out of the objective).
    n_evaluations : int
        One-step evaluations of the first stage.
    n_corrections : int
        Reference corrections made for the posterior mean (the best iterate is kept).
    stages : tuple of str
        How the model was inverted, first stage first (``"pi_play+creep: per sample"``,
        ``"second_order: deconvolution"``).
    """

    u: np.ndarray
    y: np.ndarray
    objective: str
    quantile: float
    max_error: float
    n_saturated: int
    n_nonmonotone: int
    n_failed_draws: int
    n_evaluations: int
    n_corrections: int
    stages: tuple[str, ...] = field(default=())

    def __str__(self) -> str:
        return (f"Inversion({self.objective}, {self.y.shape[0]} draws x {self.u.size} samples, "
                f"max error {self.max_error:.3g}, saturated {self.n_saturated}, "
                f"non-monotone {self.n_nonmonotone}, failed draws {self.n_failed_draws}; "
                f"stages: {'; '.join(self.stages)})")


@dataclass(frozen=True)
class Member:
    """One model and its parameter vectors in a pooled inversion (:func:`invert_pooled`).

    Attributes
    ----------
    model : HysteresisModel
    thetas : mapping
        ``name -> array (S_m, *shape)``: the member's draws.
    offset : array_like, shape (S_m,) or (S_m, N), optional
        As :func:`invert`'s ``offset``.
    """

    model: HysteresisModel
    thetas: Mapping[str, Any]
    offset: Any = None


# ------------------------------------------------------------------------------ stages


class _FirstStage:
    """The base model (with the blocks right after it) driven by the shared command.

    Evaluated through a :class:`~bayeshyst.models.onestep.StepChain`, prepared once:
    the per-sample path builds no parameter dictionary and no buffer.
    """

    def __init__(self, model: HysteresisModel, theta: Mapping[str, np.ndarray],
                 covariates: dict[str, np.ndarray] | None = None) -> None:
        self.model = model
        self.theta = theta
        self.covariates = covariates
        width = max((int(np.shape(v)[0]) for v in theta.values()), default=1)
        self.chain = StepChain.of_model(model, theta, width, covariates)

    def rest(self, x: float) -> list[np.ndarray]:
        return self.chain.rest(x)

    def step(self, x: float, t_k: np.ndarray, states: list[np.ndarray], k: int):
        return self.chain.step(x, t_k, states, k)


class _Part(NamedTuple):
    """One member of a pooled inversion, prepared: batched theta, offsets, its stages."""

    model: HysteresisModel
    theta: dict
    offset: np.ndarray  # (S_m, 1) or (S_m, N)
    first: _FirstStage
    later: list
    first_name: str
    covariates: dict | None  # the measured columns (N,) the member reads, or None


class _PooledFirstStage:
    """The first stages of several models driven by the one shared command, draws pooled.

    :meth:`step` returns arrays that the next call may overwrite (the chains' buffers);
    :meth:`advance` copies them, to commit a sample.
    """

    def __init__(self, stages: list[_FirstStage]) -> None:
        self.stages = stages
        self.name = " | ".join(st.model.name for st in stages)

    def rest(self, x: float) -> list[list[np.ndarray]]:
        return [st.rest(x) for st in self.stages]

    def step(self, x: float, t_k: np.ndarray, states: list[list[np.ndarray]], k: int):
        if len(self.stages) == 1:
            y, s, failed = self.stages[0].step(x, t_k, states[0], k)
            return y, [s], failed
        out = [st.step(x, t_k, s, k) for st, s in zip(self.stages, states, strict=True)]
        return (np.concatenate([o[0] for o in out]), [o[1] for o in out],
                np.concatenate([o[2] for o in out]))

    def advance(self, x: float, t_k: np.ndarray, states: list[list[np.ndarray]], k: int):
        y, new, failed = self.step(x, t_k, states, k)
        return y.copy(), [[a.copy() for a in s] for s in new], failed.copy()


class _BlockStage:
    """A run of blocks with per-draw inputs, inverted sample by sample."""

    def __init__(self, blocks: list[EffectBlock], thetas: list[dict],
                 covariates: dict[str, np.ndarray] | None = None) -> None:
        self.blocks = blocks
        self.thetas = thetas
        self.covariates = covariates
        self._chain: StepChain | None = None

    @property
    def label(self) -> str:
        return "+".join(b.name for b in self.blocks) + ": per sample"

    def _chain_for(self, width: int) -> StepChain:
        # built on first use, when the number of draws is known
        if self._chain is None or self._chain.width != width:
            self._chain = StepChain.of_blocks(self.blocks, self.thetas, width,
                                              self.covariates)
        return self._chain

    def invert(self, v: np.ndarray, t: np.ndarray, ftol: float, xtol: float) -> np.ndarray:
        """Per-draw inputs ``(S, N)`` making this run of blocks output ``v`` (S, N)."""
        n = v.shape[1]
        chain = self._chain_for(v.shape[0])
        out = np.empty_like(v)
        scale = np.maximum(np.ptp(v, axis=1), 1e-12 * np.maximum(np.abs(v).max(axis=1), 1.0))
        first = 1e-3 * scale
        tol = xtol * scale
        x = v[:, 0].copy()
        states = None
        for k in range(n):
            t_k = t[k:k + 1]
            v_k = v[:, k]
            if states is None:
                def fun(z, k=k, t_k=t_k, v_k=v_k):
                    return chain.step(z, t_k, chain.rest(z), k)[0] - v_k
            else:
                def fun(z, k=k, t_k=t_k, v_k=v_k, states=states):
                    return chain.step(z, t_k, states, k)[0] - v_k
            res = solve_increasing(fun, x, first, ftol=ftol, xtol=tol)
            x = res.x
            base = chain.rest(x) if states is None else states
            _, states, failed = chain.advance(x, t_k, base, k)
            if failed.any():
                raise SimulationError(f"{self.label}: draw {int(np.flatnonzero(failed)[0])} "
                                      f"failed at sample {k}")
            out[:, k] = x
        return out


def _stages(model: HysteresisModel, theta: Mapping[str, np.ndarray],
            covariates: dict[str, np.ndarray] | None = None):
    """Split ``model`` into the first stage and the later stages, in signal order."""
    if not isinstance(model, Composite):
        return _FirstStage(model, theta, covariates), [], model.name
    blocks = list(model.blocks)
    names = block_namespaces(blocks)
    thetas = [ParamSpace.sub_theta(theta, ns) for ns in names]
    lead = 0
    while lead < len(blocks) and not blocks[lead].needs_preview:
        lead += 1
    first_model, first_theta = leading_part(model, lead, theta)
    later: list[Any] = []
    i = lead
    while i < len(blocks):
        if blocks[i].needs_preview:
            later.append((blocks[i], thetas[i]))
            i += 1
            continue
        j = i
        while j < len(blocks) and not blocks[j].needs_preview:
            j += 1
        later.append(_BlockStage(blocks[i:j], thetas[i:j], covariates))
        i = j
    return _FirstStage(first_model, first_theta, covariates), later, first_model.name


# ------------------------------------------------------------------------------ driver


def _objective_value(y: np.ndarray, target: np.ndarray, active: np.ndarray,
                     objective: str, q: float) -> np.ndarray:
    e = (y - target)[active]
    if objective == "mean":
        return e.mean(axis=0)
    return np.quantile(np.abs(e), q, axis=0)


class _Sample:
    """The first stage at one sample: residuals ``y_s(z) - v_s,k`` of the draws in play."""

    def __init__(self, stage: _PooledFirstStage, v_k: np.ndarray, t_k: np.ndarray, states: Any,
                 active: np.ndarray, k: int) -> None:
        self.stage, self.t_k, self.states, self.k = stage, t_k, states, k
        self.active = active
        # the draws in play do not change while the sample is solved
        self.all_active = bool(active.all())
        self.v_act = v_k if self.all_active else v_k[active]

    def residuals(self, z: float) -> np.ndarray:
        s0 = self.stage.rest(z) if self.states is None else self.states
        y, _, failed = self.stage.step(z, self.t_k, s0, self.k)
        if failed.any():
            y = np.where(failed, np.nan, y)
        e = (y if self.all_active else y[self.active]) - self.v_act
        # a draw that fails at this candidate is dropped for good once the sample is
        # committed; meanwhile the objective over the others stays defined
        fin = np.isfinite(e)
        return e if fin.all() else e[fin]

    def reduced(self, how: str):
        """``z -> float``: mean, max or min of the residuals (each non-decreasing in z)."""
        def fun(z: float) -> float:
            e = self.residuals(z)
            if e.size == 0:
                return math.nan
            return float(e.mean() if how == "mean" else e.max() if how == "max" else e.min())
        return fun

    def quantile_loss(self, q: float):
        """``z -> q``-quantile of ``|residual|`` over the draws."""
        def loss(z: float) -> float:
            e = self.residuals(z)
            return _quantile(np.abs(e), q) if e.size else math.inf
        return loss


def _quantile(a: np.ndarray, q: float) -> float:
    """``np.quantile(a, q)`` (its default, linear method) for a small 1-D array.

    Called once per golden-section step of every sample, on a handful of draws: numpy's
    general quantile costs ~100 µs of overhead there, this sort-and-interpolate ~3 µs.
    """
    x = np.sort(a)
    h = (x.size - 1) * q
    i = math.floor(h)
    if i + 1 >= x.size:
        return float(x[-1])
    return float(x[i] + (h - i) * (x[i + 1] - x[i]))


def _invert_first(stage: _PooledFirstStage, v: np.ndarray, t: np.ndarray, objective: str, q: float,
                  lo: float, hi: float, u_scale: float, ftol: float, xtol: float,
                  active: np.ndarray) -> tuple[np.ndarray, int, int, int]:
    """Shared command (N,) for per-draw first-stage targets ``v`` (S, N); updates ``active``."""
    n = v.shape[1]
    u = np.empty(n)
    x = 0.0 if not (np.isfinite(lo) and np.isfinite(hi)) else 0.5 * (lo + hi)
    step = 0.05 * u_scale
    states = None
    n_sat = n_mono = n_eval = 0
    for k in range(n):
        t_k = t[k:k + 1]
        sample = _Sample(stage, v[:, k], t_k, states, active.copy(), k)
        if objective == "mean" or active.sum() == 1:
            res = solve_scalar(sample.reduced("mean"), x, step, lo=lo, hi=hi,
                               ftol=ftol, xtol=xtol)
            n_eval += res.n_evaluations
            xk = float(res.x[0])
            n_sat += int(res.saturated[0])
            n_mono += int(res.nonmonotone[0])
        else:
            # the q-quantile of |e_s| is smallest between the point where every draw is
            # at or below the target and the point where every draw is at or above it
            r_lo = solve_scalar(sample.reduced("max"), x, step, lo=lo, hi=hi,
                                ftol=ftol, xtol=xtol)
            r_hi = solve_scalar(sample.reduced("min"), x, step, lo=lo, hi=hi,
                                ftol=ftol, xtol=xtol)
            n_eval += r_lo.n_evaluations + r_hi.n_evaluations + GOLDEN_ITER
            n_sat += int(r_lo.saturated[0] and r_hi.saturated[0])
            n_mono += int(r_lo.nonmonotone[0] or r_hi.nonmonotone[0])
            a, b = sorted((float(r_lo.x[0]), float(r_hi.x[0])))
            xk = _golden(sample.quantile_loss(q), a, b, xtol)
        s0 = stage.rest(xk) if states is None else states
        y, states, failed = stage.advance(xk, t_k, s0, k)
        active &= ~(failed | ~np.isfinite(y))
        if not active.any():
            raise SimulationError(f"{stage.name}: every draw failed by sample {k}")
        step = max(abs(xk - x), 1e-3 * u_scale)
        x = xk
        u[k] = xk
    return u, n_sat, n_mono, n_eval


def _golden(loss, a: float, b: float, xtol: float) -> float:
    """Minimiser of ``loss`` on ``[a, b]`` by golden-section search."""
    if b - a <= xtol:
        return 0.5 * (a + b)
    r = 0.5 * (math.sqrt(5.0) - 1.0)
    c, d = b - r * (b - a), a + r * (b - a)
    fc, fd = loss(c), loss(d)
    for _ in range(GOLDEN_ITER):
        if b - a <= xtol:
            break
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - r * (b - a)
            fc = loss(c)
        else:
            a, c, fc = c, d, fd
            d = a + r * (b - a)
            fd = loss(d)
    return c if fc <= fd else d


def invert(model: HysteresisModel, y_d: Any, t: Any, thetas: Mapping[str, Any], *,
           objective: str = "mean", quantile: float = 0.9,
           u_limits: tuple[float, float] = (-math.inf, math.inf),
           offset: Any = None, periodic: bool = False, scored: Any = None,
           covariates: Mapping[str, Any] | None = None) -> Inversion:
    """Command ``u`` that makes ``model`` follow ``y_d``, for ``S`` parameter vectors at once.

    Parameters
    ----------
    model : HysteresisModel
        Any model or composition (``Composite``).
    y_d : array_like, shape (N,)
        Desired output (output unit). Should start at rest when the model has
        ``needs_preview`` blocks and ``periodic`` is False (the pre-actuation of the
        inverse dynamics must fit before the motion starts).
    t : array_like, shape (N,)
        Sample times (s); uniform when the model has ``needs_preview`` blocks.
    thetas : mapping
        ``name -> array (S, *shape)``: ``S`` parameter vectors (posterior draws, or one
        MAP with ``S = 1``).
    objective : {"mean", "quantile"}
        What the shared command achieves across draws (module docstring).
    quantile : float
        ``q`` of the robust objective, in (0, 1).
    u_limits : (float, float)
        Admissible command range (input unit), e.g. the amplifier's; targets beyond it
        saturate there and are counted in ``n_saturated``.
    offset : array_like, shape (S,) or (S, N), optional
        Observation offsets added to each draw's output (``obs.offset``), or a known
        additive term per draw and sample (a discrepancy along a command).
    periodic : bool
        ``y_d`` holds whole periods of a periodic reference (dynamics inverted as the
        periodic steady state).
    scored : array_like of bool, shape (N,), optional
        Samples the reference must be met on (``max_error`` and the posterior-mean
        corrections use only these); default all. Leave out a warm-up whose transient no
        command can remove: the model starts at rest, a periodic inverse assumes the
        steady state.
    covariates : mapping of str to array_like (N,), optional
        Measured columns along the reference (e.g. ``{"temperature_c": T}``) for a model
        that reads them; None runs such a model at its nominal conditions.

    Returns
    -------
    Inversion

    Raises
    ------
    ParameterError
        For bad arguments (unknown objective, quantile outside (0, 1), empty or
        non-finite reference, limits not increasing).
    SimulationError
        If every draw fails.
    ModelError
        If the model's output is not monotone in the input over ``u_limits``
        (:meth:`~bayeshyst.models.base.HysteresisModel.check_invertible`).
    """
    return invert_pooled([Member(model, thetas, offset)], y_d, t, objective=objective,
                         quantile=quantile, u_limits=u_limits, periodic=periodic,
                         scored=scored, covariates=covariates)


def invert_pooled(members: Any, y_d: Any, t: Any, *, objective: str = "mean",
                  quantile: float = 0.9, u_limits: tuple[float, float] = (-math.inf, math.inf),
                  periodic: bool = False, scored: Any = None,
                  covariates: Mapping[str, Any] | None = None) -> Inversion:
    """One command for the draws of several models pooled (a model-averaged design).

    Every member's draws are carried together through the shared command, exactly as
    :func:`invert` carries one model's draws: with ``objective="mean"`` the mean output
    over *all* pooled draws meets ``y_d``, with ``"quantile"`` the ``q``-quantile of
    ``|y - y_d|`` over them is smallest. Pooling draws in proportion to each model's
    weight (e.g. its stacking weight) makes that the model-averaged posterior's mean or
    quantile. Each member's later stages (dynamics) are inverted with its own
    parameters, per draw.

    Parameters
    ----------
    members : sequence of Member
        At least one.
    y_d, t, objective, quantile, u_limits, periodic, scored, covariates
        As :func:`invert`.

    Returns
    -------
    Inversion
        ``y`` stacks the members' draws in order.
    """
    members = list(members)
    if not members or not all(isinstance(m, Member) for m in members):
        raise ParameterError("members must be a non-empty sequence of Member")
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if not 0.0 < float(quantile) < 1.0:
        raise ParameterError(f"quantile must be in (0, 1), got {quantile}")
    lo, hi = (float(v) for v in u_limits)
    if not lo < hi:
        raise ParameterError(f"u_limits must be increasing, got {u_limits}")
    y_d = np.ascontiguousarray(y_d, dtype=float)
    t = np.ascontiguousarray(t, dtype=float)
    if y_d.ndim != 1 or y_d.shape != t.shape or y_d.size == 0:
        raise ParameterError(f"y_d and t must be 1-D of equal length, got {y_d.shape}, "
                             f"{t.shape}")
    if not (np.all(np.isfinite(y_d)) and np.all(np.isfinite(t))):
        raise ParameterError("y_d and t must be finite")
    parts = []
    for m in members:
        # only the columns the member reads; refused by name when one is missing
        cov = (check_covariates(covariates, m.model.covariates, y_d.size, m.model.name)
               if covariates is not None else None)
        theta_b, n_m = m.model._batch_theta(m.thetas, batched=True)
        # a model non-monotone in its input (a butterfly) is invertible on part of its
        # range only: it refuses u_limits reaching beyond, with the reason
        base, base_theta = leading_part(m.model, 0, theta_b)
        base.check_invertible(base_theta, lo, hi)
        # (S, 1): one offset per draw; (S, N): a known additive term per draw and sample
        # (the model discrepancy evaluated along a previous command)
        off = np.zeros((n_m, 1)) if m.offset is None else np.asarray(m.offset, dtype=float)
        off = off.reshape(-1, 1) if off.ndim <= 1 else off
        if off.ndim != 2 or off.shape[0] not in (1, n_m) or off.shape[1] not in (1, y_d.size):
            raise ParameterError(f"{m.model.name}: offset must have shape ({n_m},) or ({n_m}, "
                                 f"{y_d.size}), got {np.shape(m.offset)}")
        parts.append(_Part(m.model, theta_b, np.broadcast_to(off, (n_m, off.shape[1])),
                           *_stages(m.model, theta_b, cov), cov))
    pooled = _PooledFirstStage([p.first for p in parts])
    several = len(parts) > 1
    labels = [f"{' | '.join(p.first_name for p in parts)}: per sample"] + [
        (f"{p.model.name}: " if several else "")
        + (st.label if isinstance(st, _BlockStage) else f"{st[0].name}: deconvolution")
        for p in parts for st in p.later]
    n_draws = sum(p.offset.shape[0] for p in parts)
    span = float(np.ptp(y_d)) or max(abs(float(y_d[0])), 1.0)
    ftol = FTOL_REL * span
    u_scale = hi - lo if math.isfinite(hi - lo) else 1.0
    xtol = XTOL_REL * max(u_scale, 1.0)
    mask = np.ones(y_d.size, dtype=bool) if scored is None else np.asarray(scored, dtype=bool)
    if mask.shape != y_d.shape or not mask.any():
        raise ParameterError(f"scored must be a boolean mask of shape {y_d.shape} with at "
                             f"least one True, got shape {mask.shape}")
    has_later = any(p.later for p in parts)
    correction = np.zeros_like(y_d)
    active = np.ones(n_draws, dtype=bool)
    total_eval = 0
    n_corr = 0
    best = None
    while True:
        vs = []
        for p in parts:
            v = y_d[None, :] - p.offset + correction[None, :]  # (S_m, N)
            for stage in reversed(p.later):
                if isinstance(stage, _BlockStage):
                    v = stage.invert(v, t, ftol, XTOL_REL)
                else:
                    block, th = stage
                    v = deconvolve(block, th, v, t, periodic=periodic).w
            vs.append(v)
        u, n_sat, n_mono, n_eval = _invert_first(pooled, np.concatenate(vs), t, objective,
                                                 quantile, lo, hi, u_scale, ftol, xtol, active)
        total_eval += n_eval
        runs = [(p.model.run_batch(u, t, p.theta, covariates=p.covariates), p.offset)
                for p in parts]
        y = np.concatenate([traj.y + off for traj, off in runs])
        active &= ~np.concatenate([traj.failed for traj, _ in runs])
        stat = _objective_value(y, y_d[None, :], active, "mean", quantile)
        err = float(np.max(np.abs(stat[mask])))
        if best is not None and err >= best[0]:
            # the fixed-point iteration stopped contracting: keep the best command
            err, u, y, n_sat, n_mono = best
            break
        best = (err, u, y, n_sat, n_mono)
        # only the posterior mean behind per-draw dynamics needs the correction
        if (objective != "mean" or n_draws == 1 or not has_later or err <= 10 * ftol
                or n_corr >= MAX_CORRECTIONS):
            break
        correction = correction - np.where(mask, stat, 0.0)
        n_corr += 1
    if objective == "quantile" and active.sum() > 1:
        err = float(np.max(_objective_value(y, y_d[None, :], active, "quantile",
                                            quantile)[mask]))
    return Inversion(u=u, y=y, objective=objective, quantile=float(quantile), max_error=err,
                     n_saturated=n_sat, n_nonmonotone=n_mono,
                     n_failed_draws=int(n_draws - active.sum()), n_evaluations=total_eval,
                     n_corrections=n_corr, stages=tuple(labels))
