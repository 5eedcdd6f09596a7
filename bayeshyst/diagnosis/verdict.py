"""Honest verdicts of the closed loop: ties, plausibility, undecidable gates, what is left.

* **Ties.** Two effects whose score tests' Bayes factors lie within
  :data:`TIE_NATS` of each other explain the same residual within the evidence's
  resolution (3 nats: a Bayes factor of 20, Kass & Raftery 1995's "strong" boundary).
  Under one sine, creep, a first-order lag and a delay are the same phase lag; a
  branch-shape error of the hysteresis model is another copy of it (the driver scan
  says so when the loop position and the time since a reversal tie). The report says
  "cannot tell A from B on these data" and names the experiment that would.
  One sine without holds cannot tell creep, a lag and a delay apart at all, whatever the
  Bayes factors say (:func:`separates_lags`): an accepted lag-like effect is then tied
  with every other that fired.
* **Plausibility.** An accepted effect whose physical reading is outside the range a
  piezo stage can have (:data:`PLAUSIBLE`, overridable) is a warning, not a finding.
  The verdict still says what such a reading would have explained
  (:func:`refused_findings`): the structure is real, only this explanation of it is not.
* **Resolution.** So is a resonance the data cannot see (:func:`unresolved`): a natural
  frequency whose whole credible interval lies above the fastest record's Nyquist
  frequency.
* **Convergence.** A gate whose augmented fit did not converge decides nothing: the
  step is *not decided* (:data:`NOT_CONVERGED`), not accepted and not rejected, and the
  loop goes on to the next candidate. Only the resolution can be read without it
  (:func:`unresolved_throughout`, ``decided_by`` :data:`BY_RESOLUTION`): a resonance
  above Nyquist in every ensemble is no finding however long it is sampled.
* **Negligible gains.** A held-out elpd gain under :data:`MIN_ELPD_GAIN` (4 nats) is
  not an improvement, however small its standard error.
* **Gates that cannot decide.** The held-out elpd gate compares cycles; with fewer
  than :data:`MIN_GATE_UNITS` its standard error says nothing, so the loop falls back
  to the score test's BIC Bayes factor against :data:`FALLBACK_LOG_BF` ("very strong")
  and says so.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np

from bayeshyst.diagnosis.drivers import DriverScan
from bayeshyst.models.base import sample_period

__all__ = [
    "BRANCH_SHAPE",
    "BY_RESOLUTION",
    "FALLBACK_LOG_BF",
    "LAG_LIKE",
    "MIN_ELPD_GAIN",
    "MIN_GATE_UNITS",
    "NOT_A_FINDING",
    "NOT_CONVERGED",
    "PLAUSIBLE",
    "SLOW_IN_TIME",
    "TIE_NATS",
    "TIME_DOMAIN",
    "column_tie_notes",
    "column_tied",
    "experiment_for",
    "explained_beyond_shape",
    "implausible",
    "passes_gate",
    "refused_findings",
    "separates_lags",
    "shape_tie_notes",
    "shape_tied",
    "tied_beyond",
    "tied_effects",
    "unresolved",
    "unresolved_throughout",
]

#: Bayes factors closer than this (nats) do not tell two effects apart.
TIE_NATS = 3.0
#: Fewest held-out cycles with which the elpd gate's standard error means anything.
MIN_GATE_UNITS = 8
#: Smallest held-out elpd gain (nats) that counts as an improvement, however small its
#: standard error: below 4 nats two models' predictive performance is the same for
#: practical purposes and the normal approximation of the difference is unreliable
#: (Sivula, Magnusson, Matamoros & Vehtari 2020). On the MR damper creep was kept for
#: +0.7 ± 0.1 nats with the RMSE unchanged to the fourth digit.
MIN_ELPD_GAIN = 4.0


def passes_gate(d: float, se: float, threshold: float) -> bool:
    """Whether a held-out elpd change passes the gate.

    ``d`` (nats) must exceed ``threshold`` standard errors ``se`` and
    :data:`MIN_ELPD_GAIN`; the candidates' judge and the screen use this one rule.
    """
    return bool(d > threshold * se and d > MIN_ELPD_GAIN)


#: Log Bayes factor the score test must reach when the elpd gate cannot decide
#: (Kass & Raftery 1995: above 5 is "very strong").
FALLBACK_LOG_BF = 5.0

#: Effects that act as a phase lag under one periodic excitation.
LAG_LIKE = ("creep", "delay", "rate_dependence")
#: Effects credited with structure in time rather than in where on the loop.
TIME_DOMAIN = (*LAG_LIKE, "drift", "change_point")
#: Effects whose output can follow slow structure over the record (a creep's log-time
#: response, a ramp, a step): when the residual follows time, each must explain it at
#: least as well as a generic smooth term in time to be credited (a delay or a lag
#: cannot mimic such structure and are not challenged).
SLOW_IN_TIME = ("creep", "drift", "change_point")

#: Plausible posterior means of an added block's parameters on a piezo stage:
#: ``parameter -> (low, high, why)``. A delay beyond 2 ms is not a piezo amplifier
#: and sensor chain (tens of microseconds to a millisecond); a resonance below 10 Hz
#: is not a stage's; creep gains beyond 50 % of the output are not creep.
PLAUSIBLE: Mapping[str, tuple[float, float, str]] = MappingProxyType({
    "delay.d": (0.0, 2e-3, "a piezo amplifier and sensor chain delays by at most ~2 ms"),
    "second_order.f_n": (10.0, 1e6, "a piezo stage resonates between 10 Hz and 1 MHz"),
    "creep.c": (-0.5, 0.5, "creep moves the output by less than half its static value"),
})
#: How the reason of a gate that passed but is not a finding begins: a reading outside
#: the device's range (:func:`implausible`) or outside what the data resolve
#: (:func:`unresolved`). The structure is real; this explanation of it is not.
NOT_A_FINDING = ("implausible", "unresolved")
#: ``decided_by`` of a step whose augmented fit did not converge: neither kept nor
#: rejected, because either decision would rest on draws that are not yet the posterior.
NOT_CONVERGED = "not converged"
#: ``decided_by`` of a step refused as unresolved on an unconverged fit
#: (:func:`unresolved_throughout`): the gate decided nothing, the resolution did.
BY_RESOLUTION = "resolution"
#: ``decided_by`` of a candidate the screen rejected from its MAP, without sampling it
#: (:mod:`bayeshyst.diagnosis.screen`).
SCREEN = "screen"


#: Name of the base model's own misfit among the loop's candidates.
BRANCH_SHAPE = "branch shape"


def experiment_for(a: str, b: str) -> str:
    """The experiment that separates effects (or drivers) ``a`` and ``b``."""
    pair = {a, b}
    if "creep" in pair or BRANCH_SHAPE in pair:
        return ("steps with holds of several seconds (creep keeps moving while the input "
                "holds; a lag, a delay or a branch shape does not) and several excitation "
                "frequencies")
    if pair <= {"delay", "rate_dependence"}:
        return ("several excitation frequencies (a delay's phase lag grows in proportion "
                "to frequency, dynamics' does not)")
    return "records at several frequencies and amplitudes, with steps and holds"


def tied_effects(accepted: str, tests: Iterable[Any]) -> list[str]:
    """Fired lag-like effects whose Bayes factor is within :data:`TIE_NATS` of ``accepted``'s."""
    tests = list(tests)
    by = {t.effect: t for t in tests if t.significant and not t.skipped}
    if accepted not in by or accepted not in LAG_LIKE:
        return []
    ref = by[accepted].log_bayes_factor
    return [n for n, t in by.items() if n != accepted and n in LAG_LIKE
            and math.isfinite(t.log_bayes_factor) and abs(t.log_bayes_factor - ref) < TIE_NATS]


