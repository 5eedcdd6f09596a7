"""PSIS-LOO and WAIC with one input cycle left out, and their sums over groups.

Everything here hands back plain frozen dataclasses: :class:`ElpdResult` for PSIS-LOO
and WAIC, :class:`GroupElpd` for their sums over groups of cycles (per excitation
frequency, per record).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import arviz as az
import numpy as np

from bayeshyst.diagnostics.inference_data import GIVEN_REST
from bayeshyst.errors import ParameterError

__all__ = ["PARETO_K_BAD", "ElpdResult", "GroupElpd", "elpd_by_group", "loo", "waic"]

PARETO_K_BAD = 0.7
"""Pareto shape above which PSIS-LOO of a unit is unreliable (Vehtari et al. 2024)."""


@dataclass(frozen=True, eq=False)
class ElpdResult:
    """Expected log pointwise predictive density of a fit (PSIS-LOO or WAIC).

    Attributes
    ----------
    method : {"loo", "waic"}
    elpd : float
        Estimated elpd (log scale: larger is better).
    se : float
        Its standard error.
    p : float
        Effective number of parameters (``p_loo`` or ``p_waic``).
    pointwise : ndarray, shape (n_units,)
        elpd of each cycle.
    pareto_k : ndarray, shape (n_units,) or None
        Pareto shape of each cycle's importance weights (LOO only).
    n_units : int
        Number of left-out units (cycles).
    n_samples : int
        Posterior draws used.
    warnings : tuple of str
        Everything that makes the number less trustworthy, in plain words (Pareto k
        above :data:`PARETO_K_BAD`, WAIC variance warning, sampling not converged).
    """

    method: str
    elpd: float
    se: float
    p: float
    pointwise: np.ndarray
    pareto_k: np.ndarray | None
    n_units: int
    n_samples: int
    warnings: tuple[str, ...] = ()

    @property
    def reliable(self) -> bool:
        """True when there is no warning."""
        return not self.warnings

    def __str__(self) -> str:
        head = (f"elpd_{self.method} = {self.elpd:.2f} (se {self.se:.2f}), "
                f"p_{self.method} = {self.p:.2f}; {self.n_units} cycles, "
                f"{self.n_samples} draws")
        if self.pareto_k is not None and self.pareto_k.size:
            head += f"; max Pareto k {float(np.max(self.pareto_k)):.2f}"
        return "\n".join([head, *(f"  warning: {w}" for w in self.warnings)])


@dataclass(frozen=True)
class GroupElpd:
    """elpd summed over the cycles of one group (one frequency, one record).

    ``se`` is ``sqrt(n * var(pointwise))`` as for the total, and NaN for a group of a
    single cycle (one value says nothing about its own spread).
    """

    coord: str
    value: Any
    n_units: int
    elpd: float
    se: float
    max_pareto_k: float

    def __str__(self) -> str:
        value = "unknown" if _is_nan(self.value) else f"{self.value}"
        se = "n/a (one cycle)" if math.isnan(self.se) else f"{self.se:.2f}"
        k = "" if math.isnan(self.max_pareto_k) else f", max Pareto k {self.max_pareto_k:.2f}"
        return (f"{self.coord} = {value}: elpd {self.elpd:.2f} (se {se}), "
                f"{self.n_units} cycles{k}")


def _is_nan(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)


# --------------------------------------------------------------------- LOO and WAIC
def _sampling_warnings(idata: az.InferenceData) -> list[str]:
    """Why an elpd from ``idata`` may not be meaningful (unconverged run, failed draws)."""
    stats = getattr(idata, "sample_stats", None)
    if stats is not None and "converged" in stats.attrs and not int(stats.attrs["converged"]):
        reasons = stats.attrs.get("convergence_reasons", "") or "see the convergence report"
        out = [f"sampling did not converge ({reasons})"]
    else:
        out = []
    failed = int(idata.log_likelihood.attrs.get("failed_draws", 0))
    if failed:
        out.append(f"{failed} log-likelihood values are -inf (failed simulations at "
                   f"kept draws): the elpd is not meaningful")
    return out


def _n_samples(idata: az.InferenceData) -> int:
    ll = idata.log_likelihood["y"]
    return int(ll.sizes["chain"] * ll.sizes["draw"])


def _check_idata(idata: Any) -> None:
    if not isinstance(idata, az.InferenceData):
        raise ParameterError(f"idata must be an InferenceData, got {type(idata).__name__}")
    if "log_likelihood" not in idata.groups() or "y" not in idata.log_likelihood:
        raise ParameterError("idata has no log_likelihood group with a variable 'y' "
                             "(build it with to_inference_data)")


def _caught(caught: list[warnings.WarningMessage], skip: str | None = None) -> list[str]:
    """Distinct messages of caught warnings, minus those containing ``skip``."""
    out = []
    for w in caught:
        msg = " ".join(str(w.message).split())
        if (skip is None or skip not in msg) and msg not in out:
            out.append(msg)
    return out


def loo(idata: az.InferenceData) -> ElpdResult:
    """PSIS-LOO with one cycle left out at a time.

    Where the posterior has a linear block (``y_given_rest`` in the log-likelihood
    group), the importance sampling runs over the nonlinear draws only, with the block
    integrated out exactly in each cycle's term (a Rao-Blackwellised estimate of the same
    ``elpd``): one cycle moves the few nonlinear parameters far less than it moves a
    PI weight, so the Pareto k values are small where plain PSIS-LOO needs refits.
    ``p_loo`` is then ``lppd`` (from ``y``) minus that ``elpd``.

    Parameters
    ----------
    idata : arviz.InferenceData
        From :func:`to_inference_data` (or :func:`load_netcdf`).

    Returns
    -------
    ElpdResult
        ``warnings`` names the cycles with Pareto k > 0.7 (their LOO estimate is
        unreliable: refit without them, or use more draws / a more robust model) and
        those above the sample-size threshold ``min(1 - 1/log10(S), 0.7)``.
    """
    _check_idata(idata)
    var = GIVEN_REST if GIVEN_REST in idata.log_likelihood else "y"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = az.loo(idata, pointwise=True, var_name=var, scale="log")
    k = np.asarray(res.pareto_k, dtype=float).ravel()
    msgs = _sampling_warnings(idata)
    labels = _cycle_labels(idata)
    bad = np.flatnonzero(k > PARETO_K_BAD)
    if bad.size:
        names = ", ".join(labels[i] for i in bad[:8]) + (", ..." if bad.size > 8 else "")
        msgs.append(f"{bad.size} of {k.size} cycles have Pareto k > {PARETO_K_BAD} "
                    f"(max {k.max():.2f}): PSIS-LOO is unreliable for {names}")
    good_k = float(res.good_k)
    mid = np.flatnonzero((k > good_k) & (k <= PARETO_K_BAD))
    if mid.size and good_k < PARETO_K_BAD:
        msgs.append(f"{mid.size} cycles have Pareto k > {good_k:.2f}, the threshold for "
                    f"{_n_samples(idata)} draws: more draws per chain would help")
    msgs += _caught(caught, "Estimated shape parameter of Pareto")
    p_loo = float(res.p_loo)
    if var == GIVEN_REST:
        ll = np.asarray(idata.log_likelihood["y"].values, dtype=float)
        ll = ll.reshape(-1, ll.shape[-1])
        lppd = float(np.sum(_logmeanexp(ll)))
        p_loo = lppd - float(res.elpd_loo)
    return ElpdResult("loo", float(res.elpd_loo), float(res.se), p_loo,
                      np.asarray(res.loo_i, dtype=float).ravel(), k, int(res.n_data_points),
                      int(res.n_samples), tuple(msgs))


def _logmeanexp(ll: np.ndarray) -> np.ndarray:
    from scipy.special import logsumexp

    return logsumexp(ll, axis=0) - math.log(ll.shape[0])


def waic(idata: az.InferenceData) -> ElpdResult:
    """WAIC with cycles as the pointwise units (``pareto_k`` is None).

    The variance warning of arviz (posterior variance of a cycle's log predictive
    density above 0.4) is passed on in ``warnings``; prefer :func:`loo`.
    """
    _check_idata(idata)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = az.waic(idata, pointwise=True, var_name="y", scale="log")
    msgs = _sampling_warnings(idata) + _caught(caught)
    if bool(res.warning) and not any("0.4" in m for m in msgs):
        msgs.append("the posterior variance of a cycle's log predictive density exceeds 0.4: "
                    "WAIC may be unreliable, use loo")
    return ElpdResult("waic", float(res.elpd_waic), float(res.se), float(res.p_waic),
                      np.asarray(res.waic_i, dtype=float).ravel(), None,
                      int(res.n_data_points), int(res.n_samples), tuple(msgs))


def _cycle_labels(idata: az.InferenceData) -> list[str]:
    ll = idata.log_likelihood
    if "cycle_record" in ll.coords and "cycle_index" in ll.coords:
        return [f"{r}#{int(i)}" for r, i in zip(ll["cycle_record"].values,
                                                ll["cycle_index"].values, strict=True)]
    return [f"cycle {i}" for i in range(ll["y"].shape[-1])]


def elpd_by_group(
    idata: az.InferenceData,
    coord: str = "cycle_frequency_hz",
    *,
    result: ElpdResult | None = None,
) -> tuple[GroupElpd, ...]:
    """Pointwise elpd summed over groups of cycles.

    Parameters
    ----------
    idata : arviz.InferenceData
    coord : str
        A coordinate of the ``cycle`` dim: ``"cycle_frequency_hz"`` (default; records
        of unknown frequency form one NaN group) or ``"cycle_record"``.
    result : ElpdResult, optional
        A :func:`loo` (or :func:`waic`) result of ``idata``, to avoid recomputing it.

    Returns
    -------
    tuple of GroupElpd
        One per distinct value, sorted (NaN last). ``se = sqrt(n var(elpd_i))``,
        NaN for a single-cycle group.
    """
    _check_idata(idata)
    ll = idata.log_likelihood
    if coord not in ll.coords or ll[coord].dims != ("cycle",):
        have = [c for c in ll.coords if ll[c].dims == ("cycle",) and c != "cycle"]
        raise ParameterError(f"coord {coord!r} is not a coordinate of the cycles; have {have}")
    res = loo(idata) if result is None else result
    values = ll[coord].values
    if res.pointwise.size != values.size:
        raise ParameterError(f"result has {res.pointwise.size} units, idata {values.size}")
    is_float = np.issubdtype(values.dtype, np.floating)
    nan = np.isnan(values) if is_float else np.zeros(values.size, dtype=bool)
    if is_float:
        keys = [float(v) for v in np.unique(values[~nan])]
    else:  # record names: in the order of the records
        keys = list(dict.fromkeys(values.tolist()))
    out = []
    for key, mask in [(k, ~nan & (values == k)) for k in keys] + (
            [(math.nan, nan)] if nan.any() else []):
        e = res.pointwise[mask]
        n = int(mask.sum())
        se = float(np.sqrt(n * np.var(e))) if n > 1 else math.nan
        kmax = float(np.max(res.pareto_k[mask])) if res.pareto_k is not None else math.nan
        out.append(GroupElpd(coord, key, n, float(np.sum(e)), se, kmax))
    return tuple(out)
