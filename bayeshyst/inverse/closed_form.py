"""The nominal command from a model's closed-form inverse (``compensate --nominal-inverse``).

Models with ``has_inverse`` (play-PI, MBW Eq. 55, Bouc–Wen's multiplicative structure
[93], Duhem with its roles swapped [84]) give the MAP's command in closed form instead of
by per-sample root finding (:mod:`bayeshyst.inverse.numerical`). The result is a
:class:`~bayeshyst.inverse.feedforward.Feedforward` like the numerical one: the command
is checked by a forward simulation of the model (``Inversion.max_error``), and a command
beyond ``u_limits`` is held at the limit and counted (``n_saturated``), as the numerical
inverse does. Unlike the numerical inverse, the closed form does not re-anchor its state
after a saturated sample (it follows the reference as if the limit were not there); the
forward check then measures the error this leaves, and a design that saturates is better
made numerically.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.inverse.feedforward import Draws, Feedforward, predict_outputs
from bayeshyst.inverse.numerical import Inversion
from bayeshyst.models import registry
from bayeshyst.models.base import HysteresisModel

__all__ = ["NOMINAL_INVERSES", "check_closed_form", "closed_form_feedforward"]

#: what ``nominal_inverse`` chooses in :func:`~bayeshyst.inverse.compensate.compensate`
NOMINAL_INVERSES = ("numerical", "closed_form")


def check_closed_form(model: HysteresisModel, draws: Draws | None = None) -> None:
    """Raise ParameterError unless ``model`` (and one draw of it) has a closed-form inverse."""
    if not model.has_inverse:
        have = [n for n in registry.names() if registry.model_class(n).has_inverse]
        raise ParameterError(f"{model.name} has no closed-form inverse (models with one: "
                             f"{', '.join(have)}); use the numerical inverse")
    if draws is not None and draws.discrepancy is not None and draws.delta is not None:
        raise ParameterError("a closed-form inverse inverts the model alone; with a "
                             "discrepancy use the numerical inverse")
    if draws is not None and draws.size != 1:
        raise ParameterError(f"a closed-form inverse takes one parameter vector, got "
                             f"{draws.size}")


def closed_form_feedforward(model: HysteresisModel, y_d: Any, t: Any, nominal: Draws,
                            predict: Draws, *, label: str,
                            u_limits: tuple[float, float] = (-np.inf, np.inf),
                            scored: Any = None, frequency_hz: float | None = None,
                            residual: np.ndarray | None = None) -> Feedforward:
    """The command of ``model.inverse`` for one draw, predicted on ``predict`` draws.

    Parameters
    ----------
    model : HysteresisModel
        With ``has_inverse``.
    y_d, t : array_like, shape (N,)
        Reference (output unit) and times (s).
    nominal : Draws
        One draw (the MAP); its output offset is taken off the reference first.
    predict : Draws
        Draws the command's outputs are predicted on.
    label, u_limits, scored, frequency_hz, residual
        As :func:`~bayeshyst.inverse.feedforward.design_feedforward`.

    Raises
    ------
    ParameterError
        No closed form, several draws, a discrepancy, or a reference the closed form
        cannot follow (its message says where).
    """
    check_closed_form(model, nominal)
    y_d = np.asarray(y_d, dtype=float)
    t = np.asarray(t, dtype=float)
    one = {k: np.asarray(v)[0] for k, v in nominal.theta.items()}
    u = np.asarray(model.inverse(y_d - nominal.offset[0], t, one), dtype=float)
    lo, hi = u_limits
    # held at the limit and counted, as the numerical inverse does: never silent
    out = (u < lo) | (u > hi)
    u = np.clip(u, lo, hi)
    y = predict_outputs(model, u, t, nominal, frequency_hz)
    mask = np.ones(t.size, dtype=bool) if scored is None else np.asarray(scored, dtype=bool)
    err = np.abs(y[0] - y_d)[mask]
    inv = Inversion(u=u, y=y, objective="closed form", quantile=float("nan"),
                    max_error=float(np.max(err)) if np.all(np.isfinite(err)) else float("inf"),
                    n_saturated=int(out.sum()), n_nonmonotone=0,
                    n_failed_draws=int(not np.all(np.isfinite(y))), n_evaluations=0,
                    n_corrections=0, stages=(f"{model.name}: closed-form inverse",))
    return Feedforward(label, u, predict_outputs(model, u, t, predict, frequency_hz), inv,
                       residual)
