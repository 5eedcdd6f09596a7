"""One fit of a model comparison: a model, a subset of the data, its predictive scores.

:func:`bayeshyst.selection.compare_models` cuts a comparison into independent tasks —
(model, scope) with scope ``"joint"`` (all records), ``"frequency"`` (the records of
one excitation frequency) or ``"lofo"`` (all records but those of one frequency, scored
on the held-out one) — and runs them in parallel worker processes. This module is
what a worker runs; it returns a :class:`TaskResult` of plain arrays and numbers, so
nothing heavy crosses the process boundary.

Scores, per cycle (the cross-validation unit of :class:`~bayeshyst.inference.posterior.Posterior`):

- parametric models, ``joint``/``frequency``: PSIS-LOO and WAIC from the sampled
  posterior; cycles whose Pareto k exceeds 0.7 are **refitted exactly** (the posterior
  given all the other cycles, sampled again from the full-data MAP) up to
  ``max_refits`` of them, worst first; BIC at the MAP;
- parametric models, ``lofo``: the log posterior-predictive density of every held-out
  cycle, ``log mean_s p(y_cycle | theta_s)`` over draws of the posterior fitted
  without that frequency;
- Gaussian-process models: exact leave-one-cycle-out (``joint``/``frequency``) and the
  log predictive density of held-out cycles (``lofo``), from :mod:`bayeshyst.gp`, at
  the fitted hyperparameters or, with ``CompareSettings.gp_sampling``, mixed over
  draws of their posterior (sampled by the same sampler as the parametric models,
  ref. [64]); WAIC and BIC are not defined for them (NaN).

What a model spec builds is decided once, by :func:`build_spec`: a parametric model
(:func:`bayeshyst.models.get`) or a GP (:func:`bayeshyst.gp.gp_from_spec`); the code
then asks the built object what it is (:func:`is_parametric`), never its name.
"""

from __future__ import annotations

import hashlib
import math
import re
import time
import traceback
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.special import logsumexp

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.groups import Band, group_key, group_label
from bayeshyst.diagnostics import PARETO_K_BAD, loo, save_netcdf, to_inference_data, waic
from bayeshyst.diagnostics.moment_match import MomentMatch, moment_match_loo
from bayeshyst.errors import DataError, ModelError, ParameterError, SimulationError
from bayeshyst.gp import gp_from_spec
from bayeshyst.inference.error_spectrum import SpectrumBand, band_spectra
from bayeshyst.inference.fit import TrackingError, errors_by_frequency, tracking_errors
from bayeshyst.inference.held_out import held_out_log_predictive, held_out_start
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.posterior import Posterior, cycle_units
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get as get_model
from bayeshyst.models.base import HysteresisModel
from bayeshyst.selection.predictor import transfer_draws

if TYPE_CHECKING:
    from bayeshyst.gp.model import GPHysteresis

__all__ = [
    "CompareSettings", "LooScores", "TaskResult", "TaskSpec", "build_spec", "derived_seed",
    "fit_identity", "fit_sampler", "heldout_log_density", "is_parametric", "loo_scores",
    "run_task", "slug", "task_seed",
]

SCOPES = ("joint", "frequency", "lofo")


def slug(text: str) -> str:
    """``text`` made safe for a file name (``"mr damper/0.5A"`` -> ``"mr-damper-0.5A"``)."""
    return re.sub(r"[^A-Za-z0-9._]+", "-", text).strip("-") or "x"