#: A hold: the input still for at least this long (s) and this many samples.
HOLD_S, HOLD_SAMPLES = 0.05, 50


def separates_lags(data: Any) -> bool:
    """Whether the design can tell creep, a lag and a delay apart.

    Under one excitation frequency and no hold they are one phase lag, told apart only
    by its fine shape: at least two excitation frequencies (a delay's phase grows in
    proportion to frequency, a lag's does not) or a hold of the input (creep keeps
    moving while it holds, a lag settles, a delay shifts) are needed.
    """
    records = list(data)
    if len({r.frequency_hz for r in records if r.frequency_hz}) >= 2:
        return True
    for r in records:
        still = np.abs(np.diff(np.asarray(r.u, float))) <= 1e-9 * (float(np.ptp(r.u)) or 1.0)
        edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= HOLD_SAMPLES and float(r.t[b] - r.t[a]) >= HOLD_S:
                return True
    return False


def shape_tied(scan: DriverScan | None) -> bool:
    """Whether the scan cannot tell the loop position from a time since reversal or a rate."""
    if scan is None or not scan.found:
        return False
    lagged = {"time since reversal or hold", "input rate", "input acceleration"}
    for d in scan.selected:
        if d.driver == "loop position" and lagged & set(d.tied_with):
            return True
        if d.driver in lagged and "loop position" in d.tied_with:
            return True
    return False


