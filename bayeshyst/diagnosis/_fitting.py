"""One fit of the diagnosis loop, warm-started from the fit it augments.

:func:`diagnosis_fit` samples a model's posterior (from the previous fit's final
ensembles when it is a candidate), samples it again with twice the steps when it did
not converge (``DiagnosisSettings.budget_doublings``; not when the resonance it adds is
unresolved in every ensemble), scores its held-out cycles and analyses its residual.
:mod:`bayeshyst.diagnosis.loop` decides what to fit; this module only fits.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.diagnosis.candidates import added_names, unresolved_added
from bayeshyst.diagnosis.records import DiagnosisFit, DiagnosisSettings
from bayeshyst.diagnosis.residual import analyse_residual, best_point
from bayeshyst.discrepancy import Discrepancy
from bayeshyst.inference.calibration import uncertainty_budget
from bayeshyst.inference.discrepancy_fit import attach_discrepancy
from bayeshyst.inference.fit import FitResult, errors_by_frequency
from bayeshyst.inference.optimize import MAPResult, find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.base import HysteresisModel
from bayeshyst.selection.tasks import CompareSettings, fit_sampler, loo_scores
from bayeshyst.threads import with_single_threaded_blas

__all__ = ["Prepared", "diagnosis_fit", "prepare_fit"]


def _carried(post: Posterior, previous: DiagnosisFit, added: dict[str, Any],
             z_old: np.ndarray, seed: int) -> np.ndarray:
    """Points of the augmented posterior made from the previous fit's points ``z_old``.

    ``z_old`` is (M, ndim_old): its names are carried into the composite's ``static.``
    namespace, the added parameters set at the test's estimate (where their prior allows
    it), anything else taken from prior draws. Points that cannot be written in the new
    space are left out.
    """
    old = previous.posterior.space.unpack(np.atleast_2d(z_old))
    space = post.space
    fill = space.unpack(space.sample_prior(np.random.default_rng(seed), z_old.shape[0]))
    out = []
    for i in range(z_old.shape[0]):
        theta = {n: np.asarray(fill[n])[i] for n in space.names}
        for name in space.names:
            for src in (name, name.removeprefix("static.")):
                if src in old and np.shape(old[src])[1:] == np.shape(theta[name]):
                    theta[name] = np.asarray(old[src])[i]
                    break
            if name in added:
                value = np.asarray(added[name], dtype=float)
                lo, hi = space[name].prior.support
                # an estimate outside the prior (a delay longer than the block's room)
                # keeps the prior draw: the start must be a point the posterior can hold
                inside = bool(np.all((value > lo) & (value < hi)))
                if inside and (value.ndim == 0 or value.shape == np.shape(theta[name])):
                    # a scalar fills a vector parameter (the discrepancy's coefficients)
                    theta[name] = np.broadcast_to(value, np.shape(theta[name])).copy()
        try:
            out.append(space.pack(theta))
        except (ValueError, FloatingPointError):
            continue
    return np.array(out).reshape(-1, space.ndim)


def _warm_point(post: Posterior, previous: DiagnosisFit, added: dict[str, Any],
                seed: int) -> np.ndarray | None:
    """The previous fit's best point carried into ``post``: an extra MAP start.

    None where it has no finite density (the MAP search then starts alone).
    """
    best = _carried(post, previous, added, best_point(previous.sampling)[None, :], seed)
    return best[0] if best.shape[0] and np.isfinite(post.log_prob(best[0])) else None


def _warm_walkers(post: Posterior, previous: DiagnosisFit, added: dict[str, Any],
                  seed: int) -> np.ndarray | None:
    """The previous fit's final ensembles carried into ``post``: the starting walkers.

    So the augmented posterior is not sampled from scratch; None where none has finite
    density (the sampler then starts alone). The added parameters are at one estimate
    in every walker: the sampler draws such shared coordinates apart before it starts.
    """
    last = previous.sampling.chains[:, -1].reshape(-1, previous.posterior.ndim)
    walkers = _carried(post, previous, added, last, seed + 1)
    if walkers.shape[0]:
        walkers = walkers[np.isfinite(post.log_prob_batch(walkers))]
    return walkers if walkers.shape[0] else None


@dataclass(frozen=True)
class Prepared:
    """A fit's posterior and the sampler's start, before any sampling.

    ``start`` is the MAP the sampler starts from: None leaves the search to the sampler
    (which, resuming a checkpoint, reads it back instead); otherwise it is the search the
    sampler would run (same seed), so a fit handed it samples what it would have sampled.
    """

    post: Posterior
    start: MAPResult | None
    initial: np.ndarray | None
    scales: Any
    sampler: SamplerSettings


def prepare_fit(data: Dataset, model: HysteresisModel, likelihood: str,
                st: DiagnosisSettings, checkpoint_dir: Path | None,
                warm: tuple[DiagnosisFit, dict[str, Any]] | None = None,
                discrepancy: str | Discrepancy | None = None, *,
                search: bool = False) -> Prepared:
    """The posterior a diagnosis fit samples, its MAP and starting walkers.

    Parameters as :func:`diagnosis_fit`; ``search``: find the MAP even where the sampler
    would find it itself (a screen needs it).
    """
    post = Posterior(data, model, likelihood)
    start = initial = scales = None
    if discrepancy is not None and post.likelihood.name in ("gaussian", "ar1"):
        # as fit_model: the discrepancy anchored at the MAP without it and its scales
        # fixed at their held-out optimum. Sampled jointly with its coefficients, the
        # scales make a funnel: a block added on top of the shape correction (creep on
        # the 150 V piezo) reached R-hat 1.87 in 10 000 steps
        seed0 = fit_sampler(post, st.sampler, st.seed, None).seed
        x0 = None if warm is None else _warm_point(post, warm[0], warm[1], seed0)
        start0 = find_map(post, seed=np.random.default_rng(seed0), x0=x0)
        post, scales, start = attach_discrepancy(post, start0, discrepancy)
    elif discrepancy is not None:  # sampled scales: the one way for other likelihoods
        post = Posterior(data, model, likelihood, discrepancy=discrepancy)
    # the seed, checkpoint and walkers follow from what is fitted: the base fit of a report
    # is the comparison's joint fit (same posterior, same settings, same checkpoint folder)
    sampler = fit_sampler(post, st.sampler, st.seed, checkpoint_dir)
    seed = sampler.seed
    if warm is not None:
        initial = _warm_walkers(post, warm[0], warm[1], seed)
        x0 = None if scales is not None else _warm_point(post, warm[0], warm[1], seed)
        if x0 is not None:  # an extra start of the MAP search, not a replacement
            start = find_map(post, seed=np.random.default_rng(seed), x0=x0)
    if start is None and search:
        # the search sample_posterior runs when it is given no start (its last spawned
        # seed), so that handing this one over changes nothing
        spawned = np.random.SeedSequence(sampler.seed).spawn(sampler.n_ensembles + 1)
        start = find_map(post, seed=np.random.default_rng(spawned[-1]))
    return Prepared(post, start, initial, scales, sampler)


@with_single_threaded_blas
def diagnosis_fit(data: Dataset, model: HysteresisModel, likelihood: str, label: str,
                  st: DiagnosisSettings, checkpoint_dir: Path | None,
                  warm: tuple[DiagnosisFit, dict[str, Any]] | None = None,
                  discrepancy: str | Discrepancy | None = None,
                  prepared: Prepared | None = None) -> DiagnosisFit:
    """One fit of the loop: sampled (again, if unconverged), scored, its residual analysed.

    It runs with one BLAS thread wherever it runs (in the caller or in a worker of the
    loop's prefetcher, :mod:`bayeshyst.diagnosis._workers`): a reduction split over
    another number of threads may round differently, and the loop's result must not
    depend on where a fit ran.

    Parameters
    ----------
    data : Dataset
        The records every fit of the loop sees.
    model : HysteresisModel
        The model fitted (the base model, or it augmented by a candidate's block).
    likelihood : str
        Registered likelihood name.
    label : str
        How the fit is named in warnings and the report.
    st : DiagnosisSettings
        The loop's settings (sampler, draws, doublings, residual tests).
    checkpoint_dir : Path or None
        Folder of the sampler's checkpoints (the fit's identity names its file).
    warm : (DiagnosisFit, dict) or None
        For a candidate: the fit it augments and the added parameters' estimates from
        the score test; its walkers start from that fit's final ensembles. None for the
        base fit.
    discrepancy : str, Discrepancy or None
        The shape correction fitted with the model, if any.
    prepared : Prepared, optional
        What :func:`prepare_fit` made of these arguments already (the candidate's
        screen did): its MAP is not searched again.

    Returns
    -------
    DiagnosisFit
        The fit and the analysis of its residual.
    """
    if prepared is None:
        prepared = prepare_fit(data, model, likelihood, st, checkpoint_dir, warm, discrepancy)
    post, start, initial = prepared.post, prepared.start, prepared.initial
    scales, sampler = prepared.scales, prepared.sampler
    seed = sampler.seed
    res = sample_posterior(post, sampler, start=start, initial=initial)
    notes: list[str] = []
    # an unconverged fit decides nothing, so it is sampled again, from where it got, with
    # twice the steps before it is reported as not decided (its own seed and checkpoint:
    # the budget is part of a fit's identity). Second-order candidates on the MR damper and
    # the micromanipulator ran out of 10 000 steps in a slowly mixing offset direction
    # while every other fit of the run converged. Not when the block the fit adds has a
    # resonance above Nyquist in every ensemble: its step is refused as unresolved
    # however those modes end up weighted (candidates.judge), and such fits are the
    # slowest to mix (MR damper 1 A: f_n split 150/293 Hz, R-hat 1.92 after 10 000 steps)
    added = [] if warm is None else added_names(res.space.names, warm[0])
    unseen = False
    for _ in range(0 if st.decide_unconverged else st.budget_doublings):
        if res.converged:
            break
        unseen = bool(unresolved_added(res, added, data))
        if unseen:
            break
        longer = fit_sampler(post, st.sampler.replace(max_steps=2 * sampler.max_steps),
                             st.seed, checkpoint_dir)
        notes.append(f"{label}: the sampler did not converge within {sampler.max_steps} "
                     f"steps; sampled again with {longer.max_steps}, each ensemble going on "
                     f"from its last walkers")
        sampler = longer
        # from where the short run got, not from the start again: a run that ran out
        # was still climbing or mixing slowly, and its walkers are past the climb (the
        # 150 V piezo's creep-and-drift candidate climbed 550 nats over its first 6 000
        # steps). Its own start (the MAP it may have restarted to) goes with them
        res = sample_posterior(post, sampler, start=res.start, walkers=res.last_walkers)
    if unseen:
        notes.append(f"{label}: the sampler did not converge within {sampler.max_steps} "
                     f"steps; not sampled again, because the natural frequency it adds lies "
                     f"above every Nyquist frequency in every ensemble (unresolved however "
                     f"its modes end up weighted)")
    elif not res.converged:
        notes.append(f"{label}: the sampler did not converge within its budget "
                     f"({sampler.max_steps} steps)")
    draws = res.draws(st.n_draws, seed=seed)
    settings = CompareSettings(likelihood=likelihood, sampler=sampler,
                               draws_per_chain=st.draws_per_chain, max_refits=st.max_refits)
    loo_notes: list[str] = []
    scores = loo_scores(post, res, settings, seed, loo_notes)
    notes += [f"{label}: {n}" for n in loo_notes]
    if res.counts.failed:
        notes.append(f"{label}: {res.counts.failed} simulations failed during sampling "
                     f"(log-probability -inf)")
    analysis = analyse_residual(post, res, draws, effects=st.effects, alpha=st.alpha,
                                max_ar_order=st.max_ar_order,
                                n_permutations=st.n_permutations, seed=seed)
    overall, per = errors_by_frequency(data, analysis.mean_prediction)
    fit = FitResult(post, res, overall, list(per), list(analysis.mean_prediction),
                    pointwise_elpd=scores.pointwise, warnings=tuple(notes), idata=scores.idata,
                    budget=tuple(uncertainty_budget(post, draws)), discrepancy_scales=scales)
    return DiagnosisFit(label, fit, analysis)