@dataclass(frozen=True)
class CompareSettings:
    """Settings shared by every task of a comparison (see ``compare_models``).

    ``sampler`` holds the sampling settings of every fit (its seed and checkpoint are
    replaced per fit by :func:`fit_sampler`).

    ``gp_sampling``: sample the GP models' hyperparameters with ``sampler`` (its seed
    replaced by the task's, no checkpoint) and score them mixed over
    ``gp_n_draws`` posterior draws, as ref. [64] predicts; off, they are scored at
    the marginal-likelihood optimum. Off by default because of its cost: every
    evaluation is a Cholesky factorisation of the ``gp_n_train`` training points, and
    a task then takes minutes instead of seconds (measured: :func:`_run_gp`).
    """

    likelihood: str = "gaussian"
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    draws_per_chain: int = 30
    n_lofo_draws: int = 400
    max_refits: int = 5
    gp_n_train: int = 1000
    gp_sampling: bool = False
    gp_n_draws: int = 16

    def __post_init__(self) -> None:
        if not isinstance(self.gp_sampling, bool):
            raise ParameterError(f"gp_sampling: expected True or False, got "
                                 f"{self.gp_sampling!r}")
        if isinstance(self.gp_n_draws, bool) or not isinstance(self.gp_n_draws, int) \
                or self.gp_n_draws < 1:
            raise ParameterError(f"gp_n_draws: expected an integer >= 1, got "
                                 f"{self.gp_n_draws!r}")


def build_spec(spec: str, *, n_train: int = 1000,
               seed: int | None = None) -> HysteresisModel | GPHysteresis:
    """What a model spec builds, decided once for every caller.

    A GP spec (:func:`bayeshyst.gp.gp_from_spec`: ``"gp"``, ``"gp_memory"``) builds an
    unfitted :class:`~bayeshyst.gp.GPHysteresis` (with ``n_train`` and ``seed`` as its
    training-subset size and random state); any other spec a parametric model
    (:func:`bayeshyst.models.get`).

    Raises
    ------
    ModelError
        Naming the unknown part of a spec.
    """
    gp = gp_from_spec(spec, n_train=n_train, random_state=seed)
    return get_model(spec) if gp is None else gp


def is_parametric(model: object) -> bool:
    """Whether a built model (:func:`build_spec`) is a parametric forward model.

    A parametric forward model is one a :class:`~bayeshyst.inference.posterior.Posterior`
    samples, with parameters to diagnose and an inverse, rather than a predictor fitted
    to data (the GP, a :class:`~bayeshyst.inference.protocols.Predictor` only).
    """
    return isinstance(model, HysteresisModel)


@dataclass(frozen=True)
class TaskSpec:
    """One fit: ``model`` on ``scope`` data.

    The group fitted (``"frequency"``) or held out (``"lofo"``) is ``frequency_hz``
    for a frequency group, ``band`` for a band group (multisine or broadband records,
    :mod:`bayeshyst.data.groups`); both are None for ``"joint"`` and for the group of
    records with neither (never both set: build one for a group key with :meth:`at`).

    ``group`` distinguishes "records of the unknown group" (``frequency_hz`` and
    ``band`` None, ``group`` True) from "all records" (``group`` False).
    """

    model: str
    scope: str
    frequency_hz: float | None = None
    group: bool = False
    band: Band | None = None

    @classmethod
    def at(cls, model: str, scope: str, key: Any) -> TaskSpec:
        """The task of ``model`` on (or holding out) the group ``key`` (a GroupKey)."""
        if isinstance(key, Band):
            return cls(model, scope, None, True, key)
        return cls(model, scope, key, True)

    @property
    def group_key(self) -> Any:
        """The group fitted or held out (a frequency, a Band or None; None for joint)."""
        return self.band if self.band is not None else self.frequency_hz

    @property
    def key(self) -> str:
        """A readable, file-name-safe identifier (``bouc_wen__lofo_10Hz``, ``..._band5-150Hz``)."""
        where = "all" if not self.group else (
            "unknown" if self.group_key is None
            else group_label(self.band).replace(" ", "") if self.band is not None
            else f"{self.frequency_hz:g}Hz")
        name = slug(self.model)
        if name != self.model:  # two specs that differ only in punctuation stay apart
            name += f"-{zlib.crc32(self.model.encode()):08x}"
        return f"{name}__{self.scope}_{where}"


