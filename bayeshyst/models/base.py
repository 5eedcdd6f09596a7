"""The model contract: :class:`HysteresisModel` and its result record :class:`Trajectory`.

A model is a frozen dataclass of *structural* settings (operator count, polynomial
order). Everything that is estimated, or that depends on the data (thresholds placed
over the input range), lives in ``theta`` and is declared by :meth:`param_space`.
Forward simulation is pure: the state goes in (``state0``) and comes out
(``Trajectory.state``), so a record can be simulated in pieces.

Subclasses write one batched path, :meth:`HysteresisModel._run`, over ``W`` parameter
vectors at once (the numba kernel loops over walkers); the single-theta methods are the
``W = 1`` case of it. That keeps one implementation per model and makes
"batched == one-by-one" a real test of the kernel's indexing.
"""

from __future__ import annotations

import functools
import re
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models.linear_design import LinearDesign, LinearInParams, unit_signals
from bayeshyst.params import ParamSpace

__all__ = [
    "DataScales",
    "HysteresisModel",
    "LinearDesign",
    "LinearInParams",
    "Trajectory",
    "batch_theta",
    "check_count",
    "check_covariates",
    "check_signal",
    "checked_state",
    "data_scales",
    "kernel_buffers",
    "sample_period",
    "unit_signals",
]


@dataclass(frozen=True)
class DataScales:
    """Ranges of a data set that default priors and operator placements scale with.

    Attributes
    ----------
    u_min, u_max : float
        Input range (input unit).
    y_min, y_max : float
        Output range (output unit).
    u_unit, y_unit : str
        Units of input and output, used to label parameters: the data's
        (``Record.units``; ``"unknown"`` where the data give none). Without data, the
        classic piezo labels V and um of the unit ranges that a model listing shows.
    """

    u_min: float = -1.0
    u_max: float = 1.0
    y_min: float = -1.0
    y_max: float = 1.0
    u_unit: str = "V"
    y_unit: str = "um"

    @property
    def u_span(self) -> float:
        """Peak-to-peak input (input unit)."""
        return self.u_max - self.u_min

    @property
    def y_span(self) -> float:
        """Peak-to-peak output."""
        return self.y_max - self.y_min

    @property
    def gain(self) -> float:
        """Secant gain ``y_span / u_span`` (output unit per input unit)."""
        return self.y_span / self.u_span

    @property
    def gain_unit(self) -> str:
        """Output unit per input unit: ``um/V``; ``T/(A/m)`` for a compound input unit."""
        return f"{self.y_unit}/{_factor(self.u_unit)}"

    @property
    def rate_unit(self) -> str:
        """Input unit per second: ``V/s``; ``(A/m)/s`` for a compound input unit."""
        return f"{_factor(self.u_unit)}/s"


def _factor(unit: str) -> str:
    # a compound unit in a denominator or under a power needs parentheses: T/A/m is T m/A
    return f"({unit})" if re.search(r"[/* ]", unit) else unit

    def __str__(self) -> str:
        return (f"u in [{self.u_min:.4g}, {self.u_max:.4g}], "
                f"y in [{self.y_min:.4g}, {self.y_max:.4g}]")


def data_scales(data: Any = None) -> DataScales:
    """Ranges of ``data`` (a Record, a Dataset, or None for unit ranges).

    Warm-up samples count: they are simulated, so the operators must cover them too.
    """
    if data is None:
        return DataScales()
    if isinstance(data, DataScales):
        return data
    records = list(data) if hasattr(data, "records") else [data]
    us = np.concatenate([np.asarray(r.u, float) for r in records])
    ys = np.concatenate([np.asarray(r.y, float) for r in records])
    u_min, u_max = float(us.min()), float(us.max())
    y_min, y_max = float(ys.min()), float(ys.max())
    # a constant input or output gives no scale; refuse rather than divide by zero later
    if not u_max > u_min:
        raise ParameterError(f"input u is constant ({u_min}); no hysteresis can be identified")
    if not y_max > y_min:
        raise ParameterError(f"output y is constant ({y_min}); no hysteresis can be identified")
    units = dict(getattr(records[0], "units", None) or {})
    return DataScales(u_min, u_max, y_min, y_max,
                      str(units.get("u", "unknown")), str(units.get("y", "unknown")))


