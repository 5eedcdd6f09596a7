"""Fits you can reload: :func:`load_fit` and the record every saved posterior carries.

Every posterior bayeshyst writes (``fit``'s ``posterior.nc``, ``diagnose``'s
``posterior_base.nc``/``posterior_final.nc``, ``compare``'s ``posteriors/*.nc``) goes
through :func:`bayeshyst.diagnostics.to_inference_data`, which stores, next to the draws,
what it takes to rebuild the posterior they were drawn from: the model's spec string with
its settings (:func:`bayeshyst.models.compose.model_spec`), the likelihood, the offset
and fixed parameters, each record's warm-up, units and metadata, and a discrepancy's
scalings and constraint (:func:`fit_description`). :func:`load_fit` reads that back —
JSON and arrays only, nothing is unpickled — rebuilds the :class:`Posterior` from the
data stored in the same file, maps the draws into its coordinates and checks the
rebuilt posterior against the log densities the sampler recorded, so a reloaded fit is
the fit that was sampled or says why not.

The record is versioned (:data:`FIT_FORMAT`); a file of another format, or one without
the record (written before it existed, or by another tool), is refused in words.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst._version import __version__
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.discrepancy import Discrepancy
from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.predict import (
    InitialCondition,
    PredictionResult,
    checked_request,
    predict_posterior,
)
from bayeshyst.models import get as get_model
from bayeshyst.models.compose import model_spec
from bayeshyst.tables import TableRecord

__all__ = ["FIT_ATTR", "FIT_FORMAT", "FitDescription", "SavedFit", "covariate_variable",
           "fit_description",
           "load_fit"]

_log = logging.getLogger(__name__)

#: version of the rebuild record (bump when its meaning changes)
FIT_FORMAT = 1
#: the netCDF root attribute that holds it (JSON text)
FIT_ATTR = "bayeshyst_fit"
#: ``constant_data`` variables holding its arrays
SEGMENT_VAR, CONSTRAINT_VAR = "segment", "discrepancy_constraint"
#: a saved posterior's file names, in the order a directory is searched for one
SAVED_NAMES = ("posterior.nc", "posterior_final.nc", "posterior_base.nc")
#: draws whose log density is recomputed to check the rebuilt posterior, and the
#: largest difference (nats) accepted: the same arithmetic gives equal values, but a
#: likelihood summed in another order may differ in the last bits
N_CHECKED, LOG_PROB_TOLERANCE = 8, 1e-6
_DISCREPANCY_FIELDS = ("n_input", "n_rate", "u_centre", "u_half", "rate_centre", "rate_half",
                       "y_span", "y_unit")


@dataclass(frozen=True)
class FitDescription:
    """What rebuilds a posterior: JSON-ready ``meta`` and named arrays.

    Attributes
    ----------
    meta : dict
        Stored as the root attribute :data:`FIT_ATTR` (JSON text).
    constraint : ndarray, shape (m, r), or None
        The discrepancy's constraint (``constant_data`` variable :data:`CONSTRAINT_VAR`).
    segment : ndarray of int, shape (N,), or None
        Every record's segment labels end to end (-1 where a record has none), over
        the ``obs`` dimension (``constant_data`` variable :data:`SEGMENT_VAR`).
    covariates : dict of str to ndarray
        The measured columns the model reads, end to end over the ``obs`` dimension
        (``constant_data`` variables ``covariate_<i>``, names in ``meta["covariates"]``).
    """

    meta: dict[str, Any]
    constraint: np.ndarray | None = None
    segment: np.ndarray | None = None
    covariates: dict[str, np.ndarray] = field(default_factory=dict)

    def covariate_variables(self) -> dict[str, np.ndarray]:
        """``constant_data`` variable name -> values of every covariate."""
        return {covariate_variable(i): v for i, v in enumerate(self.covariates.values())}


def covariate_variable(i: int) -> str:
    """Name of the ``constant_data`` variable holding the ``i``-th covariate the model reads."""
    return f"covariate_{i}"


def _plain(value: Any) -> Any:
    # records freeze their metadata (mappings become read-only proxies)
    if isinstance(value, Mapping):
        return dict(value)
    raise TypeError(f"{type(value).__name__} is not JSON")


def _jsonable(value: Any) -> Any:
    """``value`` after a JSON round trip (tuples become lists), None if it has none."""
    try:
        return json.loads(json.dumps(value, allow_nan=False, default=_plain))
    except (TypeError, ValueError):
        return None


def fit_description(post: Posterior) -> FitDescription:
    """The record :func:`load_fit` rebuilds ``post`` from (see the module docstring).

    A model whose settings cannot be written as a spec string gets ``model_spec``
    None and the reason in ``not_reloadable``; the file is still written, and
    :func:`load_fit` refuses it with that reason.
    """
    meta: dict[str, Any] = {"format": FIT_FORMAT, "written_by": __version__}
    try:
        meta["model_spec"] = model_spec(post.model)
    except ModelError as exc:
        meta["model_spec"], meta["not_reloadable"] = None, str(exc)
    meta.update({
        "likelihood": post.likelihood.name, "offset": bool(post.offset),
        "beta": float(post.beta), "held_out": [int(i) for i in post.held_out],
        "fixed": {k: np.asarray(v, dtype=float).tolist() for k, v in post.space.fixed.items()},
        "data_name": post.data.name,
    })
    records, dropped = [], []
    for r in post.data:
        metadata = {}
        for k, v in r.metadata.items():
            kept = _jsonable(v)
            if kept is None and v is not None:
                dropped.append(f"{r.name}:{k}")
            else:
                metadata[str(k)] = kept
        records.append({"name": r.name, "warmup": int(r.warmup), "units": dict(r.units),
                        "metadata": metadata, "has_segment": r.segment is not None})
    meta["records"] = records
    if dropped:
        meta["metadata_not_stored"] = dropped
    segment = None
    if any(r.segment is not None for r in post.data):
        segment = np.concatenate([np.full(r.n, -1, dtype=np.int64) if r.segment is None
                                  else np.asarray(r.segment, dtype=np.int64) for r in post.data])
    constraint = None
    disc = post.discrepancy
    if disc is not None:
        meta["discrepancy"] = {k: getattr(disc, k) for k in _DISCREPANCY_FIELDS}
        if disc.constraint is not None:
            constraint = np.asarray(disc.constraint, dtype=float)
    else:
        meta["discrepancy"] = None
    meta["covariates"] = list(post.model.covariates)
    covariates = {c: np.concatenate([np.asarray(r.covariates[c], dtype=float) for r in post.data])
                  for c in post.model.covariates}
    return FitDescription(meta, constraint, segment, covariates)


# ------------------------------------------------------------------------------ reading
def _find_file(path: Path) -> Path:
    if path.is_file():
        return path
    if not path.is_dir():
        raise DataError(f"{path}: no such file or directory (give a fit's output directory "
                        "or its posterior .nc file)")
    for name in SAVED_NAMES:
        if (path / name).is_file():
            return path / name
    found = sorted(p.relative_to(path).as_posix() for p in path.rglob("*.nc"))
    if not found:
        raise DataError(f"{path}: no saved posterior here (expected one of "
                        f"{', '.join(SAVED_NAMES)}, written by bayeshyst fit/diagnose/compare)")
    if len(found) == 1:
        return path / found[0]
    shown = ", ".join(found[:8]) + (f" and {len(found) - 8} more" if len(found) > 8 else "")
    raise DataError(f"{path} holds {len(found)} saved posteriors ({shown}); name one file")


def _read_groups(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The root attributes and the groups ``load_fit`` needs, loaded into memory."""
    import xarray as xr

    groups: dict[str, Any] = {}
    try:
        with xr.open_dataset(path, engine="h5netcdf") as root:
            attrs = dict(root.attrs)
        for g in ("posterior", "sample_stats", "observed_data", "constant_data"):
            with xr.open_dataset(path, group=g, engine="h5netcdf") as ds:
                groups[g] = ds.load()
    except (OSError, ValueError, KeyError) as exc:
        raise DataError(f"{path}: not a posterior written by bayeshyst ({exc})") from exc
    return attrs, groups