def derived_seed(seed: int, key: str) -> int:
    """A seed that depends only on the user's seed and a job's identity ``key``.

    Not on the order or the process the job runs in: same seed, same numbers.
    """
    ss = np.random.SeedSequence([int(seed), zlib.crc32(key.encode())])
    return int(ss.generate_state(1)[0])


def task_seed(seed: int, spec: TaskSpec) -> int:
    """The per-task seed of a comparison task (:func:`derived_seed` of its key)."""
    return derived_seed(seed, spec.key)


@dataclass(frozen=True)
class TaskResult:
    """Scores of one task, per cycle and in total.

    Attributes
    ----------
    spec : TaskSpec
    pointwise : ndarray, shape (n_units,)
        elpd of each scored cycle: LOO (``joint``/``frequency``) or held-out predictive
        (``lofo``). Empty when the task failed.
    unit_frequency : ndarray, shape (n_units,)
        Frequency of each scored cycle (NaN if unknown).
    unit_labels : tuple of str
        ``record#cycle`` of each scored cycle.
    p_loo : float
        Effective number of parameters (NaN for ``lofo`` and GP).
    pareto_k : ndarray or None
        After refits, the refitted cycles carry NaN (their value is exact).
    waic_pointwise : ndarray or None
    bic : float
        At the MAP; NaN where undefined.
    n_params : int
        Free parameters (noise and offset included); GP: hyperparameters.
    converged : bool
    n_refits : int
        Cycles refitted exactly (their Pareto k stayed above 0.7 after moment matching).
    n_moment_matched : int
        Cycles whose PSIS-LOO was settled by moment matching instead of a refit.
    overall : TrackingError or None
        Of the posterior-mean prediction of the scored records.
    per_frequency : tuple of TrackingError
    warnings : tuple of str
    runtime_s : float
    failed_simulations : int
    move_acceptance : dict of str to float
        Acceptance rate of each sampler move (empty for the GP).
    netcdf : str or None
        Path of the saved InferenceData (parametric ``joint``/``frequency`` fits when an
        output folder was given).
    error : str or None
        Why the task failed (the comparison goes on without it).
    unit_group : tuple
        Group key (:func:`~bayeshyst.data.groups.group_key`: a frequency, a Band or
        None) of each scored cycle; empty in results made before band groups existed
        (their cycles are told apart by ``unit_frequency``).
    error_spectra : tuple of (Band, tuple of SpectrumBand)
        Per band group among the scored records, the error spectrum of the
        posterior-mean prediction (:func:`~bayeshyst.inference.error_spectrum.band_spectra`).
    """

    spec: TaskSpec
    pointwise: np.ndarray
    unit_frequency: np.ndarray
    unit_labels: tuple[str, ...]
    p_loo: float = math.nan
    pareto_k: np.ndarray | None = None
    waic_pointwise: np.ndarray | None = None
    bic: float = math.nan
    n_params: int = 0
    converged: bool = False
    n_refits: int = 0
    n_moment_matched: int = 0
    overall: TrackingError | None = None
    per_frequency: tuple[TrackingError, ...] = ()
    warnings: tuple[str, ...] = ()
    runtime_s: float = 0.0
    failed_simulations: int = 0
    move_acceptance: dict[str, float] = field(default_factory=dict)
    netcdf: str | None = None
    error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    unit_group: tuple[Any, ...] = ()
    error_spectra: tuple[tuple[Band, tuple[SpectrumBand, ...]], ...] = ()

    @property
    def ok(self) -> bool:
        """True when the task produced scores."""
        return self.error is None


def split_data(data: Dataset, spec: TaskSpec) -> tuple[Dataset, Dataset]:
    """(fit data, scored data) of a task."""
    def at(rec: Any) -> bool:
        return group_key(rec) == spec.group_key

    if spec.scope == "joint":
        return data, data
    inside = tuple(r for r in data if at(r))
    outside = tuple(r for r in data if not at(r))
    if not inside or (spec.scope == "lofo" and not outside):
        raise DataError(f"task {spec.key}: no records to fit or score")
    if spec.scope == "frequency":
        sub = Dataset(inside, name=data.name)
        return sub, sub
    return Dataset(outside, name=data.name), Dataset(inside, name=data.name)


