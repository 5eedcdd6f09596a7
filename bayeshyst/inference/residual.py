"""What a fit leaves unexplained, carried into the prediction of a feedforward command.

A tracking error measured on a stage is ``y - y_d`` with ``y`` the *measured* output:
the model's prediction under the command, its discrepancy (with one), and whatever the
fit attributed to its noise term -- sensor noise, and all the structure the model and
its discrepancy do not capture (creep and drift it lacks, a delay, a misfit that is
periodic in the loop). Predicting the tracking band from the noise-free draws alone
leaves that last part out: on the bundled virtual actuator the predicted 90 % band of
the posterior command's NRMSE was 0.05-0.15 % where the plant showed 0.6-1.9 %.

The likelihood's own noise model is not the right carrier either: an i.i.d. Gaussian
term averages out over the hundreds of samples of a tracking NRMSE, so its band is
narrow and centred on ``sigma`` whatever the residual's shape and dependence. What the
fit leaves is instead **resampled from the training residual itself**, ``r = y -
E[f + delta]`` on the scored samples of the records at the command's frequency (the
nearest one when the command's frequency is not in the data), by a **moving-block
bootstrap** (Künsch 1989) in two levels:

1. a pseudo training residual: as many blocks as the training residual holds, drawn
   with replacement from all its blocks -- the uncertainty of the residual's own level
   and shape, which a one-level bootstrap from two or three cycles leaves out (its 90 %
   band of an i.i.d. residual's RMS covered 50 % with two training cycles, 87 % with
   twenty; the two-level one 86-91 %, tested);
2. the command's residual: blocks drawn from that pseudo residual, started at a random
   sample of the first, cut to the command's length;
3. with several excitation conditions (frequencies) in the data, the command is treated
   as one more: each series' level is scaled by a random factor whose spread is that of
   the residual's level between the training conditions, beyond their sampling error
   (a random-effects model of the log mean square; DerSimonian & Laird 1986). A model
   whose misfit changes with the excitation will change it again under a command; with
   one condition this spread cannot be estimated and is left out (``to_dict`` says so:
   ``level_spread`` None).

A block is one input cycle when the residual repeats from cycle to cycle (its
autocorrelation one cycle apart is significantly positive: a misfit periodic in the
loop, kept whole with its phase structure), otherwise twice the residual's integrated
autocorrelation time (so that a block holds the dependence; Lahiri 2003, ch. 7), at most
one cycle.

What this does not carry: error that shows only under the command and never on the
training loops (a model that transfers poorly to minor loops the identification data
did not contain). That part can only be measured with data that contain such paths;
the compensation outputs say so when the realised error leaves the band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.segment import split_cycles
from bayeshyst.errors import ParameterError
from bayeshyst.inference.calibration import effective_size
from bayeshyst.tables import TableRecord, frame

__all__ = ["RESIDUAL_DRAWS", "ResidualBlocks", "cycle_samples"]

#: Posterior draws whose mean prediction the training residual is taken about.
RESIDUAL_DRAWS = 64
#: Fewest scored samples a record needs to contribute its residual.
MIN_SAMPLES = 8


@dataclass(frozen=True)
class ResidualBlocks(TableRecord):
    """A fit's training residual per record, resampled in blocks onto a command.

    Attributes
    ----------
    series : tuple of ndarray
        Each record's residual over its scored samples (output unit).
    frequencies : tuple of (float or None)
        Excitation frequency [Hz] of each record.
    block_lengths : tuple of int
        Block length [samples] of each record: ``ceil(2 tau)`` with ``tau`` the
        residual's integrated autocorrelation time, between 1 and one input cycle.
    """

    series: tuple[np.ndarray, ...]
    frequencies: tuple[float | None, ...]
    block_lengths: tuple[int, ...]

    def __post_init__(self) -> None:
        n = len(self.series)
        if not n or len(self.frequencies) != n or len(self.block_lengths) != n:
            raise ParameterError(f"ResidualBlocks: need one frequency and one block length "
                                 f"per series and at least one series, got {n} series, "
                                 f"{len(self.frequencies)} frequencies and "
                                 f"{len(self.block_lengths)} block lengths")
        for s, ell in zip(self.series, self.block_lengths, strict=True):
            if not (isinstance(ell, int) and 1 <= ell <= s.size) or not np.all(np.isfinite(s)):
                raise ParameterError(f"ResidualBlocks: a series of {s.size} samples needs "
                                     f"finite values and a block length in [1, {s.size}], "
                                     f"got {ell!r}")

    @classmethod
    def of(cls, post: Any, z: np.ndarray, *, discrepancy: bool = True) -> ResidualBlocks:
        """The residual of ``post``'s data about the mean prediction of draws ``z``.

        Parameters
        ----------
        post : Posterior
            Its records (scored samples) and predictions (model, offset, discrepancy).
        z : ndarray, shape (S, ndim)
            Posterior draws; the residual is taken about their mean prediction.
        discrepancy : bool
            Whether that prediction includes the discrepancy (default; without one it
            makes no difference). False: the residual of the model alone -- what a
            discrepancy that does not hold on a new input leaves there.
        """
        series, freqs, lengths = [], [], []
        for rec, pred in zip(post.data, post.predict(z, discrepancy=discrepancy), strict=True):
            ok = np.all(np.isfinite(pred), axis=1)
            if not ok.any():
                raise ParameterError(f"{rec.name}: no posterior draw simulates the record; "
                                     "its residual is undefined")
            resid = np.asarray((rec.y - np.mean(pred[ok], axis=0))[rec.scored], float)
            if resid.size < MIN_SAMPLES:
                continue
            series.append(resid)
            freqs.append(rec.frequency_hz)
            lengths.append(_block_length(resid, cycle_samples(rec)))
        if not series:
            raise ParameterError(f"no record has {MIN_SAMPLES} scored samples to take a "
                                 "residual from")
        return cls(tuple(series), tuple(freqs), tuple(lengths))

    @classmethod
    def from_series(cls, series: list[np.ndarray], frequencies: list[float | None],
                    cycle_samples: list[int]) -> ResidualBlocks:
        """Residual series measured elsewhere, e.g. on a validation record.

        Block lengths are chosen as in :meth:`of`, from each series' dependence and its
        cycle length.

        Parameters
        ----------
        series : list of ndarray
            Residuals (output unit); each at least ``MIN_SAMPLES`` long and finite.
        frequencies : list of (float or None)
            Excitation frequency [Hz] of each.
        cycle_samples : list of int
            Samples in one input cycle of each (its longest possible block).
        """
        if not (len(series) == len(frequencies) == len(cycle_samples)) or not series:
            raise ParameterError("from_series: need as many frequencies and cycle lengths as "
                                 f"series, and at least one; got {len(series)}, "
                                 f"{len(frequencies)}, {len(cycle_samples)}")
        out = [np.asarray(r, float) for r in series]
        short = [r.size for r in out if r.size < MIN_SAMPLES]
        if short:
            raise ParameterError(f"from_series: series of {short} samples; each needs "
                                 f"{MIN_SAMPLES}")
        return cls(tuple(out), tuple(frequencies),
                   tuple(_block_length(r, max(1, int(c))) for r, c in
                         zip(out, cycle_samples, strict=True)))

    def _group(self, frequency_hz: float | None) -> list[int]:
        """Indices of the records nearest to ``frequency_hz`` (in log frequency)."""
        known = sorted({f for f in self.frequencies if f is not None})
        # a command without a frequency draws from the records without one, or from all
        want = (None if frequency_hz is None or not known
                else min(known, key=lambda f: abs(math.log(f / frequency_hz))))
        picked = [i for i, f in enumerate(self.frequencies) if f == want]
        return picked or list(range(len(self.series)))

    def rms(self, frequency_hz: float | None = None) -> float:
        """RMS of the residual a command at ``frequency_hz`` draws from (output unit)."""
        pooled = np.concatenate([self.series[i] for i in self._group(frequency_hz)])
        return float(np.sqrt(np.mean(pooled ** 2)))

    def sample(self, n_series: int, n_samples: int, frequency_hz: float | None,
               rng: np.random.Generator, *, transfer: bool = True) -> np.ndarray:
        """Residual series for ``n_series`` prediction draws, shape (n_series, n_samples).

        The two-level moving-block bootstrap of the module docstring, over the records
        at the frequency nearest to ``frequency_hz`` with the longest of their block
        lengths. With ``transfer`` (default) and more than one excitation condition,
        each series is scaled by ``exp(eta / 2)``, ``eta ~ N(0, tau^2)`` with ``tau``
        the :meth:`level_spread`: the command is a new condition.
        """
        if n_series < 1 or n_samples < 1:
            raise ParameterError(f"n_series and n_samples must be >= 1, got {n_series}, "
                                 f"{n_samples}")
        group = self._group(frequency_hz)
        ell = max(self.block_lengths[i] for i in group)
        ell = min(ell, min(self.series[i].size for i in group))
        pooled = np.concatenate([self.series[i] for i in group])
        # every block start that stays inside its own record
        starts, offset = [], 0
        for i in group:
            starts.append(offset + np.arange(self.series[i].size - ell + 1))
            offset += self.series[i].size
        starts = np.concatenate(starts)
        n_pseudo = max(1, pooled.size // ell)
        n_blocks = n_samples // ell + 2
        within = np.arange(ell)
        out = np.empty((n_series, n_samples))
        for k in range(n_series):
            pseudo = starts[rng.integers(starts.size, size=n_pseudo)]
            chosen = pseudo[rng.integers(n_pseudo, size=n_blocks)]
            run = pooled[(chosen[:, None] + within).ravel()]
            first = int(rng.integers(ell))
            out[k] = run[first:first + n_samples]
        tau = self.level_spread()
        if transfer and tau:
            # a new input is a new condition: its residual level varies about the
            # training one's as the levels vary between the training conditions
            out *= np.exp(0.5 * rng.normal(0.0, tau, (n_series, 1)))
        return out

    def level_spread(self) -> float | None:
        """Between-condition sd of the residual's log mean square; None from one condition.

        A condition is an excitation frequency (records at the same one pooled). The
        DerSimonian-Laird moment estimator (1986) on ``log mean(r^2)`` per condition,
        each with its within-condition sampling variance by the delta method,
        ``var(r^2) / (n_eff mean(r^2)^2)`` (``n_eff`` from the autocorrelation of
        ``r^2``): the spread of the levels beyond what their sampling explains, 0 when
        none is left.
        """
        keys = sorted({f for f in self.frequencies if f is not None})
        if None in self.frequencies:
            keys.append(None)
        if len(keys) < 2:
            return None
        level, var = [], []
        for f in keys:
            sq = np.concatenate([self.series[i] for i, g in enumerate(self.frequencies)
                                 if g == f]) ** 2
            ms = float(np.mean(sq))
            if not ms > 0:
                return None
            level.append(math.log(ms))
            var.append(max(float(np.var(sq)) / effective_size(sq) / ms ** 2, 1e-12))
        y, w = np.asarray(level), 1.0 / np.asarray(var)
        mean = float(np.sum(w * y) / np.sum(w))
        q = float(np.sum(w * (y - mean) ** 2))
        denom = float(np.sum(w) - np.sum(w ** 2) / np.sum(w))
        tau2 = max(0.0, (q - (len(keys) - 1)) / denom) if denom > 0 else 0.0
        return math.sqrt(tau2)

    def to_dict(self) -> dict[str, Any]:
        """Per frequency: records, block length and RMS (no arrays)."""
        keys = sorted({f for f in self.frequencies if f is not None})
        if None in self.frequencies:
            keys.append(None)
        rows = []
        for f in keys:
            group = self._group(f)
            rows.append({"frequency_hz": f, "records": len(group),
                         "block_samples": max(self.block_lengths[i] for i in group),
                         "rms": self.rms(f)})
        return {"resampled": "moving blocks of the training residual, two levels",
                "rows": rows, "level_spread": self.level_spread()}

    def to_dataframe(self) -> Any:
        """One row per frequency: records, block length [samples], RMS (output unit)."""
        return frame(self.to_dict()["rows"])

    def __str__(self) -> str:
        parts = [("no frequency" if r["frequency_hz"] is None else f"{r['frequency_hz']:g} Hz")
                 + f": RMS {r['rms']:.4g} in blocks of {r['block_samples']}"
                 for r in self.to_dict()["rows"]]
        return "ResidualBlocks(" + "; ".join(parts) + ")"


def cycle_samples(rec: Any) -> int:
    """Samples in one input cycle of ``rec`` (all its scored samples without cycles)."""
    if rec.frequency_hz is not None:
        return max(1, round(1.0 / (rec.frequency_hz * rec.dt)))
    cycles = split_cycles(rec).cycles
    if cycles:
        return max(1, round(float(np.median([c.stop - c.start for c in cycles]))))
    return int(rec.n_scored)


def _block_length(resid: np.ndarray, cycle: int) -> int:
    """One input cycle when ``resid`` repeats from cycle to cycle, else ``ceil(2 tau)``.

    Repeats: its autocorrelation one cycle apart is above the 97.5 % point of that of
    white noise (``1.96 / sqrt(n - cycle)``) -- a misfit periodic in the loop, whose
    unit of dependence is the cycle. Otherwise twice the integrated autocorrelation
    time. Always between 1 and ``min(cycle, resid.size)``.
    """
    n = resid.size
    cycle = min(cycle, n)
    r = resid - np.mean(resid)
    energy = float(np.dot(r, r))
    if energy > 0 and n - cycle >= 2:
        lag_cycle = float(np.dot(r[:-cycle], r[cycle:])) / energy
        if lag_cycle > 1.96 / math.sqrt(n - cycle):
            return int(cycle)
    tau = n / effective_size(resid)
    return int(min(cycle, max(1, math.ceil(2.0 * tau))))
