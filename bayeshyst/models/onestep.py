"""One-sample evaluation of a model, or of a run of blocks, prepared once per inversion.

Numerical inversion (:mod:`bayeshyst.inverse.numerical`) evaluates the one-step map of
its first stage some 20 to 100 times per sample and command (bracketing, Illinois
refinement, the golden section of the robust objective), each time for every draw.
Through the general path, :meth:`Composite._run_with
<bayeshyst.models.compose.Composite._run_with>`, each of those evaluations rebuilds
what does not change from one sample to the next: the parameter dictionaries of every
part (``ParamSpace.sub_theta``), the kernels' buffers, the output map's coefficient
matrix (``np.column_stack``) and -- the one real computation among them -- the output
map's proof that each draw's polynomial is monotone (513 grid points per draw and call).
Measured on the demo's final model, that overhead was almost all of the 188 s the
feedforward stage took.

:class:`StepChain` does that work once: it splits the model into its parts, keeps each
part's parameters as the arrays its kernel reads, allocates the output and scratch
state buffers, and evaluates one sample as one kernel call per part. The common parts
call their numba kernels directly (``pi_play``, ``asym_output`` with its monotonicity
checked once per draw, ``creep``); any other model or block runs through its own
``_run_with``/``_apply_with`` with its parameters prepared. The arithmetic is the
kernels' own, so a step gives the bits :meth:`HysteresisModel.run_batch
<bayeshyst.models.base.HysteresisModel.run_batch>` gives on the same sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numba import njit

from bayeshyst.models._kernels.blocks import _poly_monotone, lag_bank_batch
from bayeshyst.models._kernels.operators import pi_play_batch
from bayeshyst.models.base import HysteresisModel
from bayeshyst.models.blocks import AsymmetricOutput, Creep, EffectBlock
from bayeshyst.models.blocks.base import param_columns
from bayeshyst.models.compose import Composite
from bayeshyst.models.pi import PrandtlIshlinskii

__all__ = ["StepChain", "asym_output_prepared", "asym_output_valid"]

#: Grid of the output map's monotonicity proof (as its forward kernel uses).
_MONOTONE_GRID = 513


# ------------------------------------------------------------------ output-map kernels


@njit(cache=True)
def asym_output_valid(a, centre, half, ok):
    """Which draws' output maps the forward kernel accepts, written to ``ok`` (W,).

    Parameters
    ----------
    a : ndarray, shape (W, n - 1)
        Coefficients ``a_2 .. a_n`` (1).
    centre, half : ndarray, shape (W,)
        Centre and half-span of the data's output (output unit).
    ok : ndarray of bool, shape (W,)
        Written: the same test as the forward kernel's (positive half-span, finite
        values, the polynomial provably increasing on ``[-1, 1]``).
    """
    for j in range(a.shape[0]):
        good = half[j] > 0.0 and math.isfinite(centre[j])
        for i in range(a.shape[1]):
            if not math.isfinite(a[j, i]):
                good = False
        ok[j] = good and _poly_monotone(a[j], _MONOTONE_GRID)


@njit(cache=True)
def asym_output_prepared(w, a, centre, half, ok, out, failed):
    """``y = c + h P((w - c) / h)`` for draws whose validity ``ok`` is already known.

    The forward kernel's arithmetic in the forward kernel's order (the same bits), less
    its per-call monotonicity proof, which :func:`asym_output_valid` gives once.

    Parameters
    ----------
    w : ndarray, shape (W, N)
        Block input (output unit).
    a, centre, half : ndarray
        As :func:`asym_output_valid`.
    ok : ndarray of bool, shape (W,)
        From :func:`asym_output_valid`.
    out : ndarray, shape (W, N)
        Written; rows of failed draws are NaN.
    failed : ndarray of bool, shape (W,)
        Written: not ``ok`` or a non-finite output.
    """
    p = a.shape[1]
    for j in range(w.shape[0]):
        good = ok[j]
        if good:
            for k in range(w.shape[1]):
                x = (w[j, k] - centre[j]) / half[j]
                acc = 0.0
                for i in range(p - 1, -1, -1):
                    acc = x * (a[j, i] + acc)
                v = centre[j] + half[j] * x * (1.0 + acc)
                out[j, k] = v
                if not math.isfinite(v):
                    good = False
        failed[j] = not good
        if not good:
            for k in range(w.shape[1]):
                out[j, k] = np.nan


# ------------------------------------------------------------------------ one part


class _Part:
    """One part of a chain at one sample: input ``(W, 1)`` or the shared ``(1,)``.

    ``run`` returns ``(out (W, 1), state after, failed (W,) or None)``; None means the
    part cannot fail (its kernel flags nothing). Fast parts write into buffers of their
    own, valid until their next call; ``state_in`` is never modified.
    """

    state_size: int

    def run(self, inp: np.ndarray, t_k: np.ndarray, state_in: np.ndarray,
            cov_k: Mapping[str, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray, Any]:
        raise NotImplementedError


class _PiPlay(_Part):
    """``pi_play`` with its weights and thresholds as the kernel reads them."""

    def __init__(self, theta: Mapping[str, np.ndarray], width: int) -> None:
        self.p0, self.w, self.r = theta["p0"], theta["w"], theta["r"]
        self.state_size = self.w.shape[1]
        self.out = np.empty((width, 1))
        self.state = np.empty((width, self.state_size))

    def run(self, inp, t_k, state_in, cov_k):
        np.copyto(self.state, state_in)
        pi_play_batch.serial(inp, self.p0, self.w, self.r, self.state, self.out)
        return self.out, self.state, None


class _AsymOutput(_Part):
    """``asym_output`` with its coefficient matrix built and its draws checked once."""

    state_size = 0

    def __init__(self, block: AsymmetricOutput, theta: Mapping[str, np.ndarray],
                 width: int) -> None:
        self.a = np.ascontiguousarray(np.column_stack(
            [np.asarray(theta[f"a{i}"], float).reshape(width)
             for i in range(2, block.order + 1)]))
        self.centre = np.ascontiguousarray(theta["centre"], dtype=np.float64).reshape(width)
        self.half = np.ascontiguousarray(theta["half_span"], dtype=np.float64).reshape(width)
        self.ok = np.empty(width, dtype=bool)
        asym_output_valid(self.a, self.centre, self.half, self.ok)
        self.out = np.empty((width, 1))
        self.failed = np.empty(width, dtype=bool)
        self.state = np.empty((width, 0))

    def run(self, inp, t_k, state_in, cov_k):
        asym_output_prepared(inp, self.a, self.centre, self.half, self.ok, self.out,
                             self.failed)
        return self.out, self.state, self.failed


class _Creep(_Part):
    """``creep`` (a bank of lags) with its gains and time constants prepared."""

    def __init__(self, block: Creep, theta: Mapping[str, np.ndarray], width: int) -> None:
        self.c = param_columns(theta, "c", width)
        self.tau = param_columns(theta, "tau", width)
        self.state_size = block.state_size
        self.out = np.empty((width, 1))
        self.state = np.empty((width, self.state_size))
        self.failed = np.empty(width, dtype=bool)

    def run(self, inp, t_k, state_in, cov_k):
        np.copyto(self.state, state_in)
        lag_bank_batch.serial(inp, t_k, self.c, self.tau, self.state, self.out, self.failed)
        return self.out, self.state, self.failed


class _AnyModel(_Part):
    """Any hysteresis model through its own ``_run_with`` (parameters prepared)."""

    def __init__(self, model: HysteresisModel, theta: Mapping[str, np.ndarray],
                 state_size: int) -> None:
        self.model, self.theta, self.state_size = model, theta, state_size

    def run(self, inp, t_k, state_in, cov_k):
        return self.model._run_with(inp, t_k, self.theta, state_in, cov_k)


class _AnyBlock(_Part):
    """Any effect block through its own ``_apply_with`` (parameters prepared)."""

    def __init__(self, block: EffectBlock, theta: Mapping[str, np.ndarray]) -> None:
        self.block, self.theta, self.state_size = block, theta, block.state_size

    def run(self, inp, t_k, state_in, cov_k):
        return self.block._apply_with(np.ascontiguousarray(inp), t_k, self.theta, state_in,
                                      cov_k)


def _model_part(model: HysteresisModel, theta: Mapping[str, np.ndarray], width: int,
                state_size: int) -> _Part:
    # exact types: a subclass may change what a step does
    if type(model) is PrandtlIshlinskii:
        return _PiPlay(theta, width)
    return _AnyModel(model, theta, state_size)


def _block_part(block: EffectBlock, theta: Mapping[str, np.ndarray], width: int) -> _Part:
    if type(block) is AsymmetricOutput:
        return _AsymOutput(block, theta, width)
    if type(block) is Creep:
        return _Creep(block, theta, width)
    return _AnyBlock(block, theta)


# ------------------------------------------------------------------------ the chain


def _at(covariates: dict[str, np.ndarray] | None, k: int) -> dict[str, np.ndarray] | None:
    """The measured columns at sample ``k`` (arrays of one sample), or None."""
    return None if covariates is None else {c: v[k:k + 1] for c, v in covariates.items()}


class StepChain:
    """A model (or a run of blocks) evaluated one sample at a time for ``W`` draws.

    Build it with :meth:`of_model` (a model driven by one shared input) or
    :meth:`of_blocks` (blocks with one input per draw). The state is a list of arrays,
    one ``(W, S_i)`` per part; :meth:`rest` gives the relaxed one, :meth:`step` the
    output of one sample and the state after it without touching the state given.

    Parameters
    ----------
    parts : sequence of _Part
        The prepared parts in signal order.
    width : int
        Number of draws ``W``.
    covariates : dict of str to ndarray (N,), optional
        Measured columns along the reference (None: nominal conditions).
    rest : callable
        ``x -> list of (W, S_i)``: the relaxed state for the input ``x`` (float, or
        ndarray (W,) for blocks).
    shared_input : bool
        Whether the input is one value for every draw (a model) or one per draw.
    """

    def __init__(self, parts: Sequence[_Part], width: int,
                 covariates: dict[str, np.ndarray] | None, rest: Any,
                 shared_input: bool) -> None:
        self.parts = tuple(parts)
        self.width = int(width)
        self.covariates = covariates
        self._rest = rest
        self._shared = shared_input
        self._u = np.empty(1)
        self._w = np.empty((self.width, 1))
        self._failed = np.zeros(self.width, dtype=bool)
        self._cov_k: tuple[int, Any] = (-1, None)

    # ---------------------------------------------------------------- construction
    @classmethod
    def of_model(cls, model: HysteresisModel, theta: Mapping[str, np.ndarray],
                 width: int, covariates: dict[str, np.ndarray] | None = None) -> StepChain:
        """The chain of ``model`` (base, then its blocks) for batched ``theta`` (W, ...).

        Parameters
        ----------
        model : HysteresisModel
            Any model; a :class:`Composite` is split into its base and blocks.
        theta : mapping
            ``name -> (W, *shape)`` float64, as ``model._batch_theta(.., batched=True)``.
        width : int
            ``W``.
        covariates : dict of str to ndarray (N,), optional
            Measured columns along the reference.
        """
        if isinstance(model, Composite):
            base_theta, block_thetas = model._split(theta)
            sizes = [b.state_size for b in model.blocks]
            probe = model._initial_state_with(theta, 0.0, _at(covariates, 0))
            parts = [_model_part(model.base, base_theta, width, probe.shape[1] - sum(sizes))]
            parts += [_block_part(b, th, width)
                      for b, th in zip(model.blocks, block_thetas, strict=True)]
        else:
            probe = model._initial_state_with(theta, 0.0, _at(covariates, 0))
            parts = [_model_part(model, theta, width, probe.shape[1])]
        chain: StepChain

        def rest(x: float) -> list[np.ndarray]:
            full = model._initial_state_with(theta, float(x), _at(covariates, 0))
            return chain._split_state(full)

        chain = cls(parts, width, covariates, rest, shared_input=True)
        return chain

    @classmethod
    def of_blocks(cls, blocks: Sequence[EffectBlock], thetas: Sequence[Mapping[str, Any]],
                  width: int, covariates: dict[str, np.ndarray] | None = None) -> StepChain:
        """The chain of a run of ``blocks`` with one input per draw.

        Parameters
        ----------
        blocks : sequence of EffectBlock
            In signal order.
        thetas : sequence of mapping
            Each block's parameters ``name -> (W, *shape)``.
        width : int
            ``W``.
        covariates : dict of str to ndarray (N,), optional
            Measured columns along the reference.
        """
        blocks, thetas = list(blocks), list(thetas)
        parts = [_block_part(b, th, width) for b, th in zip(blocks, thetas, strict=True)]

        def rest(x: np.ndarray) -> list[np.ndarray]:
            # each block rests at the steady output of the blocks before it
            states, w = [], np.ascontiguousarray(x, dtype=float)
            first = _at(covariates, 0)
            for i, (block, th) in enumerate(zip(blocks, thetas, strict=True)):
                s = block._initial_state(th, w, math.nan)
                states.append(s)
                if i + 1 < len(blocks):
                    out, _, _ = block._apply_with(np.ascontiguousarray(w[:, None]),
                                                  np.zeros(1), th, s, first)
                    w = np.ascontiguousarray(out[:, 0])
            return states

        return cls(parts, width, covariates, rest, shared_input=False)

    def _split_state(self, full: np.ndarray) -> list[np.ndarray]:
        """A composite's state ``(W, S)`` as one C-contiguous array per part."""
        out, start = [], 0
        for part in self.parts:
            out.append(np.ascontiguousarray(full[:, start:start + part.state_size]))
            start += part.state_size
        return out

    # ---------------------------------------------------------------- evaluation
    def rest(self, x: Any) -> list[np.ndarray]:
        """The relaxed state for the input ``x`` (float, or (W,) for blocks), per part."""
        return self._rest(x)

    def step(self, x: Any, t_k: np.ndarray, states: Sequence[np.ndarray],
             k: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
        """Output of one sample from ``states``, the state after it and the failures.

        Parameters
        ----------
        x : float or ndarray, shape (W,)
            The input at the sample: the shared command, or one value per draw.
        t_k : ndarray, shape (1,)
            Its time (s).
        states : sequence of ndarray
            State before the sample, per part (not modified).
        k : int
            Index of the sample (for the measured columns).

        Returns
        -------
        y : ndarray, shape (W,)
        states : list of ndarray
        failed : ndarray of bool, shape (W,)
            All three live in buffers that the next call overwrites: use them at once,
            or copy them (:meth:`advance`).
        """
        if self._cov_k[0] != k:
            self._cov_k = (k, _at(self.covariates, k))
        cov_k = self._cov_k[1]
        if self._shared:
            self._u[0] = x
            sig = self._u
        else:
            self._w[:, 0] = x
            sig = self._w
        failed = self._failed
        failed[:] = False
        new = []
        for part, s in zip(self.parts, states, strict=True):
            sig, s2, f = part.run(sig, t_k, s, cov_k)
            if f is not None:
                failed |= f
            new.append(s2)
        return sig[:, 0], new, failed

    def advance(self, x: Any, t_k: np.ndarray, states: Sequence[np.ndarray],
                k: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
        """:meth:`step`, its results copied out of the buffers (to commit a sample)."""
        y, new, failed = self.step(x, t_k, states, k)
        return y.copy(), [s.copy() for s in new], failed.copy()