def _units_meta(data: Dataset) -> tuple[np.ndarray, tuple[str, ...], tuple[Any, ...]]:
    """Frequency (NaN if none), ``record#cycle`` label and group key of every cycle."""
    freqs, labels, groups = [], [], []
    for rec in data:
        for i, _ in enumerate(cycle_units(rec)):
            freqs.append(math.nan if rec.frequency_hz is None else float(rec.frequency_hz))
            labels.append(f"{rec.name}#{i}")
            groups.append(group_key(rec))
    return np.asarray(freqs, dtype=float), tuple(labels), tuple(groups)


def fit_identity(post: Posterior, sampler: SamplerSettings) -> str:
    """What a fit is, as 16 hex digits.

    The digits hash the model, likelihood, priors (and the coordinates that are not
    their default, :attr:`~bayeshyst.params.ParamSpace.declared_transforms`), offset, the
    discrepancy's basis (:meth:`~bayeshyst.discrepancy.Discrepancy.fingerprint`), data
    values (not file names), held-out cycles and the sampler settings but their seed.

    Two commands that fit the same posterior with the same settings (the comparison's
    joint fit and the diagnosis' base fit of a report) get the same identity, hence the
    same seed and checkpoint (:func:`fit_sampler`): the second finds the first's
    finished run and samples nothing.
    """
    h = hashlib.sha256()
    fp = {k: v for k, v in sampler.fingerprint().items() if k != "seed"}
    what = (repr(post.model), post.likelihood.name, str(post.space), post.offset,
            post.beta, post.held_out, sorted(fp.items()))
    declared = post.space.declared_transforms
    if declared:  # (only then: other fits keep their identities)
        what += (declared,)
    if post.discrepancy is not None:  # its basis: the space alone does not tell it
        what += (post.discrepancy.fingerprint(),)
    h.update(repr(what).encode())
    for rec in post.data:
        for arr in (rec.t, rec.u, rec.y):
            h.update(np.ascontiguousarray(arr).tobytes())
        h.update(str(rec.warmup).encode())
    return h.hexdigest()[:16]


def fit_sampler(post: Posterior, sampler: SamplerSettings, seed: int,
                store: Path | None) -> SamplerSettings:
    """The settings of one fit: its own seed and its checkpoint.

    The seed is derived from ``seed`` and the fit's identity; the checkpoint is
    ``store/<identity>-<seed>.h5`` (none without a store).

    With emcee's own moves a user-given walker count is raised to ``2 ndim + 2`` (they
    need at least twice the dimension; an augmented model has more parameters), here
    and so identically for every command that fits the same posterior.
    """
    if sampler.n_walkers is not None and sampler.moves != "structured":
        sampler = sampler.replace(n_walkers=max(sampler.n_walkers, 2 * post.ndim + 2))
    key = fit_identity(post, sampler)
    fit_seed = derived_seed(seed, key)
    return sampler.replace(
        seed=fit_seed,
        checkpoint=None if store is None else Path(store) / f"{key}-{fit_seed}.h5")


def _logmeanexp(ll: np.ndarray) -> np.ndarray:
    """``log mean exp`` over axis 0, ``-inf`` rows (failed draws) included as zeros."""
    return logsumexp(ll, axis=0) - math.log(ll.shape[0])


