"""Effects driven by something other than the input: a measured column, a moment in time.

Both are tested, like every effect, by the score of the block that would add them
(:mod:`bayeshyst.diagnosis.effects`), but each has several *variants*: one per extra
column of the file (which column drives the gain?), one per candidate change time
(when did it change?). Every variant is tested; the effect's p-value is the best
variant's times their number (Bonferroni), and its BIC Bayes factor averages the
variants' under a uniform prior over them, ``log mean_k exp(log BF_k)``: a search over
many variants pays for itself in both.

============== ================================== ================================= ========
effect         regressors (per variant)            augmentation                      source
============== ================================== ================================= ========
aux            ``w z``, ``z``;                     ``+aux(column=c)``                review §3
               ``z = (c - mean) / sd`` of column c
change_point   ``w S``, ``S``; ``S`` the step at   ``+change_point``                 —
               ``t_c`` on a grid of the record
============== ================================== ================================= ========
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import numpy as np

from bayeshyst.diagnosis.effects import Effect, RecordSignals
from bayeshyst.models.blocks.base import time_scales
from bayeshyst.models.blocks.external import AuxInput, ChangePoint, change_step, column_scales
from bayeshyst.models.compose import Composite

__all__ = ["AuxEffect", "ChangePointEffect", "Variant"]

#: Candidate change times per test (evenly over the scored time, 5 % kept from the ends).
N_CHANGE_TIMES = 24

Variant = tuple[str, np.ndarray, np.ndarray]


def _stack(sigs: Sequence[RecordSignals], f: Any) -> np.ndarray:
    return np.concatenate([np.asarray(f(s))[s.s0:] for s in sigs])


class AuxEffect(Effect):
    """A gain and offset that follow a measured column (temperature, load, a second sensor).

    One variant per column every record carries (``Record.covariates``) that the model
    does not read yet. Regressors ``w z`` and ``z`` of
    :class:`~bayeshyst.models.blocks.AuxInput` (order 1); physical reading in per cent
    of gain per unit of the column.
    """

    name = "aux"
    description = "gain and offset follow a measured column of the file (temperature, load)"
    evidence_label = "the column (its own unit)"

    def regressors(self, rec, data):
        """Not used directly: the effect has one variant per column (:meth:`variants`)."""
        raise TypeError("aux is tested per column (variants)")

    def variants(self, sigs, data, model):
        """``(column, regressors, the column)`` for every column the model does not read."""
        records = list(data)
        shared = [c for c in records[0].covariates
                  if all(c in r.covariates for r in records) and c not in model.covariates]
        out = []
        w = _stack(sigs, lambda s: s.w)
        for c in shared:
            ref, scale = column_scales(data, c)
            column = np.concatenate([np.asarray(r.covariates[c], float)[s.s0:]
                                     for r, s in zip(records, sigs, strict=True)])
            z = (column - ref) / scale
            if np.ptp(z) <= 0:
                continue
            out.append((c, np.column_stack([w * z, z]), column))
        return out

    def augment(self, model, likelihood, coef, data, variant=""):
        """Append ``aux(column=variant)``."""
        blk = AuxInput(column=variant)
        return Composite(model, (blk,)), likelihood, f"+aux(column={variant!r})"

    def initial(self, coef, estimates):
        """``aux.g`` and ``aux.h`` at the score coefficients (per sd of the column)."""
        return {"aux.g": np.asarray(coef[:1], float), "aux.h": np.asarray(coef[1:2], float)}

    def interpret_variant(self, variant, coef, cov, data):
        """Gain change in per cent per unit of the column, offset change per unit."""
        _, scale = column_scales(data, variant)
        return {"gain_percent_per_unit": float(100.0 * coef[0] / scale),
                "offset_per_unit": float(coef[1] / scale),
                "gain_change_percent_per_sd": float(100.0 * coef[0])}


class ChangePointEffect(Effect):
    """A step in gain and offset at one moment: a load clamped on, a sensor re-mounted.

    Variants: :data:`N_CHANGE_TIMES` change times over the scored time span.
    Regressors ``w S`` and ``S`` of :class:`~bayeshyst.models.blocks.ChangePoint`.
    """

    name = "change_point"
    description = "gain and offset change once, at an unknown time (a load, a re-mount)"
    evidence_label = "time (s)"
    provided_by = ("change_point",)

    def regressors(self, rec, data):
        """Not used directly: one variant per change time (:meth:`variants`)."""
        raise TypeError("change_point is tested per change time (variants)")

    def variants(self, sigs, data, model):
        """``(time in s, regressors, t)`` for change times evenly over the scored span.

        None when the records are not on one clock (their times overlap, e.g. every
        record starting at 0): one change time would then mean different moments.
        """
        spans = sorted((float(s.t[0]), float(s.t[-1])) for s in sigs)
        if any(b[0] < a[1] for a, b in pairwise(spans)):
            return []
        t_all = _stack(sigs, lambda s: s.t)
        lo, hi = float(t_all.min()), float(t_all.max())
        width = 2.0 * time_scales(data).dt
        grid = lo + (hi - lo) * np.linspace(0.05, 0.95, N_CHANGE_TIMES)
        w = _stack(sigs, lambda s: s.w)
        out = []
        for tc in grid:
            label = f"{tc:.6g}"  # the regressors at the time the label names
            step = change_step(t_all, float(label), width)
            if np.ptp(step) <= 0:
                continue
            out.append((label, np.column_stack([w * step, step]), t_all))
        return out

    def augment(self, model, likelihood, coef, data, variant=""):
        """Append ``change_point``."""
        return Composite(model, (ChangePoint(),)), likelihood, "+change_point"

    def initial(self, coef, estimates):
        """``change_point.t_c`` at the best change time, ``g`` and ``h`` at the coefficients."""
        out = {"change_point.g": float(coef[0]), "change_point.h": float(coef[1])}
        if math.isfinite(estimates.get("change_time_s", math.nan)):
            out["change_point.t_c"] = float(estimates["change_time_s"])
        return out

    def interpret_variant(self, variant, coef, cov, data):
        """Change time (s), gain step (%), offset step (output unit)."""
        return {"change_time_s": float(variant), "gain_change_percent": float(100.0 * coef[0]),
                "offset_change": float(coef[1])}

