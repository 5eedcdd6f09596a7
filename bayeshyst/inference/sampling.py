"""Posterior sampling with emcee: independent ensembles, automatic extension, checkpoints.

:func:`sample_posterior` starts from the MAP (walkers drawn from its Laplace
approximation, or from an earlier fit's ensembles), runs ``n_ensembles`` independent
emcee ensembles and extends the run chunk by chunk until every convergence criterion
holds — rank-normalised R-hat < 1.01 across walkers *and* across ensembles, bulk and
tail ESS >= 400, at least 50 integrated autocorrelation times kept after burn-in — or
the step budget is spent, in which case the result says so.

The default moves use the posterior's structure (:mod:`bayeshyst.inference.moves`):
the linear block (PI weights, Preisach grid, offsets, gains) is drawn exactly from its
conditional Gaussian, the few remaining coordinates by an independence proposal fitted
to the posterior during a warm-up and by differential evolution. ``moves="de"`` (emcee's
differential-evolution moves on every coordinate) and ``"stretch"`` remain selectable.

Chunk boundaries and the warm-up's adaptation points are fixed functions of the step
count, and every adaptation is recomputed from the stored chain, so a run resumed from
a checkpoint makes exactly the decisions (and draws exactly the samples) of the
uninterrupted run.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import emcee
import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.inference.checkpoint import (
    CheckpointBackend,
    check_fingerprint,
    read_meta,
    write_meta,
)
from bayeshyst.inference.convergence import ConvergenceReport, assess
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.mixing import explain_nonconvergence
from bayeshyst.inference.moves import structured_moves
from bayeshyst.inference.optimize import MAPResult, find_map
from bayeshyst.inference.posterior import EvalCounts, Posterior
from bayeshyst.inference.profile import profile_start
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inference.starts import initial_positions, unshared_walkers
from bayeshyst.inference.structured_target import MoveStats, StructuredTarget
from bayeshyst.inference.warmup import (
    MAX_REOPENINGS,
    MIN_MOVE_RATE,
    adaptation_points,
    extension_points,
    keep_adapting,
    stuck_walkers,
)
from bayeshyst.threads import single_threaded_blas

__all__ = [
    "MIN_MOVE_RATE", "adaptation_points", "chunk_boundaries", "extension_points",
    "sample_posterior",
]

_log = logging.getLogger(__name__)


def chunk_boundaries(first: int, max_steps: int) -> list[int]:
    """Step counts at which convergence is assessed: ``first``, then growing by a quarter.

    Consecutive checks are at least ``first // 2`` steps apart.

    A fixed function of the settings, so resumed runs stop where uninterrupted ones do.
    Checks a quarter apart waste at most a fifth of a run that converges between two
    of them, and cost a few tens of milliseconds each.
    """
    out = [min(first, max_steps)]
    while out[-1] < max_steps:
        out.append(min(max_steps, out[-1] + max(first // 2, out[-1] // 4, 1)))
    return out


def _emcee_moves(moves: str) -> Any:
    if moves == "de":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    return emcee.moves.StretchMove()


def _fingerprint(post: Posterior, settings: SamplerSettings, n_walkers: int,
                 initial: np.ndarray | None) -> dict[str, Any]:
    h = hashlib.sha256()
    for rec in post.data:
        for arr in (rec.t, rec.u, rec.y):
            h.update(np.ascontiguousarray(arr).tobytes())
        h.update(str(rec.warmup).encode())
    declared = post.space.declared_transforms
    start = "" if initial is None else hashlib.sha256(
        np.ascontiguousarray(initial).tobytes()).hexdigest()
    return {
        "model": repr(post.model),
        "likelihood": post.likelihood.name,
        "beta": post.beta,
        "held_out": str(post.held_out),
        "space": str(post.space),
        # only when there are some: checkpoints of other runs written before the key
        # existed still resume; a Bouc–Wen run sampled in the logit exponent does not
        **({"transforms": declared} if declared else {}),
        "data_sha256": h.hexdigest(),
        "n_walkers_used": str(n_walkers),
        "initial_sha256": start,
        **settings.fingerprint(),
    }


#: how far above the MAP's log density a walker may be before the MAP is called wrong
#: (the polish stops within a small fraction of a nat; a draw cannot exceed the mode)
MAP_SLACK = 1.0


def _best_draw(samplers: list, n_steps: int) -> tuple[float, np.ndarray]:
    """The highest log density among the first ``n_steps`` steps of every ensemble.

    Returned with the walker position that reached it.
    """
    best_lp, where = -math.inf, None
    for sampler, _ in samplers:
        lp = sampler.get_log_prob()[:n_steps]
        step, walker = np.unravel_index(int(np.argmax(lp)), lp.shape)
        if lp[step, walker] > best_lp:
            best_lp, where = float(lp[step, walker]), (sampler, step, walker)
    sampler, step, walker = where
    return best_lp, sampler.get_chain()[step, walker].copy()


def _bulk_above(samplers: list, n_steps: int, log_prob: float) -> bool:
    """Whether most draws of the last half of ``n_steps`` lie above ``log_prob``.

    After the warm-up a restart discards every step so far, so it needs more than one
    walker above the start: a typical draw lies about ``d / 2`` nats below the mode of
    the region it samples, so when most draws lie above the start the walkers sample a
    region whose mode the start is not. A few nats gained by one walker in the region
    the start is in is the MAP's own imprecision: on the 150 V piezo (Bouc–Wen with
    creep, drift and the shape correction, 43 coordinates) one walker 2.3 nats above the
    start restarted a run at step 17 000, at R-hat 1.005.
    """
    lp = np.concatenate([s.get_log_prob()[n_steps // 2:n_steps].ravel() for s, _ in samplers])
    return bool(lp.size) and float(np.median(lp)) > log_prob


def _missed_mode(report: ConvergenceReport, samplers: list, start: MAPResult
                 ) -> ConvergenceReport:
    """Name the likely cause when a non-converged run's walkers found density above the MAP.

    The cause: the search missed the main mode, the chains started elsewhere and are still
    migrating (or stuck between modes).
    """
    best, _ = _best_draw(samplers, report.n_steps)
    if not best > start.log_prob + MAP_SLACK:
        return report
    why = (f"walkers reached a log density {best - start.log_prob:.3g} nats above the "
           f"MAP's: the MAP search missed the main mode and the chains started in a "
           f"minor one (rerun with another seed, or start from the best draw)")
    return replace(report, reasons=(*report.reasons, why))


#: how often a run may restart from a better mode its walkers found (each restart
#: re-samples from scratch; a posterior that keeps revealing modes is reported as such)
MAX_RESTARTS = 2


@dataclass
class _Advance:
    """Where one attempt of :func:`sample_posterior` ended."""

    report: ConvergenceReport | None = None
    restart_from: np.ndarray | None = None
    best_log_prob: float = -math.inf


def _write_run_meta(checkpoint: Any, fingerprint: dict[str, Any], start: MAPResult,
                    restarts: int) -> None:
    write_meta(checkpoint, {"fingerprint": fingerprint, "restarts": restarts, "start": {
        "z": start.z, "theta": start.theta, "log_prob": start.log_prob,
        "covariance": start.covariance, "laplace_ok": start.laplace_ok,
        "n_evals": start.n_evals, "candidates": start.candidates, "notes": start.notes}})


def _start_from_meta(meta: dict[str, Any], checkpoint: Any) -> MAPResult:
    """The MAP a checkpointed run started (or restarted) from (:func:`_write_run_meta`)."""
    try:
        d = meta["start"]
        return MAPResult(
            z=np.asarray(d["z"], dtype=float), theta=dict(d["theta"]),
            log_prob=float(d["log_prob"]), covariance=np.asarray(d["covariance"], dtype=float),
            laplace_ok=bool(d["laplace_ok"]), n_evals=int(d["n_evals"]),
            candidates=tuple(float(c) for c in d["candidates"]),
            notes=tuple(str(n) for n in d["notes"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ParameterError(f"checkpoint {checkpoint}: its start record is incomplete "
                             f"({exc!r}); delete it to start afresh") from exc


def _attempt_rngs(seed: int, n_ens: int, attempt: int,
                  seeds: list[np.random.SeedSequence]) -> list[np.random.Generator]:
    """Each ensemble's generator for an attempt.

    The run's own streams first, then streams fixed by (seed, attempt), so a resumed
    restart starts where the uninterrupted one did.
    """
    if attempt == 0:
        return [np.random.default_rng(seeds[e]) for e in range(n_ens)]
    return [np.random.default_rng(s)
            for s in np.random.SeedSequence([int(seed), attempt]).spawn(n_ens)]


def _ensembles(post: Posterior, settings: SamplerSettings, target: StructuredTarget,
               start: MAPResult, initial: np.ndarray | None, n_walkers: int,
               rngs: list[np.random.Generator], walkers: np.ndarray | None = None
               ) -> tuple[list, list, list]:
    """The emcee samplers of one attempt, their move statistics and independence moves.

    The samplers are resumed from the checkpoint where it has steps.
    """
    ndim = post.ndim
    other = target.other_idx
    samplers, stats, indeps = [], [], []
    starts = None
    for e in range(settings.n_ensembles):
        backend = (CheckpointBackend(settings.checkpoint, f"ensemble_{e}",
                                     flush_seconds=settings.flush_seconds)
                   if settings.checkpoint is not None else emcee.backends.Backend())
        st = MoveStats()
        indep = None
        if settings.moves == "structured":
            moves, indep = structured_moves(target, st, start.z[other],
                                            start.covariance[np.ix_(other, other)])
        else:
            moves = _emcee_moves(settings.moves)
        # (a new checkpoint's groups are created here, by emcee)
        sampler = emcee.EnsembleSampler(n_walkers, ndim, post.log_prob_batch, vectorize=True,
                                        moves=moves, backend=backend)
        if isinstance(backend, CheckpointBackend):
            if backend.iteration > 0:
                # the moves' counts as of the last flushed step, which the run resumes from
                restored = MoveStats.from_dict(backend.stored_extra())
                st.proposed.update(restored.proposed)
                st.accepted.update(restored.accepted)
            backend.extra_provider = st.to_dict
        p0 = None
        if backend.iteration == 0:
            if starts is None:
                starts = initial_positions(post, start, initial, settings.n_ensembles,
                                           n_walkers, rngs, walkers)
            p0 = starts[e]
            sampler.random_state = np.random.RandomState(
                int(rngs[e].integers(2**31 - 1))).get_state()
        samplers.append([sampler, p0])
        stats.append(st)
        indeps.append(indep)
    return samplers, stats, indeps


def _refit(indeps: list, chains: list[np.ndarray], boundary: int,
           stuck: list[np.ndarray]) -> None:
    """Re-fit the shared independence proposal to the second half of the stored chains.

    ``stuck`` are the draws of walkers the current proposal held in one place; each gets an
    anchor component (:meth:`~bayeshyst.inference.moves.IndependenceMove.adapt`).
    """
    # one proposal from the draws of every ensemble (twice the draws for its shape; each
    # ensemble stays a valid chain of its own once it is frozen, and they started apart,
    # so R-hat between them keeps its meaning)
    live = [i for i in indeps if i is not None]
    if not live:
        return
    ndim = chains[0].shape[2]
    pooled = np.concatenate([c[boundary // 2:].reshape(-1, ndim) for c in chains])
    live[0].adapt(pooled, tuple(stuck))
    for other_move in live[1:]:
        other_move.set_proposal(live[0].means, live[0].covariances, live[0].weights)


def _advance(samplers: list, indeps: list, other: np.ndarray, settings: SamplerSettings,
             start: MAPResult, bar: Any, *, can_restart: bool,
             continuing: bool = False) -> _Advance:
    """Run one attempt's ensembles chunk by chunk.

    Adapt the proposal during warm-up, assess convergence at the checks, and stop early
    when the walkers show the start was not the mode (``can_restart``): during the
    warm-up one walker above it suffices, after it most of the draws must be
    (:func:`_bulk_above`), and so must they throughout a run ``continuing`` an earlier
    one's walkers (draws already: one of them a nat or two above a MAP polished on a
    flat ridge is not a missed mode). A check that fails
    after the warm-up with walkers the frozen proposal holds still re-opens it (at most
    :data:`~bayeshyst.inference.warmup.MAX_REOPENINGS` times, in the first half of the
    budget): the proposal is re-fitted with an anchor on each and the burn-in moves there.
    """
    warmup = settings.warmup_steps if any(i is not None for i in indeps) else 0
    adapt_at = set(adaptation_points(warmup))
    extend_at = extension_points(warmup, settings.max_steps)
    checks = set(chunk_boundaries(settings.first_chunk, settings.max_steps))
    boundaries = sorted(checks | adapt_at | set(extend_at))
    out = _Advance()
    warm_end, frozen, last_adapt, last_rate = warmup, False, warmup, -math.inf
    reopened = 0

    def warm_over(boundary: int) -> bool:
        # frozen by a decision, or no extension point left to re-fit at
        return frozen or not any(e > boundary for e in extend_at)

    for boundary in boundaries:
        for pair in samplers:
            sampler, p0 = pair
            todo = boundary - sampler.iteration
            if todo <= 0:
                continue
            # continue from the stored last state (positions, log p, random state):
            # after a resume that is the checkpoint, so the run goes on identically
            state = p0 if sampler.iteration == 0 else sampler.get_last_sample()
            for _ in sampler.sample(state, iterations=todo, store=True,
                                    skip_initial_state_check=settings.moves == "structured"):
                if bar is not None:
                    bar.update(1)
            if isinstance(sampler.backend, CheckpointBackend):
                sampler.backend.flush()
        # every decision below is a fixed function of the stored chain: a resumed run
        # re-fits the same proposals and restarts at the same steps
        if can_restart:
            best_lp, best_z = _best_draw(samplers, boundary)
            if best_lp > start.log_prob + MAP_SLACK and (
                    (not continuing and not warm_over(boundary))
                    or _bulk_above(samplers, boundary, start.log_prob)):
                out.restart_from, out.best_log_prob = best_z, best_lp
                return out
        refit = boundary in adapt_at
        decide = boundary in extend_at and not frozen
        if not (refit or decide or boundary in checks):
            continue  # an extension point after the warm-up froze: nothing reads the chain
        # the re-fit, the warm-up decision and the check all read the stored chain: read
        # it once (from a checkpoint that is a read of the file)
        chains = [s.get_chain()[:boundary] for s, _ in samplers]
        if decide:
            decision = keep_adapting(chains, other, last_adapt, boundary, last_rate)
            _log.debug("step %d: warm-up %s", boundary, decision)
            if decision.refit:
                refit, warm_end = True, boundary
            else:
                frozen = True
            last_rate = decision.move_rate
        if refit:
            _refit(indeps, chains, boundary, stuck_walkers(chains, other, last_adapt, boundary))
            last_adapt = boundary
        if boundary not in checks:
            continue
        out.report = assess(chains, rhat_threshold=settings.rhat_threshold,
                            min_ess=settings.min_ess, tau_factor=settings.tau_factor,
                            min_burn=warm_end)
        _log.debug("step %d: R-hat %.4f, ESS bulk %.0f, tail %.0f, tau %.1f%s", boundary,
                   out.report.rhat_max, out.report.ess_bulk_min, out.report.ess_tail_min,
                   out.report.tau_max, "" if out.report.converged else " (not yet)")
        if bar is not None:
            bar.set_postfix_str(f"R-hat {out.report.rhat_max:.3f}, ESS "
                                f"{out.report.ess_bulk_min:.0f}, tau {out.report.tau_max:.0f}")
        if out.report.converged:
            break
        if warm_over(boundary) and reopened < MAX_REOPENINGS and \
                boundary <= settings.max_steps // 2:
            # a region the frozen proposal misses holds a walker still (a tail along a
            # ridge, a mode found late): re-fit with an anchor on each such walker and
            # burn in to here, so the kept chain has one fixed proposal again
            stuck = stuck_walkers(chains, other, warm_end, boundary)
            if stuck:
                _log.info("step %d: %d walker(s) held still under the frozen proposal; "
                          "re-fitted with an anchor on each, burn-in moved to this step",
                          boundary, len(stuck))
                _refit(indeps, chains, boundary, stuck)
                last_adapt, warm_end, reopened = boundary, boundary, reopened + 1
    return out


def sample_posterior(
    post: Posterior,
    settings: SamplerSettings | None = None,
    *,
    start: MAPResult | None = None,
    initial: np.ndarray | None = None,
    walkers: np.ndarray | None = None,
) -> SamplingResult:
    """Sample the posterior with independent emcee ensembles until converged.

    Parameters
    ----------
    post : Posterior
    settings : SamplerSettings, optional
        Moves, walkers, ensembles, budget, convergence criteria, seed, checkpoint,
        progress (defaults: :class:`SamplerSettings`). With a checkpoint the run is
        written as it goes and resumed when the file exists: a run killed at any point
        continues where its last flush left it and ends with the draws of an
        uninterrupted run.
    start : MAPResult, optional
        Skip the MAP search and start from this one.
    initial : ndarray, shape (..., ndim), optional
        Starting walkers (e.g. an earlier fit's draws of the same coordinates: a
        leave-one-cycle-out refit starts from the full-data ensembles); each ensemble
        takes its walkers from them, and Laplace draws replace any without finite
        density. A coordinate every given walker shares (a parameter set at one
        estimate) is drawn apart first, from the Laplace conditional: an ensemble's
        moves cannot leave the subspace it starts in.
    walkers : ndarray, shape (n_ensembles, n_walkers, ndim), optional
        Each ensemble's own starting walkers, kept apart and in place: an earlier run of
        the same posterior continued (:attr:`SamplingResult.last_walkers`), so that a
        longer budget does not climb again from the start to where that run got
        (any walker without finite density is replaced by a Laplace draw). Not with
        ``initial``.

    Returns
    -------
    SamplingResult

    Raises
    ------
    ParameterError
        For too few walkers for the move set, a checkpoint of another run, or
        ``walkers`` of another shape than the run's ensembles.
    """
    # a hysteresis posterior alternates numba kernels with small BLAS products: one BLAS
    # thread (bayeshyst.threads); other targets (a GP's hyperparameters over a large
    # training set) choose their own
    limit = single_threaded_blas() if isinstance(post, Posterior) else contextlib.nullcontext()
    with limit:
        return _sample_posterior(post, settings, start, initial, walkers)


def _sample_posterior(post: Posterior, settings: SamplerSettings | None,
                      start: MAPResult | None, initial: np.ndarray | None,
                      walkers: np.ndarray | None = None) -> SamplingResult:
    t0 = time.perf_counter()
    settings = SamplerSettings() if settings is None else settings
    if not isinstance(settings, SamplerSettings):
        raise ParameterError(f"settings must be a SamplerSettings, got {type(settings).__name__}")
    ndim = post.ndim
    n_ens = settings.n_ensembles
    seeds = np.random.SeedSequence(settings.seed).spawn(n_ens + 1)
    checkpoint = settings.checkpoint
    counts0 = post.counts
    meta = None
    attempt = 0
    if checkpoint is not None:
        meta = read_meta(checkpoint)
        if meta is not None:
            # a run that restarted goes on from the start it restarted from
            attempt = int(meta.get("restarts", 0))
            if start is None or attempt > 0:
                start = _start_from_meta(meta, checkpoint)
    if start is None:
        start = find_map(post, seed=np.random.default_rng(seeds[-1]))
    structured = settings.moves == "structured"
    structure = LinearStructure.of(post, reference=start.z) if structured else None
    n_walkers = settings.walkers(StructuredTarget(post, structure).n_other if structured
                                 else ndim, ndim)
    if not structured and n_walkers < 2 * ndim:
        raise ParameterError(f"n_walkers={n_walkers} is too few for {ndim} dimensions with "
                             f"{settings.moves!r} moves (need >= {2 * ndim})")
    if walkers is not None:
        if initial is not None:
            raise ParameterError("give the starting walkers as a pool (initial) or per "
                                 "ensemble (walkers), not both")
        walkers = np.asarray(walkers, dtype=float)
        if walkers.shape != (n_ens, n_walkers, ndim):
            raise ParameterError(f"walkers must have shape (n_ensembles, n_walkers, ndim) = "
                                 f"{(n_ens, n_walkers, ndim)} for this run, got "
                                 f"{walkers.shape}")
    if initial is not None:
        # the seed's child n_ens + 1: a stream no ensemble and no MAP search draws from
        initial = unshared_walkers(
            post, start, initial, StructuredTarget(post, structure).other_idx,
            np.random.default_rng(np.random.SeedSequence(settings.seed).spawn(n_ens + 2)[-1]))
    fp = None
    if checkpoint is not None:
        fp = _fingerprint(post, settings, n_walkers, initial if walkers is None else walkers)
        if meta is not None:
            check_fingerprint(checkpoint, meta["fingerprint"], fp)
        else:
            checkpoint.parent.mkdir(parents=True, exist_ok=True)
            _write_run_meta(checkpoint, fp, start, 0)
    bar = None
    if settings.progress:
        from tqdm.auto import tqdm

        # a terminal gets a live bar; a log file an update every 10 s, not thousands
        bar = tqdm(total=settings.max_steps * n_ens, desc=f"sampling {post.model.name}",
                   unit="step", mininterval=0.2 if sys.stderr.isatty() else 10.0)
    try:
        while True:
            target = StructuredTarget(post, structure)
            rngs = _attempt_rngs(settings.seed, n_ens, attempt, seeds)
            # the given walkers start the first attempt only: a restart samples afresh
            # around its new start
            first = attempt == 0
            samplers, stats, indeps = _ensembles(
                post, settings, target, start, initial if first else None,
                n_walkers, rngs, walkers if first else None)
            if bar is not None:
                bar.reset(total=settings.max_steps * n_ens)
                bar.update(sum(s.iteration for s, _ in samplers))
            run = _advance(samplers, indeps, target.other_idx, settings, start, bar,
                           can_restart=attempt < MAX_RESTARTS,
                           continuing=first and walkers is not None)
            if run.restart_from is None:
                break
            # walkers found higher density than the MAP: it was not the mode. Polish from
            # the best walker and sample afresh from there (the chains so far started in
            # a minor mode; their draws are discarded, not mixed in)
            gain = run.best_log_prob - start.log_prob
            _log.info("%s: a walker found log density %.3g above the MAP; restarting from "
                      "it (restart %d)", post.model.name, gain, attempt + 1)
            if structure is not None and getattr(post, "discrepancy", None) is not None:
                # with a discrepancy the linear block has ~100 coordinates: the polish
                # searches the others with the block at its conditional mean (a full
                # search differentiates every coefficient: 10+ minutes on 30 000
                # samples, measured). Keeping the best walker's nonlinear coordinates
                # instead left a start the walkers then climbed 550 nats from, over
                # 6 000 steps (Bouc-Wen with creep and drift on the 150 V piezo)
                new = profile_start(
                    post, LinearStructure.of(post, reference=run.restart_from), start,
                    run.restart_from)
            else:
                # a local polish from the walker, as the note below says: the multi-start
                # search with its global stage is what missed this mode, and repeating
                # it took over 40 minutes on the MR-damper records (measured)
                new = find_map(post, seed=np.random.default_rng(rngs[0].integers(2**31 - 1)),
                               x0=run.restart_from, n_screen=16, n_starts=1,
                               global_search=False)
            attempt += 1
            structure = LinearStructure.of(post, reference=new.z) if structured else None
            start = replace(new, notes=(*start.notes, *new.notes, (
                f"walkers found a log density {gain:.3g} nats above the MAP search's "
                f"optimum during sampling: the search had missed the main mode, and "
                f"sampling restarted from the optimum polished from there "
                f"(restart {attempt} of at most {MAX_RESTARTS})")))
            if checkpoint is not None:
                # chains emptied first, then the new start: a kill between the two redoes
                # this attempt from its beginning and restarts at the same step again
                for sampler, _ in samplers:
                    sampler.backend.reset(n_walkers, ndim)
                _write_run_meta(checkpoint, fp, start, attempt)
    finally:
        if bar is not None:
            bar.close()
    report = run.report
    if report is None:  # internal invariant: chunk_boundaries always ends at max_steps
        raise ParameterError("no convergence check was made")
    if not report.converged:
        report = _missed_mode(report, samplers, start)
    burn = report.burn
    chains = np.stack([s.get_chain()[burn:report.n_steps] for s, _ in samplers])
    logp = np.stack([s.get_log_prob()[burn:report.n_steps] for s, _ in samplers])
    if not report.converged:
        # what held the run back, in the coordinates' own names: slow directions,
        # pairs the data do not separate, ensembles in separate regions
        report = replace(report, reasons=(*report.reasons, *explain_nonconvergence(
            chains, logp, post.space, tau_factor=settings.tau_factor)))
    acc = np.stack([s.backend.accepted / max(s.iteration, 1) for s, _ in samplers])
    c1 = post.counts
    counts = EvalCounts(c1.evaluations - counts0.evaluations,
                        c1.prior_rejected - counts0.prior_rejected, c1.failed - counts0.failed)
    info = {**settings.to_dict(), "n_walkers": n_walkers}
    return SamplingResult(post.space, chains, logp, report, start, counts, acc,
                          time.perf_counter() - t0, post.model.name, post.likelihood.name,
                          int(settings.seed), info, MoveStats.merge(stats).rates(),
                          () if structure is None else structure.names)