def sample_period(data: Any = None, default: float = 1e-4) -> float:
    """Shortest median sampling step of ``data`` (s); ``default`` without time stamps.

    Parameters
    ----------
    data : Record, Dataset, DataScales or None
        Anything with ``.t`` (or ``.records`` holding such).
    default : float
        Returned for ``None`` or data without ``t`` (s).
    """
    if data is None or isinstance(data, DataScales):
        return float(default)
    records = list(data) if hasattr(data, "records") else [data]
    steps = []
    for r in records:
        t = np.asarray(getattr(r, "t", ()), dtype=float)
        if t.size >= 2:
            steps.append(float(np.median(np.diff(t))))
    if not steps:
        return float(default)
    dt = min(steps)
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"data time stamps must increase, median step is {dt}")
    return dt


@dataclass(frozen=True)
class Trajectory:
    """The result of a forward simulation.

    Attributes
    ----------
    y : ndarray, shape (N,) or (W, N)
        Model output (output unit). Rows of failed walkers hold NaN and are flagged in
        ``failed``; a single run that fails raises instead of returning.
    state : ndarray, shape (S,) or (W, S)
        State after the last sample; pass it as ``state0`` to continue.
    failed : ndarray of bool, shape () or (W,)
        Whether the simulation of that parameter vector failed.
    """

    y: np.ndarray
    state: np.ndarray
    failed: np.ndarray

    @property
    def n_failed(self) -> int:
        """Number of failed simulations."""
        return int(np.count_nonzero(self.failed))

    def __str__(self) -> str:
        shape = "x".join(map(str, self.y.shape))
        return f"Trajectory(y: {shape}, state size {self.state.shape[-1]}, failed {self.n_failed})"


def check_count(n: Any, what: str = "n_operators", minimum: int = 1) -> None:
    """Raise ModelError unless ``n`` is an integer ``>= minimum`` (a structural count).

    Parameters
    ----------
    n : Any
        The setting (``bool`` is refused: ``True`` is not a count).
    what : str
        Its name, for the message.
    minimum : int
        Smallest valid value.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < minimum:
        raise ModelError(f"{what} must be an integer >= {minimum}, got {n!r}")


def batch_theta(owner: str, shapes: Mapping[str, tuple[int, ...]], theta: Mapping[str, Any],
                *, batched: bool) -> tuple[dict[str, np.ndarray], int | None]:
    """Validate parameter values and give them a leading walker axis.

    Shared by models and effect blocks: the kernels take every parameter as a
    C-contiguous, writable float64 array with a leading ``W`` axis.

    Parameters
    ----------
    owner : str
        Name of the model or block, for error messages.
    shapes : mapping
        Declared shape of every parameter (free and fixed), by name.
    theta : mapping
        Values by name: one parameter vector (``batched=False``, shapes as declared) or
        ``W`` of them (``batched=True``, each with a leading ``W`` axis).
    batched : bool
        Whether ``theta`` already has the walker axis.

    Returns
    -------
    out : dict
        ``name -> ndarray (W, *shape)``; arrays that already qualify are not copied.
    width : int or None
        ``W``; None when nothing is declared.

    Raises
    ------
    ParameterError
        For a missing or unknown name, a wrong shape, or unequal walker counts.
    """
    missing = [n for n in shapes if n not in theta]
    unknown = [n for n in theta if n not in shapes]
    if missing or unknown:
        raise ParameterError(f"{owner}: theta is missing {missing} / has unknown {unknown}; "
                             f"expected {list(shapes)}")
    out: dict[str, np.ndarray] = {}
    width = None
    for name, shape in shapes.items():
        arr = np.asarray(theta[name], dtype=np.float64)
        if not batched:
            arr = arr[None, ...]
        if arr.shape[1:] != shape:
            want = ("(W, " if batched else "(") + ", ".join(map(str, shape)) + ")"
            raise ParameterError(f"{owner}: theta[{name!r}] has shape "
                                 f"{np.shape(theta[name])}, expected {want}")
        if width is None:
            width = arr.shape[0]
        elif arr.shape[0] != width:
            raise ParameterError(f"{owner}: theta[{name!r}] has {arr.shape[0]} rows, "
                                 f"other parameters have {width}")
        # fixed values are read-only arrays; numba types those separately, so a copy
        # keeps one compiled specialisation per kernel
        out[name] = arr if arr.flags.writeable and arr.flags.c_contiguous else arr.copy()
    return out, None if width is None else int(width)


def checked_state(name: str, state0: np.ndarray, size: int) -> np.ndarray:
    """A kernel's own copy of ``state0``, checked to hold ``size`` entries per walker.

    Parameters
    ----------
    name : str
        The model's name, for the message.
    state0 : array_like, shape (W, size)
        State before the first sample; not modified.
    size : int
        Entries of the model's state.

    Returns
    -------
    ndarray, shape (W, size)
        C-contiguous float64 copy, for the kernel to update in place.

    Raises
    ------
    ParameterError
        If ``state0`` is not two-dimensional with ``size`` columns.
    """
    state = np.array(state0, dtype=np.float64, copy=True, order="C")
    if state.ndim != 2 or state.shape[1] != size:
        raise ParameterError(f"{name}: state must have {size} entries, got {state.shape}")
    return state


def kernel_buffers(state0: np.ndarray, n_samples: int, *, size: int | None = None,
                   owner: str = "model") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Buffers of one batched kernel call, in the order ``_run`` returns them.

    Parameters
    ----------
    state0 : ndarray, shape (W, S)
        State before the first sample; not modified.
    n_samples : int
        Number of samples ``N``.
    size : int, optional
        Entries the model's state must have (``S``); checked by :func:`checked_state`
        when given.
    owner : str
        The model's name, for that check's message.

    Returns
    -------
    y : ndarray, shape (W, N)
        Uninitialised output.
    state : ndarray, shape (W, S)
        C-contiguous float64 copy of ``state0``, for the kernel to update in place.
    failed : ndarray of bool, shape (W,)
        All False.
    """
    state = (np.array(state0, dtype=np.float64, order="C") if size is None
             else checked_state(owner, state0, size))
    return np.empty((state.shape[0], n_samples)), state, np.zeros(state.shape[0], dtype=bool)