def heldout_log_density(post: Posterior, test: Dataset, z: np.ndarray
                        ) -> tuple[np.ndarray, Posterior, np.ndarray]:
    """Log posterior-predictive density of every cycle of ``test``.

    ``elpd_c = log (1/S) sum_s p(y_c | theta_s)`` with ``theta_s`` the draws ``z``
    (S, ndim) of ``post`` — the Monte Carlo estimate of ``log p(y_c | training data)``,
    each cycle's samples taken jointly (the same unit as the cycles of PSIS-LOO).

    Returns the pointwise values (n_cycles,), the test posterior (same model space and
    offset, the test records) and the draws in its coordinates.
    """
    test_post = Posterior(test, post.model, post.likelihood, space=post.model_space,
                          offset=post.offset)
    zt = transfer_draws(post, test_post, z)
    return _logmeanexp(test_post.log_likelihood_units(zt)), test_post, zt


#: Full-posterior draws the moment matching of a cycle moves (thinned over every chain)
MOMENT_MATCH_DRAWS = 1000
#: Points per batch of density evaluations (bounds the simulation's memory)
_MM_BATCH = 128


def _batched(fn: Any) -> Any:
    """``fn`` over (S, d) points, evaluated ``_MM_BATCH`` at a time."""
    def run(z: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(fn(z[a:a + _MM_BATCH]), dtype=float)
                               for a in range(0, z.shape[0], _MM_BATCH)])
    return run


def _moment_matched(post: Posterior, res: Any, bad: list[int], seed: int
                    ) -> dict[int, MomentMatch]:
    """Moment-matched LOO of each cycle in ``bad`` from the full posterior's draws.

    The target of cycle ``i`` is the posterior without it (:meth:`Posterior.holding_out`,
    so an AR(1) likelihood keeps its conditioning), its predictive the cycle's
    log-likelihood, as in an exact refit.
    """
    z = res.draws(MOMENT_MATCH_DRAWS, seed=seed)
    z = z[np.all(np.isfinite(z), axis=1)]
    if z.shape[0] < 20:
        return {}
    log_full = _batched(post.log_prob_batch)
    lf0 = log_full(z)  # shared by every cycle: the proposal's density at the draws
    out = {}
    for i in bad:
        held = post.holding_out([i])
        out[i] = moment_match_loo(
            z, log_full, _batched(held.log_prob_batch),
            _batched(lambda q, i=i: post.log_likelihood_units(q)[:, i]), log_full_z=lf0)
    return out


def _refit_log_predictive(post: Posterior, res: Any, z: np.ndarray, i: int) -> float:
    """``log p(y_i | y_-i)`` from draws ``z`` of the posterior without cycle ``i``.

    With a linear block it is integrated out exactly for each draw of the other
    coordinates (:func:`~bayeshyst.inference.held_out.held_out_log_predictive`, as
    PSIS-LOO does). The plain average of ``p(y_i | theta)`` over the refit's draws is
    dominated by the few draws nearest the left-out cycle: on the virtual actuator's
    worst 200 Hz cycle under PI (offset 4 sd away without it) it read -681.6, -679.3
    and -676.4 nat with 100, 1 000 and 10 000 draws, against -659.2 integrated.
    """
    structure = LinearStructure.of(post, reference=res.start.z)
    if structure is not None:
        ll = held_out_log_predictive(structure, z)[:, i]
    else:
        ll = post.log_likelihood_units(z)[:, i]
    return float(_logmeanexp(ll[:, None])[0])


