"""Models linear in some of their parameters: the design ``y = Phi beta + c``.

:class:`LinearInParams` is the mixin a model declares its linear group with;
:class:`LinearDesign` is the design of ``W`` parameter vectors that the sampler's exact
linear draws, the conjugate posterior and the least-squares starts use;
:func:`unit_signals` builds the unit coefficient vectors a design is simulated from.
(Split from :mod:`bayeshyst.models.base`, which re-exports these names.)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ParameterError

__all__ = ["LinearDesign", "LinearInParams", "unit_signals"]


def unit_signals(names: tuple[str, ...], shapes: Mapping[str, tuple[int, ...]], width: int,
                 n_sig: int) -> dict[str, np.ndarray]:
    """Values of the linear parameters ``names`` for ``n_sig`` signals per walker.

    Signal ``j < P`` of every walker sets the ``j``-th scalar of the stacked (flattened)
    parameters to 1 and the rest to 0; a signal beyond the ``P``-th (``n_sig = P + 1``)
    is ``beta = 0``. Walker-major: ``name -> (width * n_sig, *shape)``, as the other
    parameters repeated ``n_sig`` times per walker.
    """
    sizes = [int(np.prod(shapes[n], dtype=int)) for n in names]
    basis = np.eye(n_sig, sum(sizes))  # the last row is zero when n_sig = P + 1
    out, start = {}, 0
    for n, size in zip(names, sizes, strict=True):
        cols = np.tile(basis[:, start:start + size], (width, 1))
        out[n] = cols.reshape(width * n_sig, *shapes[n])
        start += size
    return out


@dataclass(frozen=True)
class LinearDesign:
    """The output of ``W`` parameter vectors written as ``y = phi @ beta + const``.

    Attributes
    ----------
    names : tuple of str
        The parameters stacked (flattened, in this order) in ``beta``.
    phi : ndarray, shape (W, N, P) or (1, N, P)
        Column ``j``: the output's derivative with respect to ``beta_j`` (output unit
        per unit of the parameter). A leading 1 means shared by all walkers.
    const : ndarray, shape (W, N) or (1, N)
        The output at ``beta = 0`` (output unit).
    failed : ndarray of bool, shape (W,)
        Walkers whose other parameters are outside the model's support (or whose
        simulation failed): their rows are not usable.
    """

    names: tuple[str, ...]
    phi: np.ndarray
    const: np.ndarray
    failed: np.ndarray

    @property
    def n_columns(self) -> int:
        """``P``, the number of scalar linear parameters."""
        return int(self.phi.shape[2])

    def predict(self, beta: np.ndarray) -> np.ndarray:
        """``phi @ beta + const`` for ``beta`` (W, P): outputs (W, N)."""
        beta = np.atleast_2d(np.asarray(beta, dtype=float))
        return (self.phi @ beta[:, :, None])[:, :, 0] + self.const

    def __str__(self) -> str:
        w, n, p = self.phi.shape
        return (f"LinearDesign({', '.join(self.names)}: {p} columns x {n} samples, "
                f"{w} walker(s), {int(np.count_nonzero(self.failed))} failed)")


class LinearInParams:
    """Mixin for models whose output is linear in some of their parameters.

    With every other parameter held fixed, ``y = Phi @ beta + c`` where ``beta`` stacks
    the (flattened) parameters named in ``linear_params`` and ``c`` is the output at
    ``beta = 0`` (zero for the operator models, ``-h`` for Bouc–Wen's ``k u - h``).
    Posterior sampling draws ``beta`` from its exact conditional Gaussian given the
    rest (:mod:`bayeshyst.inference.linear`); the conjugate posterior and
    least-squares starts use the same design.

    Contract (tested for every implementing model): the output is affine in the
    linear parameters from the relaxed initial state, and whether a simulation fails
    depends on the other parameters only.
    """

    linear_params: ClassVar[tuple[str, ...]] = ()
    #: whether the output at ``beta = 0`` can be non-zero (else one simulation is saved)
    linear_affine: ClassVar[bool] = False
    name: ClassVar[str]
    _shapes: dict[str, tuple[int, ...]]
    run_batch: Any
    simulate_batch: Any

    def _linear_sizes(self, names: tuple[str, ...]) -> list[int]:
        shapes = self._shapes
        bad = [n for n in names if n not in self.linear_params]
        if bad:
            raise ParameterError(f"{self.name}: {bad} are not linear parameters; linear: "
                                 f"{list(self.linear_params)}")
        return [int(np.prod(shapes[n], dtype=int)) for n in names]

    def linear_design(self, u: Any, t: Any, thetas: Mapping[str, Any],
                      names: tuple[str, ...] | None = None, *,
                      covariates: Mapping[str, Any] | None = None) -> LinearDesign:
        """``Phi`` and ``c`` of ``W`` parameter vectors, from the relaxed initial state.

        Parameters
        ----------
        u, t : array_like, shape (N,)
            Input (V) and times (s).
        thetas : mapping
            Every parameter with a leading ``W`` axis (``name -> (W, *shape)``); the
            values of ``names`` are ignored, linear parameters not in ``names`` keep
            their values (they then contribute to ``const``).
        names : tuple of str, optional
            The linear parameters to write as columns; default all of
            ``linear_params``.

        Returns
        -------
        LinearDesign
            ``phi (W, N, P)``, ``const (W, N)``. The default implementation runs
            ``W (P + 1)`` simulations in one batch (``W P`` when the model is
            homogeneous in all its linear parameters): column ``j`` is the output at
            ``beta = e_j`` minus the output at ``beta = 0``.
        """
        names = tuple(self.linear_params) if names is None else tuple(names)
        sizes = self._linear_sizes(names)
        shapes = self._shapes
        width = None
        for n in shapes:
            if n in thetas:
                width = int(np.shape(thetas[n])[0])
                break
        if width is None:
            raise ParameterError(f"{self.name}: thetas has none of {list(shapes)}")
        p = sum(sizes)
        homogeneous = not self.linear_affine and set(names) == set(self.linear_params)
        n_sig = p + (0 if homogeneous else 1)
        batch = {}
        for n in shapes:
            if n in names:
                continue
            if n not in thetas:
                raise ParameterError(f"{self.name}: thetas is missing {n!r}")
            arr = np.asarray(thetas[n], dtype=float)
            batch[n] = np.repeat(arr, n_sig, axis=0)  # walker-major: (W * n_sig, ...)
        batch.update(unit_signals(names, shapes, width, n_sig))
        traj = self.run_batch(u, t, batch, covariates=covariates)
        y = traj.y.reshape(width, n_sig, -1)
        failed = traj.failed.reshape(width, n_sig).any(axis=1)
        if homogeneous:
            const = np.zeros((width, y.shape[2]))
            phi = y
        else:
            const = y[:, p]
            phi = y[:, :p] - const[:, None, :]
        return LinearDesign(names, np.ascontiguousarray(phi.transpose(0, 2, 1)), const,
                            failed)

    def regressors(self, u: Any, t: Any, theta: Mapping[str, Any], *,
                   state0: np.ndarray | None = None,
                   covariates: Mapping[str, Any] | None = None) -> np.ndarray:
        """Design matrix ``Phi`` (N, P) with ``simulate(u, t, theta) == Phi @ beta``.

        Parameters
        ----------
        u, t : array_like, shape (N,)
            Input (V) and times (s).
        theta : mapping
            Values of every parameter not in ``linear_params`` (those are ignored if
            present).
        state0 : ndarray, shape (S,), optional
            State before the first sample. Only valid where the state does not depend
            on the linear parameters (operator models); default relaxed at ``u[0]``.
        covariates : mapping of str to array_like, optional
            Measured channels, for a model that reads some (as in :meth:`run`).

        Returns
        -------
        ndarray, shape (N, P)
            Column ``j`` is the output with ``beta = e_j``: one batched simulation.

        Raises
        ------
        ParameterError
            For a model whose output is not homogeneous in its linear parameters
            (``linear_affine``): use :meth:`linear_design`, which returns the constant
            term too.
        """
        if self.linear_affine:
            raise ParameterError(f"{self.name}: the output is affine, not linear, in "
                                 f"{list(self.linear_params)}; use linear_design")
        shapes = self._shapes
        lin = self.linear_params
        need = [k for k in shapes if k not in lin]
        missing = [k for k in need if k not in theta]
        unknown = [k for k in theta if k not in shapes]
        if missing or unknown:
            raise ParameterError(f"{self.name}: theta is missing {missing} / has unknown "
                                 f"{unknown}; expected {need}")
        sizes = [int(np.prod(shapes[n], dtype=int)) for n in lin]
        width = sum(sizes)
        basis = np.eye(width)
        thetas = {n: np.broadcast_to(np.asarray(theta[n], dtype=float), (width, *shapes[n]))
                  for n in need}
        start = 0
        for n, size in zip(lin, sizes, strict=True):
            thetas[n] = basis[:, start:start + size].reshape(width, *shapes[n])
            start += size
        s0 = None if state0 is None else np.tile(np.asarray(state0, dtype=float), (width, 1))
        return np.ascontiguousarray(self.simulate_batch(u, t, thetas, state0=s0,
                                                        covariates=covariates).T)
