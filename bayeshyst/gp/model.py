"""The GP hysteresis estimator, :class:`GPHysteresis` (overview: :mod:`bayeshyst.gp`).

A scikit-learn regressor from the input voltage of a record to its displacement,
simulated in free run. This module holds the estimator's fit (standardisation, training
subset, the marginal-likelihood optima tried until one's free run reproduces the
training records), its prediction (the free run, mixed over hyperparameter draws after
:meth:`GPHysteresis.sample_hyperparameters`), the sampling of the hyperparameters
through :func:`~bayeshyst.inference.sampling.sample_posterior`, and
:func:`fit_gp_inverse`. The per-cycle log densities are in
:mod:`bayeshyst.gp.scoring`, the features in :mod:`bayeshyst.gp.features`, the kernel
in :mod:`bayeshyst.gp.kernel`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.utils import check_random_state
from sklearn.utils.validation import check_is_fitted

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.data.segment import default_prominence
from bayeshyst.errors import ParameterError
from bayeshyst.gp.features import (
    RATE_SCHEMES,
    SignalRecord,
    as_records,
    farthest_subset,
    gather_memory,
    memory_indices,
    rate,
    split_columns,
    stratified_subset,
)
from bayeshyst.gp.hyperparameters import HyperparameterReport, HyperparameterTarget
from bayeshyst.gp.kernel import (
    Conditioned,
    blas_limit,
    make_kernel,
    maximise_marginal_likelihood,
    small_blas,
)
from bayeshyst.gp.prediction import FreeRun
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings

__all__ = ["FREE_RUN_TOLERANCE", "GPHysteresis", "fit_gp_inverse"]

#: Largest accepted ratio of the free-run RMSE to the teacher-forced (one-step) RMSE
#: on the training records (``GPHysteresis.free_run_ratio_``). Measured on the bundled
#: ``virtual_multifreq`` records with the memory variant: one frequency per fit (1-200
#: Hz, 20 random states each) 0.9-3.9 at every optimum whose free run is sound (NRMSE
#: 0.09-0.22 %) and 310-610 at the ones whose free run collapses (NRMSE 25-50 %);
#: several frequencies per fit (all five, or four of them; 26 fits) 4.4-15, a graded
#: loss (training NRMSE 0.5-2.7 %) that this check is not meant to catch. 50 leaves a
#: factor of 3 above the one and of 6 below the other.
FREE_RUN_TOLERANCE = 50.0

#: RMSE floor of that ratio [standardised target units]: errors below 0.1 % of the
#: target's standard deviation count as equal (noise-free data).
_RMSE_FLOOR = 1e-3


class GPHysteresis(FreeRun, RegressorMixin, BaseEstimator):
    """GP hysteresis model with free-run prediction and per-cycle log-densities.

    Parameters
    ----------
    features : {"rate", "memory", "static"}, default "rate"
        ``"rate"``: ``(u, du/dt)`` (Tao et al. [64]). ``"memory"``: ``(u, du/dt, d, u_r1,
        y_r1, u_r2, y_r2)``, target ``y - y_r1``. ``"static"``: ``"memory"`` without
        ``du/dt`` (rate-independent). See :mod:`bayeshyst.gp`.
    n_train : int, default 1000
        Training-subset size ``m`` (all candidates when there are fewer). Cost: fit
        ``O(m^3)`` per likelihood evaluation, prediction ``O(N m)`` for the mean and
        ``O(N m^2)`` for the standard deviation.
    subset : {"farthest", "stratified"}, default "farthest"
        Subset scheme (:mod:`bayeshyst.gp`).
    kernel : {"rbf", "matern52"}, default "rbf"
        ARD correlation function, times a constant, plus white noise.
    length_scale : float or array_like of shape (d,), default 1.0
        Initial length-scales in standardised feature units.
    signal_variance : float, default 1.0
        Initial amplitude of the constant kernel (standardised target units).
    noise_level : float, default 1e-2
        Initial white-noise variance (standardised target units).
    optimizer : {"fmin_l_bfgs_b", None}, default "fmin_l_bfgs_b"
        ``None`` keeps the initial hyperparameters.
    n_restarts_optimizer : int, default 2
        Extra optimisations from log-uniform random starts within
        :data:`~bayeshyst.gp.kernel.BOUNDS`. The optima are tried from the highest
        marginal likelihood down; the first whose free run reproduces the training
        records is kept (:mod:`bayeshyst.gp`).
    reversal_threshold : float, optional
        Zig-zag threshold of the memory features [input unit]. Default
        :func:`~bayeshyst.data.segment.default_prominence` of the training inputs.
    inverse : bool, default False
        Record methods use ``y`` as input and ``u`` as target (the inverse model, for
        feedforward); the array methods are unaffected.
    random_state : int, RandomState instance or None
        Subset draws and optimiser restarts.
    rate : {"central", "backward"}, default "central"
        Difference scheme of ``du/dt`` (:func:`~bayeshyst.gp.features.rate`):
        ``"backward"`` is causal, what a controller computes in real time.

    Attributes
    ----------
    gp_ : sklearn.gaussian_process.GaussianProcessRegressor
        Fitted on the standardised subset, kernel fixed at the optimum.
    kernel_ : sklearn kernel
    log_marginal_likelihood_ : float
    noise_std_ : float
        Noise standard deviation [target unit].
    n_hyperparameters_ : int
    converged_ : bool
        The optimiser run whose optimum was kept converged, its free run reproduces the
        training records (``free_run_ratio_ <= FREE_RUN_TOLERANCE``) and, after
        sampling, the chains converged.
    free_run_ratio_ : float
        Free-run RMSE over the training candidates divided by the teacher-forced
        (one-step) RMSE over the same samples, at the kept hyperparameters.
    rejected_optima_ : tuple of (float, ndarray of shape (p,))
        Log marginal likelihood and log hyperparameters (``kernel_.theta`` order) of
        each optimum rejected because its free run failed that check, highest first
        (empty when the highest optimum passed; the kept one when none passed).
    n_features_in_ : int
        Columns of ``X`` (2 or 3).
    train_index_ : ndarray of int, shape (m,)
        Rows of the training input (``X``, or
        :func:`~bayeshyst.gp.features.records_to_X` of the data) used.
    reversal_threshold_ : float
    feature_mean_, feature_scale_ : ndarray, shape (d,)
    target_mean_, target_scale_ : float
    anchor_output_ : float
        Output feature of each record's first sample (its output is unknown in a free
        run): the mean measured output of the candidates.
    at_bounds_ : tuple of str
        Hyperparameters within 1 % (in log) of a bound.
    hyperparameter_samples_ : ndarray, shape (M, p)
        Every kept draw of the log hyperparameters (``kernel_.theta`` order), set by
        :meth:`sample_hyperparameters`.
    hyperparameter_draws_ : ndarray, shape (n_draws, p)
        The draws predictions mix over (set by :meth:`sample_hyperparameters`).
    hyperparameter_report_ : HyperparameterReport
        Set by :meth:`sample_hyperparameters`.
    """

    def __init__(self, features: str = "rate", n_train: int = 1000, subset: str = "farthest",
                 kernel: str = "rbf", length_scale: float | Sequence[float] = 1.0,
                 signal_variance: float = 1.0, noise_level: float = 1e-2,
                 optimizer: str | None = "fmin_l_bfgs_b", n_restarts_optimizer: int = 2,
                 reversal_threshold: float | None = None, inverse: bool = False,
                 random_state: int | np.random.RandomState | None = None,
                 rate: str = "central") -> None:
        self.features = features
        self.n_train = n_train
        self.subset = subset
        self.kernel = kernel
        self.length_scale = length_scale
        self.signal_variance = signal_variance
        self.noise_level = noise_level
        self.optimizer = optimizer
        self.n_restarts_optimizer = n_restarts_optimizer
        self.reversal_threshold = reversal_threshold
        self.inverse = inverse
        self.random_state = random_state
        self.rate = rate

    # ------------------------------------------------------------------ inputs
    @property
    def _in(self) -> str:
        return "y" if self.inverse else "u"

    def _split_X(self, X: np.ndarray, y: np.ndarray | None) -> list[SignalRecord]:
        return [SignalRecord(t, s, target, np.ones(t.size, dtype=bool))
                for t, s, target in split_columns(X, y, self._in)]

    def _from_records(self, data: Dataset | Record, targets: bool = True) -> list[SignalRecord]:
        # warm-up samples are candidates for the memory variants: their anchor features
        # tell the first branch apart, and a free run must start on it; for the rate
        # variant that branch contradicts the loop at the same (u, du/dt), so no
        return [SignalRecord(r.t, r.y if self.inverse else r.u,
                     (r.u if self.inverse else r.y) if targets else None,
                     r.scored_mask if self.features == "rate" else np.ones(r.n, dtype=bool), r)
                for r in as_records(data)]

    def _check_params(self) -> None:
        choices = {"features": ("rate", "memory", "static"), "subset": ("stratified", "farthest"),
                   "kernel": ("rbf", "matern52"), "optimizer": ("fmin_l_bfgs_b", None),
                   "rate": RATE_SCHEMES}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ParameterError(f"{name}: expected one of {allowed}, found "
                                     f"{getattr(self, name)!r}")
        for name, low in (("n_train", 1), ("n_restarts_optimizer", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < low:
                raise ParameterError(f"{name}: expected an integer >= {low}, found {v!r}")
        for name, low in (("signal_variance", 0), ("noise_level", 0), ("reversal_threshold", -1)):
            v = getattr(self, name)
            if not ((v is None and low < 0) or (isinstance(v, int | float) and np.isfinite(v)
                                                and v > low and v >= 0)):
                raise ParameterError(f"{name}: expected a {'positive' if low == 0 else '>= 0'} "
                                     f"finite number{'' if low == 0 else ' or None'}, found {v!r}")

    # ------------------------------------------------------------------ features
    def _layout(self, rec: SignalRecord) -> dict:
        """Everything about a record's features that depends on its input alone."""
        cols = [rec.s] if self.features == "static" else [rec.s, rate(rec.t, rec.s, self.rate)]
        lay = {"base": np.column_stack(cols), "n": rec.s.size}
        if self.features != "rate":
            d, r1, r2 = memory_indices(rec.s, self.reversal_threshold_)
            refs = np.unique(np.concatenate([r1, r2]))
            lay.update(d=d, r1=r1, r2=r2, refs=refs[refs > 0])
        return lay

    def _features(self, lay: dict, s: np.ndarray, y_ref: np.ndarray | None,
                  rows: np.ndarray | slice = slice(None),
                  raw: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Features of ``rows`` and the output offset of the target.

        The features are standardised unless ``raw``; the offset is ``y_r1`` for the
        memory variants, else 0. ``y_ref[0]`` must hold the anchor value.
        """
        base = lay["base"][rows]
        if self.features == "rate":
            f, off = base, np.zeros(base.shape[0])
        else:
            mem = gather_memory(s, y_ref, lay["d"][rows], lay["r1"][rows], lay["r2"][rows])
            f, off = np.column_stack([base, mem]), mem[:, 2]
        return (f if raw else (f - self.feature_mean_) / self.feature_scale_), off

    # ------------------------------------------------------------------ fitting
    def fit(self, X: np.ndarray, y: np.ndarray) -> GPHysteresis:
        """Fit on arrays; every sample is a training candidate.

        Parameters
        ----------
        X : ndarray, shape (N, 2) or (N, 3)
            Columns ``t`` [s] (strictly increasing within a record) and the input
            (``u`` [V]) of one record, or a third column with an integer record id
            (each record one contiguous block; features never reach across records).
        y : ndarray, shape (N,)
            The output (displacement [um]).

        Returns
        -------
        GPHysteresis
            ``self``.

        Raises
        ------
        DataError
            Malformed ``X`` or ``y`` (the message names the column and the row).
        ParameterError
            Invalid settings.
        """
        return self._fit(self._split_X(X, y), np.asarray(X).shape[1])

    def fit_records(self, data: Dataset | Record) -> GPHysteresis:
        """Fit on records (``y`` as input and ``u`` as target if ``inverse``).

        Candidates for the training subset: the scored samples for the rate variant
        (the first branch of a record, from its unknown initial state, contradicts the
        loop at the same ``(u, du/dt)``); every sample for the memory variants, whose
        anchor features tell that first branch apart and whose free run must start on
        it. ``train_index_`` counts rows of :func:`records_to_X` of ``data``.

        Parameters
        ----------
        data : Dataset or Record

        Returns
        -------
        GPHysteresis
            ``self``.
        """
        return self._fit(self._from_records(data), 3)

    def _fit(self, recs: list[SignalRecord], n_columns: int) -> GPHysteresis:
        self._check_params()
        rs = check_random_state(self.random_state)
        subset_rng = np.random.default_rng(rs.randint(2**31 - 1))
        restart_rng = np.random.default_rng(rs.randint(2**31 - 1))
        self.reversal_threshold_ = float(
            default_prominence(np.concatenate([r.s for r in recs]))
            if self.reversal_threshold is None else self.reversal_threshold)
        cand = np.concatenate([r.candidate for r in recs])
        self.anchor_output_ = float(np.mean(np.concatenate([r.target for r in recs])[cand]))
        lays = [self._layout(r) for r in recs]
        raw, off = zip(*(self._features(lay, r.s, np.r_[self.anchor_output_, r.target[1:]],
                                        raw=True) for lay, r in zip(lays, recs, strict=True)),
                       strict=True)
        raw = np.vstack(raw)[cand]
        tgt = (np.concatenate([r.target for r in recs]) - np.concatenate(off))[cand]
        self.feature_mean_ = raw.mean(axis=0)
        scale = raw.std(axis=0)
        self.feature_scale_ = np.where(scale > 0, scale, 1.0)
        self.target_mean_ = float(tgt.mean())
        self.target_scale_ = float(tgt.std()) if tgt.std() > 0 else 1.0
        z = (raw - self.feature_mean_) / self.feature_scale_
        zt = (tgt - self.target_mean_) / self.target_scale_
        if self.subset == "stratified":
            pick = stratified_subset(z.shape[0], int(self.n_train), subset_rng)
        else:
            pick = farthest_subset(z, int(self.n_train), subset_rng)
        rows = np.flatnonzero(cand)[pick]
        self.train_index_ = rows
        # per training point: record, sample, and the latest measured output its
        # features read (for the leave-one-cycle-out bookkeeping)
        starts = np.cumsum([0] + [r.s.size for r in recs])
        rec_of = np.searchsorted(starts, rows, side="right") - 1
        refs = np.zeros((rows.size, 2), dtype=np.int64)
        if self.features != "rate":
            refs = np.column_stack([np.concatenate([lay[r] for lay in lays])[rows]
                                    for r in ("r1", "r2")])
        self._train = {"rec": rec_of, "pos": rows - starts[rec_of], "z": z[pick],
                       "y": zt[pick], "refs": refs}
        self._fit_data = recs
        # every candidate's teacher-forced features: the free-run check of sampled draws
        self._candidates = (z, zt)
        self.n_features_in_ = int(n_columns)
        with blas_limit(pick.size):
            self._fit_hyperparameters(z[pick], zt[pick], restart_rng, recs, lays, z, zt)
        for attr in ("hyperparameter_samples_", "hyperparameter_draws_",
                     "hyperparameter_report_"):
            self.__dict__.pop(attr, None)
        return self

    def _fit_hyperparameters(self, z: np.ndarray, y: np.ndarray, rng: np.random.Generator,
                             recs: list[SignalRecord], lays: list[dict], z_all: np.ndarray,
                             y_all: np.ndarray) -> None:
        """ML-II hyperparameters whose free run reproduces the training records.

        ``z``, ``y``: the training subset; ``z_all``, ``y_all``: every candidate
        (teacher-forced features, standardised), for :meth:`_free_run_ratio`. The
        optima of all starts are tried from the highest log marginal likelihood down;
        the first with a free-run ratio of at most :data:`FREE_RUN_TOLERANCE` is kept.
        If none passes, the one with the smallest ratio is kept, ``converged_`` is
        False and a ``ConvergenceWarning`` says why.
        """
        kernel = make_kernel(self.kernel, z.shape[1], self.length_scale, self.signal_variance,
                             self.noise_level)
        theta0, bounds = kernel.theta, kernel.bounds
        if self.optimizer is None:
            optima = [(theta0, np.nan, True)]
        else:
            starts = [theta0] + [rng.uniform(bounds[:, 0], bounds[:, 1])
                                 for _ in range(int(self.n_restarts_optimizer))]
            optima = maximise_marginal_likelihood(starts, bounds, self.kernel, z, y)
        tried: list[tuple[np.ndarray, float, bool, float]] = []
        for theta, lml, success in optima:
            same = [t for t in tried if np.allclose(t[0], theta, rtol=0.0, atol=1e-6)]
            ratio = same[0][3] if same else self._free_run_ratio(
                Conditioned(theta, self.kernel, z, y), recs, lays, z_all, y_all)
            tried.append((theta, lml, success, ratio))
            if ratio <= FREE_RUN_TOLERANCE:
                break
        passed = tried[-1][3] <= FREE_RUN_TOLERANCE
        theta, _, success, ratio = tried[-1] if passed else min(tried, key=lambda t: t[3])
        self.free_run_ratio_ = float(ratio)
        self.rejected_optima_ = tuple((float(t[1]), t[0].copy()) for t in tried
                                      if not t[3] <= FREE_RUN_TOLERANCE)
        self.converged_ = bool(success and passed)
        if not passed:
            where = ("at the initial hyperparameters" if self.optimizer is None else
                     f"at any of the {len(optima)} optima of the marginal likelihood")
            warnings.warn(
                f"GP fit: the free run does not reproduce the training records {where} "
                f"(free-run RMSE {ratio:.3g} times the teacher-forced one, tolerance "
                f"{FREE_RUN_TOLERANCE:g}); the fit is marked not converged (converged_ "
                f"False). Try more restarts (n_restarts_optimizer), another random_state, or "
                f"training data with more varied reversals.", ConvergenceWarning, stacklevel=4)
        kernel = kernel.clone_with_theta(theta)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # bounds: see at_bounds_
            self.gp_ = GaussianProcessRegressor(kernel, alpha=0.0, optimizer=None,
                                                normalize_y=False).fit(z, y)
        self.kernel_ = self.gp_.kernel_
        self.log_marginal_likelihood_ = float(self.gp_.log_marginal_likelihood_value_)
        self.n_hyperparameters_ = int(self.kernel_.theta.size)
        self.noise_std_ = float(np.sqrt(self.kernel_.k2.noise_level) * self.target_scale_)
        names = self._theta_names()
        log_b = self.kernel_.bounds
        near = (np.abs(self.kernel_.theta[:, None] - log_b) < 0.01 * np.abs(np.diff(log_b))).any(1)
        self.at_bounds_ = tuple(n for n, flag in zip(names, near, strict=True) if flag)

    def _free_run_ratio(self, state: Conditioned, recs: list[SignalRecord], lays: list[dict],
                        z_all: np.ndarray, y_all: np.ndarray) -> float:
        """Free-run RMSE over the training candidates divided by the teacher-forced RMSE.

        The teacher-forced RMSE is over the same samples; both are floored at
        :data:`_RMSE_FLOOR` standardised units.

        The marginal likelihood is that of the teacher-forced regression: it never
        sees the model's own outputs fed back at the reversals, so a maximum can be an
        unstable recurrence (see the module docstring). Mean only, ``O(N m d)``.
        """
        one_step = float(np.sqrt(np.mean((y_all - state.predict(z_all, var=False)[0]) ** 2)))
        res = [((rec.target - self._free_run(state, lay, rec.s, var=False)[0])
                / self.target_scale_)[rec.candidate] for rec, lay in zip(recs, lays, strict=True)]
        free = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
        if not np.isfinite(free):
            return np.inf
        return max(free, _RMSE_FLOOR) / max(one_step, _RMSE_FLOOR)

    def _theta_names(self) -> tuple[str, ...]:
        names = []
        for hp in self.kernel_.hyperparameters:
            names += [hp.name] if hp.n_elements == 1 else [f"{hp.name}[{i}]"
                                                          for i in range(hp.n_elements)]
        return tuple(names)

    # ------------------------------------------------------------------ hyperparameters
    @small_blas
    def sample_hyperparameters(self, settings: SamplerSettings | None = None, *,
                               n_draws: int = 16) -> HyperparameterReport:
        """Sample the log hyperparameters; later predictions and scores mix the draws.

        Target (:class:`~bayeshyst.gp.hyperparameters.HyperparameterTarget`): the
        training subset's log marginal likelihood (the value of
        ``gp_.log_marginal_likelihood(theta)``, computed by the faster
        :func:`~bayeshyst.gp.kernel.log_marginal_likelihood`) plus a uniform prior on
        ``theta = log(hyperparameters)`` inside :data:`~bayeshyst.gp.kernel.BOUNDS`.
        Why this prior: with standardised inputs and targets the box spans every
        plausible value by orders of magnitude, it is proper and scale-invariant
        (uniform in log), and it is not centred on the ML values, so the data are not
        used twice; a length-scale whose feature is irrelevant has a flat likelihood up
        to the bound, and the posterior honestly reports that.

        Sampled by :func:`~bayeshyst.inference.sampling.sample_posterior`, the sampler of
        every model: ``settings.n_ensembles`` (>= 2) independent ensembles started from
        the kept optimum (:meth:`HyperparameterTarget.start_at`), run until the shared
        criteria hold (R-hat, bulk and tail ESS, autocorrelation times) or the step
        budget is spent. ``n_draws`` draws (:meth:`SamplingResult.draws`, a
        deterministic thinning seeded by ``settings.seed``) are stored in
        ``hyperparameter_draws_``; each later prediction costs ``n_draws`` Cholesky
        factorisations and free runs. The free run of every stored draw must reproduce
        the training records as at the fit (``free_run_ratio_`` check); otherwise a
        ``ConvergenceWarning`` says so and ``converged_`` is False.

        Parameters
        ----------
        settings : SamplerSettings, optional
            Moves, walkers, ensembles, budget, criteria and seed (default
            ``SamplerSettings()``); ``checkpoint`` must be None.
        n_draws : int, default 16
            Draws kept for prediction (all kept draws when there are fewer).

        Returns
        -------
        HyperparameterReport
            The shared :class:`~bayeshyst.inference.sampling_result.SamplingResult`
            (``.sampling``) seen per hyperparameter; also ``hyperparameter_report_``.
            ``converged_`` is updated.

        Raises
        ------
        ParameterError
            For a checkpoint, a bad ``n_draws`` or sampler settings the sampler refuses.
        """
        check_is_fitted(self, "gp_")
        settings = SamplerSettings() if settings is None else settings
        if not isinstance(settings, SamplerSettings):
            raise ParameterError(f"settings: expected a SamplerSettings, found "
                                 f"{type(settings).__name__}")
        if settings.checkpoint is not None:
            raise ParameterError("settings.checkpoint: GP hyperparameter runs are not "
                                 "checkpointed (the sampler fingerprints records, the GP "
                                 "samples a training subset); pass checkpoint=None")
        if isinstance(n_draws, bool) or not isinstance(n_draws, int | np.integer) or n_draws < 1:
            raise ParameterError(f"n_draws: expected an integer >= 1, found {n_draws!r}")
        target = HyperparameterTarget(self.kernel, self.gp_.X_train_, self.gp_.y_train_,
                                      name=f"gp({self.features})")
        result = sample_posterior(target, settings, start=target.start_at(self.kernel_.theta))
        report = HyperparameterReport(result, self._theta_names(), target, int(n_draws))
        draws = target.theta(result.draws(int(n_draws), seed=settings.seed))
        self.hyperparameter_samples_ = report.samples
        self.hyperparameter_draws_ = draws
        self.hyperparameter_report_ = report
        ratio = max(self._free_run_ratio(Conditioned(th, self.kernel, self.gp_.X_train_,
                                                     self.gp_.y_train_),
                                         self._fit_data, [self._layout(r) for r in
                                                          self._fit_data], *self._candidates)
                    for th in draws)
        self.hyperparameter_free_run_ratio_ = float(ratio)
        if ratio > FREE_RUN_TOLERANCE:
            warnings.warn(
                f"GP hyperparameters: the free run of a sampled draw does not reproduce the "
                f"training records (free-run RMSE {ratio:.3g} times the teacher-forced one, "
                f"tolerance {FREE_RUN_TOLERANCE:g}): the posterior reaches an unstable "
                f"recurrence; the fit is marked not converged", ConvergenceWarning,
                stacklevel=3)
        self.converged_ = bool(self.converged_ and report.converged
                               and ratio <= FREE_RUN_TOLERANCE)
        return report


def fit_gp_inverse(data: Dataset | Record, **settings: object) -> GPHysteresis:
    """Fit the inverse model: a GP from the output (and its rate and memory) to the input.

    The same estimator with input and output swapped (``inverse=True``): its
    ``predict`` on ``X`` with columns ``t`` [s] and the desired output ``y_d`` gives the
    command ``u`` [V] (feedforward compensation).

    Parameters
    ----------
    data : Dataset or Record
        Measured records.
    **settings
        :class:`GPHysteresis` parameters (every name checked; ``inverse`` is implied).

    Returns
    -------
    GPHysteresis
        Fitted, ``inverse=True``.

    Raises
    ------
    ParameterError
        For ``inverse`` or a name that is not a :class:`GPHysteresis` parameter.
    """
    if "inverse" in settings:
        raise ParameterError("fit_gp_inverse: 'inverse' is implied; do not pass it")
    known = set(GPHysteresis._get_param_names()) - {"inverse"}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ParameterError(f"fit_gp_inverse: unknown GPHysteresis parameter(s) {unknown}; "
                             f"parameters: {sorted(known)}")
    return GPHysteresis(inverse=True, **settings).fit_records(data)
