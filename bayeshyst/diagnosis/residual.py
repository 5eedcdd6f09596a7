"""The residual of a fitted model and the score test of every candidate effect on it.

:func:`test_effects` takes a sampled posterior and returns one :class:`EffectTest` per
candidate effect (:mod:`bayeshyst.diagnosis.effects`):

1. the residual ``r = y - y_bar`` of the posterior-mean prediction on the scored samples
   of every record, its RMS per record and per cycle;
2. the fit's sensitivities ``J = d y_hat / d z`` at the best sampled point (central
   differences, all free parameters including the offset): the nuisance regressors;
3. every effect's score regressors on the posterior-mean model output;
4. one AR(p) error model (order by BIC) for the residual of the widest regression (all
   effects at once: consistent under the null and under any of the alternatives), with
   which every column is whitened;
5. per effect, the F test of its regressors beyond ``J`` (p-value) and the BIC Bayes
   factor; the coloured-noise test (Breusch–Godfrey) on what is left after ``J`` and the
   nominally significant structural effects; Holm's correction over all tests.

Why a structural effect outranks coloured noise: structure in the mean shows up as
serial correlation too, so the noise model is the explanation of last resort — it is
chosen only when no structural test fires.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from scipy import stats

from bayeshyst.data.dataset import Dataset
from bayeshyst.diagnosis.catalogue import EFFECTS
from bayeshyst.diagnosis.drivers import (
    DriverScan,
    driver_blocks,
    loop_position_basis,
    scan_drivers,
)
from bayeshyst.diagnosis.effects import (
    ColoredNoise,
    DelayEffect,
    RateDependence,
    RecordSignals,
)
from bayeshyst.diagnosis.spectrum import SpectralLine, spectral_lines
from bayeshyst.diagnosis.stats import (
    FTest,
    f_test,
    fit_ar,
    holm,
    lag_test,
    orthonormal_basis,
    project_out,
    whiten,
)
from bayeshyst.inference.posterior import Posterior, cycle_units
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.tables import TableRecord, frame

__all__ = ["CycleResidual", "EffectTest", "ResidualAnalysis", "analyse_residual", "best_point"]

#: Shares of the family-wise level for the score tests, the driver scan, the lines.
LEVEL_SHARES = (0.5, 0.25, 0.25)

#: points kept per evidence plot (evenly thinned)
_EVIDENCE_POINTS = 4000


@dataclass(frozen=True)
class EffectTest(TableRecord):
    """The score test of one candidate effect on a fit's residual.

    Attributes
    ----------
    effect : str
    statistic : str
        Which test (``"F"``: Gauss–Newton score test of the effect's regressors;
        ``"Breusch-Godfrey F"`` for coloured noise).
    value : float
        The statistic.
    df1, df2 : int
    p_value : float
        Unadjusted.
    p_adjusted : float
        Holm-adjusted over all effects tested on this residual.
    log_bayes_factor : float
        BIC approximation of log BF(effect : no effect) on the whitened regression.
    partial_r2 : float
        Share of the residual (beyond the fit's own directions) the effect explains.
    explained_rms : float
        RMS of the effect's fitted contribution on the scored samples (output unit).
    explained_percent : float
        The same in per cent of the measured peak-to-peak output.
    per_frequency_rms : dict
        ``frequency (Hz) -> RMS`` of the contribution (records of unknown frequency
        under ``nan``): a rate effect grows with frequency, creep and drift do not.
    estimates : dict
        Physical reading of the coefficients (``delay_s``, ``natural_frequency_hz``, ...).
    significant : bool
        ``p_adjusted < alpha``.
    skipped : str or None
        Why the effect was not tested (already in the model); the numbers are NaN.
    ar_order : int
        Order of the AR error model the columns were whitened with.
    variant : str
        The variant the test chose, for effects with several (the column of ``aux``,
        the change time of ``change_point``); empty otherwise.
    n_variants : int
        How many variants were tested (the p-value and Bayes factor pay for them).
    p_beyond_shape : float
        p-value of the same test with the loop-position basis of the driver scan among
        the nuisance regressors: whether the effect explains anything a branch-shape
        error of the model could not (times the variants, as the p-value). Large for a
        creep, lag or delay under one sine, where the two are one coordinate.
    p_beyond_columns : float
        p-value of the same test with the driver scan's blocks of the measured columns it
        kept (``beyond_columns``) among the nuisance regressors: whether the effect
        explains anything a smooth dependence on those columns could not. NaN when the
        scan kept no column. Large for a delay on an MR damper whose viscous force
        follows its velocity column (on a sine, a rate is a function of the velocity).
    beyond_columns : tuple of str
        The columns ``p_beyond_columns`` was computed beyond.
    evidence : dict
        Arrays for the evidence plot: ``x`` (explaining variable), ``partial_residual``
        (residual minus what the fit's own directions explain), ``component`` (the
        effect's fitted contribution), ``x_label``; thinned to a few thousand points.
    """

    effect: str
    statistic: str
    value: float
    df1: int
    df2: int
    p_value: float
    p_adjusted: float
    log_bayes_factor: float
    partial_r2: float
    explained_rms: float
    explained_percent: float
    per_frequency_rms: dict[str, float]
    estimates: dict[str, float]
    significant: bool
    skipped: str | None = None
    ar_order: int = 0
    variant: str = ""
    n_variants: int = 1
    p_beyond_shape: float = math.nan
    p_beyond_columns: float = math.nan
    beyond_columns: tuple[str, ...] = ()
    coef: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    evidence: dict[str, Any] = field(default_factory=dict, repr=False)

    #: the arrays an evidence plot needs
    EVIDENCE_KEYS: ClassVar[tuple[str, ...]] = ("x", "partial_residual", "component")

    @property
    def has_evidence(self) -> bool:
        """Whether the test carries the arrays of an evidence plot.

        A skipped test has none, nor have the candidates built from the driver scan or
        the spectrum (the branch shape, a disturbance line, an unexplained smooth term):
        their numbers are the scan's held-out gain, not a regression on a partial residual.
        """
        return self.skipped is None and all(k in self.evidence for k in self.EVIDENCE_KEYS)

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (no evidence arrays)."""
        return {
            "effect": self.effect, "statistic": self.statistic, "value": self.value,
            "df": [self.df1, self.df2], "p_value": self.p_value,
            "p_adjusted": self.p_adjusted, "log_bayes_factor": self.log_bayes_factor,
            "partial_r2": self.partial_r2, "explained_rms": self.explained_rms,
            "explained_percent": self.explained_percent,
            "per_frequency_rms": dict(self.per_frequency_rms), "estimates": dict(self.estimates),
            "significant": self.significant, "skipped": self.skipped,
            "ar_order": self.ar_order, "variant": self.variant, "n_variants": self.n_variants,
            "p_beyond_shape": self.p_beyond_shape, "p_beyond_columns": self.p_beyond_columns,
            "beyond_columns": list(self.beyond_columns),
        }

    def __str__(self) -> str:
        if self.skipped:
            return f"{self.effect:>16}: not tested ({self.skipped})"
        flag = "FIRES" if self.significant else "     "
        est = ", ".join(f"{k} {v:.3g}" for k, v in self.estimates.items())
        if self.variant:
            est = f"{self.variant!r} best of {self.n_variants}" + (f", {est}" if est else "")
        return (f"{self.effect:>16}: {flag} {self.statistic} = {self.value:.3g} "
                f"({self.df1}, {self.df2}), p = {self.p_value:.2g} (Holm {self.p_adjusted:.2g}),"
                f" log BF {self.log_bayes_factor:.1f}, explains {self.explained_percent:.3f} %"
                f" of stroke{'; ' + est if est else ''}")


@dataclass(frozen=True)
class CycleResidual:
    """RMS and largest absolute residual of one cycle (output unit)."""

    record: str
    cycle: int
    frequency_hz: float | None
    rms: float
    max_abs: float


@dataclass(frozen=True)
class ResidualAnalysis:
    """A fit's residual and every effect's test on it.

    Attributes
    ----------
    tests : tuple of EffectTest
        In :data:`~bayeshyst.diagnosis.catalogue.EFFECTS` order.
    residual : list of ndarray
        Per record, on its scored samples (output unit).
    time : list of ndarray
        The matching times (s).
    cycles : tuple of CycleResidual
    mean_prediction : list of ndarray
        Posterior-mean prediction per record (full records, offset included).
    ar_order : int
        Order of the AR error model used for whitening.
    alpha : float
        Family-wise level of the score tests (their share of the diagnosis' level).
    drivers : DriverScan or None
        What the residual still depends on among everything observed
        (:func:`~bayeshyst.diagnosis.drivers.scan_drivers`), None if not scanned.
    lines : tuple of SpectralLine
        Lines in the residual's spectrum away from the excitation's harmonics.
    """

    tests: tuple[EffectTest, ...]
    residual: list[np.ndarray]
    time: list[np.ndarray]
    cycles: tuple[CycleResidual, ...]
    mean_prediction: list[np.ndarray]
    ar_order: int
    alpha: float
    drivers: DriverScan | None = None
    lines: tuple[SpectralLine, ...] = ()

    @property
    def structure_left(self) -> bool:
        """Whether anything observed still explains the residual (a driver or a line)."""
        return bool(self.lines) or bool(self.drivers is not None and self.drivers.found)

    def remaining(self) -> str:
        """What is left in the residual, in words."""
        if self.drivers is None:
            return "not scanned"
        parts = [self.drivers.summary()] if self.drivers.found or not self.lines else []
        parts += [str(x) for x in self.lines]
        return "; ".join(parts)

    def fired(self) -> list[EffectTest]:
        """Significant tests, most supported first.

        Structural effects come by Bayes factor, then coloured noise (only when no
        structural effect fires, see module notes).
        """
        sig = [t for t in self.tests if t.significant]
        structural = sorted((t for t in sig if t.effect != ColoredNoise.name),
                            key=lambda t: -t.log_bayes_factor)
        names = [t.effect for t in structural]
        if RateDependence.name in names and DelayEffect.name in names:
            # Both start with -tau dw/dt. Dynamics proper (a resonance) shows as a
            # significantly negative d2w/dt2 coefficient (gain rising with frequency);
            # otherwise the lag is, in band, a delay: the one-parameter explanation.
            rate = structural[names.index(RateDependence.name)]
            z = rate.estimates.get("curvature_z", math.nan)
            i, j = names.index(RateDependence.name), names.index(DelayEffect.name)
            resonant = math.isfinite(z) and z < -_z_crit(self.alpha)
            if (i < j) != resonant:
                structural[i], structural[j] = structural[j], structural[i]
        if structural:
            return structural
        return [t for t in sig if t.effect == ColoredNoise.name]

    def test(self, effect: str) -> EffectTest:
        """The test of ``effect``."""
        for t in self.tests:
            if t.effect == effect:
                return t
        raise KeyError(effect)

    def __str__(self) -> str:
        lines = [str(t) for t in self.tests]
        if self.drivers is not None:
            lines.append(str(self.drivers))
        lines += [str(x) for x in self.lines]
        return "\n".join(lines)


def _z_crit(alpha: float) -> float:
    """One-sided standard-normal critical value at level ``alpha``."""
    return float(stats.norm.isf(alpha))


# ------------------------------------------------------------------------ the residual
def best_point(res: SamplingResult) -> np.ndarray:
    """The highest-posterior point seen (MAP start or a sampled draw)."""
    lp = np.asarray(res.log_prob)
    z = res.chains.reshape(-1, res.chains.shape[-1])
    flat = lp.reshape(-1)
    i = int(np.nanargmax(np.where(np.isfinite(flat), flat, -np.inf)))
    if np.isfinite(flat[i]) and flat[i] > res.start.log_prob:
        return z[i]
    return np.asarray(res.start.z, dtype=float)


def _jacobian(post: Posterior, z0: np.ndarray, h: float = 1e-4) -> list[np.ndarray]:
    """Sensitivities of the prediction to every free ``z`` entry, per record (N, ndim).

    Central differences; one-sided where one side of the step fails to simulate (a
    constrained parameter near its boundary), zero (dropped later) where both fail.
    Noise parameters give zero columns.
    """
    d = z0.size
    pts = np.repeat(z0[None, :], 2 * d + 1, axis=0)
    step = h * np.maximum(1.0, np.abs(z0))
    idx = np.arange(d)
    pts[2 * idx, idx] += step
    pts[2 * idx + 1, idx] -= step
    out = []
    for p in post.predict(pts):
        plus, minus, mid = p[0:-1:2], p[1:-1:2], p[-1][None, :]
        ok_p = np.all(np.isfinite(plus), axis=1)[:, None]
        ok_m = np.all(np.isfinite(minus), axis=1)[:, None]
        central = (plus - minus) / (2 * step[:, None])
        fwd, bwd = (plus - mid) / step[:, None], (mid - minus) / step[:, None]
        jac = np.where(ok_p & ok_m, central, np.where(ok_p, fwd, np.where(ok_m, bwd, 0.0)))
        out.append(np.where(np.isfinite(jac), jac, 0.0).T)
    return out


def _signals(post: Posterior, z: np.ndarray) -> tuple[list[RecordSignals], list[np.ndarray]]:
    """Posterior-mean model output (no offset) and prediction (with offset) per record."""
    _, off = post.model_draws(z)
    preds = post.predict(z)
    sigs, means = [], []
    for rec, p in zip(post.data, preds, strict=True):
        ok = np.all(np.isfinite(p), axis=1)
        if not np.any(ok):
            raise RuntimeError(f"every posterior draw failed to simulate record {rec.name!r}")
        means.append(np.mean(p[ok], axis=0))
        w = np.mean(p[ok] - off[ok, None], axis=0)
        sigs.append(RecordSignals(rec.name, np.asarray(rec.t, float), np.asarray(rec.u, float),
                                  w, int(rec.scored.start or 0), rec.frequency_hz))
    return sigs, means


def _cycles(data: Dataset, residual: list[np.ndarray]) -> tuple[CycleResidual, ...]:
    out = []
    for rec, r in zip(data, residual, strict=True):
        s0 = rec.scored.start or 0
        for i, (a, b) in enumerate(cycle_units(rec)):
            seg = r[a - s0:b - s0]
            if seg.size:
                out.append(CycleResidual(rec.name, i, rec.frequency_hz,
                                         float(np.sqrt(np.mean(seg ** 2))),
                                         float(np.max(np.abs(seg)))))
    return tuple(out)


def _freq_key(f: float | None) -> str:
    return "nan" if f is None or not math.isfinite(f) else f"{f:g}"


def _thin(n: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, _EVIDENCE_POINTS)).astype(int))


