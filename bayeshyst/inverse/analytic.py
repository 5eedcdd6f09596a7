"""Analytic inverses and direct-inverse identification (MODELS.md §2, §6, §8).

* play-PI: the exact inverse (Kuhnen 2003, review ref. [52]) is again a play-PI, or
  equally a stop-PI (:meth:`~bayeshyst.models.pi.PrandtlIshlinskii.inverse`,
  :attr:`~bayeshyst.models.pi.PIInverse.stop_theta`);
* modified Bouc–Wen: the inverse MBW operator, review Eq. 55
  (:meth:`~bayeshyst.models.modified_bouc_wen.ModifiedBoucWen.inverse`);
* Bouc–Wen: the multiplicative structure ``u = (y_d + h) / k`` (review ref. [93]) with
  ``h`` driven by the output, and Coleman–Hodgdon Duhem solved for its input (ref. [84])
  (:mod:`bayeshyst.models.output_driven_inverse`);
* **direct inverse**: a model identified with the output as its input and the input as
  its output is itself the compensator (a stop-PI, review ref. [57]; the GP with roles
  swapped, :func:`~bayeshyst.gp.fit_gp_inverse`; the clockwise-relay Preisach grid,
  review Eq. 9–10, ref. [60], :class:`~bayeshyst.models.preisach_clockwise.
  PreisachClockwise`). :func:`swap_input_output` gives the data for that identification.

Every other model (and every composition) is inverted numerically,
:func:`bayeshyst.inverse.numerical.invert`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError
from bayeshyst.models import registry
from bayeshyst.models.base import HysteresisModel

__all__ = ["analytic_inverse", "swap_input_output"]


def analytic_inverse(model: HysteresisModel, y_d: Any, t: Any,
                     theta: Mapping[str, Any]) -> np.ndarray:
    """Command ``u`` (N,) from the model's closed-form inverse, relaxed start.

    Parameters
    ----------
    model : HysteresisModel
        A model with ``has_inverse`` (``pi_play``, ``mbw``, ``bouc_wen``,
        ``bouc_wen_asym``, ``duhem``).
    y_d : array_like, shape (N,)
        Desired output (output unit).
    t : array_like, shape (N,)
        Times (s).
    theta : mapping
        One parameter vector of ``model``.

    Raises
    ------
    ModelError
        If the model has no analytic inverse (the message lists those that do).
    """
    if not model.has_inverse:
        have = [n for n in registry.names() if registry.get(n).has_inverse]
        raise ModelError(f"{model.name} has no analytic inverse (models with one: "
                         f"{', '.join(have)}); use bayeshyst.inverse.numerical.invert")
    return np.asarray(model.inverse(y_d, t, theta), dtype=float)


def swap_input_output(data: Dataset | Record) -> Dataset:
    """The data with input and output exchanged, for identifying a direct inverse.

    A model fitted to the result maps the actuator's displacement to the voltage that
    produced it: driven by a desired displacement, its output is the feedforward
    command (review ref. [57]). Units, warm-up and metadata are kept, and the metadata
    records ``swapped_io = True``.
    """
    records = (data,) if isinstance(data, Record) else tuple(data)
    out = []
    for rec in records:
        units = dict(rec.units)
        units["u"], units["y"] = rec.units.get("y", ""), rec.units.get("u", "")
        meta = dict(rec.metadata)
        meta["swapped_io"] = True
        out.append(rec.with_(u=np.array(rec.y), y=np.array(rec.u), units=units, metadata=meta))
    name = data.name if isinstance(data, Dataset | Record) else "data"
    return Dataset(tuple(out), name=f"{name} (y -> u)")
