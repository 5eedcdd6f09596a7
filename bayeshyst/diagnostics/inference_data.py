"""Sampling results as ``arviz.InferenceData``: conversion, netCDF files, summaries.

The left-out unit of cross-validation is one input cycle (:attr:`Posterior.units`),
so ``log_likelihood`` holds one value per cycle and draw. Each of those values costs a
forward simulation of every record, so the conversion keeps ``draws_per_chain`` draws
(evenly spaced in steps) of every walker of every ensemble: a few thousand draws in
all, plenty for PSIS-LOO. The full chains stay in :class:`SamplingResult` and in the
sampler's HDF5 checkpoint; convergence was judged on all of them (the report is copied
into ``sample_stats.attrs``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import arviz as az
import numpy as np
import xarray as xr

from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.inference.held_out import held_out_log_predictive
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.posterior import NOISE, Posterior
from bayeshyst.inference.sampling_result import ParamSummary, SamplingResult, summarise_draws
from bayeshyst.inference.saved import CONSTRAINT_VAR, FIT_ATTR, SEGMENT_VAR, fit_description
from bayeshyst.params import ParamSpace

__all__ = [
    "GIVEN_REST",
    "load_netcdf",
    "posterior_summary",
    "sampling_report",
    "save_netcdf",
    "to_inference_data",
]

_BATCH = 512  # draws per batched log-likelihood evaluation
#: log-likelihood variable of the Rao-Blackwellised leave-one-cycle-out terms
GIVEN_REST = "y_given_rest"


def _check_pair(post: Posterior, result: SamplingResult) -> None:
    if not isinstance(post, Posterior):
        raise ParameterError(f"post must be a Posterior, got {type(post).__name__}")
    if not isinstance(result, SamplingResult):
        raise ParameterError(f"result must be a SamplingResult, got {type(result).__name__}")
    if post.space != result.space:
        raise ParameterError("the result was not sampled from this posterior: their "
                             "parameter spaces differ")


def _positive_int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ParameterError(f"{what} must be a positive integer, got {value!r}")
    return int(value)


def _thin_index(n_steps: int, n_keep: int) -> np.ndarray:
    """``n_keep`` step indices spread evenly over ``n_steps`` (all when fewer)."""
    if n_keep >= n_steps:
        return np.arange(n_steps)
    return np.unique(np.round(np.linspace(0, n_steps - 1, n_keep)).astype(int))


def _value_vars(space: ParamSpace, theta: dict[str, np.ndarray], lead: tuple[int, ...],
                lead_dims: tuple[str, ...]) -> dict[str, xr.Variable]:
    """Free parameters as xarray variables (vector ones get ``<name>_dim_<i>`` dims)."""
    out = {}
    for p in space.params:
        value = np.asarray(theta[p.name], dtype=float).reshape((*lead, *p.shape))
        dims = lead_dims + tuple(f"{p.name}_dim_{i}" for i in range(len(p.shape)))
        out[p.name] = xr.Variable(dims, value, attrs={"unit": p.unit,
                                                      "description": p.description})
    return out


def _unit_of(post: Posterior, key: str) -> str:
    units = sorted({r.units.get(key, "") for r in post.data})
    return units[0] if len(units) == 1 else ",".join(units)


def _obs_layout(post: Posterior) -> dict[str, np.ndarray]:
    """Per-observation record index, name, scored flag and cycle (-1 in warm-up)."""
    record, names, scored, cycle = [], [], [], []
    for i, rec in enumerate(post.data):
        record.append(np.full(rec.n, i, dtype=np.int64))
        names.append(np.full(rec.n, rec.name, dtype=object))
        scored.append(np.asarray(rec.scored_mask, dtype=bool))
        c = np.full(rec.n, -1, dtype=np.int64)
        for j, unit in enumerate(post.units):
            if unit.record == rec.name:
                c[unit.start:unit.stop] = j
        cycle.append(c)
    return {"record": np.concatenate(record), "name": np.concatenate(names).astype(str),
            "scored": np.concatenate(scored), "cycle": np.concatenate(cycle)}


def _report_attrs(post: Posterior, result: SamplingResult, thin: np.ndarray) -> dict[str, Any]:
    conv = result.convergence
    counts = result.counts
    return {
        "model": result.model,
        "likelihood": result.likelihood,
        "seed": int(result.seed),
        "runtime_s": float(result.runtime_s),
        "beta": float(post.beta),
        "converged": int(conv.converged),
        "convergence": str(conv),
        "convergence_reasons": "; ".join(conv.reasons),
        "rhat_max": float(conv.rhat_max),
        "ess_bulk_min": float(conv.ess_bulk_min),
        "ess_tail_min": float(conv.ess_tail_min),
        "tau_max": float(conv.tau_max),
        "n_steps": int(conv.n_steps),
        "burn": int(conv.burn),
        "n_ensembles": int(result.chains.shape[0]),
        "n_walkers": int(result.chains.shape[2]),
        "n_kept_steps": int(result.chains.shape[1]),
        "kept_step_index": thin.astype(np.int64),
        "evaluations": int(counts.evaluations),
        "failed_simulations": int(counts.failed),
        "prior_rejected": int(counts.prior_rejected),
        "acceptance_mean": float(np.mean(result.acceptance)),
        # netCDF attributes are scalars or arrays: the per-move rates as JSON text
        "move_acceptance": json.dumps(dict(result.move_acceptance)),
        "map_log_prob": float(result.start.log_prob),
        "map_z": np.asarray(result.start.z, dtype=float),
        "settings": json.dumps(result.settings, default=str, sort_keys=True),
    }


def to_inference_data(
    post: Posterior,
    result: SamplingResult,
    *,
    draws_per_chain: int = 30,
    n_predictive: int = 200,
    seed: int = 0,
) -> az.InferenceData:
    """Everything about a fit as an ``arviz.InferenceData`` (netCDF-ready).

    Parameters
    ----------
    post : Posterior
        The posterior that ``result`` sampled.
    result : SamplingResult
        Its draws.
    draws_per_chain : int
        Draws kept per walker, evenly spaced over the kept steps. Each draw costs one
        simulation (its per-cycle log-likelihood), so keep ``E * W * draws_per_chain``
        to a few thousand; the full chains live in ``result`` and in the checkpoint.
    n_predictive : int
        Posterior-predictive draws (``result.draws(n_predictive, seed=seed)``).
    seed : int
        Seeds the choice of predictive draws and their noise.

    Returns
    -------
    arviz.InferenceData
        Groups (dims in brackets):

        ``posterior``
            Free parameters in physical units [chain, draw, (``<name>_dim_0``)];
            every walker of every ensemble is a chain (``chain = e * W + w``, coords
            ``ensemble`` and ``walker``); ``draw`` is the step after burn-in.
        ``sample_stats``
            ``lp`` (log posterior) [chain, draw], ``walker_acceptance`` [chain];
            attrs: convergence report, evaluation counts, runtime, seed, model,
            likelihood, settings.
        ``log_likelihood``
            ``y`` [chain, draw, cycle]: log-likelihood of each cycle, coords
            ``cycle_record``, ``cycle_index``, ``cycle_frequency_hz`` (NaN if unknown);
            ``arviz.loo`` leaves out one cycle at a time. Where the posterior has a
            linear block, also ``y_given_rest``: ``log p(y_c | y_-c, z_n)`` with the block
            integrated out exactly (:func:`~bayeshyst.inference.held_out.held_out_log_predictive`),
            which :func:`loo` uses.
        ``posterior_predictive``
            ``y`` [chain (1), draw, obs]: noise-free prediction plus a noise draw
            from the likelihood, over every sample of every record (warm-up included).
        ``observed_data``
            ``y`` [obs], coord ``obs_record``.
        ``constant_data``
            ``t``, ``u``, ``record`` (index into ``attrs["records"]``), ``scored``
            (False in warm-up), ``cycle`` (index into ``cycle``, -1 in warm-up) [obs].

    Raises
    ------
    ParameterError
        If ``result`` was not sampled from ``post`` or a count is not positive.
    """
    _check_pair(post, result)
    draws_per_chain = _positive_int(draws_per_chain, "draws_per_chain")
    n_predictive = _positive_int(n_predictive, "n_predictive")
    n_ens, n_steps, n_walk, ndim = result.chains.shape
    thin = _thin_index(n_steps, draws_per_chain)
    n_chain, n_draw = n_ens * n_walk, thin.size
    # (E, D, W, ndim) -> (E, W, D, ndim) -> (chain, draw, ndim)
    z = result.chains[:, thin].transpose(0, 2, 1, 3).reshape(n_chain, n_draw, ndim)
    lp = result.log_prob[:, thin].transpose(0, 2, 1).reshape(n_chain, n_draw)
    flat = z.reshape(-1, ndim)
    theta = post.space.unpack(flat)
    loglik = np.concatenate([post.log_likelihood_units(flat[i:i + _BATCH])
                             for i in range(0, flat.shape[0], _BATCH)])
    loglik = loglik.reshape(n_chain, n_draw, post.n_units)
    structure = LinearStructure.of(post, reference=result.start.z)
    given_rest = None
    if structure is not None:
        given_rest = held_out_log_predictive(structure, flat).reshape(n_chain, n_draw,
                                                                      post.n_units)

    chain_coords = {
        "chain": np.arange(n_chain),
        "draw": (result.convergence.burn + thin).astype(np.int64),
        "ensemble": ("chain", np.repeat(np.arange(n_ens), n_walk)),
        "walker": ("chain", np.tile(np.arange(n_walk), n_ens)),
    }
    posterior = xr.Dataset(_value_vars(post.space, theta, (n_chain, n_draw),
                                       ("chain", "draw")), coords=chain_coords)
    posterior.attrs["fixed"] = json.dumps({k: np.asarray(v).tolist()
                                           for k, v in post.space.fixed.items()})
    sample_stats = xr.Dataset(
        {"lp": (("chain", "draw"), lp),
         "walker_acceptance": ("chain", result.acceptance.reshape(n_chain))},
        coords=chain_coords, attrs=_report_attrs(post, result, thin))

    units = post.units
    cycle_coords = {
        "cycle": np.arange(post.n_units),
        "cycle_record": ("cycle", np.array([u.record for u in units], dtype=str)),
        "cycle_index": ("cycle", np.array([u.index for u in units], dtype=np.int64)),
        "cycle_frequency_hz": ("cycle", np.array(
            [math.nan if u.frequency_hz is None else float(u.frequency_hz) for u in units])),
    }
    ll_vars = {"y": (("chain", "draw", "cycle"), loglik)}
    if given_rest is not None:
        ll_vars[GIVEN_REST] = (("chain", "draw", "cycle"), given_rest)
    log_likelihood = xr.Dataset(ll_vars, coords={**chain_coords, **cycle_coords},
                                attrs={"failed_draws": int(np.sum(~np.isfinite(loglik))),
                                       "linear_block": json.dumps(
                                           [] if structure is None else list(structure.names))})

    layout = _obs_layout(post)
    obs_coords = {"obs": np.arange(layout["record"].size), "obs_record": ("obs", layout["name"])}
    y_unit = _unit_of(post, "y")
    zp = result.draws(n_predictive, seed=seed)
    rng = np.random.default_rng(seed)
    theta_p = post.space.unpack(zp)
    noise = {k[len(NOISE) + 1:]: np.asarray(theta_p[k], dtype=float)
             for k in post._noise_names}
    pred = np.concatenate([yhat + post.likelihood.sample(noise, yhat.shape[1], rng)
                           for yhat in post.predict(zp)], axis=1)
    predictive = xr.Dataset(
        {"y": (("chain", "draw", "obs"), pred[None], {"unit": y_unit})},
        coords={"chain": [0], "draw": np.arange(pred.shape[0]), **obs_coords},
        attrs={"seed": int(seed), "failed_draws": int(np.sum(np.isnan(pred).any(axis=1)))})

    observed = xr.Dataset(
        {"y": ("obs", np.concatenate([r.y for r in post.data]), {"unit": y_unit})},
        coords=obs_coords)
    # what load_fit rebuilds the posterior from (JSON at the root, arrays beside the data)
    rebuild = fit_description(post)
    extra: dict[str, Any] = {}
    if rebuild.segment is not None:
        extra[SEGMENT_VAR] = ("obs", rebuild.segment)
    if rebuild.constraint is not None:
        extra[CONSTRAINT_VAR] = (("disc_basis", "disc_direction"), rebuild.constraint)
    extra.update({k: ("obs", v) for k, v in rebuild.covariate_variables().items()})
    constant = xr.Dataset(
        {"t": ("obs", np.concatenate([r.t for r in post.data]), {"unit": _unit_of(post, "t")}),
         "u": ("obs", np.concatenate([r.u for r in post.data]), {"unit": _unit_of(post, "u")}),
         "record": ("obs", layout["record"]),
         "scored": ("obs", layout["scored"]),
         "cycle": ("obs", layout["cycle"]), **extra},
        coords=obs_coords,
        attrs={"records": json.dumps([r.name for r in post.data]),
               "record_frequency_hz": json.dumps([r.frequency_hz for r in post.data])})

    return az.InferenceData(
        posterior=posterior, sample_stats=sample_stats, log_likelihood=log_likelihood,
        posterior_predictive=predictive, observed_data=observed, constant_data=constant,
        attrs={"model": result.model, "likelihood": result.likelihood,
               "bayeshyst_converged": int(result.convergence.converged),
               FIT_ATTR: json.dumps(rebuild.meta)})


# -------------------------------------------------------------------------- netCDF
def save_netcdf(idata: az.InferenceData, path: str | os.PathLike[str]) -> Path:
    """Write ``idata`` to a netCDF file atomically.

    The data go to a temporary file in the same folder, which then replaces ``path``
    (``os.replace``): a reader never sees a half-written file, and a failure leaves no
    temporary file behind.

    Parameters
    ----------
    idata : arviz.InferenceData
    path : path-like
        Target file (its folder is created if needed).

    Returns
    -------
    Path
        ``path``.
    """
    if not isinstance(idata, az.InferenceData):
        raise ParameterError(f"idata must be an InferenceData, got {type(idata).__name__}")
    path = Path(path)
    with atomic_path(path) as tmp:
        idata.to_netcdf(tmp)
    return path


def load_netcdf(path: str | os.PathLike[str]) -> az.InferenceData:
    """Read an InferenceData written by :func:`save_netcdf` (loaded into memory).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no netCDF file at {path}")
    return az.from_netcdf(path)