def column_tied(tests: Sequence[Any], level: float) -> list[Any]:
    """The time-domain effects that explain nothing beyond the measured columns kept.

    A test whose ``p_beyond_columns`` (the score test with the scan's blocks of the
    columns it kept among the nuisance regressors) is not below ``level``: on these data
    the structure it fires on is a smooth dependence on a measured column (on one sine a
    rate is a function of the velocity, a slow trend one of a drifting temperature), and
    the column's own candidate (``aux``, ``unexplained(feature=column)``) is the more
    direct reading. NaN (no column kept) ties nothing.
    """
    return tied_beyond(tests, "p_beyond_columns", level)


def tied_beyond(tests: Sequence[Any], p_beyond: str, level: float) -> list[Any]:
    """The time-domain tests whose p-value beyond a nuisance is not below ``level``.

    ``p_beyond`` names the test's attribute: ``"p_beyond_shape"`` (the loop position
    among the nuisance regressors) or ``"p_beyond_columns"`` (the measured columns the
    scan kept). A p-value that was not computed (NaN) is no evidence of a tie.
    """
    return [t for t in tests if t.effect in TIME_DOMAIN
            and math.isfinite(getattr(t, p_beyond)) and getattr(t, p_beyond) >= level]


def _tie_sentence(names: Sequence[str], nuisance: str, beyond: str, experiment: str) -> str:
    """'cannot tell A, B from <nuisance> ... beyond <beyond>; what would: <experiment>'."""
    return (f"cannot tell {', '.join(names)} from {nuisance} on these data "
            f"({'they explain' if len(names) > 1 else 'it explains'} nothing beyond "
            f"{beyond}); what would: {experiment}")


def explained_beyond_shape(steps: Iterable[Any]) -> set[str]:
    """Effects whose refit on top of the shape correction passed its gate, kept or not.

    Such an effect explains structure beyond the loop position (its gate compared two
    fits that both carry the correction), so "cannot tell it from the branch shape" is
    no longer true of it, even when its reading was refused as implausible or
    unresolved. The micromanipulator's delay: tied with the shape on the base residual,
    then +1 109 (se 41) nats on top of the correction, a 33 ms reading refused.

    Parameters
    ----------
    steps : iterable of DiagnosisStep
        The loop's steps in the order tried (``effect``, ``accepted``, ``refused``).
    """
    out: set[str] = set()
    corrected = False
    for s in steps:
        if corrected and (s.accepted or s.refused):
            out.add(s.effect)
        corrected |= bool(s.accepted and s.effect == BRANCH_SHAPE)
    return out


