"""Exceptions raised at bayeshyst's boundaries."""

from __future__ import annotations

__all__ = ["DataError", "ModelError", "ParameterError", "SimulationError"]


class DataError(ValueError):
    """Malformed or unusable measurement data.

    The message names the file (when there is one), the column and the row (1-based,
    counting the header line as row 1 for text files) together with what was expected
    and what was found.
    """


class ParameterError(ValueError):
    """A parameter value, prior or parameter-space operation that is not valid."""


class ModelError(ValueError):
    """A model was asked for that does not exist or was configured inconsistently."""


class SimulationError(RuntimeError):
    """A forward simulation failed (non-finite state, solver breakdown).

    Raised by single simulations; batched runs report failures per walker instead so
    that the posterior can count them.
    """