def posterior_summary(idata: az.InferenceData, prob: float = 0.9) -> list[ParamSummary]:
    """Mean, sd and ``prob`` HDI of every free scalar element of a saved posterior.

    The same numbers as :meth:`SamplingResult.summary`, computed from the draws kept in
    ``idata`` (thinned: ``draws_per_chain`` per walker) instead of the full chains.
    Vector parameters give one row per element, labelled ``name[i]``.
    """
    if not isinstance(idata, az.InferenceData) or "posterior" not in idata.groups():
        raise ParameterError("idata has no posterior group (build it with to_inference_data)")
    if not 0.0 < prob < 1.0:
        raise ParameterError(f"prob must be in (0, 1), got {prob!r}")
    post = idata.posterior
    draws = {str(name): np.asarray(var.values, dtype=float).reshape(-1, *var.shape[2:])
             for name, var in post.data_vars.items()}
    units = {str(name): str(var.attrs.get("unit", "")) for name, var in post.data_vars.items()}
    return summarise_draws(draws, units, prob)


def sampling_report(idata: az.InferenceData) -> dict[str, Any]:
    """The sampler's convergence report and counts saved with a posterior.

    Keys: ``converged`` (bool), ``convergence_reasons`` (list), ``rhat_max``,
    ``ess_bulk_min``, ``ess_tail_min``, ``tau_max``, ``n_steps``, ``evaluations``,
    ``failed_simulations``, ``runtime_s``, ``model``, ``likelihood``, ``move_acceptance``
    (dict; judged on the full chains, not the saved draws). Missing entries are
    ``None``.
    """
    stats = getattr(idata, "sample_stats", None)
    attrs = dict(stats.attrs) if stats is not None else {}

    def num(key: str) -> float | None:
        v = attrs.get(key)
        return None if v is None or not math.isfinite(float(v)) else float(v)

    reasons = str(attrs.get("convergence_reasons", "") or "")
    return {
        "model": attrs.get("model"), "likelihood": attrs.get("likelihood"),
        "converged": bool(int(attrs["converged"])) if "converged" in attrs else None,
        "convergence_reasons": [r.strip() for r in reasons.split(";") if r.strip()],
        "rhat_max": num("rhat_max"), "ess_bulk_min": num("ess_bulk_min"),
        "ess_tail_min": num("ess_tail_min"), "tau_max": num("tau_max"),
        "n_steps": None if "n_steps" not in attrs else int(attrs["n_steps"]),
        "evaluations": None if "evaluations" not in attrs else int(attrs["evaluations"]),
        "failed_simulations": (None if "failed_simulations" not in attrs
                               else int(attrs["failed_simulations"])),
        "runtime_s": num("runtime_s"),
        "move_acceptance": (json.loads(attrs["move_acceptance"])
                            if "move_acceptance" in attrs else None),
    }
