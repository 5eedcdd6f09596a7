"""The posterior density of a model's parameters given measured records.

``log p(z | data) = log p(z) + sum_records sum_scored log p(y_k | yhat_k(theta), noise)``

where ``yhat`` is the **free-run** simulation of each whole record from the model's
relaxed state at its first input (warm-up samples are simulated but not scored) plus an
observation offset when the model has none of its own. The vectorised
:meth:`Posterior.log_prob_batch` evaluates a whole emcee ensemble with one batched
simulation per record; it is what the sampler calls.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.discrepancy import DISC, Discrepancy, make_discrepancy
from bayeshyst.errors import DataError, ParameterError, SimulationError
from bayeshyst.inference.cv_units import cycle_units, unit_kind
from bayeshyst.likelihoods import Likelihood, get_likelihood
from bayeshyst.models import get as get_model
from bayeshyst.models.base import HysteresisModel
from bayeshyst.params import Normal, Param, ParamSpace
from bayeshyst.threads import with_single_threaded_blas

__all__ = ["EvalCounts", "Posterior", "Unit", "cycle_units", "record_covariates",
           "unit_kind"]

OBS, NOISE = "obs", "noise"


@dataclass(frozen=True)
class Unit:
    """One left-out unit for cross-validation: a cycle of one record.

    Attributes
    ----------
    record : str
        Record name.
    index : int
        Cycle number within the record (0-based).
    start, stop : int
        Sample range ``[start, stop)`` within the record (scored samples only).
    frequency_hz : float or None
        The record's excitation frequency.
    """

    record: str
    index: int
    start: int
    stop: int
    frequency_hz: float | None


@dataclass(frozen=True)
class EvalCounts:
    """How many log-probability evaluations ran, and how many failed.

    ``prior_rejected``: outside the prior support (no simulation run);
    ``failed``: the simulation failed or gave a non-finite likelihood (counted, and
    the point given ``-inf``).
    """

    evaluations: int
    prior_rejected: int
    failed: int

    def __str__(self) -> str:
        return (f"{self.evaluations} evaluations, {self.failed} failed simulations, "
                f"{self.prior_rejected} outside the prior")


def record_covariates(model: HysteresisModel, record: Record) -> dict[str, np.ndarray] | None:
    """The measured columns of ``record`` that ``model`` reads; None if it reads none.

    Raises
    ------
    DataError
        If the record lacks a column the model reads (naming both).
    """
    needed = model.covariates
    if not needed:
        return None
    missing = [c for c in needed if c not in record.covariates]
    if missing:
        have = ", ".join(record.covariates) or "none"
        raise DataError(f"record {record.name!r}: the model {model.name} reads the column(s) "
                        f"{missing}, which the record does not have (its extra columns: "
                        f"{have})")
    return {c: np.ascontiguousarray(record.covariates[c]) for c in needed}


def _offset_prior(model: HysteresisModel, space: ParamSpace,
                  data: Dataset) -> tuple[float, float]:
    """Centre and width of the observation offset's Normal prior.

    Centred where the model at the centre of its prior needs it, ``mean(y - yhat_0)``,
    with width ``sqrt((2 span(y))^2 + mean|yhat_0|^2)``: the output's own span, plus the
    model output's magnitude, which the gain priors (100 % wide) can move as much. For
    an input far from zero (a stage driven at 1 kV +- 10 V) the needed offset is
    ``mean(y) - gain mean(u)``, far outside ``mean(y) +- 2 span(y)``; at the usual
    0-150 V it changes little. Without a finite simulation at the prior centre the
    prior is ``Normal(mean(y), 2 span(y))``.
    """
    y = np.concatenate([r.y for r in data])
    span = float(np.ptp(y))
    centre, extra = float(np.mean(y)), 0.0
    try:
        z0 = np.median(space.sample_prior(np.random.default_rng(0), 501), axis=0)
        theta = space.unpack(z0)
        resid, mag = [], []
        for rec in data:
            yhat = model.simulate(rec.u, rec.t, theta, covariates=record_covariates(model, rec))
            resid.append(rec.y - yhat)
            mag.append(np.abs(yhat))
        r, m = np.concatenate(resid), np.concatenate(mag)
        if np.all(np.isfinite(r)) and np.all(np.isfinite(m)):
            centre, extra = float(np.mean(r)), float(np.mean(m))
    except (ParameterError, SimulationError, FloatingPointError, ValueError):
        pass
    sd = math.hypot(2.0 * span, extra) if math.isfinite(extra) else 2.0 * span
    return centre, sd if sd > 0 else 1.0


class Posterior:
    """Posterior of a model's parameters (and noise, and offset) given data.

    Parameters
    ----------
    data : Dataset or Record
        Measured records; each is simulated from its first sample.
    model : HysteresisModel or str
        The forward model, or a model spec string (``"bouc_wen+second_order"``). Data
        first, then model, as in every verb (``fit``, ``compare``, ``diagnose``, ...).
    likelihood : Likelihood or str
        ``"gaussian"`` (default), ``"student_t"`` or ``"ar1"``.
    space : ParamSpace, optional
        The model's parameter space; default ``model.param_space(data)`` (priors
        scaled from the data). Edit it (``fix``/``replace``) to change priors.
    offset : bool, optional
        Add an observation offset ``obs.offset`` (output unit). Default: when the
        model has no output offset of its own (``model.has_output_offset``) — a
        measured displacement's zero is arbitrary.
    beta : float
        Power of the likelihood, ``p(z) L(z)^beta``: 1 is the posterior, 0 the prior
        alone (no simulation is run), values between temper it.
    discrepancy : {"none", "hsgp"} or Discrepancy, optional
        A model-discrepancy term ``delta`` added to the model output
        (:mod:`bayeshyst.discrepancy`): ``"hsgp"`` builds the reduced-rank GP over the
        loop's coordinates for this data; None or ``"none"``: no discrepancy.

    Notes
    -----
    Parameter names: the model's (``k``, ``alpha``; ``static.w`` for compositions),
    ``obs.offset``, ``disc.<name>`` and ``noise.<name>``. The object is picklable (for
    process pools); its evaluation counters are per process.
    """

    def __init__(
        self,
        data: Dataset | Record,
        model: HysteresisModel | str,
        likelihood: Likelihood | str = "gaussian",
        *,
        space: ParamSpace | None = None,
        offset: bool | None = None,
        beta: float = 1.0,
        discrepancy: str | Discrepancy | None = None,
    ) -> None:
        if not (np.isfinite(beta) and 0.0 <= beta <= 1.0):
            raise ParameterError(f"beta (likelihood power) must be in [0, 1], got {beta}")
        self.beta = float(beta)
        if isinstance(model, Dataset | Record) and not isinstance(data, Dataset | Record):
            # the order before 0.1: refused in words rather than swapped behind the
            # caller's back
            raise ParameterError("Posterior(data, model, ...): the data come first, then the "
                                 f"model; got a {type(model).__name__} as the model")
        self.model = get_model(model) if isinstance(model, str) else model
        if isinstance(data, Record):
            data = Dataset((data,), name=data.name)
        if not isinstance(data, Dataset):
            raise DataError(f"data must be a Dataset or Record, got {type(data).__name__}")
        self.data = data
        self.likelihood = get_likelihood(likelihood)
        self.model_space = space if space is not None else self.model.param_space(data)
        if offset is None:
            offset = not bool(getattr(self.model, "has_output_offset", False))
        self.offset = bool(offset)
        parts = [self.model_space]
        if self.offset:
            centre, sd = _offset_prior(self.model, self.model_space, data)
            parts.append(ParamSpace((Param(
                "offset", Normal(centre, sd), unit=data[0].units.get("y", ""),
                description="observation offset added to the model output"),)).prefixed(OBS))
        self.discrepancy = make_discrepancy(discrepancy, data)
        if self.discrepancy is not None:
            parts.append(self.discrepancy.param_space().prefixed(DISC))
        parts.append(self.likelihood.param_space(data).prefixed(NOISE))
        self.space = ParamSpace.concat(parts)
        self._model_names = self.model_space.all_names
        self._disc_names = tuple(n for n in self.space.all_names if n.startswith(DISC + "."))
        self._noise_names = tuple(n for n in self.space.all_names if n.startswith(NOISE + "."))
        self.units: list[Unit] = []
        self._records = []
        for rec in data:
            s0 = rec.scored.start or 0
            spans = cycle_units(rec)
            first = len(self.units)
            for i, (a, b) in enumerate(spans):
                self.units.append(Unit(rec.name, i, a, b, rec.frequency_hz))
            self._records.append({
                "u": np.ascontiguousarray(rec.u), "t": np.ascontiguousarray(rec.t),
                "y": np.ascontiguousarray(rec.y[s0:]), "s0": s0,
                "unit_starts": np.array([a - s0 for a, _ in spans]), "unit_first": first,
                "keep": None, "frequency_hz": rec.frequency_hz,
                "covariates": record_covariates(self.model, rec),
                # the discrepancy's basis over the whole record (N, m), fixed by the data
                "basis": (None if self.discrepancy is None else np.ascontiguousarray(
                    self.discrepancy.basis(rec.u, rec.frequency_hz))),
            })
        self.held_out: tuple[int, ...] = ()
        self._n_evals = 0
        self._n_prior = 0
        self._n_failed = 0

    # ------------------------------------------------------------------ bookkeeping
    @property
    def ndim(self) -> int:
        """Dimension of the unconstrained vector ``z``."""
        return self.space.ndim

    @property
    def n_units(self) -> int:
        """Number of cycles (cross-validation units) over all records."""
        return len(self.units)

    @property
    def counts(self) -> EvalCounts:
        """Evaluation counters of this process."""
        return EvalCounts(self._n_evals, self._n_prior, self._n_failed)

    def fix(self, name: str, value: Any) -> Posterior:
        """A copy of this posterior with parameter ``name`` held at ``value``.

        Any parameter can be fixed (``"noise.sigma"``, ``"obs.offset"``, a model
        parameter); the copy's counters start at zero.
        """
        new = copy.copy(self)
        new.space = self.space.fix(name, value)
        new.reset_counts()
        return new

    def with_priors(self, space: ParamSpace) -> Posterior:
        """A copy whose whole parameter space (model, offset and noise) is ``space``.

        The default priors of the offset and noise are scaled from the data; a study
        that needs the same prior for every dataset (simulation-based calibration, a
        fleet of actuators) passes one space, e.g. another posterior's ``space``.

        Raises
        ------
        ParameterError
            If ``space`` does not declare exactly this posterior's parameters.
        """
        if not isinstance(space, ParamSpace) or set(space.all_names) != set(self.space.all_names):
            got = sorted(space.all_names) if isinstance(space, ParamSpace) else space
            raise ParameterError(f"with_priors: the space must declare "
                                 f"{sorted(self.space.all_names)}, got {got}")
        new = copy.copy(self)
        new.space = space
        new.model_space = ParamSpace(
            tuple(p for p in space.params if p.name in self._model_names),
            {k: v for k, v in space.fixed.items() if k in self._model_names},
            tuple(p for p in space.fixed_params if p.name in self._model_names))
        new.reset_counts()
        return new

    def holding_out(self, units: Sequence[int]) -> Posterior:
        """A copy whose likelihood leaves out the cycles ``units`` (indices into :attr:`units`).

        The held-out cycles are still simulated (the model's memory runs through them)
        but not scored: the posterior given all the other cycles, as exact
        leave-one-cycle-out cross-validation needs. With the AR(1) likelihood the first
        sample after a held-out cycle is still conditioned on the residual before it
        (the innovation form is kept); that sample is one of hundreds per cycle.

        Parameters
        ----------
        units : sequence of int
            Indices of the cycles to hold out; empty restores the full likelihood.
        """
        idx = sorted({int(i) for i in units})
        if idx and (idx[0] < 0 or idx[-1] >= self.n_units):
            raise ParameterError(f"held-out units must be in [0, {self.n_units}), got {idx}")
        new = copy.copy(self)
        new.held_out = tuple(idx)
        new._records = []
        for rec in self._records:
            keep = None
            if idx:
                n = rec["y"].size
                keep = np.ones(n, dtype=bool)
                starts = [*rec["unit_starts"], n]
                for j in range(len(starts) - 1):
                    if rec["unit_first"] + j in idx:
                        keep[starts[j]:starts[j + 1]] = False
            new._records.append({**rec, "keep": keep})
        new.reset_counts()
        return new

    def record_counts(self, evaluations: int, prior_rejected: int, failed: int) -> None:
        """Count evaluations made outside :meth:`log_prob_batch`.

        The sampler's moves evaluate proposals from their linear-block statistics.
        """
        self._n_evals += int(evaluations)
        self._n_prior += int(prior_rejected)
        self._n_failed += int(failed)

    def reset_counts(self) -> None:
        """Zero the evaluation counters."""
        self._n_evals = self._n_prior = self._n_failed = 0

    def __getstate__(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def __repr__(self) -> str:
        temper = "" if self.beta == 1.0 else f", beta={self.beta}"
        if self.held_out:
            temper += f", held_out={list(self.held_out)}"
        if self.discrepancy is not None:
            temper += ", discrepancy='hsgp'"
        return (f"Posterior(model={self.model.name!r}, likelihood={self.likelihood.name!r}, "
                f"records={len(self.data)}, ndim={self.ndim}{temper})")

    # ------------------------------------------------------------------ evaluation
    def _split_theta(self, theta: Mapping[str, Any]) -> tuple[dict, dict, Any]:
        model_theta = {k: theta[k] for k in self._model_names}
        noise = {k[len(NOISE) + 1:]: theta[k] for k in self._noise_names}
        off = theta.get(f"{OBS}.offset", 0.0) if self.offset else 0.0
        return model_theta, noise, off

    def discrepancy_coefficients(self, z: np.ndarray) -> np.ndarray | None:
        """Basis coefficients ``s * xi`` (W, m) of ``W`` points, None without a discrepancy."""
        if self.discrepancy is None:
            return None
        z = np.atleast_2d(np.asarray(z, dtype=float))
        return self._coefficients(self.space.unpack(z), z.shape[0])

    def _coefficients(self, theta: Mapping[str, Any], w: int) -> np.ndarray | None:
        # the coefficients (W, m) from an unpacked theta (the callers have one already)
        if self.discrepancy is None:
            return None
        return self.discrepancy.coefficients(
            {k[len(DISC) + 1:]: np.broadcast_to(np.asarray(theta[k], float),
                                                (w, *np.shape(theta[k])[1:]))
             for k in self._disc_names})

    def _delta(self, rec: dict, coef: np.ndarray | None) -> np.ndarray | float:
        # delta over the whole record (W, N); 0 without a discrepancy
        if coef is None:
            return 0.0
        return coef @ rec["basis"].T

    def _pointwise(self, z: np.ndarray,
                   inside: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Per-record pointwise log-likelihood for the walkers inside the prior.

        ``inside`` (W,) marks the walkers with a finite log prior (the caller has it
        already). Returns the list of (W_in, N_scored) arrays and the mask of the
        walkers whose simulation failed (W_in,).
        """
        zi = z[inside]
        if zi.shape[0] == 0:
            return [], np.zeros(0, dtype=bool)
        theta = self.space.unpack(zi)
        model_theta, noise, off = self._split_theta(theta)
        failed = np.zeros(zi.shape[0], dtype=bool)
        out = []
        off = np.asarray(off, dtype=float).reshape(-1, 1) if self.offset else 0.0
        noise = {k: np.asarray(v, dtype=float) for k, v in noise.items()}
        coef = self._coefficients(theta, zi.shape[0])
        for rec in self._records:
            traj = self.model.run_batch(rec["u"], rec["t"], model_theta,
                                        covariates=rec["covariates"])
            yhat = traj.y[:, rec["s0"]:] + off
            if coef is not None:
                yhat = yhat + self._delta(rec, coef)[:, rec["s0"]:]
            with np.errstate(invalid="ignore", over="ignore"):
                pw = self.likelihood.pointwise(rec["y"] - yhat, noise)
            failed |= traj.failed | ~np.all(np.isfinite(pw), axis=1)
            out.append(pw)
        return out, failed

    @with_single_threaded_blas
    def log_prob_batch(self, z: np.ndarray) -> np.ndarray:
        """Log posterior density (up to a constant) of ``W`` points.

        Parameters
        ----------
        z : ndarray, shape (W, ndim)

        Returns
        -------
        ndarray, shape (W,)
            Finite or ``-inf`` (outside the prior, or a failed simulation); never NaN.
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        if z.shape[1] != self.ndim:
            raise ParameterError(f"z must have {self.ndim} columns, got {z.shape}")
        lp = np.atleast_1d(self.space.log_prior(z)).astype(float)
        self._n_evals += z.shape[0]
        if self.beta == 0.0:
            self._n_prior += int(np.count_nonzero(~np.isfinite(lp)))
            return np.where(np.isfinite(lp), lp, -np.inf)
        inside = np.isfinite(lp)
        pws, failed = self._pointwise(z, inside)
        self._n_prior += int(np.count_nonzero(~inside))
        if pws:
            ll = np.sum([pw.sum(axis=1) if rec["keep"] is None else pw[:, rec["keep"]].sum(axis=1)
                         for pw, rec in zip(pws, self._records, strict=True)], axis=0)
            ll[failed] = -np.inf
            self._n_failed += int(np.count_nonzero(failed))
            lp[inside] += self.beta * ll
        lp[~np.isfinite(lp)] = -np.inf
        return lp

    def log_prob(self, z: np.ndarray) -> float:
        """Log posterior density of one point ``z`` (ndim,): a float or ``-inf``."""
        return float(self.log_prob_batch(np.asarray(z, dtype=float)[None, :])[0])

    __call__ = log_prob_batch

    @with_single_threaded_blas
    def log_likelihood_units(self, z: np.ndarray) -> np.ndarray:
        """Log-likelihood of each unit (cycle) for ``W`` points.

        Returns
        -------
        ndarray, shape (W, n_units)
            ``-inf`` rows for points outside the prior or with failed simulations.
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        out = np.full((z.shape[0], self.n_units), -np.inf)
        inside = np.isfinite(np.atleast_1d(self.space.log_prior(z)))
        pws, failed = self._pointwise(z, inside)
        if not pws:
            return out
        cols = []
        for rec, pw in zip(self._records, pws, strict=True):
            cols.append(np.add.reduceat(pw, rec["unit_starts"], axis=1))
        block = np.concatenate(cols, axis=1)
        block[failed] = -np.inf
        out[inside] = block
        return out

    def model_draws(self, z: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The model's parameters and the observation offsets of ``W`` points ``z``.

        Returns
        -------
        theta : dict
            ``name -> array (W, *shape)``, the model's parameters only (no noise).
        offset : ndarray, shape (W,)
            ``obs.offset`` of each point (zeros when the posterior has none).
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        theta, _, off = self._split_theta(self.space.unpack(z))
        return theta, np.broadcast_to(np.asarray(off, dtype=float).ravel(),
                                      (z.shape[0],)).copy()

    @with_single_threaded_blas
    def predict(self, z: np.ndarray, *, discrepancy: bool = True) -> list[np.ndarray]:
        """Noise-free predictions (offset included) for ``W`` points, per record.

        Parameters
        ----------
        z : ndarray, shape (W, ndim)
        discrepancy : bool
            Include the discrepancy ``delta`` (the statistical model's mean); False gives
            the physical model alone.

        Returns
        -------
        list of ndarray, each (W, N_record)
            Full records (warm-up included); failed rows are NaN.
        """
        return self._simulate(z, self._records, discrepancy)

    def _simulate(self, z: np.ndarray, records: Sequence[dict], discrepancy: bool
                  ) -> list[np.ndarray]:
        # one arithmetic for the fitted records and for others (predict_records), so
        # that a prediction of a fitted record equals the fit's own to the last bit
        z = np.atleast_2d(np.asarray(z, dtype=float))
        theta = self.space.unpack(z)
        model_theta, _, off = self._split_theta(theta)
        off = np.asarray(off, dtype=float).reshape(-1, 1) if self.offset else 0.0
        coef = self._coefficients(theta, z.shape[0]) if discrepancy else None
        return [self.model.run_batch(r["u"], r["t"], model_theta, covariates=r["covariates"]).y
                + off + self._delta(r, coef) for r in records]

    @with_single_threaded_blas
    def predict_records(self, z: np.ndarray, data: Dataset | Record, *,
                        discrepancy: bool = True) -> list[np.ndarray]:
        """Noise-free free-run simulations of ``W`` points on other records.

        The same computation as :meth:`predict` (model from its relaxed state at each
        record's first input, offset, discrepancy over the record's own input), on
        records the posterior was not built on: the parameters, the offset and the
        discrepancy's weights are the fit's; only the inputs (and the measured
        channels the model reads) are the new records'.

        Parameters
        ----------
        z : ndarray, shape (W, ndim)
            Points of this posterior.
        data : Dataset or Record
            Records in the units of the fitted data.
        discrepancy : bool
            Include the discrepancy ``delta``.

        Returns
        -------
        list of ndarray, each (W, N_record)
            Full records (warm-up included); failed rows are NaN.

        Raises
        ------
        DataError
            A record lacks a measured column the model reads.
        """
        records = [data] if isinstance(data, Record) else list(data)
        recs = [{"u": np.ascontiguousarray(r.u), "t": np.ascontiguousarray(r.t),
                 "covariates": record_covariates(self.model, r),
                 "basis": (None if self.discrepancy is None else np.ascontiguousarray(
                     self.discrepancy.basis(r.u, r.frequency_hz)))} for r in records]
        return self._simulate(z, recs, discrepancy)

    def noise_draws(self, z: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
        """Observation-noise draws (W, n) of the likelihood at ``W`` points ``z``.

        What the posterior predictive adds to a noise-free simulation of ``n`` samples
        (:meth:`bayeshyst.likelihoods.Likelihood.sample`; AR(1) noise is a correlated
        series).
        """
        theta = self.space.unpack(np.atleast_2d(np.asarray(z, dtype=float)))
        noise = {k[len(NOISE) + 1:]: np.asarray(theta[k], float) for k in self._noise_names}
        return self.likelihood.sample(noise, int(n), rng)

    @with_single_threaded_blas
    def discrepancy_draws(self, z: np.ndarray) -> list[np.ndarray] | None:
        """The discrepancy ``delta`` (W, N_record) per record, None without one."""
        coef = self.discrepancy_coefficients(z)
        if coef is None:
            return None
        return [np.asarray(self._delta(r, coef)) for r in self._records]