def _meta(path: Path, attrs: dict[str, Any]) -> dict[str, Any]:
    raw = attrs.get(FIT_ATTR)
    if raw is None:
        raise DataError(f"{path}: the file has no {FIT_ATTR!r} record — it was written by a "
                        f"bayeshyst older than {__version__}'s fit format {FIT_FORMAT}, or by "
                        "another tool; refit to get a reloadable posterior")
    try:
        meta = json.loads(raw)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: its {FIT_ATTR!r} record is not JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FIT_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else None
        raise DataError(f"{path}: fit format {got!r} (written by bayeshyst "
                        f"{meta.get('written_by') if isinstance(meta, dict) else '?'}); "
                        f"this bayeshyst ({__version__}) reads format {FIT_FORMAT}")
    if meta.get("model_spec") is None:
        raise DataError(f"{path}: the fitted model cannot be rebuilt: "
                        f"{meta.get('not_reloadable', 'no model spec stored')}")
    return meta


def _records(path: Path, meta: dict[str, Any], groups: dict[str, Any]) -> Dataset:
    const, observed = groups["constant_data"], groups["observed_data"]
    index = np.asarray(const["record"].values, dtype=np.int64)
    t, u = np.asarray(const["t"].values, float), np.asarray(const["u"].values, float)
    y = np.asarray(observed["y"].values, float)
    segment = (np.asarray(const[SEGMENT_VAR].values, dtype=np.int64)
               if SEGMENT_VAR in const else None)
    records = []
    for i, spec in enumerate(meta["records"]):
        sel = index == i
        if not sel.any():
            raise DataError(f"{path}: record {spec.get('name')!r} has no samples in the file")
        seg = None
        if spec.get("has_segment") and segment is not None:
            seg = segment[sel]
        covariates = {c: np.asarray(const[covariate_variable(j)].values, float)[sel]
                      for j, c in enumerate(meta.get("covariates") or [])}
        records.append(Record(t[sel], u[sel], y[sel], segment=seg, warmup=int(spec["warmup"]),
                              metadata=spec.get("metadata") or {},
                              units=spec.get("units") or {}, name=str(spec["name"]),
                              covariates=covariates))
    return Dataset(tuple(records), name=str(meta.get("data_name", path.stem)))


