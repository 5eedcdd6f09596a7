"""Bipolar drive: butterfly strain loops of a ferroelectric driven past its coercive field.

MODELS.md §9. Driven through ±E beyond the coercive field ``E_c``, a poled ceramic
switches its polarisation and its strain traces a *butterfly*: two wings, minima near
``±E_c``, both field extremes giving positive strain. Every other family in
:mod:`bayeshyst.models` draws a monotone, counter-clockwise loop and cannot represent it.
The phenomenological form writes the strain through the polarisation::

    P = H[E]                    symmetric, saturating, rate-independent hysteresis
    S = Q P^2 + d_lin E         quadratic electrostriction plus a linear term, Q > 0

:class:`Butterfly` is that form (optionally with a reversible part of ``P`` that follows
the field without hysteresis); :class:`ButterflyBoucWen` adds an asymmetric Bouc–Wen
term, the hybrid static model of the review's ref. [110] (§10).

Units and identifiability. ``P`` is in units of its saturation, ``|P| < 1``: the strain
sees the polarisation only through ``Q P^2``, so a saturation ``P_s`` and ``Q`` enter
only as ``Q P_s^2`` and one of them must be fixed; fixing ``P_s = 1`` makes ``Q`` the
electrostrictive strain at saturation (output unit). Where ``P`` is measured too (P–E
loops), its scale can be fitted separately (:meth:`Butterfly.polarisation`). The strain
offset ``s_0`` is not a parameter here: like every model without an output offset of
its own (``has_output_offset = False``) the posterior adds the observation offset
``obs.offset``, and a second offset would be an exact non-identifiability.

Inversion. ``S`` is non-monotone in ``E`` wherever ``P`` changes sign, so a butterfly has
no inverse over a bipolar command; on one wing — a unipolar command ``E >= 0`` after
positive poling, where ``P > 0`` stays — the one-step map is non-decreasing (for
``d_lin >= 0``) and the generic numerical inverse
(:func:`bayeshyst.inverse.numerical.invert`) applies. A command range reaching below
``-E_c`` is refused with the reason (:meth:`Butterfly.check_invertible`): the per-sample
root finder only walks towards the target from the last command, so it would not see the
decreasing part of the one-step map (``Inversion.n_nonmonotone`` stays 0) and would meet
a bipolar target silently on the other wing, with a command jumping by ``2 E_c``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.bipolar import butterfly_batch
from bayeshyst.models._kernels.bouc_wen import C_L, bw_batch
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    LinearInParams,
    check_signal,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.bouc_wen import AsymmetricBoucWen
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, TruncatedNormal, Uniform

__all__ = ["STARTS", "Butterfly", "ButterflyBoucWen"]

#: Initial states: ``"poled"`` (positive saturation, then down to the first field) or
#: ``"virgin"`` (depolarised, ``P = 0`` at zero field, then to the first field).
STARTS = ("poled", "virgin")


def _check_start(start: Any) -> None:
    if start not in STARTS:
        raise ModelError(f"start must be one of {STARTS}, got {start!r}")


def _u_ref(sc: DataScales) -> float:
    # the field magnitude the drive reaches: E_c is a magnitude, so a bipolar record
    # (-E_max..E_max) and a unipolar one (0..E_max) give it the same scale
    return max(abs(sc.u_min), abs(sc.u_max))


def _switching_params(sc: DataScales) -> tuple[Param, ...]:
    """``e_c`` and ``width``, with priors scaled to the field the data reach."""
    ur = _u_ref(sc)
    return (
        # truncated to the drive range: a coercive field beyond the largest field in the
        # data never switches and leaves no trace to identify it by
        Param("e_c", TruncatedNormal(0.4 * ur, 0.3 * ur, 0.0, ur), unit=sc.u_unit,
              description="coercive field: half-width of the play, P = 0 on the major loop"),
        Param("width", LogNormal.from_median(0.15 * ur, 0.7), unit=sc.u_unit,
              description="switching width w of P = tanh(v / w)"),
    )


def _check_one_wing(name: str, theta: Mapping[str, np.ndarray], u_lo: float,
                    reversible: bool = False) -> None:
    """Refuse a command range that reaches below ``-E_c`` (module docstring, Inversion)."""
    e_c = np.asarray(theta["e_c"], dtype=float)
    floor = -float(np.min(e_c)) if e_c.size else -np.inf
    what = f"-E_c = {floor:.4g}"
    if reversible:
        # the reversible part turns negative with the field: P >= 0 only for E >= 0
        floor, what = 0.0, "0 (the reversible polarisation follows the field's sign)"
    if not u_lo >= floor:
        raise ModelError(
            f"{name}: the strain is not monotone in the field over a command range "
            f"reaching {u_lo:.4g}: below {what} the polarisation can change sign "
            "and the butterfly has no inverse. It is invertible on one wing only: after "
            "positive poling, keep the command at E >= -E_c (E >= 0 with a reversible "
            "part), e.g. u_limits=(0, E_max)")


def _play_state(theta: Mapping[str, np.ndarray], u0: float, start: str) -> np.ndarray:
    e_c = theta["e_c"]
    if start == "poled":
        # the last excursion was a positive saturation above every field of the record:
        # coming down from it to u0 leaves the play at its upper edge
        return u0 + e_c
    # virgin: v = 0 (P = 0) at zero field, then a monotone path to u0
    return np.clip(0.0, u0 - e_c, u0 + e_c)


@register
@dataclass(frozen=True)
class Butterfly(LinearInParams, HysteresisModel):
    r"""Butterfly strain of a ferroelectric under bipolar drive (MODELS.md §9).

    .. math::  v = F_{E_c}[E], \quad P = \tanh(v / w), \quad S = Q P^2 + d_{lin} E

    ``F_{E_c}`` is the play operator of half-width ``E_c`` (review Eq. 11), ``P`` the
    polarisation in units of its saturation. Review §10 (the butterfly operator of
    ref. [110]) and MODELS.md §9.

    Which hysteresis for ``P``: a Preisach model with ±1 relays symmetric about the
    origin (MODELS.md §9's first option) whose density is concentrated on the line of
    half-width ``E_c`` with logistic centres of scale ``w / 2``: then the relay sum is
    exactly ``tanh(F_{E_c}[E] / w)`` (:mod:`bayeshyst.models._kernels.bipolar`), the
    classic ``tanh((E ∓ E_c) / w)`` branches of a ferroelectric P–E loop, with the
    play's memory for minor loops. Chosen for its clean oracle (a play and a ``tanh``,
    exact — no quadrature, no ODE, so rate independence and the symmetry
    ``P[-E] = -P[E]`` hold to rounding), O(1) cost per sample and a direct meaning of
    both parameters: ``P = 0`` on the major loop exactly at ``E = ±E_c``, where the
    strain has its minima. A Bouc–Wen or Jiles–Atherton law rounds the loop from the
    reversal on and has no field at which switching starts; a 2-D Preisach density
    needs an Everett table per parameter vector.

    Reversible polarisation (``reversible=True``): the wings of a measured butterfly
    rise with the field on both sides because part of the polarisation follows the
    field without hysteresis (the linearised piezoelectric coefficient is
    ``2 Q P_r dP_rev/dE``). It is
    the same Preisach reading on the diagonal (relays of zero half-width, logistic
    centres of scale ``w_r / 2``):
    ``P = (1 - eta) tanh(F_{E_c}[E] / w) + eta tanh(E / w_r)``, still ``|P| < 1``.
    ``P = 0`` on the major loop then lies slightly inside ``±E_c``. While the reversible
    part stays nearly linear over the drive, the data pin ``Q (1 - eta)^2`` (the
    switched part), ``Q eta (1 - eta) / w_rev`` (the wings' slope) and only weakly
    ``Q eta^2 / w_rev^2`` (their curvature), so ``Q``, ``eta`` and ``w_rev`` trade off
    along a ridge: expect wide, correlated marginals for them, while ``E_c``, ``w`` and
    ``d_lin`` stay sharp (measured on the virtual actuator's bipolar mode: ``Q`` to
    ±35 %, ``E_c`` to ±0.1 %).

    Parameters
    ----------
    start : {"poled", "virgin"}
        Initial state. ``"poled"`` (default): positively saturated, then down to the
        first field, ``v_0 = E_0 + E_c`` (``P = tanh(E_c / w)``, the remanent
        polarisation, at ``E_0 = 0``): a poled element. ``"virgin"``: depolarised,
        ``v = 0`` at zero field, then a monotone path to ``E_0``
        (``v_0 = clip(0, E_0 - E_c, E_0 + E_c)``): symmetric, so the response to
        ``-E`` is the mirror image.
    reversible : bool
        Add the reversible polarisation (parameters ``eta``, ``w_rev``; default False).

    Notes
    -----
    Parameters (input unit: the field, V or kV/mm; output unit: strain or
    displacement): ``e_c`` (input unit) ``~ TruncatedNormal(0.4 u_ref, 0.3 u_ref)`` on
    ``[0, u_ref]``, ``u_ref = max(|u_min|, |u_max|)`` (so the prior keeps ``E_c`` inside
    the drive range, for bipolar and unipolar data alike); ``width`` ``w`` (input unit)
    ``~ LogNormal(median 0.15 u_ref, 0.7)``; ``q`` ``Q`` (output unit, ``> 0``)
    ``~ LogNormal(median y_span, 1)``; ``d_lin`` (output unit per input unit)
    ``~ Normal(0, 0.5 y_span / u_ref)``; with ``reversible``, ``eta`` (1)
    ``~ Uniform(0, 1)`` and ``w_rev`` (input unit) ``~ LogNormal(median u_ref, 0.7)``.
    No offset: ``obs.offset`` (module docstring).

    ``S`` is linear in ``(q, d_lin)`` for fixed ``(e_c, width)`` (columns ``P^2`` and
    ``E``): the sampler draws them from their conditional Gaussian. State ``[v]``
    (``v_0`` as for ``start``, whatever ``reversible``).
    Rate-independent: the times are ignored. Failed simulations (``e_c < 0``,
    ``width <= 0``, non-finite values) are flagged, never NaN in a log-probability.
    """

    name: ClassVar[str] = "butterfly"
    # non-monotone below -E_c (switching): invertible on one wing (check_invertible)
    monotone_in_input: ClassVar[bool] = False
    equation: ClassVar[str] = "review Eq. 11 (play), §10 ref. [110]; MODELS.md §9"
    linear_params: ClassVar[tuple[str, ...]] = ("q", "d_lin")
    start: str = "poled"
    reversible: bool = False

    def __post_init__(self) -> None:
        _check_start(self.start)
        if not isinstance(self.reversible, bool):
            raise ModelError(f"reversible must be True or False, got {self.reversible!r}")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``e_c``, ``width``, ``q`` and ``d_lin`` with the priors of the class Notes.

        ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        rev = (
            Param("eta", Uniform(0.0, 1.0), unit="1",
                  description="reversible fraction of the polarisation"),
            Param("w_rev", LogNormal.from_median(_u_ref(sc), 0.7), unit=sc.u_unit,
                  description="width of the reversible part eta tanh(E / w_rev)"),
        ) if self.reversible else ()
        return ParamSpace((
            *_switching_params(sc),
            *rev,
            Param("q", LogNormal.from_median(sc.y_span, 1.0), unit=sc.y_unit,
                  description="electrostrictive strain Q at saturation (S = Q P^2 + ...)"),
            Param("d_lin", Normal(0.0, 0.5 * sc.y_span / _u_ref(sc)),
                  unit=sc.gain_unit, description="linear term d_lin E"),
        ))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return _play_state(theta, u0, self.start)[:, None].copy()

    def _kernel(self, u, theta, state0, polar):
        if state0.ndim != 2 or state0.shape[1] != 1:
            raise ParameterError(f"{self.name}: state must have 1 entry [v], got "
                                 f"{state0.shape}")
        y, state, failed = kernel_buffers(state0, u.shape[0])
        width = state.shape[0]
        eta = theta["eta"] if self.reversible else np.zeros(width)
        w_rev = theta["w_rev"] if self.reversible else np.ones(width)
        butterfly_batch(u, theta["e_c"], theta["width"], eta, w_rev, theta["q"],
                        theta["d_lin"], polar, state, y, failed)
        state[failed] = np.nan
        return y, state, failed

    def _run(self, u, t, theta, state0):
        return self._kernel(u, theta, state0, False)

    def check_invertible(self, theta: Mapping[str, np.ndarray], u_lo: float,
                         u_hi: float) -> None:
        """Refuse commands below ``-E_c`` or ``d_lin < 0`` (the strain is then not monotone).

        From a state with ``v >= 0`` (poled, or virgin at ``E_0 >= -E_c``) a command
        ``E >= -E_c`` keeps ``v >= 0`` and ``P >= 0``, where ``S`` is non-decreasing in
        ``E`` if ``d_lin >= 0``; below ``-E_c`` the polarisation switches and ``S``
        decreases with ``E``. With the reversible part the floor is ``E >= 0``.
        See :meth:`HysteresisModel.check_invertible`.
        """
        _check_one_wing(self.name, theta, u_lo, self.reversible)
        d = np.asarray(theta["d_lin"], dtype=float)
        if np.any(d < 0):
            raise ModelError(f"{self.name}: d_lin < 0 ({float(d.min()):.4g}) makes the strain "
                             "decrease with the field where the polarisation does not move; "
                             "no monotone wing to invert")

    def polarisation(self, u: Any, theta: Mapping[str, Any], *,
                     state0: np.ndarray | None = None) -> np.ndarray:
        """Polarisation ``P = tanh(F_{E_c}[E] / w)`` (units of saturation) along ``u``.

        Parameters
        ----------
        u : array_like, shape (N,)
            Field (input unit).
        theta : mapping
            One parameter vector.
        state0 : ndarray, shape (1,), optional
            Play state; default the model's initial state at ``u[0]``.

        Returns
        -------
        ndarray, shape (N,)

        Raises
        ------
        ParameterError
            For parameters outside ``e_c >= 0, width > 0``.
        """
        u, _ = check_signal(u, np.zeros(np.size(u)))
        tb, _ = self._batch_theta(theta, batched=False)
        s0 = (self._initial_state(tb, float(u[0])) if state0 is None
              else np.asarray(state0, dtype=float).reshape(1, -1))
        p, _, failed = self._kernel(u, tb, s0, True)
        if failed[0]:
            raise ParameterError(f"{self.name}: parameters outside e_c >= 0, width > 0: "
                                 f"{dict(theta)}")
        return p[0]


@register
@dataclass(frozen=True)
class ButterflyBoucWen(HysteresisModel):
    r"""Butterfly operator plus an asymmetric Bouc–Wen term (review §10, ref. [110]).

    .. math::  S = Q \tanh(F_{E_c}[E] / w)^2 + k E - h, \quad
               \dot h = \alpha \dot E - \beta |\dot E| |h|^{n-1} h
                        - \gamma \dot E |h|^n + \delta E \dot E

    Which form: the review says only that ref. [110] "superimposed a butterfly
    hysteresis operator based on exponential function with the asymmetric Bouc–Wen
    model to form a hybrid static hysteresis model" (used as the static part of a
    Hammerstein model); it prints neither operator. "Superimposed" is read as a sum of
    the two outputs. The butterfly operator is :class:`Butterfly`'s (its ``tanh`` is the
    exponential ratio ``(1 - e^{-2x}) / (1 + e^{-2x})``: the closest well-defined form
    we can state; ref. [110]'s own exponential operator is not reproduced). The
    asymmetric Bouc–Wen term is :class:`~bayeshyst.models.bouc_wen.AsymmetricBoucWen`
    exactly (review Eq. 49, with its documented reading ``δ E Ė`` of the asymmetric
    term), whose linear gain ``k`` takes the place of ``d_lin``. The Hammerstein
    dynamics of ref. [110] is an effect block: ``butterfly_bw+second_order``.

    Parameters
    ----------
    start : {"poled", "virgin"}
        Initial state of the butterfly operator, as for :class:`Butterfly`; ``h = 0``.
    step_scale : float
        Bouc–Wen integration step, as for :class:`~bayeshyst.models.bouc_wen.BoucWen`.

    Notes
    -----
    Parameters: ``e_c``, ``width``, ``q`` as for :class:`Butterfly`; ``k``, ``alpha``,
    ``beta``, ``gamma``, ``n``, ``delta`` with the priors of
    :class:`~bayeshyst.models.bouc_wen.AsymmetricBoucWen`. State ``[v, h, E_prev]``.
    Rate-independent (both parts are integrated in the input). Draws outside the Bouc–Wen
    stable region or with ``α + δ E <= 0`` on the record are flagged as failed.
    """

    name: ClassVar[str] = "butterfly_bw"
    # non-monotone below -E_c (switching): invertible on one wing (check_invertible)
    monotone_in_input: ClassVar[bool] = False
    equation: ClassVar[str] = "review Eq. 49 + butterfly operator, §10 ref. [110]"
    start: str = "poled"
    step_scale: float = C_L

    def __post_init__(self) -> None:
        _check_start(self.start)
        # the Bouc–Wen part validates its own settings
        AsymmetricBoucWen(step_scale=self.step_scale)

    def param_space(self, data: Any = None) -> ParamSpace:
        """``e_c``, ``width``, ``q`` (:class:`Butterfly`) and the asymmetric Bouc–Wen parameters.

        ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        butterfly = ParamSpace((
            *_switching_params(sc),
            Param("q", LogNormal.from_median(sc.y_span, 1.0), unit=sc.y_unit,
                  description="electrostrictive strain Q at saturation (S = Q P^2 + ...)"),
        ))
        return ParamSpace.concat([butterfly, AsymmetricBoucWen().param_space(sc)])

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = np.zeros((theta["e_c"].shape[0], 3))
        s[:, 0] = _play_state(theta, u0, self.start)
        s[:, 2] = u0
        return s

    def check_invertible(self, theta: Mapping[str, np.ndarray], u_lo: float,
                         u_hi: float) -> None:
        """Refuse commands below ``-E_c``, as :meth:`Butterfly.check_invertible`.

        The Bouc–Wen term is checked as for ``bouc_wen_asym``: not at all (its
        monotonicity depends on ``k`` against the hysteretic slope; the inverse's
        ``n_nonmonotone`` reports a decreasing one-step map it meets).
        """
        _check_one_wing(self.name, theta, u_lo)

    def _run(self, u, t, theta, state0):
        if state0.ndim != 2 or state0.shape[1] != 3:
            raise ParameterError(f"{self.name}: state must have 3 entries [v, h, E_prev], "
                                 f"got {state0.shape}")
        y, state, failed = kernel_buffers(state0, u.shape[0])
        zeros = np.zeros(state.shape[0])
        play_state = np.ascontiguousarray(state[:, :1])
        butterfly_batch(u, theta["e_c"], theta["width"], zeros, np.ones(state.shape[0]),
                        theta["q"], zeros, False, play_state, y, failed)
        state[:, :1] = play_state
        bw_state = np.ascontiguousarray(state[:, 1:])
        y_bw = np.empty_like(y)
        bw_failed = np.zeros_like(failed)
        # α + δE > 0 must hold over every field of the run, the previous one included
        lo = float(min(u.min(), np.nanmin(bw_state[:, 1], initial=np.inf)))
        hi = float(max(u.max(), np.nanmax(bw_state[:, 1], initial=-np.inf)))
        bw_batch(u, theta["k"], theta["alpha"], theta["beta"], theta["gamma"], theta["n"],
                 theta["delta"], lo, hi, float(self.step_scale), bw_state, y_bw, bw_failed)
        state[:, 1:] = bw_state
        failed |= bw_failed
        y += y_bw
        y[failed] = np.nan
        state[failed] = np.nan
        return y, state, failed
