"""Screening a candidate effect from its MAP: the full fit runs only where it can decide.

Every catalogue block whose residual test fires is screened before any candidate is
sampled, a smooth term or a spectral line when the round's budget would end the round
before it (the shape correction and coloured noise are not screened: they come after
the blocks and their pair, and the shape's screen is the costliest and least often
reliable). A screen is the augmented posterior's MAP (the search the sampler would
start from, warm-started at the current fit) and its held-out score without chains,
:func:`~bayeshyst.diagnostics.laplace_loo.laplace_loo` (Laplace draws importance-
corrected to the posterior and to each leave-one-cycle-out posterior). Against the
current fit's cycle-wise elpd this gives the gate's change ``d`` and its standard error
``se`` at a few hundredths of a full fit's cost.

A screen **rejects** a candidate only when it can stand in for the full fit and the
gate fails even with the screen's error given to the candidate:

* every Pareto ``k`` of the screen is at most 0.7 (:attr:`LaplaceLoo.reliable`);
* the gate has its cycles (at least ``MIN_GATE_UNITS``): the scan- and BIC-judged
  fallbacks rest on the fit itself and are never screened;
* ``d + margin`` does not pass: ``d + margin <= threshold * se`` or ``d + margin <=
  MIN_ELPD_GAIN``, where ``margin`` bounds the screen's error in ``d``: 0.1 nat per
  cycle with ``k <= 0.5`` and 1 nat per cycle with ``0.5 < k <= 0.7``, the errors
  measured against the exact leave-one-out of a conjugate posterior
  (``tests/test_laplace_loo.py``: at most 0.04 and 0.7 nat over six seeds).

Anything else is sampled and judged as before: the screen never accepts, it only spares
the full fits of candidates that would lose. A candidate the screen judged and did not
reject (:attr:`CandidateScreen.passes`) is sampled whatever the round's budget
(``max_candidates``): a round does not end with such a candidate untried. The budget
bounds the candidates the screen could not judge. A rejected candidate's step says it was
decided by the screen (``decided_by`` :data:`SCREEN`) with the screen's numbers.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bayeshyst.diagnosis._fitting import Prepared, prepare_fit
from bayeshyst.diagnosis.records import DiagnosisFit, DiagnosisStep
from bayeshyst.diagnosis.residual import EffectTest
from bayeshyst.diagnosis.verdict import MIN_GATE_UNITS, SCREEN, passes_gate
from bayeshyst.diagnostics.laplace_loo import LaplaceLoo, laplace_loo
from bayeshyst.inference.fit import TrackingError, tracking_errors
from bayeshyst.selection.ranking import paired_difference
from bayeshyst.tables import TableRecord, frame
from bayeshyst.threads import with_single_threaded_blas

__all__ = ["SCREEN", "SCREEN_DRAWS", "CandidateScreen", "ScreenedFit", "screen_candidate",
           "screened_step"]
#: Proposal draws of a screen (two posterior evaluations each).
SCREEN_DRAWS = 1000
#: Bound on one cycle's screen error (nats) by its Pareto k: (largest k, bound).
ERROR_BOUNDS = ((0.5, 0.1), (0.7, 1.0))


@dataclass(frozen=True)
class CandidateScreen(TableRecord):
    """A candidate's held-out score from its MAP, against the current fit.

    Attributes
    ----------
    label : str
        The candidate fit's label.
    loo : LaplaceLoo
        Its leave-one-cycle-out from the MAP.
    delta_elpd, delta_se : float
        The gate's change against the current fit and its standard error (nats).
    margin : float
        Bound on the screen's error in ``delta_elpd`` (nats), from the cycles' k.
    rejects : bool
        Whether the candidate loses its gate even with ``margin`` in its favour (and
        the screen can stand in for the fit).
    overall : TrackingError
        The MAP's tracking error.
    per_frequency : tuple of TrackingError
    seconds : float
        Wall time of the screen (the MAP search included).
    """

    label: str
    loo: LaplaceLoo
    delta_elpd: float
    delta_se: float
    margin: float
    rejects: bool
    overall: TrackingError
    per_frequency: tuple[TrackingError, ...]
    seconds: float

    @property
    def judged(self) -> bool:
        """Whether the screen could judge: reliable, with the gate's cycles, finite."""
        return bool(self.loo.reliable and self.loo.pointwise.size >= MIN_GATE_UNITS
                    and math.isfinite(self.delta_elpd) and math.isfinite(self.delta_se)
                    and math.isfinite(self.margin))

    @property
    def passes(self) -> bool:
        """Judged and not rejected: the gate may pass (the fit decides)."""
        return self.judged and not self.rejects

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (NaN and inf as None)."""
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None
        return {"label": self.label, "delta_elpd": num(self.delta_elpd),
                "delta_se": num(self.delta_se), "margin": num(self.margin),
                "rejects": self.rejects, "worst_k": num(self.loo.worst_k),
                "reliable": self.loo.reliable, "rmse": num(self.overall.rmse),
                "seconds": round(self.seconds, 3)}

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])

    def __str__(self) -> str:
        verdict = "rejects" if self.rejects else "leaves it to the fit"
        return (f"screen of {self.label}: held-out elpd {self.delta_elpd:+.1f} (se "
                f"{self.delta_se:.1f}, error <= {self.margin:.1f}); worst Pareto k "
                f"{self.loo.worst_k:.2f}; {verdict} ({self.seconds:.1f} s)")


@dataclass(frozen=True)
class ScreenedFit:
    """What a screened-out candidate brings to the pairing of a round: its cycle-wise elpd.

    :func:`~bayeshyst.diagnosis.candidates.pair_for` reads ``pointwise_elpd`` only; a
    screened candidate chosen as a pair's first effect is sampled before the pair is.
    """

    label: str
    pointwise_elpd: np.ndarray


def _margin(k: np.ndarray) -> float:
    """Bound on the summed error of the cycles' screened elpd (inf if any k > 0.7)."""
    out = 0.0
    for kk in np.asarray(k, dtype=float):
        bound = next((b for top, b in ERROR_BOUNDS if kk <= top), math.inf)
        out += bound
    return out