def _posterior(path: Path, meta: dict[str, Any], data: Dataset,
               groups: dict[str, Any]) -> Posterior:
    model = get_model(meta["model_spec"])
    disc = None
    if meta.get("discrepancy") is not None:
        const = groups["constant_data"]
        constraint = (np.asarray(const[CONSTRAINT_VAR].values, float)
                      if CONSTRAINT_VAR in const else None)
        disc = Discrepancy(**meta["discrepancy"], constraint=constraint)
    post = Posterior(data, model, meta["likelihood"], offset=bool(meta["offset"]),
                     beta=float(meta["beta"]), discrepancy=disc)
    for name, value in meta.get("fixed", {}).items():
        if name not in post.space.all_names:
            raise DataError(f"{path}: fixed parameter {name!r} is not a parameter of "
                            f"{meta['model_spec']} in this bayeshyst")
        value = np.asarray(value, dtype=float)
        if name in post.space.fixed:  # fixed by the model itself (data-scaled thresholds)
            if not np.array_equal(np.asarray(post.space.fixed[name], float), value):
                raise DataError(f"{path}: {name!r} is fixed at {post.space.fixed[name]!r} "
                                f"by {meta['model_spec']} now, the fit had {value!r}")
            continue
        post = post.fix(name, value)
    if meta.get("held_out"):
        post = post.holding_out(meta["held_out"])
    return post


def _draws(path: Path, post: Posterior, posterior: Any) -> np.ndarray:
    """The stored draws (chain x draw) in the rebuilt posterior's coordinates ``z``."""
    space = post.space
    stored = {str(k) for k in posterior.data_vars}
    free = set(space.names)
    if stored != free:
        raise DataError(f"{path}: the file's parameters {sorted(stored)} are not those of "
                        f"{post.model.name} in this bayeshyst ({sorted(free)})")
    n_chain, n_draw = posterior.sizes["chain"], posterior.sizes["draw"]
    z = np.empty((n_chain * n_draw, space.ndim))
    for p in space.params:
        x = np.asarray(posterior[p.name].values, dtype=float).reshape(n_chain * n_draw, -1)
        if x.shape[1] != int(np.prod(p.shape, dtype=int)):
            raise DataError(f"{path}: parameter {p.name!r} has {x.shape[1]} values per draw, "
                            f"{post.model.name} declares shape {p.shape}")
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            z[:, space.slice_of(p.name)] = p.transform.forward(x)
    if not np.all(np.isfinite(z)):
        bad = int(np.sum(~np.all(np.isfinite(z), axis=1)))
        raise DataError(f"{path}: {bad} stored draws lie outside the parameters' supports")
    return z