def _refit_bad_cycles(post: Posterior, res: Any, pointwise: np.ndarray, k: np.ndarray,
                      settings: CompareSettings, seed: int, notes: list[str]
                      ) -> tuple[np.ndarray, np.ndarray, int, float, int]:
    """Leave-one-cycle-out for the cycles whose PSIS-LOO is unreliable (Pareto k > 0.7).

    The worst ``settings.max_refits`` such cycles are corrected: each is first
    moment-matched (:func:`~bayeshyst.diagnostics.moment_match.moment_match_loo`: the
    full posterior's draws moved by affine maps towards the posterior without it, a few
    batches of simulations) and refitted exactly only when its k stays above 0.7. Returns
    the pointwise elpd, the Pareto k (the moment-matched k; NaN where refitted), the
    number of refits, the change of ``p_loo`` (``lppd - elpd`` moves by the elpd
    change) and the number of cycles the moment matching settled.
    """
    bad = [int(i) for i in np.argsort(-k) if k[i] > PARETO_K_BAD]
    budget = bad[:settings.max_refits]
    pw, kk, dp = pointwise.copy(), k.copy(), 0.0
    matched = _moment_matched(post, res, budget, seed) if budget else {}
    settled = [i for i in budget if i in matched and matched[i].reliable]
    for i in settled:
        dp += pw[i] - matched[i].elpd
        pw[i], kk[i] = matched[i].elpd, matched[i].pareto_k
    todo = [i for i in budget if i not in settled]
    n_draws = max(400, settings.n_lofo_draws)
    for j, i in enumerate(todo):
        held = post.holding_out([i])
        # from the held-out posterior's own MAP: a cycle PSIS cannot handle is one that
        # moves the posterior by several sd (the noise scale, when it is the worst-fitted
        # cycle), and walkers started in the old posterior feed the warm-up's proposal
        # fit draws still in transit (PI + output map on the bundled record without a
        # 200 Hz cycle: sigma 10 sd lower; 3 000 steps unconverged from the full-data MAP
        # or ensembles, 250 from its own). That MAP is found by least squares from the
        # full-data one (searched globally already; one cycle moves the optimum locally)
        # and a small screen, without a global search (15 of the 18 s of each refit of a
        # 10 kHz PI + second-order fit); a mode the walkers find above it still restarts
        # the run
        sampler = settings.sampler.replace(seed=seed + 1 + j, checkpoint=None, progress=False)
        r = sample_posterior(held, sampler, start=held_out_start(held, res.start, sampler.seed))
        new = _refit_log_predictive(post, res, r.draws(n_draws, seed=seed), i)
        dp += pw[i] - new
        pw[i], kk[i] = new, math.nan
        if not r.converged:
            notes.append(f"the exact refit without cycle {i} did not converge")
    if settled:
        notes.append(f"{len(settled)} cycles with Pareto k > {PARETO_K_BAD} were moment-"
                     f"matched (importance-weighted moment matching, k now "
                     f"{max(matched[i].pareto_k for i in settled):.2f} or less)")
    if len(bad) > len(budget):
        notes.append(f"{len(bad) - len(budget)} more cycles have Pareto k > {PARETO_K_BAD} "
                     f"and were neither moment-matched nor refitted "
                     f"(max_refits={settings.max_refits}): their LOO values are unreliable")
    return pw, kk, len(todo), dp, len(settled)


@dataclass(frozen=True)
class LooScores:
    """Leave-one-cycle-out scores of one sampled posterior (see :func:`loo_scores`).

    ``pointwise`` (n_units,) is the PSIS-LOO elpd of each cycle, moment-matched where
    plain PSIS had Pareto k > 0.7 (``pareto_k`` then the matched k; ``n_moment_matched``
    of them), exact for the refitted ones (their ``pareto_k`` is NaN); ``p_loo``
    includes both corrections.
    """

    pointwise: np.ndarray
    pareto_k: np.ndarray
    n_refits: int
    p_loo: float
    idata: Any
    waic: Any
    n_moment_matched: int = 0


def loo_scores(post: Posterior, res: Any, settings: CompareSettings, seed: int,
               notes: list[str]) -> LooScores:
    """PSIS-LOO over cycles with exact refits of the cycles whose Pareto k is too high.

    Appends what makes the numbers less trustworthy to ``notes`` (plain words).
    """
    idata = to_inference_data(post, res, draws_per_chain=settings.draws_per_chain,
                              n_predictive=min(200, settings.n_lofo_draws), seed=seed)
    lo, wa = loo(idata), waic(idata)
    notes += [w for w in lo.warnings if "Pareto k >" not in w and w not in notes]
    pw, k, n_refits, dp, n_mm = _refit_bad_cycles(post, res, lo.pointwise, lo.pareto_k,
                                                  settings, seed, notes)
    if n_refits:
        notes.append(f"{n_refits} cycles with Pareto k > {PARETO_K_BAD} were refitted exactly")
    return LooScores(pw, k, n_refits, lo.p + dp, idata, wa, n_mm)