def refused_findings(steps: Iterable[Any], judged_against: str) -> tuple[str, ...]:
    """What passed its gate against ``judged_against`` but is no finding, in words.

    One sentence per effect, from its last step judged against that fit (the final
    model's round): the reason it was refused, what it did to the error, and its held-out
    elpd change when the elpd gate decided. A refused reading is a warning, but the
    structure it explained is still there, so the verdict says how much. A step refused
    on an unconverged fit (:data:`BY_RESOLUTION`) passed no gate: its sentence gives only
    the reason.

    Parameters
    ----------
    steps : iterable of DiagnosisStep
    judged_against : str
        Label of the fit the steps were judged against (``model_before``).
    """
    last: dict[str, Any] = {}
    for s in steps:
        if s.model_before == judged_against:
            last[s.effect] = s
    out = []
    for effect, s in last.items():
        if not s.refused:
            continue
        if s.decided_by == BY_RESOLUTION:
            # its gate decided nothing (the fit did not converge): no claim that it
            # would explain anything, only why it is not credited
            out.append(f"{effect} is not credited: {s.reason}")
            continue
        gain = (f", held-out elpd {s.delta_elpd:+.1f} (se {s.delta_elpd_se:.1f})"
                if s.decided_by == "elpd" and math.isfinite(s.delta_elpd)
                and math.isfinite(s.delta_elpd_se) else "")
        out.append(f"{effect} would explain structure that is left (RMSE "
                   f"{s.before.rmse:.4g} -> {s.after.rmse:.4g}{gain}) but is not credited: "
                   f"{s.reason}")
    return tuple(out)


def column_tie_notes(ties: Mapping[str, tuple[float, Sequence[str]]]) -> tuple[str, ...]:
    """One sentence per set of columns that effects are tied with (``effect -> (p, columns)``)."""
    by_columns: dict[tuple[str, ...], list[str]] = {}
    for effect, (p, columns) in ties.items():
        by_columns.setdefault(tuple(columns), []).append(f"{effect} (p = {p:.2g})")
    return tuple(
        _tie_sentence(names, f"a dependence on {', '.join(columns)}",
                      "that column" if len(columns) == 1 else "those columns",
                      f"a record in which {', '.join(columns)} varies independently of the "
                      f"input and its rate")
        for columns, names in by_columns.items())


def shape_tie_notes(ties: Mapping[str, float]) -> tuple[str, ...]:
    """One sentence per experiment that would separate effects from the branch shape.

    ``ties`` maps an effect to the p-value of its test beyond the loop position.
    """
    by_experiment: dict[str, list[str]] = {}
    for effect, p in ties.items():
        by_experiment.setdefault(experiment_for(effect, BRANCH_SHAPE), []).append(
            f"{effect} (p = {p:.2g})")
    return tuple(_tie_sentence(names, "the base model's branch shape", "the loop position",
                               experiment)
                 for experiment, names in by_experiment.items())


def implausible(means: Mapping[str, Sequence[float] | float],
                ranges: Mapping[str, tuple[float, float, str]]) -> list[str]:
    """Readings outside their plausible range, in words (empty when all are plausible).

    Parameters
    ----------
    means : mapping
        Posterior means of the added parameters by full name (``"delay.d"``); vector
        parameters are checked entry by entry.
    ranges : mapping
        ``parameter -> (low, high, why)``.
    """
    out = []
    for name, (lo, hi, why) in ranges.items():
        if name not in means:
            continue
        raw = means[name]
        values = list(raw) if isinstance(raw, Sequence) else [float(raw)]
        bad = [v for v in values if not lo <= float(v) <= hi]
        if bad:
            out.append(f"{name} = {', '.join(f'{v:.3g}' for v in bad)} is outside "
                       f"[{lo:g}, {hi:g}] ({why})")
    return out


