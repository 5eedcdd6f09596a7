"""The record of a posterior sampling run: draws, convergence, counts, and their summaries.

:class:`SamplingResult` is what :func:`~bayeshyst.inference.sampling.sample_posterior`
returns; :func:`summarise_draws` is the one place posterior summaries
(:class:`ParamSummary`) are computed, for full chains and for a saved posterior's draws.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.inference.convergence import ConvergenceReport, hdi
from bayeshyst.inference.optimize import MAPResult
from bayeshyst.inference.posterior import EvalCounts
from bayeshyst.params import ParamSpace

__all__ = ["ParamSummary", "SamplingResult", "summarise_draws"]


@dataclass(frozen=True)
class ParamSummary:
    """Posterior summary of one scalar element (physical units).

    ``hdi_lo``/``hdi_hi`` bound the highest-density interval of mass ``prob``.
    """

    label: str
    unit: str
    mean: float
    sd: float
    hdi_lo: float
    hdi_hi: float
    prob: float = 0.9

    def __str__(self) -> str:
        return (f"{self.label:<22} {self.mean:>12.5g} {self.sd:>11.4g}  "
                f"[{self.hdi_lo:.5g}, {self.hdi_hi:.5g}] {self.unit}")


def summarise_draws(draws: Mapping[str, np.ndarray], units: Mapping[str, str],
                    prob: float = 0.9) -> list[ParamSummary]:
    """One :class:`ParamSummary` per scalar element of every parameter's draws.

    The one place posterior summaries are computed: :meth:`SamplingResult.summary` (full
    chains) and :func:`bayeshyst.diagnostics.posterior_summary` (a saved posterior's
    thinned draws) both call it.

    Parameters
    ----------
    draws : mapping of str to ndarray, each shape (n_draws, *shape)
        Draws of each parameter in physical units.
    units : mapping of str to str
        Unit of each parameter (missing: dimensionless, ``""``).
    prob : float
        Mass of the highest-density interval, in (0, 1).

    Returns
    -------
    list of ParamSummary
        In the order of ``draws``; vector and matrix parameters give one row per
        element, labelled ``name[i]`` / ``name[i,j]`` (as :meth:`Param.labels`).
    """
    out = []
    for name, values in draws.items():
        x = np.asarray(values, dtype=float)
        shape = x.shape[1:]
        flat = x.reshape(x.shape[0], -1)
        labels = ([name] if not shape else
                  [f"{name}[{','.join(map(str, idx))}]" for idx in np.ndindex(*shape)])
        for j, label in enumerate(labels):
            lo, hi = hdi(flat[:, j], prob)
            out.append(ParamSummary(label, units.get(name, ""), float(np.mean(flat[:, j])),
                                    float(np.std(flat[:, j], ddof=1)), lo, hi, prob))
    return out


@dataclass(frozen=True)
class SamplingResult:
    """Draws of a posterior and everything needed to judge them.

    Attributes
    ----------
    space : ParamSpace
        The posterior's parameter space (maps ``z`` to named values).
    chains : ndarray, shape (E, S, W, ndim)
        Post-burn-in draws of ``z``: E ensembles, S steps, W walkers.
    log_prob : ndarray, shape (E, S, W)
    convergence : ConvergenceReport
    start : MAPResult
        The MAP the walkers started from.
    counts : EvalCounts
        Posterior evaluations, failed simulations, prior rejections in this run.
    acceptance : ndarray, shape (E, W)
        Acceptance fraction per walker.
    runtime_s : float
        Wall time of this call (MAP included).
    model, likelihood : str
    seed : int
    settings : dict
        Sampler settings (:meth:`SamplerSettings.to_dict`, with the walkers used).
    move_acceptance : dict of str to float
        Acceptance rate of each move over the whole run, all ensembles (for the
        structured moves: ``gibbs_linear``, ``gibbs_sigma``, ``gibbs_phi``,
        ``independence``, ``differential``).
    linear_block : tuple of str
        Parameters drawn exactly from their conditional Gaussian (empty when none).
    """

    space: ParamSpace
    chains: np.ndarray
    log_prob: np.ndarray
    convergence: ConvergenceReport
    start: MAPResult
    counts: EvalCounts
    acceptance: np.ndarray
    runtime_s: float
    model: str
    likelihood: str
    seed: int
    settings: dict[str, Any] = field(default_factory=dict)
    move_acceptance: dict[str, float] = field(default_factory=dict)
    linear_block: tuple[str, ...] = ()

    @property
    def converged(self) -> bool:
        """Whether every convergence criterion held."""
        return self.convergence.converged

    @property
    def last_walkers(self) -> np.ndarray:
        """Each ensemble's walkers at the last step, shape (E, W, ndim).

        Where a longer run of the same posterior goes on from
        (``sample_posterior(walkers=...)``).
        """
        return self.chains[:, -1].copy()

    @property
    def flat_z(self) -> np.ndarray:
        """All kept draws of ``z``, shape (E * S * W, ndim)."""
        return self.chains.reshape(-1, self.chains.shape[-1])

    def draws(self, n: int | None = None, *, seed: int = 0) -> np.ndarray:
        """``n`` draws of ``z`` spread evenly over steps, walkers and ensembles.

        The thinning is deterministic (evenly spaced indices into the flattened draws
        after a fixed shuffle by ``seed``), so predictions and LOO are reproducible.
        """
        flat = self.flat_z
        if n is None or n >= flat.shape[0]:
            return flat
        idx = np.random.default_rng(seed).permutation(flat.shape[0])[:n]
        return flat[np.sort(idx)]

    def theta(self) -> dict[str, np.ndarray]:
        """All kept draws as named physical values, each ``(M, *shape)``."""
        return self.space.unpack(self.flat_z)

    def summary(self, prob: float = 0.9) -> list[ParamSummary]:
        """Mean, sd and ``prob`` HDI of every free scalar element, in physical units."""
        theta = self.theta()
        return summarise_draws({p.name: theta[p.name] for p in self.space.params},
                               {p.name: p.unit for p in self.space.params}, prob)

    def ensemble_summaries(self, names: Sequence[str], prob: float = 0.9, *,
                           last: float = 0.5) -> list[list[ParamSummary]]:
        """:meth:`summary` of the parameters ``names``, each ensemble on its own.

        Unconverged, the ensembles are not yet one posterior, and their pooled interval
        depends on how the sampler has weighed modes so far; what holds in the last part
        of every ensemble (an interval on one side of a bound) holds however the modes end
        up weighted.

        Parameters
        ----------
        names : sequence of str
            Parameter names (as declared, not element labels).
        prob : float
            Mass of each highest-density interval, in (0, 1).
        last : float
            Fraction of each ensemble's kept steps summarised (the latest ones), in
            (0, 1].

        Returns
        -------
        list of list of ParamSummary
            One list per ensemble, as :meth:`summary` restricted to ``names``.
        """
        if not 0.0 < last <= 1.0:
            raise ParameterError(f"last must be a fraction in (0, 1], got {last!r}")
        units = {p.name: p.unit for p in self.space.params}
        unknown = [n for n in names if n not in units]
        if unknown:
            raise ParameterError(f"no free parameters {unknown} in this posterior "
                                 f"(free: {sorted(units)})")
        n_steps = self.chains.shape[1]
        first = n_steps - max(1, round(last * n_steps))
        out = []
        for chain in self.chains:
            # only the named coordinates are transformed: unpacking all of a 120-dim
            # chain's last 5 000 steps would hold ~300 MB per ensemble for one summary
            theta = self.space.unpack(chain[first:].reshape(-1, chain.shape[-1]), names=names)
            out.append(summarise_draws(theta, units, prob))
        return out

    def __str__(self) -> str:
        moves = ", ".join(f"{k} {v:.2f}" for k, v in sorted(self.move_acceptance.items()))
        head = (f"{self.model} / {self.likelihood}: {self.chains.shape[0]} ensembles x "
                f"{self.chains.shape[2]} walkers, {self.convergence}\n"
                f"{self.counts}; acceptance {np.mean(self.acceptance):.2f}"
                f"{f' ({moves})' if moves else ''}; {self.runtime_s:.1f} s")
        rows = [f"{'parameter':<22} {'mean':>12} {'sd':>11}  90% HDI"]
        rows += [str(s) for s in self.summary()]
        return head + "\n" + "\n".join(rows)
