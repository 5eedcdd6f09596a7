"""Any static hysteresis model conditioned on a measured column (temperature, load).

Review §3: temperature and mechanical load change a piezo loop's average slope
(refs. [117]–[119]) and a load also its width. ``pi_covariate`` builds that into one
family (weights and thresholds of a play PI); :class:`Conditioned` does it for every
rate-independent family by conjugating the base model ``H`` with a scaling of the loop
about its centre, so it reuses the base's kernel unchanged. In a spec string the base
comes first, as the one positional argument::

    conditioned(bouc_wen, column='temperature_c')
    conditioned(preisach(n_levels=8), column='load_n')+creep

The wrapper's own parameters live under ``cond.`` (``cond.a``, ``cond.b``); a base
model's parameter names never hold a ``.``, so the two cannot collide.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError
from bayeshyst.models import registry
from bayeshyst.models.base import HysteresisModel, LinearInParams, data_scales
from bayeshyst.models.blocks.external import _COLUMN, GAIN_PRIOR, column_scales
from bayeshyst.models.bouc_wen import BoucWen
from bayeshyst.models.compose import Composite
from bayeshyst.models.pi_weighted import WIDTH_PRIOR
from bayeshyst.models.registry import register
from bayeshyst.params import Normal, Param, ParamSpace

__all__ = ["COND", "Conditioned"]

#: Namespace of the wrapper's own parameters.
COND = "cond"


class _PerInstance:
    """A class attribute that an instance takes from its settings (its base).

    The registry and the registry-wide code read flags on the class (``cls.name`` is
    ``"conditioned"``, ``cls.monotone_in_input`` the default base's); an instance
    answers from what it wraps (``"conditioned(bouc_wen, column='temperature_c')"``),
    so composites and messages say which base and which column.
    """

    def __init__(self, on_class: Any, attribute: str) -> None:
        self.on_class = on_class
        self.attribute = attribute

    def __get__(self, obj: Any, owner: type) -> Any:
        if obj is None:
            return self.on_class
        return getattr(obj, self.attribute)


def _default_base() -> HysteresisModel:
    return BoucWen()


@register
@dataclass(frozen=True)
class Conditioned(LinearInParams, HysteresisModel):
    r"""A static hysteresis model whose slope and width follow a measured column.

    .. math::  y_k = f_k \big(y_c + s_k (H[v]_k - y_c)\big), \quad
               v_k = u_c + \frac{u_k - u_c}{s_k}, \quad
               f_k = 1 + a\,\Delta c_k, \quad s_k = 1 + b\,\Delta c_k, \quad
               \Delta c_k = c_k - c_0

    ``H`` is the base model, ``c`` the column named by ``column``, ``c_0`` its mean over
    the fitted data, ``u_c`` the centre of the data's input range and ``y_c`` the
    base's output at rest at ``u_c`` (its relaxed state there, one sample): both
    fixed by the data and the base's parameters, not estimated.

    Reading (review §3 gives no equation): the bracket is the base's loop magnified by
    ``s`` about its centre ``(u_c, y_c)`` in the ``(u, y)`` plane -- an input excursion
    ``x`` from ``u_c`` drives the base through ``x / s`` and its output excursion is
    multiplied by ``s`` -- so a purely linear base is left unchanged (slope ``dy/du``
    kept) while the loop's width along ``u`` scales by ``s``; ``f`` then scales the
    whole output (the slope). ``a`` changes the slope, ``b`` the width. The centre
    ``y_c`` matters: ``f s H[v]`` alone differs from it by ``f (s - 1) y_c``, an offset
    that follows the column (for a PI ``(s - 1)(p0 + sum w) u_c``), which is not a
    width change and would break the equality with ``pi_covariate`` below.

    * For positively homogeneous operators with thresholds measured from ``u_c``
      (play/stop PI, Maxwell-slip, Preisach) the magnification is exactly a
      threshold scaling by ``s``: a play ``F_r`` obeys
      ``u_c + s (F_r[u_c + (u - u_c) / s] - u_c) = F_{s r}[u]``, so with a constant
      column ``conditioned(pi_play)`` is ``pi_covariate`` at the same ``a``, ``b``
      (tested to 1e-12); Maxwell-slip gets slip deflections ``x s``, a Preisach grid
      levels ``u_c + s (L - u_c)`` with relay weights ``x s`` (slope kept; tested).
    * For Bouc–Wen, Duhem and other non-homogeneous families it is still a
      well-defined change of width, not a threshold scaling: the loop is the base's
      loop at amplitude ``x / s``, magnified by ``s``. For Bouc–Wen (``y = k u - h``)
      it is exactly Bouc–Wen with ``beta, gamma`` divided by ``s^n`` (and ``k, alpha``
      times ``f``, ``beta, gamma`` times ``f^(1-n)``; tested): the
      saturation level ``(alpha / (beta + gamma))^(1/n)`` of ``h``, the width of a
      saturated loop, scales by ``s``. Below saturation a larger ``s`` means *less*
      saturation, so there a loop's area can shrink as ``b Δc`` grows: ``b`` is the
      width of the saturated loop, not the area of every loop.
    * Memory: the base's state is kept in its own (scaled) coordinates. With a column
      that varies while the input is held, a held operator therefore moves with the
      magnification about ``(u_c, y_c)``, where ``pi_covariate`` holds its play in
      physical units; the two agree whenever the column is constant, and whenever
      ``b = 0`` (only the slope changes). The difference is a modelling choice that a
      generic wrapper cannot avoid: only the family knows what its state means.

    With ``a = b = 0`` the model is the base exactly.

    Parameters
    ----------
    base : HysteresisModel or str
        The rate-independent model to condition (a spec string such as
        ``"preisach(n_levels=8)"`` is built with :func:`bayeshyst.models.get`). Not a
        composite (put effect blocks after the wrapper:
        ``conditioned(bouc_wen, column='temperature_c')+creep``), not rate-dependent
        (its time axis would need a scaling too), not a model that reads a column
        itself.
    column : str
        Name of the measured column (``Record.covariates``), e.g. ``"temperature_c"``.

    Notes
    -----
    Parameters: the base's, by their own names; ``cond.a`` and ``cond.b`` (per unit of
    the column), priors Normal(0, 0.05 / sd) and Normal(0, 0.1 / sd) with ``sd`` the
    column's standard deviation over the data -- 5 % slope and 10 % width change per
    sd, as ``pi_covariate``; fixed ``cond.c0`` (the column's mean) and ``cond.u_c``
    (V, the centre of the input range). State: the base's state. Initial state: the
    base relaxed at ``v_0`` (the physical loop at rest at ``u_0``). Walkers whose slope
    factor ``f`` or width factor ``s`` is ``<= 0`` anywhere on the run are reported
    failed (their output is not computed from a division by zero).

    Linear parameters: for fixed ``a, b`` the output is ``f (s H[v] + (1 - s) y_c)``,
    and ``H[v]`` and ``y_c`` are both linear (affine) in the base's linear parameters,
    so the wrapper is too: ``linear_params`` are the base's, the design is computed by
    simulation (:meth:`LinearInParams.linear_design`).

    Cost: the input ``v`` depends on a walker's ``b``, so with the column the base's
    kernel runs once per distinct ``(b, c0, u_c)`` (once per walker while sampling; a
    linear design's signals share their walker's call); without it, one batched call.

    Without the column (``covariates=None``: a feedforward command for a future run,
    the numerical inverse) the wrapper runs at nominal conditions ``c = c0``, where it
    is the base exactly; given a mapping that lacks the column, it raises
    :class:`~bayeshyst.errors.ModelError` naming it.
    """

    name: ClassVar[str] = _PerInstance("conditioned", "_instance_name")  # type: ignore[assignment]
    equation: ClassVar[str] = _PerInstance(  # type: ignore[assignment]
        "review §3: any static model with slope and width of a measured column",
        "_instance_equation")
    rate_dependent: ClassVar[bool] = False
    base: HysteresisModel = field(default_factory=_default_base)
    column: str = "temperature_c"

    def __post_init__(self) -> None:
        base = self.base
        if isinstance(base, str):
            base = registry.get(base)
            object.__setattr__(self, "base", base)
        if not isinstance(base, HysteresisModel):
            raise ModelError(f"conditioned: base must be a hysteresis model (a name such as "
                             f"'bouc_wen' or a model), got {base!r}")
        if isinstance(base, Composite):
            raise ModelError(f"conditioned: base {base.name!r} is a composite; condition the "
                             f"hysteresis model and add the blocks after it: "
                             f"'conditioned({base.base.name}, column=...)+...'")
        if base.rate_dependent:
            raise ModelError(f"conditioned: base {base.name!r} is rate-dependent; only static "
                             f"(rate-independent) models can be conditioned on a column")
        if base.covariates:
            raise ModelError(f"conditioned: base {base.name!r} already reads the measured "
                             f"column(s) {list(base.covariates)}; condition a model that "
                             f"reads none (pi_play is pi_covariate's base)")
        if not isinstance(self.column, str) or not _COLUMN.match(self.column):
            raise ModelError(f"conditioned: column must name a data column (no '=', '+', "
                             f"parentheses, commas or quotes), got {self.column!r}")

    # ------------------------------------------------------------------ what it is
    @property
    def _instance_name(self) -> str:
        return f"conditioned({self.base.name}, column={self.column!r})"

    @property
    def _instance_equation(self) -> str:
        return f"{self.base.equation} (the base's), slope and width of a measured column (§3)"

    # the base's flags: v rises with u and both factors are positive (monotone), and
    # its offset enters y_c and H alike, so it stays an offset
    monotone_in_input: ClassVar[bool] = _PerInstance(  # type: ignore[assignment]
        True, "_base_monotone")
    multimodal_posterior: ClassVar[bool] = _PerInstance(  # type: ignore[assignment]
        False, "_base_multimodal")
    has_output_offset: ClassVar[bool] = _PerInstance(  # type: ignore[assignment]
        False, "_base_offset")

    @property
    def _base_monotone(self) -> bool:
        return bool(self.base.monotone_in_input)

    @property
    def _base_multimodal(self) -> bool:
        return bool(self.base.multimodal_posterior)

    @property
    def _base_offset(self) -> bool:
        return bool(self.base.has_output_offset)

    @property
    def covariates(self) -> tuple[str, ...]:
        """The one column the wrapper reads."""
        return (self.column,)

    @property
    def linear_params(self) -> tuple[str, ...]:  # type: ignore[override]
        """The base's linear parameters (none if the base declares none)."""
        if isinstance(self.base, LinearInParams) and hasattr(self.base, "linear_design"):
            return tuple(self.base.linear_params)
        return ()

    @property
    def linear_affine(self) -> bool:  # type: ignore[override]
        """The base's: ``y_c`` and ``H`` are homogeneous when the base is."""
        return bool(getattr(self.base, "linear_affine", True))

    def check_invertible(self, theta: Mapping[str, np.ndarray], u_lo: float,
                         u_hi: float) -> None:
        """The base's check: an inversion runs at nominal conditions, where it is the base."""
        self.base.check_invertible(self._base_theta(theta), u_lo, u_hi)

    # ------------------------------------------------------------------ parameters
    def param_space(self, data: Any = None) -> ParamSpace:
        """The base's space, ``cond.a``, ``cond.b`` and fixed ``cond.c0``, ``cond.u_c``."""
        sc = data_scales(data)
        ref, scale = column_scales(data, self.column)
        col = self.column
        u_c = 0.5 * (sc.u_min + sc.u_max)
        own = ParamSpace(
            (Param("a", Normal(0.0, GAIN_PRIOR / scale), unit=f"1/{col}",
                   description=f"relative change of the slope per unit of {col}"),
             Param("b", Normal(0.0, WIDTH_PRIOR / scale), unit=f"1/{col}",
                   description=f"relative change of the loop width per unit of {col}")),
            fixed={"c0": ref, "u_c": u_c},
            fixed_params=(
                Param("c0", Normal(ref, scale), unit=col,
                      description=f"reference value of {col} (fixed: its mean over the data)"),
                Param("u_c", Normal(u_c, sc.u_span), unit=sc.u_unit,
                      description="centre of the width scaling (fixed: the input's centre)")),
        )
        base_space = self.base.param_space(data)
        clash = [n for n in base_space.all_names if n.startswith(f"{COND}.")]
        if clash:
            raise ModelError(f"conditioned: base parameters {clash} use the wrapper's "
                             f"namespace {COND!r}")
        return ParamSpace.concat([base_space, own.prefixed(COND)])

    def _base_theta(self, theta: Mapping[str, Any]) -> dict[str, Any]:
        pre = f"{COND}."
        return {k: v for k, v in theta.items() if not k.startswith(pre)}

    # ------------------------------------------------------------------ simulation
    def _factors(self, theta: Mapping[str, np.ndarray], cv: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Slope and width factors ``f``, ``s`` (W, N) and which walkers keep both > 0."""
        a = np.asarray(theta[f"{COND}.a"], dtype=np.float64)[:, None]
        b = np.asarray(theta[f"{COND}.b"], dtype=np.float64)[:, None]
        dc = cv[None, :] - np.asarray(theta[f"{COND}.c0"], dtype=np.float64)[:, None]
        with np.errstate(invalid="ignore", over="ignore"):
            f = 1.0 + a * dc
            s = 1.0 + b * dc
            f_ok = np.all(f > 0, axis=1) & np.all(np.isfinite(f), axis=1)
            s_ok = np.all(s > 0, axis=1) & np.all(np.isfinite(s), axis=1)
        # an input is never divided by a width factor <= 0: such a walker runs unscaled
        # (and is failed). Only s's own validity decides, so walkers with equal (b, c0)
        # keep equal rows of s, whatever their a
        s = np.where(s_ok[:, None], s, 1.0)
        return f, s, f_ok & s_ok

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return self.base._initial_state(self._base_theta(theta), u0)

    def _initial_state_with(self, theta: Mapping[str, np.ndarray], u0: float,
                            covariates: Mapping[str, np.ndarray] | None) -> np.ndarray:
        if covariates is None:
            return self._initial_state(theta, u0)
        cv = np.ascontiguousarray(covariates[self.column][:1], dtype=np.float64)
        _, s, _ = self._factors(theta, cv)
        u_c = np.asarray(theta[f"{COND}.u_c"], dtype=np.float64)
        v0 = u_c + (float(u0) - u_c) / s[:, 0]
        base_theta = self._base_theta(theta)
        states = None
        for value, rows in _groups(v0):
            part = self.base._initial_state(_rows(base_theta, rows), float(value))
            if states is None:
                states = np.empty((v0.size, part.shape[1]))
            states[rows] = part
        return np.ascontiguousarray(states)

    def _centre_output(self, base_theta: Mapping[str, np.ndarray],
                       u_c: np.ndarray) -> np.ndarray:
        """``y_c`` (W,): the base's output at rest at ``u_c`` (one sample from relaxed)."""
        out = np.empty(u_c.size)
        for value, rows in _groups(u_c):
            th = _rows(base_theta, rows)
            s0 = self.base._initial_state(th, float(value))
            y, _, _ = self.base._run_with(np.array([float(value)]), np.zeros(1), th,
                                          np.ascontiguousarray(s0, dtype=np.float64), None)
            out[rows] = y[:, 0]
        return out

    def _run(self, u, t, theta, state0):
        return self._run_with(u, t, theta, state0, None)

    def _run_with(self, u, t, theta, state0, covariates):
        base_theta = self._base_theta(theta)
        finite = (np.isfinite(theta[f"{COND}.a"]) & np.isfinite(theta[f"{COND}.b"]))
        if covariates is None:
            # nominal conditions, c = c0: f = s = 1 and the wrapper is the base itself
            y, state, failed = self.base._run_with(u, t, base_theta, state0, None)
            return y, state, np.asarray(failed, dtype=bool) | ~finite
        cv = np.ascontiguousarray(covariates[self.column], dtype=np.float64)
        f, s, ok = self._factors(theta, cv)
        u_c = np.asarray(theta[f"{COND}.u_c"], dtype=np.float64)
        y_c = self._centre_output(base_theta, u_c)
        width, n = s.shape
        h = np.empty((width, n))
        state = np.empty_like(state0, dtype=np.float64)
        failed = ~ok
        # walkers with the same width factors drive the base with the same input: one
        # batched kernel call per distinct (b, c0, u_c), so a linear design's signals
        # (which repeat a walker's b) cost no more calls than walkers
        key = np.stack([theta[f"{COND}.b"], theta[f"{COND}.c0"], u_c], axis=1)
        for _, rows in _groups(key):
            i = rows[0]
            v = np.ascontiguousarray(u_c[i] + (u - u_c[i]) / s[i])
            yy, ss, ff = self.base._run_with(v, t, _rows(base_theta, rows),
                                             np.ascontiguousarray(state0[rows]), None)
            h[rows], state[rows] = yy, ss
            failed[rows] |= np.asarray(ff, dtype=bool)
        with np.errstate(invalid="ignore", over="ignore"):
            # s H + (1 - s) y_c: exactly H where s is 1 (no round-off through y_c)
            y = f * (s * h + (1.0 - s) * y_c[:, None])
        failed |= ~finite | ~np.all(np.isfinite(y), axis=1)
        return np.ascontiguousarray(y), np.ascontiguousarray(state), failed

    def __repr__(self) -> str:
        return f"Conditioned({self.base!r}, column={self.column!r})"


def _groups(values: np.ndarray) -> list[tuple[Any, np.ndarray]]:
    """Distinct rows of ``values`` (W,) or (W, K) with the walker indices holding each.

    One sort, not a pass per group: a sampler's walkers are usually all distinct.
    NaN rows are never equal, so each is its own group.
    """
    arr = np.asarray(values, dtype=np.float64)
    flat = arr.reshape(arr.shape[0], -1)
    order = np.lexsort(flat.T[::-1])
    ranked = flat[order]
    breaks = np.flatnonzero(np.any(ranked[1:] != ranked[:-1], axis=1)) + 1
    return [(arr[part[0]], np.sort(part)) for part in np.split(order, breaks)]


def _rows(theta: Mapping[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The parameter vectors ``rows`` of a batched ``theta``, C-contiguous."""
    return {k: np.ascontiguousarray(np.asarray(v)[rows]) for k, v in theta.items()}
