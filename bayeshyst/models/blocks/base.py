"""The effect-block contract :class:`EffectBlock`, its registry and the data's time scales.

See :mod:`bayeshyst.models.blocks` for the conventions every block follows.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models.base import Trajectory, batch_theta, check_covariates, sample_period
from bayeshyst.params import ParamSpace

__all__ = [
    "DEFAULT_DT",
    "DEFAULT_DURATION",
    "EffectBlock",
    "TimeScales",
    "block_class",
    "block_names",
    "param_columns",
    "register_block",
    "time_scales",
]

#: Sampling period assumed when no data is given (s): a 10 kHz piezo rig.
DEFAULT_DT = 1e-4
#: Record duration assumed when no data is given (s).
DEFAULT_DURATION = 10.0


@dataclass(frozen=True)
class TimeScales:
    """Sampling period ``dt`` (s, the finest median step) and ``duration`` (s, longest record)."""

    dt: float = DEFAULT_DT
    duration: float = DEFAULT_DURATION

    @property
    def fs(self) -> float:
        """Sampling rate (Hz)."""
        return 1.0 / self.dt


def time_scales(data: Any = None) -> TimeScales:
    """Time scales of a Record, a Dataset or any object with ``t``; defaults for None.

    ``dt`` is :func:`~bayeshyst.models.base.sample_period` (the finest median step);
    records of fewer than two samples do not count.

    Raises
    ------
    ParameterError
        If the times do not increase.
    """
    if data is None or not (hasattr(data, "t") or hasattr(data, "records")):
        return TimeScales()
    records = list(data) if hasattr(data, "records") else [data]
    times = [np.asarray(rec.t, dtype=float) for rec in records]
    durations = [float(t[-1] - t[0]) for t in times if t.size >= 2]
    if not durations:
        return TimeScales()
    dt, duration = sample_period(data), max(durations)
    if not math.isfinite(duration):
        raise ParameterError(f"sample times must be finite; a record lasts {duration}")
    return TimeScales(dt, duration)


# ------------------------------------------------------------------------ base class


@dataclass(frozen=True)
class EffectBlock(ABC):
    """A causal single-input single-output block with explicit state.

    Class attributes
    ----------------
    name : str
        Name in spec strings (``"pi_play+arx"``) and the parameter namespace.
    rate_dependent : bool
        Whether the output depends on the time axis (or on the sample count).
    equation : str
        What the block implements, for docs.
    affine : bool
        Whether the output is affine in the input signal from the steady initial
        state: ``B[a w1 + b w2] = a B[w1] + b B[w2] + (1 - a - b) B[0]`` (linear
        dynamics, creep, delay, drift). A model that is linear in some parameters stays
        so after affine blocks (:meth:`Composite.linear_design`), which lets the
        sampler draw those parameters exactly.
    example : mapping
        Settings to build an instance for listings when some setting has no default.
    linear_params : tuple of str
        Parameters the block's output is linear in, given its input and its other
        parameters, from its steady initial state (the ``unexplained`` term's
        coefficients). A composite whose later blocks are affine lets the sampler draw
        them exactly (:attr:`~bayeshyst.models.compose.Composite.linear_group`).
    needs_preview : bool
        Whether the block is linear time-invariant dynamics whose output responds to its
        present input weakly or not at all (a delay, sampled second-order dynamics): its
        exact inverse is not causal, so inversion deconvolves it over the whole
        (known) trajectory (:mod:`bayeshyst.inverse.lti`) instead of sample by sample.
    """

    name: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = True
    equation: ClassVar[str] = ""
    affine: ClassVar[bool] = False
    linear_params: ClassVar[tuple[str, ...]] = ()
    needs_preview: ClassVar[bool] = False
    #: settings that a block without defaults for all of them is shown with
    #: (``bayeshyst models``): ``aux`` needs a column to read
    example: ClassVar[Mapping[str, Any]] = MappingProxyType({})

    @property
    @abstractmethod
    def state_size(self) -> int:
        """Number of state entries ``S`` (fixed by the structural settings)."""

    @abstractmethod
    def param_space(self, data: Any = None) -> ParamSpace:
        """Declared parameters with priors scaled from ``data`` (Record, Dataset or None)."""

    @abstractmethod
    def _initial_state(self, theta: Mapping[str, np.ndarray], w0: np.ndarray,
                       t0: float) -> np.ndarray:
        """Steady state (W, S) for the input ``w0`` (W,) held since forever, at time ``t0``.

        ``t0`` may be NaN: the state is then taken to be at the first sample's time.
        """

    @abstractmethod
    def _apply(self, w: np.ndarray, t: np.ndarray, theta: Mapping[str, np.ndarray],
               state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apply to ``w`` (W, N) at times ``t`` (N,) from ``state`` (W, S).

        Returns ``out (W, N)``, the final state ``(W, S)`` and ``failed (W,)``; the
        arguments are not modified. ``theta`` holds float64 arrays with a leading W axis.
        """

    @property
    def covariates(self) -> tuple[str, ...]:
        """Measured columns the block reads besides its input (none for most blocks)."""
        return ()

    def _apply_with(self, w: np.ndarray, t: np.ndarray, theta: Mapping[str, np.ndarray],
                    state: np.ndarray, covariates: Mapping[str, np.ndarray] | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_apply` with the measured channels ``column -> (N,)`` (None: nominal)."""
        return self._apply(w, t, theta, state)

    def _linear_columns(self, w: np.ndarray, t: np.ndarray, theta: Mapping[str, np.ndarray],
                        names: tuple[str, ...], covariates: Mapping[str, np.ndarray] | None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The block's design in its :attr:`linear_params` ``names``, in closed form.

        From the steady initial state at the first sample: ``phi (W, N, P)`` (columns
        in the order of ``names``, each parameter flattened), ``const (W, N)`` (the
        output with those parameters zero) and ``failed (W,)``, for input ``w (W, N)``
        and the other parameters ``theta`` (leading axis W). None (the default): the
        composite applies the block to one unit signal per column instead, which is
        exact for any block but costs ``P + 1`` applications.
        """
        return None

    # ------------------------------------------------------------------ conveniences
    @functools.cached_property
    def _shapes(self) -> dict[str, tuple[int, ...]]:
        space = self.param_space()
        return {n: space[n].shape for n in space.all_names}

    def _batch_theta(self, theta: Mapping[str, Any],
                     batched: bool) -> tuple[dict, int | None]:
        return batch_theta(self.name, self._shapes, theta, batched=batched)

    def initial_state(self, theta: Mapping[str, Any], w0: float,
                      t0: float = math.nan) -> np.ndarray:
        """Steady state (S,) of one parameter vector for the input ``w0`` held since forever."""
        tb, _ = self._batch_theta(theta, batched=False)
        return self._initial_state(tb, np.array([float(w0)]), float(t0))[0]

    def apply(self, w: Any, t: Any, theta: Mapping[str, Any], *,
              state0: np.ndarray | None = None,
              covariates: Mapping[str, Any] | None = None) -> Trajectory:
        """Apply the block to one signal ``w`` (N,) at times ``t`` (N,) (s).

        ``state0`` (S,) defaults to the steady state at ``w[0]``; ``covariates`` as in
        :meth:`~bayeshyst.models.base.HysteresisModel.run`. Raises
        :class:`SimulationError` if the parameter vector fails.
        """
        tb, _ = self._batch_theta(theta, batched=False)
        traj = self.apply_batch(np.asarray(w, float)[None, :], t, tb,
                                state0=None if state0 is None else np.asarray(state0)[None],
                                covariates=covariates)
        if traj.failed[0]:
            raise SimulationError(f"{self.name}: block failed for theta={dict(theta)}")
        return Trajectory(traj.y[0], traj.state[0], np.asarray(False))

    def apply_batch(self, w: Any, t: Any, thetas: Mapping[str, Any], *,
                    state0: np.ndarray | None = None,
                    covariates: Mapping[str, Any] | None = None) -> Trajectory:
        """Apply ``W`` parameter vectors (arrays ``(W, *shape)``) to ``w`` (W, N) or (N,)."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        w = np.asarray(w, dtype=np.float64)
        if (t.ndim != 1 or t.size == 0 or w.shape[-1:] != t.shape or w.ndim > 2
                or not (np.all(np.isfinite(t)) and np.all(np.isfinite(w)))):
            raise ParameterError(f"w {w.shape} and t {t.shape} must be finite, t 1-D and "
                                 "non-empty, w (N,) or (W, N) with N = len(t)")
        tb, width = self._batch_theta(thetas, batched=True)
        if width is None:  # a block without parameters: the walkers are the rows of w
            width = w.shape[0] if w.ndim == 2 else 1
        w = np.ascontiguousarray(np.broadcast_to(w, (width, t.size)))
        s0 = (self._initial_state(tb, w[:, 0].copy(), math.nan) if state0 is None
              else np.ascontiguousarray(state0, dtype=np.float64))
        if s0.shape != (width, self.state_size):
            raise ParameterError(f"{self.name}: state0 must have shape ({width}, "
                                 f"{self.state_size}), got {s0.shape}")
        cov = check_covariates(covariates, self.covariates, t.size, self.name)
        y, state, failed = self._apply_with(w, t, tb, s0, cov)
        return Trajectory(y, state, failed)

    def describe(self) -> str:
        """Name, equation and the default parameter table."""
        return f"{self.name}  ({type(self).__name__}; {self.equation})\n{self.param_space()}"


_BLOCKS: dict[str, type[EffectBlock]] = {}


def register_block(cls: type[EffectBlock]) -> type[EffectBlock]:
    """Class decorator adding an effect block under its ``name``."""
    if not cls.name or (cls.name in _BLOCKS and _BLOCKS[cls.name] is not cls):
        raise ModelError(f"block {cls.__name__}: name {cls.name!r} is empty or taken")
    _BLOCKS[cls.name] = cls
    return cls


def block_names() -> list[str]:
    """Registered effect-block names, sorted."""
    return sorted(_BLOCKS)


def block_class(name: str) -> type[EffectBlock]:
    """The block class registered under ``name``; ModelError listing the valid names."""
    try:
        return _BLOCKS[name]
    except KeyError:
        raise ModelError(f"unknown effect block {name!r}; valid blocks: "
                         f"{', '.join(block_names())}") from None


def param_columns(theta: Mapping[str, np.ndarray], name: str, width: int) -> np.ndarray:
    """A (W, n) parameter array, or (W, 0) when the block declares none of that name."""
    if name in theta:
        return np.ascontiguousarray(theta[name], dtype=np.float64).reshape(width, -1)
    return np.empty((width, 0))