def _run_parametric(data: Dataset, spec: TaskSpec, settings: CompareSettings, seed: int,
                    out_dir: Path | None) -> TaskResult:
    t0 = time.perf_counter()
    train, test = split_data(data, spec)
    post = Posterior(train, spec.model, settings.likelihood)
    sampler = fit_sampler(post, settings.sampler, seed,
                          None if out_dir is None else out_dir / "checkpoints")
    res = sample_posterior(post, sampler)
    seed = sampler.seed
    notes = [] if res.converged else ["the sampler did not converge within its budget"]
    freqs, labels, groups = _units_meta(test)
    failed = res.counts.failed
    if spec.scope == "lofo":
        pw, test_post, zt = heldout_log_density(post, test,
                                                res.draws(settings.n_lofo_draws, seed=seed))
        failed += test_post.counts.failed
        overall, per, means = tracking_errors(test_post, zt)
        return TaskResult(spec, pw, freqs, labels, n_params=post.ndim,
                          converged=res.converged, overall=overall, per_frequency=tuple(per),
                          warnings=tuple(notes), runtime_s=time.perf_counter() - t0,
                          failed_simulations=failed,
                          move_acceptance=dict(res.move_acceptance), unit_group=groups,
                          error_spectra=band_spectra(test, means))
    scores = loo_scores(post, res, settings, seed, notes)
    idata, wa, pw, k, n_refits = (scores.idata, scores.waic, scores.pointwise,
                                  scores.pareto_k, scores.n_refits)
    ll_map = float(np.sum(post.log_likelihood_units(res.start.z[None, :])))
    n_obs = sum(r.n_scored for r in train)
    bic = post.ndim * math.log(n_obs) - 2.0 * ll_map
    overall, per, means = tracking_errors(post, res.draws(settings.n_lofo_draws, seed=seed))
    path = None
    if out_dir is not None:
        path = str(save_netcdf(idata, out_dir / "posteriors" / f"{spec.key}.nc"))
    return TaskResult(spec, pw, freqs, labels, p_loo=scores.p_loo, pareto_k=k,
                      waic_pointwise=wa.pointwise, bic=bic, n_params=post.ndim,
                      converged=res.converged, n_refits=n_refits,
                      n_moment_matched=scores.n_moment_matched, overall=overall,
                      per_frequency=tuple(per), warnings=tuple(notes),
                      runtime_s=time.perf_counter() - t0, failed_simulations=failed,
                      move_acceptance=dict(res.move_acceptance), netcdf=path,
                      unit_group=groups, error_spectra=band_spectra(test, means))