def unresolved(added: Sequence[Any], data: Any) -> list[str]:
    """Natural frequencies the data cannot resolve, in words (empty when all are resolved).

    A sampled record carries nothing above its Nyquist frequency ``fs / 2``. Below its
    resonance, second-order dynamics ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` are a phase
    lag ``2 zeta f / f_n`` and a gain roll-off ``(f / f_n)^2``, which a first-order lag
    or a delay also give: a resonance whose whole credible interval lies above the
    fastest record's Nyquist frequency is an extrapolation, not a reading, however
    narrow its interval. On the MR damper at 0.25 A (records sampled at 5-200 Hz) the
    gate kept second-order dynamics with ``f_n`` 248 Hz [234, 260] (+9.0 +- 3.2 nats);
    at 0.75 A the same block's posterior split between 32 Hz and 190 Hz. The structure
    such a block explains is a lag the data see; that it is a resonance they do not.

    Parameters
    ----------
    added : sequence of ParamSummary
        The added block's posterior summaries; natural frequencies are those whose name
        ends in ``.f_n`` (Hz).
    data : Dataset or Record
        The fitted data (their sample times give the Nyquist frequency).
    """
    if not any(p.label.endswith(".f_n") for p in added):
        return []  # no resonance: the records' sampling steps need not be read
    nyquist = 0.5 / sample_period(data)
    return [f"{p.label} = {p.mean:.3g} Hz ({p.prob:.0%} interval {p.hdi_lo:.3g}-"
            f"{p.hdi_hi:.3g} Hz) lies above every record's Nyquist frequency (at most "
            f"{nyquist:.3g} Hz): {_UNSEEN} {2.0 * p.hdi_hi:.3g} Hz, excited near it"
            for p in _above(added, nyquist)]


def unresolved_throughout(ensembles: Sequence[Sequence[Any]], data: Any) -> list[str]:
    """Natural frequencies above Nyquist in every ensemble of an unconverged posterior.

    An unconverged fit's gate decides nothing, but :func:`unresolved` need not wait for
    it: a resonance whose credible interval lies above the fastest record's Nyquist
    frequency in the last half of *every* ensemble is above it however the sampler
    ends up weighing those modes, so the block is no finding whatever its gate would
    say; a longer run could change that only by finding a mode below Nyquist that no
    ensemble has visited. (A resonance above Nyquist folds
    differently into each record's sampling rate, so its likelihood has several such
    modes, which the sampler weighs against each other only slowly: on the MR damper at
    1 A, ``f_n`` split between 150 and 293 Hz with split-R-hat 1.92 after 10 000 steps,
    every ensemble's 90 % interval above 148 Hz; at 0.25 A, with modes at 194 and 250 Hz,
    only a second run with 20 000 steps, hours on a shared core, converged.)

    Parameters
    ----------
    ensembles : sequence of sequence of ParamSummary
        Per ensemble, the summaries of the block's natural frequencies (labels ending in
        ``.f_n``, Hz), e.g. from :meth:`SamplingResult.ensemble_summaries`.
    data : Dataset or Record
        The fitted data (their sample times give the Nyquist frequency).

    Returns
    -------
    list of str
        One sentence per natural frequency above Nyquist in every ensemble (empty when
        any ensemble's interval reaches below it, or there are no ensembles).
    """
    if not ensembles:
        return []
    nyquist = 0.5 / sample_period(data)
    above = [{p.label: p for p in _above(e, nyquist)} for e in ensembles]
    out = []
    for label in above[0]:
        if not all(label in a for a in above):
            continue
        rows = [a[label] for a in above]
        spans = ", ".join(f"{p.hdi_lo:.3g}-{p.hdi_hi:.3g} Hz" for p in rows)
        top = max(p.hdi_hi for p in rows)
        out.append(f"{label} lies above every record's Nyquist frequency (at most "
                   f"{nyquist:.3g} Hz) in each of the {len(rows)} ensembles of a posterior "
                   f"that did not converge ({rows[0].prob:.0%} intervals over their last "
                   f"half: {spans}), however its modes end up weighted: {_UNSEEN} "
                   f"{2.0 * top:.3g} Hz, excited near it")
    return out


#: What an unresolved resonance is and what would resolve it (its rate follows).
_UNSEEN = ("the data see a lag below it, not a resonance; what would resolve it: records "
           "sampled faster than")


def _above(summaries: Sequence[Any], nyquist: float) -> list[Any]:
    """The natural frequencies (labels ending in ``.f_n``) whose interval is above ``nyquist``."""
    return [p for p in summaries if p.label.endswith(".f_n") and p.hdi_lo > nyquist]