def analyse_residual(
    post: Posterior,
    res: SamplingResult,
    draws: np.ndarray,
    *,
    effects: Sequence[str] | None = None,
    alpha: float = 0.01,
    max_ar_order: int = 10,
    n_permutations: int = 999,
    seed: int = 0,
) -> ResidualAnalysis:
    """Residual of the posterior-mean prediction and the score test of every effect.

    Parameters
    ----------
    post : Posterior
        The fitted posterior (model, likelihood, data).
    res : SamplingResult
        Its samples (the best point anchors the sensitivities ``J``).
    draws : ndarray, shape (S, ndim)
        Posterior draws averaged for the mean prediction.
    effects : sequence of str, optional
        Candidate effects (default: all of :data:`~bayeshyst.diagnosis.catalogue.EFFECTS`).
    alpha : float
        Family-wise significance level of everything tested on this residual, shared
        (:data:`LEVEL_SHARES`) between the effects' score tests (Holm), the driver scan
        and the spectral lines.
    max_ar_order : int
        Largest AR order of the error model used for whitening.
    n_permutations : int
        Sign patterns of the driver scan's randomisation test; 0 skips the scan and the
        spectral lines.
    seed : int
        Seed of the driver scan's sign patterns.
    """
    names = list(EFFECTS) if effects is None else list(effects)
    data = post.data
    # the family-wise level is shared (Bonferroni over the three families): half for the
    # catalogue's score tests (Holm within), a quarter each for the driver scan and the
    # spectral lines, so that clean data raise nothing at rate alpha, not 3 alpha
    level = float(alpha)
    alpha = LEVEL_SHARES[0] * level
    sigs, means = _signals(post, draws)
    jac = _jacobian(post, best_point(res))
    resid, times, segs, js, freqs = [], [], [], [], []
    start = 0
    for rec, sig, m, jr in zip(data, sigs, means, jac, strict=True):
        s0 = sig.s0
        r = np.asarray(rec.y[s0:], float) - m[s0:]
        resid.append(r)
        times.append(sig.t[s0:])
        js.append(jr[s0:])
        freqs.append(np.full(r.size, np.nan if rec.frequency_hz is None else rec.frequency_hz))
        segs.append((start, start + r.size))
        start += r.size
    r_all = np.concatenate(resid)
    z_all = np.concatenate(js)
    z_all = z_all[:, np.any(z_all != 0, axis=0)]
    freq_all = np.concatenate(freqs)
    ptp = float(np.ptp(np.concatenate([np.asarray(rec.y[s.s0:], float)
                                        for rec, s in zip(data, sigs, strict=True)]))) or math.nan
    lik = post.likelihood.name
    structural: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    skipped: dict[str, str] = {}
    for name in names:
        eff = EFFECTS[name]
        why = eff.not_applicable(post.model, lik)
        if why:
            skipped[name] = why
        elif name != ColoredNoise.name:
            variants = eff.variants(sigs, data, post.model)
            if not variants:
                skipped[name] = ("nothing to test on these data (no extra column; for a "
                                 "change point: records not on one clock)")
                continue
            if not all(np.all(np.isfinite(x)) for _, x, _ in variants):
                raise RuntimeError(f"{name}: non-finite score regressors")
            structural[name] = variants

    # one error model for all tests: AR(p) of the widest regression's residual, with one
    # variant of each effect that has several (the best by an unwhitened F test): all 24
    # change times at once would absorb structure the AR model must see
    wide_cols = []
    for variants in structural.values():
        if len(variants) == 1:
            wide_cols.append(variants[0][1])
        else:
            raw_f = [f_test(r_all, z_all, x).statistic for _, x, _ in variants]
            wide_cols.append(variants[int(np.argmax(raw_f))][1])
    wide = np.column_stack([z_all, *wide_cols])
    e_wide = r_all - wide @ np.linalg.lstsq(wide, r_all, rcond=None)[0]
    ar = fit_ar(e_wide, segs, max_order=max_ar_order)
    rw, zw = whiten(r_all, segs, ar.phi), whiten(z_all, segs, ar.phi)

    qz = orthonormal_basis(z_all)
    loop = loop_position_basis(data, [s.s0 for s in sigs])
    # the scan first: the measured columns it keeps are nuisance for what a time-domain
    # effect is credited with (as the loop position is, below)
    scan, lines = None, ()
    if n_permutations > 0:
        blocks = driver_blocks(data, [s.w for s in sigs], [s.s0 for s in sigs])
        scan = scan_drivers(data, resid, [s.w for s in sigs], alpha=LEVEL_SHARES[1] * level,
                            n_permutations=n_permutations, seed=seed, blocks=blocks)
        lines = spectral_lines(data, resid, alpha=LEVEL_SHARES[2] * level)
    columns = () if scan is None else tuple(d.driver for d in scan.selected
                                             if d.kind == "external")
    col_basis = None
    if columns:
        col_basis = whiten(np.column_stack([b.columns for b in blocks if b.name in columns]),
                           segs, ar.phi)
    loop_w = whiten(loop, segs, ar.phi)  # the same nuisance for every effect
    beyond: dict[str, float] = {}
    beyond_cols: dict[str, float] = {}
    raw: dict[str, tuple[FTest, np.ndarray, int, str, np.ndarray]] = {}
    for name, variants in structural.items():
        xws = [whiten(x, segs, ar.phi) for _, x, _ in variants]
        tests_v = [f_test(rw, zw, xw) for xw in xws]
        best = int(np.argmax([t.statistic for t in tests_v]))
        t = tests_v[best]
        k = len(variants)
        if k > 1:
            # a search over k variants pays for itself: Bonferroni on the p-value, and
            # the Bayes factor averaged over a uniform prior on the variants
            lbf = np.array([v.log_bayes_factor for v in tests_v])
            mean_lbf = float(np.max(lbf) + np.log(np.mean(np.exp(lbf - np.max(lbf)))))
            t = FTest(t.statistic, t.df1, t.df2, min(1.0, k * t.p_value), mean_lbf,
                      t.partial_r2, t.coef, t.n, t.cov)
        label, x, ax = variants[best]
        # the effect's contribution beyond what the fit's own directions can absorb
        raw[name] = (t, project_out(qz, x @ t.coef), k, label, ax)
        # and beyond what a branch-shape error could: the loop position among the nuisance
        shaped = f_test(rw, np.column_stack([zw, loop_w]), xws[best])
        beyond[name] = min(1.0, k * shaped.p_value)
        if col_basis is not None:
            by_cols = f_test(rw, np.column_stack([zw, col_basis]), xws[best])
            beyond_cols[name] = min(1.0, k * by_cols.p_value)
    lag = None
    if ColoredNoise.name in names and ColoredNoise.name not in skipped:
        nominal = [structural[n][[v[0] for v in structural[n]].index(raw[n][3])][1]
                   for n in structural if raw[n][0].p_value < alpha]
        zc = np.column_stack([z_all, *nominal]) if nominal else z_all
        e0 = r_all - zc @ np.linalg.lstsq(zc, r_all, rcond=None)[0]
        lag = (*lag_test(e0, zc, segs), e0)

    tested = [n for n in names if n not in skipped]
    pvals = [raw[n][0].p_value if n in raw else lag[0].p_value for n in tested]
    adj = dict(zip(tested, holm(pvals), strict=True)) if tested else {}
    nan = math.nan
    tests = []
    for name in names:
        eff = EFFECTS[name]
        if name in skipped:
            tests.append(EffectTest(name, "", nan, 0, 0, nan, nan, nan, nan, nan, nan, {}, {},
                                    False, skipped=skipped[name], ar_order=ar.order))
            continue
        if name == ColoredNoise.name:
            t, rho, e0 = lag
            n_var, variant = 1, ""
            comp = t.coef[0] * np.concatenate([np.r_[0.0, e0[a:b - 1]] for a, b in segs])
            keep = _thin(r_all.size)
            prev = np.concatenate([np.r_[nan, e0[a:b - 1]] for a, b in segs])
            evidence = {"x": prev[keep], "partial_residual": e0[keep],
                        "component": comp[keep], "x_label": eff.evidence_label}
            est = eff.interpret(np.array([rho]), np.zeros((1, 1)), data)
            stat, order = "Breusch-Godfrey F", 0
        else:
            t, comp, n_var, variant, ax = raw[name]
            # the residual beyond the fit's own directions, against which comp is drawn
            partial = project_out(qz, r_all)
            keep = _thin(r_all.size)
            evidence = {"x": ax[keep], "partial_residual": partial[keep],
                        "component": comp[keep], "x_label": eff.evidence_label}
            est = eff.interpret_variant(variant, t.coef, t.cov, data)
            stat, order = "F", ar.order
        per_f = {}
        for f in np.unique(freq_all[np.isfinite(freq_all)]):
            per_f[_freq_key(float(f))] = float(np.sqrt(np.mean(comp[freq_all == f] ** 2)))
        if np.any(~np.isfinite(freq_all)):
            per_f["nan"] = float(np.sqrt(np.mean(comp[~np.isfinite(freq_all)] ** 2)))
        rms = float(np.sqrt(np.mean(comp ** 2)))
        tests.append(EffectTest(
            name, stat, t.statistic, t.df1, t.df2, t.p_value, float(adj[name]),
            t.log_bayes_factor, t.partial_r2, rms, 100.0 * rms / ptp, per_f, est,
            bool(adj[name] < alpha), ar_order=order, variant=variant, n_variants=n_var,
            p_beyond_shape=beyond.get(name, math.nan),
            p_beyond_columns=beyond_cols.get(name, math.nan),
            beyond_columns=columns if name in beyond_cols else (), coef=t.coef, cov=t.cov,
            evidence=evidence))
    return ResidualAnalysis(tuple(tests), resid, times, _cycles(data, resid), means, ar.order,
                            float(alpha), scan, lines)
