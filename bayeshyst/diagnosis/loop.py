"""The closed loop of :func:`diagnose`: fit, test the residual, augment, refit, keep or stop.

Each round goes fit → residual tests → augment with the best-supported effect → refit →
keep it only if held-out prediction improves → repeat.

Two gates stand between a residual pattern and an effect in ``effects_found``:

1. its score test fires: Holm-adjusted p-value below ``alpha`` over all effects tested
   on that residual (:mod:`bayeshyst.diagnosis.residual`);
2. the augmented model predicts held-out cycles better: the paired difference of the
   cycle-wise PSIS-LOO elpd (exact refits for Pareto k > 0.7) exceeds ``threshold``
   standard errors (default 2, Vehtari, Gelman & Gabry 2017, §5.2).

Fired effects are tried in order of support (Bayes factor; coloured noise last); the
first that passes gate 2 is kept and the loop starts again from the augmented fit.
Every fired block of the catalogue is screened first, from its augmented posterior's
MAP (:mod:`bayeshyst.diagnosis.screen`: Laplace draws importance-corrected to each
leave-one-cycle-out posterior): one that loses gate 2 even with the screen's error in
its favour is rejected without being sampled, one the screen judges able to pass is
sampled whatever the round's budget, and one it cannot judge is sampled within it. A
smooth term or a spectral line is screened when the budget would end the round before
it; the shape correction and coloured noise, the last resorts, come after the round's
pair and are sampled when reached.
Effects that fire but fail gate 2 are recorded as rejected steps. When every candidate
of a round fails and the best of them lost on some held-out cycles while gaining on the
whole, it is fitted once more together with a partner that explains those cycles
(:func:`~bayeshyst.diagnosis.candidates.pair_for`: one noise scale serves every cycle,
so a delay that fits the fast cycles tighter loses on the slow ones that creep
explains); the pair passes the same gate. The loop stops when no test fires, when
every fired effect (and the pair) is rejected, or after ``max_rounds``.

Beyond the catalogue (:mod:`bayeshyst.diagnosis.verdict` has the rules):

* every residual is also scanned for dependence on anything observed
  (:mod:`bayeshyst.diagnosis.drivers`); when the hysteresis model's own branch shape is
  what is left (the loop position is a kept driver), a shape correction -- the
  discrepancy over the loop's coordinates, :mod:`bayeshyst.discrepancy` -- is a
  candidate, tried *before* any time-domain effect (creep, rate, delay, drift, a change
  point);
* a time-domain effect whose score test explains nothing beyond the measured columns
  the scan kept (``EffectTest.p_beyond_columns``: on one sine a rate is a function of a
  velocity column, a slow trend one of a drifting temperature) is not tried but
  reported as tied with them; the column's own candidates take that structure;
* with fewer than ``MIN_GATE_UNITS`` cycles gate 2 cannot decide, and the step says so
  and falls back to the score test's Bayes factor (or, for the shape, to the scan);
* an accepted effect ties with the effects whose Bayes factors are within 3 nats of its
  own, and an implausible physical reading, or a resonance above every record's
  Nyquist frequency, makes it a warning, not a finding;
* a candidate whose fit did not converge is *not decided* (neither kept nor rejected,
  and said so in the verdict); the round goes on to the next candidate;
* the verdict says what is left: "the base model explains the data" only when nothing
  fires and nothing observed explains the residual.

The loop decides serially, but need not wait serially: while it fits a candidate in
its own process, worker processes fit the ones it may need next -- the next candidates
of the round, the smooth term that would challenge a kept effect, a pair's challenger
(:class:`~bayeshyst.diagnosis._workers.Prefetcher`, ``n_jobs``). A fit's seed and
checkpoint follow from what it is, so a prefetched fit is the one the loop would have
made; the ones it does not reach are discarded unreported.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnosis._fitting import Prepared, diagnosis_fit
from bayeshyst.diagnosis._steps import (
    PAIRABLE,
    augmented,
    before_noise,
    candidate_discrepancy,
    credited,
    speculative,
    try_pair,
)
from bayeshyst.diagnosis._workers import Prefetcher
from bayeshyst.diagnosis.candidates import (
    BRANCH_SHAPE,
    judge,
    line_candidate,
    pair_for,
    shape_candidate,
    unexplained_candidate,
)
from bayeshyst.diagnosis.catalogue import EFFECTS
from bayeshyst.diagnosis.effects import ColoredNoise
from bayeshyst.diagnosis.records import (
    DiagnosisFit,
    DiagnosisResult,
    DiagnosisSettings,
    DiagnosisStep,
)
from bayeshyst.diagnosis.residual import EffectTest
from bayeshyst.diagnosis.screen import (
    CandidateScreen,
    ScreenedFit,
    screen_candidate,
    screened_step,
)
from bayeshyst.diagnosis.verdict import (
    NOT_CONVERGED,
    PLAUSIBLE,
    column_tie_notes,
    column_tied,
    explained_beyond_shape,
    shape_tie_notes,
    tied_beyond,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.likelihoods import get_likelihood
from bayeshyst.models import get as get_model
from bayeshyst.models.base import HysteresisModel
from bayeshyst.workers import resolve_jobs

__all__ = ["DiagnosisFit", "DiagnosisResult", "DiagnosisSettings", "DiagnosisStep", "diagnose"]

_log = logging.getLogger(__name__)
#: Candidates tried only after the round's pair (:func:`~bayeshyst.diagnosis.candidates.
#: pair_for`): the shape correction and coloured noise.
_LAST_RESORTS = (BRANCH_SHAPE, ColoredNoise.name)


# --------------------------------------------------------------------------- the loop
def _check_settings(st: DiagnosisSettings) -> None:
    bad = [e for e in st.effects if e not in EFFECTS]
    if bad:
        raise ParameterError(f"effects: unknown {bad}; valid: {', '.join(EFFECTS)}")
    if not (0.0 < st.alpha < 1.0):
        raise ParameterError(f"alpha must be in (0, 1), got {st.alpha}")
    if not (math.isfinite(st.threshold) and st.threshold >= 0):
        raise ParameterError(f"threshold (standard errors) must be >= 0, got {st.threshold}")
    for name in ("max_rounds", "max_candidates", "n_draws"):
        if int(getattr(st, name)) < 1:
            raise ParameterError(f"{name} must be >= 1, got {getattr(st, name)}")
    if isinstance(st.budget_doublings, bool) or not isinstance(st.budget_doublings, int) \
            or st.budget_doublings < 0:
        raise ParameterError(f"budget_doublings must be an integer >= 0, got "
                             f"{st.budget_doublings!r}")


def diagnose(
    data: Dataset | Record,
    model: HysteresisModel | str,
    likelihood: str = "gaussian",
    *,
    effects: Sequence[str] | None = None,
    alpha: float = 0.01,
    threshold: float = 2.0,
    max_rounds: int = 6,
    max_candidates: int = 2,
    sampler: SamplerSettings | None = None,
    n_draws: int = 200,
    max_refits: int = 5,
    n_permutations: int = 999,
    plausible: Mapping[str, tuple[float, float, str]] | None = None,
    decide_unconverged: bool = False,
    budget_doublings: int = 1,
    checkpoint_dir: str | Path | None = None,
    on_fit: Callable[[DiagnosisFit], None] | None = None,
    n_jobs: int | None = None,
    screen: bool = False,
) -> DiagnosisResult:
    """Find what a fitted model misses, add it, refit, and report the error before and after.

    Parameters
    ----------
    data : Dataset or Record
        Measured records (frequencies in the metadata make the per-frequency report).
    model : HysteresisModel or str
        Base model or spec string (``"bouc_wen"``, ``"pi_play(n_operators=8)"``).
    likelihood : str
        Base likelihood; ``colored_noise`` switches it to ``"ar1"``.
    effects : sequence of str, optional
        Candidate effects (default all: creep, rate_dependence, asymmetry, drift, delay,
        colored_noise).
    alpha : float
        Family-wise level of the residual tests (Holm over the effects of a round).
    threshold : float
        Standard errors by which the augmented model's cycle-wise elpd must exceed the
        current one's for the effect to be kept.
    max_rounds : int
        Most effects added.
    max_candidates : int
        Fired effects sampled per round before giving up on the round; one rejected only
        because its physical reading is implausible (``plausible``) or unresolved (a
        resonance above every record's Nyquist frequency) does not count, nor does one
        the screen rejected (``screen``).
    sampler : SamplerSettings, optional
        How every fit is sampled (:func:`~bayeshyst.inference.sampling.sample_posterior`);
        each fit's seed derives from ``sampler.seed`` and what the fit is
        (:func:`~bayeshyst.selection.tasks.fit_sampler`): same seed, same result.
    n_draws : int
        Posterior draws averaged for predictions and residuals.
    max_refits : int
        Cycles per fit whose PSIS-LOO is unreliable (Pareto k > 0.7) that are refitted
        exactly, worst first (each refit costs a fit).
    n_permutations : int
        Sign patterns calibrating the driver scan on every residual
        (:func:`~bayeshyst.diagnosis.drivers.scan_drivers`); 0 skips the scan.
    plausible : mapping, optional
        ``parameter -> (low, high, why)``: posterior means of an added block outside
        these ranges make the step a warning, not a finding (default
        :data:`~bayeshyst.diagnosis.verdict.PLAUSIBLE`).
    decide_unconverged : bool
        False (default): a candidate whose fit did not converge is *not decided*. True:
        its gate decides on the draws there are (the step's ``converged`` and the fit's
        warning still say so) -- for studies of what the loop names on short chains
        (``analyses.hidden_effects``), whose decisions are provisional.
    budget_doublings : int
        Times an unconverged fit is sampled again with twice the step budget of its last
        run, each ensemble going on from that run's last walkers, before it is reported
        as not converged (0: never). Not
        with ``decide_unconverged``, which decides on the draws there are, nor for a
        candidate whose added natural frequency lies above every Nyquist frequency in
        every ensemble: it is refused as unresolved, however its modes end up weighted.
    checkpoint_dir : path, optional
        Each fit checkpoints here (``<identity>.h5``); a rerun resumes finished fits,
        and a fit another command made with the same data and settings into the same
        folder (the comparison's joint fit) is reused, not sampled again.
    on_fit : callable, optional
        Called with every :class:`DiagnosisFit` the loop uses, in the loop's order
        (progress reports).
    n_jobs : int, optional
        Processes fitting at once (default one per core). The loop decides in the order
        above whatever ``n_jobs``; with more than one, worker processes fit ahead of it
        the candidates (and challengers) it may need next, and the fits it turns out not
        to need are discarded unreported. Every fit's seed follows from what is fitted,
        so the result is the same as with 1 (every fit in this process, one at a time).
        Workers start as :mod:`bayeshyst.workers` starts them (``fork`` where the
        platform has it; under ``spawn`` a script needs the ``if __name__ ==
        "__main__":`` guard). Every fit runs with one BLAS thread, wherever it runs.
    screen : bool
        Screen the fired candidates of a round from their MAP first
        (:mod:`bayeshyst.diagnosis.screen`): one the screen shows losing its gate even
        with the screen's error in its favour is rejected without being sampled (its
        step's ``decided_by`` is ``"screen"``), one it judges able to pass is sampled
        whatever ``max_candidates``. Off by default: on short chains a screen's MAP
        searches can cost more than the fits they spare (the hidden-effect suite's
        creep case took 322 s screened against 73 s; RESULTS.md).

    Returns
    -------
    DiagnosisResult
    """
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if not isinstance(data, Dataset):
        raise DataError(f"data must be a Dataset or Record, got {type(data).__name__}")
    st = DiagnosisSettings(
        effects=tuple(EFFECTS) if effects is None else tuple(effects), alpha=float(alpha),
        threshold=float(threshold), max_rounds=int(max_rounds),
        max_candidates=int(max_candidates),
        sampler=SamplerSettings() if sampler is None else sampler, n_draws=int(n_draws),
        max_refits=int(max_refits), n_permutations=int(n_permutations),
        plausible=PLAUSIBLE if plausible is None else MappingProxyType(dict(plausible)),
        decide_unconverged=bool(decide_unconverged), budget_doublings=budget_doublings,
        screen=bool(screen))
    _check_settings(st)
    base_label = model if isinstance(model, str) else model.name
    base_model = get_model(model) if isinstance(model, str) else model
    likelihood = get_likelihood(likelihood).name
    ckdir = None if checkpoint_dir is None else Path(checkpoint_dir)
    if ckdir is not None:
        ckdir.mkdir(parents=True, exist_ok=True)
    ahead = resolve_jobs(n_jobs) - 1  # fits run ahead of the loop, beside its own
    # the fit function looked up here, so a stand-in put in its place runs (in this
    # process: the prefetcher refuses a function a fresh interpreter cannot import)
    with Prefetcher(ahead, diagnosis_fit) as pool:
        return _loop(data, base_model, base_label, likelihood, st, ckdir, on_fit, pool)


def _loop(data: Dataset, base_model: HysteresisModel, base_label: str, likelihood: str,
          st: DiagnosisSettings, ckdir: Path | None,
          on_fit: Callable[[DiagnosisFit], None] | None, pool: Prefetcher) -> DiagnosisResult:
    """The rounds of :func:`diagnose`; ``pool`` fits ahead of them what they may need."""
    FitArgs = tuple[Any, ...]  # the arguments of diagnosis_fit

    def fit(args: FitArgs, key: Hashable | None = None,
            prepared: Prepared | None = None) -> DiagnosisFit:
        # a fit prefetched under ``key`` is the workers'; any other is fitted here, from
        # what its screen prepared (the same posterior and MAP the fit would find)
        if key is not None and key in pool:
            f = pool.take(key)
        else:
            with pool.sharing():
                f = (diagnosis_fit(*args) if prepared is None
                     else diagnosis_fit(*args, prepared=prepared))
        if on_fit is not None:
            on_fit(f)
        return f

    def lab(spec: str, lik: str, disc: str | None) -> str:
        out = spec if lik == "gaussian" else f"{spec} with likelihood {lik}"
        return out + (f" with discrepancy {disc}" if disc else "")

    current = fit((data, base_model, likelihood, lab(base_label, likelihood, None), st, ckdir))
    base, spec, disc = current, base_label, None
    rounds, steps, found = [current.analysis], [], []
    warnings = list(current.warnings)
    shape_ties: dict[str, float] = {}  # effect -> p beyond the loop position, first seen
    column_ties: dict[str, tuple[float, tuple[str, ...]]] = {}  # ... beyond the columns
    for rnd in range(1, st.max_rounds + 1):
        candidates = list(current.analysis.fired())
        # structure a measured column explains is the column's (aux, a smooth term in
        # it), not a time-domain effect's that explains nothing beyond it
        tied_cols = column_tied(candidates, current.analysis.alpha)
        for t in tied_cols:
            column_ties.setdefault(t.effect, (t.p_beyond_columns, t.beyond_columns))
        candidates = [t for t in candidates if all(t is not u for u in tied_cols)]
        shape = shape_candidate(current, st.alpha)
        if shape is not None and disc is None:
            # residual structure in where-on-the-loop is the model's own shape: a
            # time-domain effect (creep, a lag, a delay, drift, a change) is credited only
            # with what it explains beyond the loop position; the shape correction itself
            # is the last resort, before coloured noise
            level = current.analysis.alpha
            tied = tied_beyond(candidates, "p_beyond_shape", level)
            for t in tied:
                shape_ties.setdefault(t.effect, t.p_beyond_shape)
            candidates = [t for t in candidates if all(t is not u for u in tied)]
            candidates.insert(before_noise(candidates), shape)
        line = line_candidate(current, st.alpha)
        if line is not None:
            # a line is structure, which an AR(1) noise model would only blur: it goes
            # before coloured noise
            candidates.insert(before_noise(candidates), line)
        unexplained = unexplained_candidate(current, st.alpha)
        if unexplained is not None:
            # what no physical block explains is still structure: a smooth term in the
            # feature it follows says how much, before coloured noise would blur it
            at = before_noise(candidates)
            kept = [d.driver for d in current.analysis.drivers.selected]
            shape_at = [i for i, t in enumerate(candidates) if t.effect == BRANCH_SHAPE]
            if shape_at and kept.index(unexplained.variant) < kept.index("loop position"):
                at = shape_at[0]  # the scan kept its feature first: it is the stronger
            candidates.insert(at, unexplained)
        if not candidates:
            break

        def planned(test: EffectTest, on: tuple[DiagnosisFit, str, str | None] | None,
                    rnd: int = rnd, current: DiagnosisFit = current, spec: str = spec,
                    disc: str | None = disc) -> tuple[Hashable, FitArgs, str, str | None]:
            # ``on``: augment that fit (a candidate of this round) instead of the current
            # one. The key names the fit within the round: what it augments and the label
            below, below_spec, below_disc = (current, spec, disc) if on is None else on
            new_model, new_lik, new_spec, new_disc, warm = augmented(
                test, below, below_spec, below_disc, data)
            label = lab(new_spec, new_lik, new_disc)
            return ((rnd, below.label, label),
                    (data, new_model, new_lik, label, st, ckdir, warm,
                     candidate_discrepancy(below.posterior, new_disc)), new_spec, new_disc)

        # every candidate screened from its MAP first (on the current fit); one that
        # loses its gate even with the screen's error in its favour is not sampled
        screens: dict[int, tuple[CandidateScreen, Prepared, str, str | None]] = {}

        def screen_now(t: EffectTest, rnd: int = rnd, current: DiagnosisFit = current,
                       screens: dict[int, Any] = screens) -> None:
            try:
                _, args, t_spec, t_disc = planned(t, None)
            except Exception:  # raised again when (if) it is fitted
                return
            scr, prep = screen_candidate(args, current, st.threshold)
            _log.info("round %d: %s", rnd, scr)
            screens[id(t)] = (scr, prep, t_spec, t_disc)

        if st.screen:
            # the catalogue's blocks up front; a smooth term or a line only when the
            # budget would end the round before it; never the shape correction or
            # coloured noise. Those screens cost most (on the demo 47 s for the shape
            # and for the smooth term, 2-6 s for a block) and the shape's ended
            # unreliable
            for t in candidates:
                if t.effect in PAIRABLE:
                    screen_now(t)
        rejected = {i for i, (scr, *_) in screens.items() if scr.rejects}

        def attempt(test: EffectTest, rnd: int = rnd, current: DiagnosisFit = current,
                    on: tuple[DiagnosisFit, str, str | None] | None = None,
                    screens: dict[int, Any] = screens
                    ) -> tuple[DiagnosisFit, DiagnosisStep, str, str | None]:
            # the result is judged against the current fit, whatever it augments
            key, args, new_spec, new_disc = planned(test, on)
            prep = screens[id(test)][1] if on is None and id(test) in screens else None
            cand = fit(args, key, prep)
            warnings.extend(w for w in cand.warnings if w not in warnings)
            return cand, judge(rnd, test, current, cand, st), new_spec, new_disc

        def prefetch(tests: Sequence[EffectTest],
                     on: tuple[DiagnosisFit, str, str | None] | None = None) -> None:
            # the first of ``tests`` the workers do not hold yet, while they have room
            for t in tests:
                if pool.pending >= pool.n_workers:
                    break
                try:
                    key, args, _, _ = planned(t, on)
                except Exception:  # raised again when (if) it is fitted
                    continue
                pool.submit(key, *args)

        accepted, refitted, challenged, paired = None, 0, False, False
        tried: list[tuple[EffectTest, Any, DiagnosisStep, str, str | None]] = []
        guesses = speculative([t for t in candidates if id(t) not in rejected],
                              unexplained, st.max_candidates)
        reached: list[EffectTest] = []

        def pair_up(tried: list[Any] = tried, current: DiagnosisFit = current,
                    candidates: list[EffectTest] = candidates, rnd: int = rnd,
                    unexplained: EffectTest | None = unexplained,
                    attempt: Callable[..., Any] = attempt) -> Any:
            # two rejected effects fitted together (candidates.pair_for), or None
            nonlocal challenged
            untried = [t for t in candidates if all(t is not u for u, *_ in tried)]
            pick = pair_for([(t, c, s) for t, c, s, _, _ in tried], untried, current,
                            PAIRABLE)
            while pick is not None and isinstance(tried[pick[0]][1], ScreenedFit):
                # the pair builds on the first effect's fit: a screened first is sampled
                # now, its step becomes the fit's (kept if the fit passes after all),
                # and the pair is chosen again on the fit's own numbers
                test_a, _, screened, _, _ = tried[pick[0]]
                steps.remove(screened)
                fitted, ran = credited(test_a.effect, attempt(test_a), unexplained,
                                       lambda u=unexplained: attempt(u), st.threshold,
                                       steps, rnd)
                challenged |= ran
                tried[pick[0]] = (test_a, *fitted)
                if fitted[1].accepted:
                    return fitted[0], fitted[2], fitted[3], (fitted[1].effect,)
                # the same first, on its fit's own numbers (another screened first would
                # be sampled in turn for a gain the screen already weighed)
                pick = pair_for([(t, c, s) for t, c, s, _, _ in tried], untried,
                                current, PAIRABLE, first=pick[0])
            if pick is None:
                return None
            _, fit_a, _, spec_a, disc_a = tried[pick[0]]
            if speculative([pick[1]], unexplained, 1)[1:]:
                # the pair's challenger, fitted on the first effect's fit as the pair is,
                # is needed when the pair passes its gate: likely, as a pair is tried
                # only when each effect explains cycles the other loses on
                prefetch([unexplained], on=(fit_a, spec_a, disc_a))
            out = try_pair(tried[pick[0]], pick[1], current, attempt, unexplained,
                           st.threshold, steps, rnd)
            pool.discard()
            return out

        for test in candidates:
            if (refitted >= st.max_candidates and st.screen and id(test) not in screens
                    and test.effect not in _LAST_RESORTS):
                # a smooth term or a line past the budget: screened now, to be sampled
                # if it may pass (within the budget it is sampled without a screen)
                screen_now(test)
            if refitted >= st.max_candidates and not (
                    id(test) in screens and screens[id(test)][0].passes):
                # past the budget only what the screen judged able to pass is sampled
                if not st.screen:
                    break
                continue
            if test is unexplained and challenged:
                continue  # already fitted as a challenger this round
            if not paired and test.effect in _LAST_RESORTS and any(
                    t.effect in PAIRABLE for t, *_ in tried):
                # the last resorts (the shape correction, coloured noise) come after two
                # physical effects that each lost alone, fitted together. Without the
                # screen the round's budget usually ended it before them; with it every
                # block is weighed, and the shape correction, which can take up a
                # block's structure, must not pre-empt the pair (on the demo it did:
                # kept in round 2 where delay + creep had been, and creep never found)
                paired = True
                pool.discard()
                accepted = pair_up()
                if accepted is not None:
                    break
            if id(test) in screens and screens[id(test)][0].rejects:
                # decided by the screen: its numbers are the step's; it does not use up
                # the round's budget, and a pair may still build on it (fitted then)
                scr, _, t_spec, t_disc = screens[id(test)]
                step = screened_step(rnd, test, current, scr, st.threshold)
                steps.append(step)
                tried.append((test, ScreenedFit(scr.label, scr.loo.pointwise), step,
                              t_spec, t_disc))
                _log.info("round %d: %s %s", rnd, test.effect, step.verdict())
                continue
            # the workers fit what may come after this one while it is fitted (or taken)
            reached.append(test)
            prefetch([t for t in guesses if all(t is not u for u in reached)])
            cand, step, new_spec, new_disc = attempt(test)
            tried.append((test, cand, step, new_spec, new_disc))
            if step.refused:
                # the structure is real, this explanation of it is not: the next
                # candidate gets its turn without using up the round's budget
                warnings.append(f"{test.effect}: {step.reason}")
            else:
                refitted += 1
                if step.decided_by == NOT_CONVERGED:
                    warnings.append(f"{test.effect}: {step.reason}")
            (cand, step, new_spec, new_disc), ran = credited(
                test.effect, (cand, step, new_spec, new_disc), unexplained,
                lambda u=unexplained: attempt(u), st.threshold, steps, rnd)
            challenged |= ran
            if step.accepted:
                accepted = (cand, new_spec, new_disc, (step.effect,))
                break
        pool.discard()  # what the workers guessed and the loop did not reach
        if accepted is None and not paired:
            accepted = pair_up()
        if accepted is None:
            break
        current, spec, disc, effects = accepted
        found.extend(effects)
        rounds.append(current.analysis)
    # an effect kept in a later round, or one whose refit on top of the shape correction
    # passed its gate (a refused reading too), explains something beyond the loop
    # position: no longer a tie with the shape
    untied = set(found) | explained_beyond_shape(steps)
    return DiagnosisResult(base.label, current.label, tuple(found), tuple(steps), base,
                           current, tuple(rounds), st, tuple(warnings),
                           shape_tie_notes({e: p for e, p in shape_ties.items()
                                             if e not in untied})
                           + column_tie_notes({e: v for e, v in column_ties.items()
                                               if e not in found}))