def _run_gp(gp: GPHysteresis, data: Dataset, spec: TaskSpec, settings: CompareSettings,
            seed: int) -> TaskResult:
    """Fit the GP ``gp`` (unfitted, from :func:`build_spec`) to the task's data and score it.

    With ``settings.gp_sampling`` its hyperparameters are sampled first (sampler
    ``settings.sampler`` with the task's ``seed``), so the scores mix over their
    posterior.

    Measured on the five records of ``data/virtual_multifreq.csv`` (joint task,
    ``gp_n_train`` 300, default sampler settings, 2 cores shared with other jobs):
    ``gp`` fits in 2.5 s and its 16-draw LOO takes 1.9 s; its sampling converged in
    500 steps (2 ensembles x 24 walkers, 12 144 evaluations) in 58 s. ``gp_memory``
    fits in 5.5 s; 600 steps (2 x 40 walkers) took 161 s and had not converged (R-hat
    1.05, tau 15 steps: the length-scales of the direction and of ``u_r1`` are
    resolved only jointly, sd 2.6 in log). Each evaluation is a Cholesky factorisation
    of the training subset: about 4 ms at 300 points, 43 ms at the default 1000.
    """
    # scikit-learn is imported only when a GP runs
    from sklearn.exceptions import ConvergenceWarning

    from bayeshyst.gp import FREE_RUN_TOLERANCE

    t0 = time.perf_counter()
    train, test = split_data(data, spec)
    gp.fit_records(train)
    notes = [] if gp.converged_ else [
        f"the GP's free run does not reproduce its training records (RMSE "
        f"{gp.free_run_ratio_:.3g} times the one-step RMSE); the fit did not converge"
        if gp.free_run_ratio_ > FREE_RUN_TOLERANCE
        else "the GP hyperparameter optimisation did not converge"]
    moves: dict[str, float] = {}
    if settings.gp_sampling:
        with warnings.catch_warnings():
            # said in the task's notes instead (a worker's warnings reach no one)
            warnings.simplefilter("ignore", ConvergenceWarning)
            report = gp.sample_hyperparameters(
                settings.sampler.replace(seed=seed, checkpoint=None, progress=False),
                n_draws=settings.gp_n_draws)
        moves = dict(report.sampling.move_acceptance)
        if not report.converged:
            notes.append("the GP hyperparameter sampler did not converge within its budget")
        if gp.hyperparameter_free_run_ratio_ > FREE_RUN_TOLERANCE:
            notes.append(f"the free run of a sampled GP hyperparameter draw does not "
                         f"reproduce the training records (RMSE "
                         f"{gp.hyperparameter_free_run_ratio_:.3g} times the one-step RMSE)")
    scores = gp.log_density_units(test) if spec.scope == "lofo" else gp.loo_units(test)
    freqs, labels, groups = _units_meta(test)
    preds = [p.mean for p in gp.predict_records(test)]
    overall, per = errors_by_frequency(test, preds)
    return TaskResult(spec, np.asarray(scores.values, dtype=float), freqs, labels,
                      n_params=int(gp.n_hyperparameters_), converged=bool(gp.converged_),
                      overall=overall, per_frequency=tuple(per), warnings=tuple(notes),
                      runtime_s=time.perf_counter() - t0, move_acceptance=moves,
                      unit_group=groups, error_spectra=band_spectra(test, preds))


def run_task(data: Dataset, spec: TaskSpec, settings: CompareSettings, seed: int,
             out_dir: str | Path | None = None) -> TaskResult:
    """Run one comparison task; a failure is returned as a result with ``error`` set.

    Parameters
    ----------
    data : Dataset
        All records of the comparison (the task selects its own).
    spec : TaskSpec
    settings : CompareSettings
    seed : int
        The comparison's seed; the task derives its own with :func:`task_seed`.
    out_dir : path, optional
        Where posteriors (``posteriors/<key>.nc``) and sampler checkpoints
        (``checkpoints/<identity>.h5``, :func:`fit_identity`: a re-run with the same
        data and settings resumes, and another command fitting the same posterior
        with the same checkpoint folder reuses it) go.
    """
    out = None if out_dir is None else Path(out_dir)
    t0 = time.perf_counter()
    try:
        own_seed = task_seed(seed, spec)
        model = build_spec(spec.model, n_train=settings.gp_n_train, seed=own_seed)
        if is_parametric(model):
            # a parametric fit's seed follows from what it fits (fit_sampler), so the
            # same posterior fitted by another command reuses this one
            return _run_parametric(data, spec, settings, seed, out)
        return _run_gp(model, data, spec, settings, own_seed)
    except (DataError, ModelError, ParameterError, SimulationError, FloatingPointError,
            np.linalg.LinAlgError, ValueError) as exc:
        freqs = np.zeros(0)
        detail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return TaskResult(spec, np.zeros(0), freqs, (), runtime_s=time.perf_counter() - t0,
                          error=f"{spec.model} ({spec.scope}) failed: {detail}")
