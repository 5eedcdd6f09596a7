"""Effect blocks: dynamics, creep, drift, delay, output maps and external drivers after a model.

A block maps the output ``w`` of whatever precedes it (a hysteresis model or another
block) to a new signal, sample by sample, with an explicit state (MODELS.md §7, review
Eq. 56–57). Blocks compose with any :class:`~bayeshyst.models.base.HysteresisModel` in
:class:`~bayeshyst.models.compose.Composite`.

Conventions shared by every block:

* **The hysteresis model carries gain and offset.** Every linear block passes a
  constant input unchanged once settled (ARX ``B(1) = A(1)``, second order
  ``G(0) = 1``, creep banks settle to ``w``); drift has no constant term and the output
  map has unit slope and no offset at the data's centre. So no block parameter trades
  off against the base model's gain (a ridge in the posterior otherwise).
* **Steady initial state.** ``_initial_state(theta, w0, t0)`` is the state after the
  input ``w0`` was held since forever; the first sample then outputs the steady value.
* **Exact continuation.** The state holds everything the block remembers (previous
  time, input and output histories, cached step), so applying a record in pieces,
  down to one sample at a time (the ``step`` of numerical inversion), gives the same
  output as one call.
* **Failures are flagged, not raised.** A parameter vector outside the valid set
  (unstable, non-monotone, too long a delay) or a non-finite output sets ``failed``.

The package holds the contract and the registry (:mod:`~bayeshyst.models.blocks.base`),
linear dynamics (:mod:`~bayeshyst.models.blocks.linear`), creep
(:mod:`~bayeshyst.models.blocks.creep`), the drift, delay and output-map blocks
(:mod:`~bayeshyst.models.blocks.output`) and the blocks driven by a measured column or a
moment in time (:mod:`~bayeshyst.models.blocks.external`) and the smooth term for
structure no physical block explains (:mod:`~bayeshyst.models.blocks.smooth`); every
public name is importable from here.
"""

from __future__ import annotations

from bayeshyst.models.blocks.base import (
    DEFAULT_DT,
    DEFAULT_DURATION,
    EffectBlock,
    TimeScales,
    block_class,
    block_names,
    register_block,
    time_scales,
)
from bayeshyst.models.blocks.creep import Creep, FractionalCreep
from bayeshyst.models.blocks.external import AuxInput, ChangePoint, Disturbance
from bayeshyst.models.blocks.linear import ARX, SecondOrder
from bayeshyst.models.blocks.output import AsymmetricOutput, Delay, Drift
from bayeshyst.models.blocks.smooth import Unexplained

__all__ = [
    "ARX",
    "DEFAULT_DT",
    "DEFAULT_DURATION",
    "AsymmetricOutput",
    "AuxInput",
    "ChangePoint",
    "Creep",
    "Delay",
    "Disturbance",
    "Drift",
    "EffectBlock",
    "FractionalCreep",
    "SecondOrder",
    "TimeScales",
    "Unexplained",
    "block_class",
    "block_names",
    "register_block",
    "time_scales",
]