@dataclass(frozen=True)
class SavedFit(TableRecord):
    """A posterior read back from disk: the model, its draws, the data it was fitted to.

    Attributes
    ----------
    path : Path
        The netCDF file read.
    posterior : Posterior
        Rebuilt from the file (model, likelihood, offset, fixed parameters,
        discrepancy, data).
    z : ndarray, shape (S, ndim)
        The kept draws in the posterior's unconstrained coordinates (chain-major).
    log_prob : ndarray, shape (S,)
        The log posterior density the sampler recorded for each draw.
    converged : bool
        The sampler's verdict when the fit was made.
    convergence : str
        Its report, as written.
    seed : int
    settings : dict
        The sampler settings of the fit.
    written_by : str
        The bayeshyst version that wrote the file.
    max_log_prob_error : float
        Largest ``|log p|`` difference (nats) between the rebuilt posterior and the
        recorded values over the checked draws.
    map_z : ndarray, shape (ndim,)
        The MAP the sampler started from (the nominal design's parameters).
    warnings : tuple of str
    """

    path: Path
    posterior: Posterior = field(repr=False)
    z: np.ndarray = field(repr=False)
    log_prob: np.ndarray = field(repr=False)
    converged: bool
    convergence: str
    seed: int
    settings: dict[str, Any]
    written_by: str
    max_log_prob_error: float
    map_z: np.ndarray = field(repr=False)
    warnings: tuple[str, ...] = ()

    @property
    def model(self) -> Any:
        """The fitted model (a HysteresisModel)."""
        return self.posterior.model

    @property
    def likelihood(self) -> str:
        """The likelihood's name."""
        return self.posterior.likelihood.name

    @property
    def data(self) -> Dataset:
        """The records the posterior was fitted to."""
        return self.posterior.data

    @property
    def n_draws(self) -> int:
        """Number of stored draws ``S``."""
        return int(self.z.shape[0])

    @property
    def theta(self) -> dict[str, np.ndarray]:
        """Every parameter's draws in physical units, ``name -> (S, *shape)``."""
        return self.posterior.space.unpack(self.z)

    def draws(self, n: int | None = None, *, seed: int = 0) -> np.ndarray:
        """``n`` of the stored draws ``z`` (all by default), chosen without replacement.

        Parameters
        ----------
        n : int, optional
            At most :attr:`n_draws`.
        seed : int
            Seeds the choice: same seed, same draws.

        Returns
        -------
        ndarray, shape (n, ndim)
        """
        if n is None:
            return self.z.copy()
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or not 1 <= n <= self.n_draws:
            raise ParameterError(f"n must be an integer in [1, {self.n_draws}] (the stored "
                                 f"draws), got {n!r}")
        pick = np.random.default_rng(seed).choice(self.n_draws, size=int(n), replace=False)
        return self.z[np.sort(pick)]

    def predict(self, data: Dataset | Record, *, initial: InitialCondition | str | None = None,
                n_draws: int = 400, seed: int = 0) -> PredictionResult:
        """The posterior predictive on ``data`` in free run, scored against its outputs.

        See :func:`bayeshyst.inference.predict.predict_posterior`.

        Parameters
        ----------
        data : Dataset or Record
            Records with measured outputs (any units that convert to the fit's).
        initial : InitialCondition or str, optional
            ``"relaxed"`` (default), ``"rest"``, ``"warmup:SECONDS"`` or
            ``"periodic:PERIODS"``.
        n_draws : int
            Stored draws simulated (all of them when fewer are stored).
        seed : int
            Seeds the choice of draws, the noise and the PIT.

        Returns
        -------
        PredictionResult
        """
        initial, n_draws = checked_request(initial, n_draws)
        z = self.draws(min(n_draws, self.n_draws), seed=seed)
        return predict_posterior(self.posterior, z, data, initial=initial, seed=seed,
                                 source=str(self.path), warnings=self.warnings)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no draws)."""
        labels = self.posterior.space.labels
        return {"path": str(self.path), "model": model_spec(self.model),
                "likelihood": self.likelihood, "converged": self.converged,
                "convergence": self.convergence, "n_draws": self.n_draws, "seed": self.seed,
                "written_by": self.written_by, "parameters": list(labels),
                "records": [{"name": r.name, "n": r.n, "frequency_hz": r.frequency_hz,
                             "warmup": r.warmup, "units": dict(r.units)} for r in self.data],
                "max_log_prob_error": self.max_log_prob_error,
                "warnings": list(self.warnings)}

    def to_dataframe(self) -> Any:
        """The draws in physical units, one column per scalar parameter (pandas)."""
        import pandas as pd

        space = self.posterior.space
        theta = self.theta
        columns: dict[str, np.ndarray] = {}
        for p in space.params:
            values = np.asarray(theta[p.name], dtype=float).reshape(self.n_draws, -1)
            for j, label in enumerate(p.labels()):
                columns[label] = values[:, j]
        return pd.DataFrame(columns)

    def __str__(self) -> str:
        state = "converged" if self.converged else "NOT converged"
        lines = [f"saved fit {self.path}: {model_spec(self.model)}, {self.likelihood} "
                 f"likelihood, {self.n_draws} draws ({state}; written by bayeshyst "
                 f"{self.written_by})",
                 f"  data: {self.data.name}, {len(self.data)} record(s): "
                 + ", ".join(r.name for r in self.data)]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def load_fit(path: str | Path) -> SavedFit:
    """Read a fit that ``fit``, ``diagnose``, ``compare`` or ``report`` wrote.

    Parameters
    ----------
    path : str or Path
        A posterior file (``.nc``) or a directory holding one (``posterior.nc``, else
        ``posterior_final.nc``, else ``posterior_base.nc``, else its only ``.nc``).

    Returns
    -------
    SavedFit
        With the rebuilt :class:`Posterior` and the stored draws in its coordinates.

    Raises
    ------
    DataError
        If there is no saved posterior at ``path``, several (name one), the file was
        not written by bayeshyst with fit format :data:`FIT_FORMAT`, or the rebuilt
        posterior does not give the log densities the sampler recorded (the model,
        priors or data differ from those of the fit).
    """
    path = _find_file(Path(path))
    attrs, groups = _read_groups(path)
    meta = _meta(path, attrs)
    data = _records(path, meta, groups)
    try:
        post = _posterior(path, meta, data, groups)
    except (ModelError, ParameterError) as exc:
        raise DataError(f"{path}: the fit cannot be rebuilt in this bayeshyst ({exc})") from exc
    z = _draws(path, post, groups["posterior"])
    stats = groups["sample_stats"]
    lp = np.asarray(stats["lp"].values, dtype=float).reshape(-1)
    # the rebuilt posterior must be the one sampled: recompute a few recorded densities
    check = np.unique(np.linspace(0, z.shape[0] - 1, min(N_CHECKED, z.shape[0])).astype(int))
    again = np.asarray(post.log_prob_batch(z[check]), dtype=float)
    finite = np.isfinite(lp[check]) & np.isfinite(again)
    if not np.array_equal(np.isfinite(lp[check]), np.isfinite(again)):
        raise DataError(f"{path}: the rebuilt posterior gives -inf where the sampler did not "
                        "(or the reverse); the model or its priors differ from the fit's")
    err = float(np.max(np.abs(lp[check][finite] - again[finite]), initial=0.0))
    if not err <= LOG_PROB_TOLERANCE * max(1.0, float(np.max(np.abs(lp[check][finite]),
                                                               initial=1.0))):
        raise DataError(f"{path}: the rebuilt posterior's log density differs from the "
                        f"recorded one by {err:.3g} nats; the model, its priors or the "
                        f"likelihood in this bayeshyst ({__version__}) differ from those of "
                        f"the fit (written by {meta.get('written_by')})")
    post.reset_counts()
    _log.info("%s: %s, %d draws, log densities reproduced to %.2g nats", path,
              meta["model_spec"], z.shape[0], err)
    s = stats.attrs
    try:
        settings = json.loads(s.get("settings", "{}"))
    except (TypeError, ValueError):
        settings = {}
    warnings = []
    if not int(s.get("converged", 0)):
        warnings.append("the fit did NOT converge when it was sampled: "
                        f"{s.get('convergence_reasons', '')}")
    if meta.get("metadata_not_stored"):
        warnings.append("record metadata not stored (not JSON): "
                        + ", ".join(meta["metadata_not_stored"]))
    map_z = np.asarray(s.get("map_z", ()), dtype=float).reshape(-1)
    if map_z.size != post.ndim or not np.all(np.isfinite(map_z)):
        raise DataError(f"{path}: its MAP (sample_stats attribute map_z) has {map_z.size} "
                        f"finite coordinates, the posterior {post.ndim}")
    return SavedFit(path, post, z, lp, bool(int(s.get("converged", 0))),
                    str(s.get("convergence", "")), int(s.get("seed", 0)), settings,
                    str(meta.get("written_by", "")), err, map_z, tuple(warnings))