@with_single_threaded_blas
def screen_candidate(args: tuple[Any, ...], current: DiagnosisFit, threshold: float
                     ) -> tuple[CandidateScreen, Prepared]:
    """Screen the fit :func:`~bayeshyst.diagnosis._fitting.diagnosis_fit` would make of ``args``.

    Parameters
    ----------
    args : tuple
        ``diagnosis_fit``'s positional arguments (data, model, likelihood, label,
        settings, checkpoint folder, warm start, discrepancy).
    current : DiagnosisFit
        The fit the candidate is judged against (its cycle-wise elpd).
    threshold : float
        The gate's multiple of the standard error.

    Returns
    -------
    (CandidateScreen, Prepared)
        The screen, and the posterior and MAP it found (the full fit reuses them).
    """
    t0 = time.perf_counter()
    data, model, likelihood, label, st, ckdir = args[:6]
    warm = args[6] if len(args) > 6 else None
    disc = args[7] if len(args) > 7 else None
    prep = prepare_fit(data, model, likelihood, st, ckdir, warm, disc, search=True)
    loo = laplace_loo(prep.post, prep.start, n_draws=SCREEN_DRAWS, seed=prep.sampler.seed)
    d, se = paired_difference(loo.pointwise, current.pointwise_elpd)
    margin = _margin(loo.pareto_k)
    overall, per, _ = tracking_errors(prep.post, prep.start.z[None, :])
    scr = CandidateScreen(label, loo, d, se, margin, False, overall, tuple(per),
                          time.perf_counter() - t0)
    rejects = scr.judged and not passes_gate(d + margin, se, threshold)
    return replace(scr, rejects=bool(rejects)), prep


def screened_step(rnd: int, test: EffectTest, current: DiagnosisFit,
                  screen: CandidateScreen, threshold: float) -> DiagnosisStep:
    """The step of a candidate the screen rejected: no full fit, the screen's numbers."""
    reason = (f"screened out at its MAP: held-out elpd changes by {screen.delta_elpd:z.1f} "
              f"(se {screen.delta_se:.1f}; the screen's error at most "
              f"{screen.margin:.1f}), not above {threshold:g} x se even with that error; "
              f"Laplace-PSIS leave-one-out, worst Pareto k {screen.loo.worst_k:.2f}; "
              f"not sampled")
    per = tuple(zip(current.per_frequency, screen.per_frequency, strict=True))
    return DiagnosisStep(rnd, test.effect, test, current.label, screen.label, False, reason,
                         current.overall, screen.overall, per, screen.delta_elpd,
                         screen.delta_se, (), True, (), "", SCREEN)