def check_covariates(covariates: Mapping[str, Any] | None, needed: Sequence[str], n: int,
                     who: str) -> dict[str, np.ndarray] | None:
    """The measured channels a model reads, as float64 (n,) arrays; None if none given.

    Parameters
    ----------
    covariates : mapping or None
        ``column -> (n,)`` values; None runs the model at its nominal conditions (every
        covariate block at its reference value).
    needed : sequence of str
        Columns the model reads (:attr:`HysteresisModel.covariates`).
    n : int
        Samples of the input.
    who : str
        The model's name, for messages.

    Raises
    ------
    ModelError
        A needed column missing from a given mapping, of the wrong length or not finite.
    """
    if covariates is None or not needed:
        return None
    missing = [c for c in needed if c not in covariates]
    if missing:
        raise ModelError(f"{who}: reads the measured column(s) {missing}; the covariates "
                         f"given are {sorted(covariates)}")
    out = {}
    for c in needed:
        arr = np.ascontiguousarray(covariates[c], dtype=np.float64)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise ModelError(f"{who}: covariate {c!r} must be {n} finite values (one per "
                             f"input sample), got shape {arr.shape}")
        out[c] = arr
    return out


def check_signal(u: Any, t: Any) -> tuple[np.ndarray, np.ndarray]:
    """``u`` and ``t`` as C-contiguous float64, 1-D, equal length, finite; else raise."""
    u = np.ascontiguousarray(u, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if u.ndim != 1 or t.ndim != 1 or u.shape != t.shape:
        raise ParameterError(f"u and t must be 1-D of equal length, got {u.shape} and {t.shape}")
    if u.size == 0:
        raise ParameterError("u and t are empty")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(t))):
        raise ParameterError("u and t must be finite")
    return u, t


