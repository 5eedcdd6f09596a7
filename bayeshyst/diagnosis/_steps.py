"""The pieces of a diagnosis round: the candidate's model, its credit, a pair, the guesses.

:func:`~bayeshyst.diagnosis.loop.diagnose` runs the rounds; this module builds what a
round fits (:func:`augmented`), credits a kept effect against a smooth term in time
(:func:`credited`), fits two effects together when each lost alone (:func:`try_pair`),
and says which fits the prefetcher may start early (:func:`speculative`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.diagnosis.candidates import (
    BRANCH_SHAPE,
    DISTURBANCE,
    SHAPE_DISCREPANCY,
    UNEXPLAINED,
)
from bayeshyst.diagnosis.catalogue import EFFECTS, get_effect
from bayeshyst.diagnosis.effects import ColoredNoise, insert_after_base
from bayeshyst.diagnosis.records import DiagnosisFit, DiagnosisStep
from bayeshyst.diagnosis.residual import EffectTest
from bayeshyst.diagnosis.verdict import SLOW_IN_TIME
from bayeshyst.discrepancy import DISC, Discrepancy
from bayeshyst.inference.posterior import Posterior
from bayeshyst.models.base import HysteresisModel
from bayeshyst.models.blocks import Disturbance, Unexplained
from bayeshyst.models.blocks.smooth import TIME
from bayeshyst.models.compose import Composite
from bayeshyst.selection import paired_difference

__all__ = ["PAIRABLE", "Fitted", "augmented", "before_noise", "candidate_discrepancy",
           "credited", "speculative", "try_pair"]

_log = logging.getLogger("bayeshyst.diagnosis.loop")


def candidate_discrepancy(below: Posterior, disc: str | None) -> str | Discrepancy | None:
    """The discrepancy a candidate is fitted with, given the posterior it augments.

    On top of a shape correction the candidate keeps that very correction -- its basis
    kept off the sensitivities of the model it was added to -- so that the augmented
    model nests the current one (its new parameters at their null value give the same
    density). Re-anchored at the augmented model, the correction would lose the
    direction of every added parameter whether the data use it or not (a delay at
    ``d = 0`` moves the output one way only), and the gate would compare two different
    corrections: on the MR damper at 0.75 A every round-4 candidate raised the in-sample
    RMSE (67.4 -> 71.6-77.5 N) and lost 175-379 nats of held-out density that way.
    ``disc`` (a kind, ``"hsgp"``) is used when ``below`` has none: the shape candidate.
    """
    if disc is not None and below.discrepancy is not None:
        return below.discrepancy
    return disc


def before_noise(candidates: Sequence[EffectTest]) -> int:
    """Where a structural candidate goes: before coloured noise, which only blurs it."""
    noise = [i for i, t in enumerate(candidates) if t.effect == ColoredNoise.name]
    return noise[0] if noise else len(candidates)


def augmented(test: EffectTest, current: DiagnosisFit, spec: str, disc: str | None,
               data: Dataset) -> tuple[HysteresisModel, str, str, str | None,
                                       tuple[DiagnosisFit, dict[str, Any]]]:
    """The model ``test`` proposes: (model, likelihood, spec, discrepancy, warm start)."""
    if test.effect == BRANCH_SHAPE:
        # start where the current fit is, with the shape correction at zero
        return (current.model, current.likelihood, spec, SHAPE_DISCREPANCY,
                (current, {f"{DISC}.xi": 0.0}))
    if test.effect == UNEXPLAINED:
        return (Composite(current.model, (Unexplained(feature=test.variant),)),
                current.likelihood, f"{spec}+unexplained(feature={test.variant})", disc,
                (current, {}))
    if test.effect == DISTURBANCE:
        blk = Disturbance(frequency_hz=float(test.variant))
        return (Composite(current.model, (blk,)), current.likelihood,
                f"{spec}+disturbance(frequency_hz={blk.frequency_hz!r})", disc, (current, {}))
    eff = get_effect(test.effect)
    new_model, new_lik, suffix = eff.augment(current.model, current.likelihood, test.coef,
                                             data, variant=test.variant)
    if suffix.startswith(" "):  # the likelihood changed, not the model
        new_spec = spec
    elif (isinstance(new_model, Composite) and isinstance(current.model, Composite)
          and new_model.blocks[1:] == current.model.blocks):
        new_spec = insert_after_base(spec, suffix)  # placed before the existing blocks
    else:
        new_spec = spec + suffix
    return (new_model, new_lik, new_spec, disc,
            (current, eff.initial(test.coef, test.estimates)))


def _challenge(step: DiagnosisStep, cand: DiagnosisFit, alt_step: DiagnosisStep,
               alt: DiagnosisFit, threshold: float) -> tuple[DiagnosisStep, DiagnosisStep]:
    """A kept effect that follows slow structure against a smooth term in time in its place.

    The smooth term wins only when it passed the gate itself and its held-out elpd beats
    the effect's by more than ``threshold`` standard errors; otherwise the physical
    effect, the simpler reading, is kept. Returns both steps with their verdicts.
    """
    d, se = paired_difference(alt.pointwise_elpd, cand.pointwise_elpd)
    versus = f"held-out elpd {d:+z.1f} (se {se:.1f}) against {step.effect}"
    if alt_step.accepted and math.isfinite(se) and d > threshold * se and d > 0:
        return (replace(step, accepted=False,
                        reason=f"{step.reason}; but a smooth term in time explains the "
                        f"residual better ({versus}): {step.effect} is not credited"),
                replace(alt_step, reason=f"{alt_step.reason}; beats {step.effect}: {versus}"))
    why = "not better" if alt_step.accepted else "not kept on its own"
    return step, replace(alt_step, accepted=False,
                         reason=f"{alt_step.reason}; {why} than {step.effect} ({versus}, "
                         f"needs > {threshold:g} x se): the physical effect is kept")


#: A fitted candidate: the fit, its step, its spec and its discrepancy (or None).
Fitted = tuple[DiagnosisFit, DiagnosisStep, str, "str | None"]


def credited(effect: str, fitted: Fitted, unexplained: EffectTest | None,
              challenger: Callable[[], Fitted], threshold: float, steps: list[DiagnosisStep],
              rnd: int) -> tuple[Fitted, bool]:
    """Record a fitted candidate's step, after its challenge when one is due.

    When the scan says the residual follows time, an accepted effect that can follow
    slow structure is credited only if it explains it at least as well as a generic
    smooth term in time (``challenger()`` fits that term in its place; it cannot be read
    physically). Returns the winner and whether the challenger was fitted.
    """
    cand, step, _, _ = fitted
    ran = bool(step.accepted and effect in SLOW_IN_TIME and unexplained is not None
               and unexplained.variant == TIME)
    if ran:
        alt, alt_step, alt_spec, alt_disc = challenger()
        step, alt_step = _challenge(step, cand, alt_step, alt, threshold)
        steps += [step, alt_step]  # in the order they were fitted
        if alt_step.accepted:
            _log.info("round %d: %s beaten by %s", rnd, effect, UNEXPLAINED)
            fitted = (alt, alt_step, alt_spec, alt_disc)
        else:
            fitted = (cand, step, fitted[2], fitted[3])
    else:
        steps.append(step)
    _log.info("round %d: %s %s", rnd, fitted[1].effect, fitted[1].verdict())
    return fitted, ran


#: Effects :func:`pair_for` may fit together: the catalogue's blocks (the noise model
#: changes the likelihood, and the scan-judged candidates have their own gate)
PAIRABLE = tuple(e for e in EFFECTS if e != ColoredNoise.name)


def try_pair(first: tuple[EffectTest, DiagnosisFit, DiagnosisStep, str, str | None],
              partner: EffectTest, current: DiagnosisFit, attempt: Callable[..., Fitted],
              unexplained: EffectTest | None, threshold: float, steps: list[DiagnosisStep],
              rnd: int) -> tuple[DiagnosisFit, str, str | None, tuple[str, ...]] | None:
    """Fit ``partner`` on top of the rejected ``first`` candidate and gate the pair.

    The pair is judged against the round's current fit like any candidate, and credited
    to both effects. A partner that can follow slow structure is challenged by a smooth
    term in time in its place, as a single effect is. Appends the steps it takes.
    """
    test_a, fit_a, _, spec_a, disc_a = first
    lost = int(np.sum(fit_a.pointwise_elpd < current.pointwise_elpd))
    n = current.pointwise_elpd.size
    why = (f"fitted together, neither having passed alone ({test_a.effect} lost on {lost} "
           f"of {n} held-out cycles: one noise scale serves every cycle, and it tightens "
           f"where {test_a.effect} fits)")

    def on_first(test: EffectTest, label: str) -> Fitted:
        # fitted on top of the first effect's fit, named as the pair
        cand, step, spec, disc = attempt(test, on=(fit_a, spec_a, disc_a))
        return cand, replace(step, effect=label, reason=f"{why}; {step.reason}"), spec, disc

    (cand, step, new_spec, new_disc), _ = credited(
        partner.effect, on_first(partner, f"{test_a.effect}+{partner.effect}"), unexplained,
        lambda: on_first(unexplained, f"{test_a.effect}+{UNEXPLAINED}"), threshold, steps,
        rnd)
    # the step names the pair kept: the partner, or the smooth term that beat it
    return (cand, new_spec, new_disc, tuple(step.effect.split("+"))) if step.accepted else None


def speculative(candidates: Sequence[EffectTest], unexplained: EffectTest | None,
                 budget: int) -> list[EffectTest]:
    """A round's fits on the current fit that the serial loop may need, in its order.

    The candidates within the round's ``budget`` (``max_candidates``; the first is
    sure to be needed, each later one when every one before it was rejected or refused)
    and, right after the first that can follow slow structure, the smooth term in time
    that would challenge it when it passes its gate (:func:`credited`). A refused
    candidate does not use up the budget: what the serial loop fits beyond it is not
    guessed and is fitted when it is reached.
    """
    challenger = unexplained if unexplained is not None and unexplained.variant == TIME \
        else None
    out: list[EffectTest] = []
    for t in candidates[:budget]:
        for u in (t, challenger if t.effect in SLOW_IN_TIME else None):
            if u is not None and all(u is not v for v in out):
                out.append(u)
    return out