class HysteresisModel(ABC):
    """Base class of every forward model ``u -> y``.

    Class attributes
    ----------------
    name : str
        Registry name (``"pi_play"``).
    rate_dependent : bool
        Whether the output depends on the speed of the input (and so on ``t``).
    equation : str
        The review equation(s) the model implements, for docs and ``bayeshyst models``.
    monotone_in_input : bool
        Whether the output rises with the input on every branch for valid parameters
        (what a numerical inverse needs). False where the one-step map can fall: a
        compensator's clockwise relay grid (its output steps down where a relay
        switches), a model whose output at a sample depends on the rate into it
        (``pi_rate``, ``pi_rate_weights``, the rate-weighted Preisach models), a
        butterfly below ``-E_c``. Their numerical inversion reports the non-monotone
        steps (``Inversion.n_nonmonotone``) or refuses the range
        (:meth:`check_invertible`).
    multimodal_posterior : bool
        Whether the family is known to give posteriors with a minor mode that local
        searches from prior draws can agree on (a bilinear model): the MAP search then
        always searches the prior globally as well
        (:func:`~bayeshyst.inference.optimize.find_map`, ``global_search="auto"``).
    """

    name: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = False
    equation: ClassVar[str] = ""
    has_inverse: ClassVar[bool] = False
    monotone_in_input: ClassVar[bool] = True
    multimodal_posterior: ClassVar[bool] = False
    has_output_offset: ClassVar[bool] = False

    # ------------------------------------------------------------------ subclass API
    @abstractmethod
    def param_space(self, data: Any = None) -> ParamSpace:
        """Declared parameters, with default priors scaled from ``data``.

        Parameters
        ----------
        data : Record, Dataset, DataScales or None
            Data the priors and any data-dependent fixed values (operator thresholds)
            are scaled to; ``None`` uses an input and output range of ``[-1, 1]``.
        """

    @abstractmethod
    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        """Relaxed initial state for a batch of ``W`` parameter vectors, shape (W, S)."""

    @abstractmethod
    def _run(
        self,
        u: np.ndarray,
        t: np.ndarray,
        theta: Mapping[str, np.ndarray],
        state0: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate ``W`` parameter vectors; return ``y (W, N)``, ``state (W, S)``, ``failed (W,)``.

        ``theta`` holds C-contiguous float64 arrays with a leading ``W`` axis.
        """

    @property
    def covariates(self) -> tuple[str, ...]:
        """Measured columns besides ``u`` the model reads (none for a hysteresis model).

        A composite with a covariate block (``aux(column=temperature_c)``) names them;
        its simulations take them as ``covariates={column: values}`` and, without them,
        run at the block's reference value (nominal conditions).
        """
        return ()

    def check_invertible(self, theta: Mapping[str, np.ndarray], u_lo: float,
                         u_hi: float) -> None:
        """Raise ModelError unless the one-step map is non-decreasing on ``[u_lo, u_hi]``.

        Numerical inversion (:mod:`bayeshyst.inverse.numerical`) finds each command sample
        by bracketing a root of the one-step map, which is only unique where that map is
        non-decreasing in the input; it asks the model first. Every family that draws a
        monotone, counter-clockwise loop has nothing to check (this default); a model whose
        output is non-monotone in the input over part of its range (a butterfly, which
        is invertible on one wing only) refuses a command range that reaches beyond it.

        Parameters
        ----------
        theta : mapping
            ``name -> (W, *shape)``: the parameter vectors to be inverted together.
        u_lo, u_hi : float
            Admissible command range (input unit), possibly infinite.
        """
        return None

    def _initial_state_with(self, theta: Mapping[str, np.ndarray], u0: float,
                            covariates: Mapping[str, np.ndarray] | None) -> np.ndarray:
        """:meth:`_initial_state` given the measured channels (N,) of the run.

        The default ignores them; a composite rests its blocks at the output its parts
        give at the first sample's channel values.
        """
        return self._initial_state(theta, u0)

    def _run_with(self, u: np.ndarray, t: np.ndarray, theta: Mapping[str, np.ndarray],
                  state0: np.ndarray, covariates: Mapping[str, np.ndarray] | None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_run` with the measured channels (models that read none ignore them)."""
        return self._run(u, t, theta, state0)

    # ------------------------------------------------------------------ public API
    @functools.cached_property
    def _shapes(self) -> dict[str, tuple[int, ...]]:
        space = self.param_space()
        return {name: space[name].shape for name in space.all_names}

    def _batch_theta(self, theta: Mapping[str, Any], batched: bool) -> tuple[dict, int]:
        out, width = batch_theta(self.name, self._shapes, theta, batched=batched)
        return out, 1 if width is None else width

    def initial_state(self, theta: Mapping[str, Any], u0: float) -> np.ndarray:
        """The relaxed state before the first sample, for input value ``u0``, shape (S,)."""
        tb, _ = self._batch_theta(theta, batched=False)
        return self._initial_state(tb, float(u0))[0]

    def run(self, u: Any, t: Any, theta: Mapping[str, Any], *,
            state0: np.ndarray | None = None,
            covariates: Mapping[str, Any] | None = None) -> Trajectory:
        """Simulate one parameter vector and return output and final state.

        Parameters
        ----------
        u : array_like, shape (N,)
            Input (V).
        t : array_like, shape (N,)
            Sample times (s); rate-independent models ignore them.
        theta : mapping
            Physical parameter values by name (as from ``param_space().unpack(z)``).
        state0 : ndarray, shape (S,), optional
            State before the first sample; default :meth:`initial_state` at ``u[0]``.
        covariates : mapping of str to array_like, optional
            Measured channels ``column -> (N,)`` for a model that reads some
            (:attr:`covariates`); None runs it at nominal conditions.

        Raises
        ------
        SimulationError
            If the simulation fails (non-finite output or state).
        """
        u, t = check_signal(u, t)
        cov = check_covariates(covariates, self.covariates, u.size, self.name)
        tb, _ = self._batch_theta(theta, batched=False)
        s0 = (self._initial_state_with(tb, float(u[0]), cov) if state0 is None
              else np.ascontiguousarray(np.asarray(state0, dtype=np.float64)[None, :]))
        y, state, failed = self._run_with(u, t, tb, s0, cov)
        if failed[0]:
            raise SimulationError(f"{self.name}: simulation failed for theta={dict(theta)}")
        return Trajectory(y[0], state[0], np.asarray(False))

    def step(self, u_k: float, t_k: float, theta: Mapping[str, Any],
             state: np.ndarray) -> Trajectory:
        """Advance one sample from ``state``: the building block of numerical inversion.

        Parameters
        ----------
        u_k : float
            Input at this sample (V).
        t_k : float
            Its time (s).
        theta : mapping
            Physical parameter values.
        state : ndarray, shape (S,)
            State before the sample (from :meth:`initial_state` or an earlier run).

        Returns
        -------
        Trajectory
            ``y`` of shape (1,) and the state after the sample. Stepping through a
            record sample by sample reproduces :meth:`run` on the whole record, because
            every model keeps in its state all it needs to continue.
        """
        return self.run(np.array([u_k], dtype=float), np.array([t_k], dtype=float), theta,
                        state0=state)

    def simulate(self, u: Any, t: Any, theta: Mapping[str, Any], *,
                 state0: np.ndarray | None = None,
                 covariates: Mapping[str, Any] | None = None) -> np.ndarray:
        """Model output ``y`` (shape (N,)) for input ``u``; see :meth:`run`."""
        return self.run(u, t, theta, state0=state0, covariates=covariates).y

    def run_batch(self, u: Any, t: Any, thetas: Mapping[str, Any], *,
                  state0: np.ndarray | None = None,
                  covariates: Mapping[str, Any] | None = None) -> Trajectory:
        """Simulate ``W`` parameter vectors at once (e.g. a whole emcee ensemble).

        Parameters
        ----------
        u, t : array_like, shape (N,)
            Input (V) and times (s), shared by all parameter vectors.
        thetas : mapping
            ``name -> array (W, *shape)`` (as from ``param_space().unpack(Z)`` with
            ``Z`` of shape ``(W, ndim)``).
        state0 : ndarray, shape (W, S), optional
        covariates : mapping of str to array_like, optional
            As in :meth:`run`.

        Returns
        -------
        Trajectory
            ``y (W, N)``, ``state (W, S)``, ``failed (W,)``; failed rows of ``y`` are NaN.
        """
        u, t = check_signal(u, t)
        cov = check_covariates(covariates, self.covariates, u.size, self.name)
        tb, width = self._batch_theta(thetas, batched=True)
        if state0 is None:
            s0 = self._initial_state_with(tb, float(u[0]), cov)
        else:
            s0 = np.ascontiguousarray(state0, dtype=np.float64)
            if s0.ndim != 2 or s0.shape[0] != width:
                raise ParameterError(f"state0 must have shape (W={width}, S), got {s0.shape}")
        y, state, failed = self._run_with(u, t, tb, s0, cov)
        y[failed] = np.nan
        return Trajectory(y, state, failed)

    def simulate_batch(self, u: Any, t: Any, thetas: Mapping[str, Any], *,
                       state0: np.ndarray | None = None,
                       covariates: Mapping[str, Any] | None = None) -> np.ndarray:
        """Outputs ``(W, N)`` for ``W`` parameter vectors; raises if any simulation fails."""
        traj = self.run_batch(u, t, thetas, state0=state0, covariates=covariates)
        if traj.n_failed:
            raise SimulationError(f"{self.name}: {traj.n_failed} of {traj.y.shape[0]} "
                                  f"simulations failed (rows {np.flatnonzero(traj.failed)[:10]})")
        return traj.y

    def describe(self) -> str:
        """Name, equation and the default parameter table, for ``bayeshyst models``."""
        head = f"{self.name}  ({type(self).__name__}; {self.equation})"
        if self.rate_dependent:
            head += "  [rate-dependent]"
        return head + "\n" + str(self.param_space())

    def __str__(self) -> str:
        return repr(self)
