"""Posterior sampling with emcee: independent ensembles, automatic extension, checkpoints.

:func:`sample_posterior` starts from the MAP (walkers drawn from its Laplace
approximation), runs ``n_ensembles`` independent emcee ensembles with
differential-evolution moves (hysteresis posteriors are thin curved ridges; DE moves
propose along the ensemble's own spread and mix far better there than the default
stretch move), and extends the run chunk by chunk until every convergence criterion
holds — rank-normalised R-hat < 1.01 across walkers *and* across ensembles, bulk and
tail ESS >= 400, at least 50 integrated autocorrelation times kept after burn-in — or
the step budget is spent, in which case the result says so.

Chunk boundaries are a fixed function of the step count, so a run resumed from a
checkpoint makes exactly the decisions (and draws exactly the samples) of the
uninterrupted run.
"""

from __future__ import annotations

import hashlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
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
from bayeshyst.inference.convergence import ConvergenceReport, assess, hdi
from bayeshyst.inference.optimize import MAPResult, find_map, initial_ensemble
from bayeshyst.inference.posterior import EvalCounts, Posterior
from bayeshyst.params import ParamSpace

__all__ = ["ParamSummary", "SamplingResult", "chunk_boundaries", "sample_posterior"]


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
        Sampler settings (walkers, ensembles, budget, moves).
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

    @property
    def converged(self) -> bool:
        """Whether every convergence criterion held."""
        return self.convergence.converged

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
        out = []
        for p in self.space.params:
            x = np.asarray(theta[p.name]).reshape(theta[p.name].shape[0], -1)
            for j, label in enumerate(p.labels()):
                lo, hi = hdi(x[:, j], prob)
                out.append(ParamSummary(label, p.unit, float(np.mean(x[:, j])),
                                        float(np.std(x[:, j], ddof=1)), lo, hi, prob))
        return out

    def __str__(self) -> str:
        head = (f"{self.model} / {self.likelihood}: {self.chains.shape[0]} ensembles x "
                f"{self.chains.shape[2]} walkers, {self.convergence}\n"
                f"{self.counts}; acceptance {np.mean(self.acceptance):.2f}; "
                f"{self.runtime_s:.1f} s")
        rows = [f"{'parameter':<22} {'mean':>12} {'sd':>11}  90% HDI"]
        rows += [str(s) for s in self.summary()]
        return head + "\n" + "\n".join(rows)


def chunk_boundaries(first: int, max_steps: int) -> list[int]:
    """Step counts at which convergence is assessed: ``first``, then growing by half.

    A fixed function of the settings, so resumed runs stop where uninterrupted ones do.
    """
    out = [min(first, max_steps)]
    while out[-1] < max_steps:
        out.append(min(max_steps, out[-1] + max(first, out[-1] // 2)))
    return out


def _moves(moves: str | list) -> Any:
    if moves == "de":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    if moves == "stretch":
        return emcee.moves.StretchMove()
    if isinstance(moves, list):
        return moves
    raise ParameterError(f"moves must be 'de', 'stretch' or a list of emcee moves, got "
                         f"{moves!r}")


def _fingerprint(post: Posterior, settings: dict[str, Any]) -> dict[str, Any]:
    h = hashlib.sha256()
    for rec in post.data:
        for arr in (rec.t, rec.u, rec.y):
            h.update(np.ascontiguousarray(arr).tobytes())
        h.update(str(rec.warmup).encode())
    return {
        "model": repr(post.model),
        "likelihood": post.likelihood.name,
        "beta": post.beta,
        "held_out": str(post.held_out),
        "space": str(post.space),
        "data_sha256": h.hexdigest(),
        **{k: str(v) for k, v in settings.items()},
    }


def sample_posterior(
    post: Posterior,
    *,
    n_walkers: int | None = None,
    n_ensembles: int = 2,
    max_steps: int = 20_000,
    first_chunk: int = 1_000,
    seed: int = 0,
    start: MAPResult | None = None,
    moves: str | list = "de",
    checkpoint: str | Path | None = None,
    progress: bool = False,
    rhat_threshold: float = 1.01,
    min_ess: float = 400.0,
    tau_factor: float = 50.0,
    flush_seconds: float = 2.0,
) -> SamplingResult:
    """Sample the posterior with independent emcee ensembles until converged.

    Parameters
    ----------
    post : Posterior
    n_walkers : int, optional
        Walkers per ensemble (even); default ``max(32, 4 * ndim)``.
    n_ensembles : int
        Independent ensembles (>= 2 so that R-hat can compare them).
    max_steps : int
        Step budget per ensemble; a run that has not converged by then stops and
        says so.
    first_chunk : int
        Steps before the first convergence check (see :func:`chunk_boundaries`).
    seed : int
        Seeds the MAP search and every ensemble: same seed, same draws.
    start : MAPResult, optional
        Skip the MAP search and start from this one.
    moves : {"de", "stretch"} or list of emcee moves
    checkpoint : path, optional
        HDF5 file; written during the run, and resumed from when it exists (a run
        killed at any point continues where its last flush left it, and ends with the
        same draws as an uninterrupted run).
    progress : bool
        Show a progress bar (tqdm) on stderr.
    rhat_threshold, min_ess, tau_factor : float
        Convergence criteria.
    flush_seconds : float
        Longest interval between checkpoint writes.
    """
    t0 = time.perf_counter()
    if n_ensembles < 2:
        raise ParameterError(f"n_ensembles must be >= 2 to compare ensembles, got {n_ensembles}")
    ndim = post.ndim
    if n_walkers is None:
        n_walkers = max(32, 4 * ndim)
    n_walkers = int(n_walkers) + int(n_walkers) % 2
    if n_walkers < 2 * ndim:
        raise ParameterError(f"n_walkers={n_walkers} is too few for {ndim} dimensions "
                             f"(need >= {2 * ndim})")
    if max_steps < 10 or first_chunk < 10:
        raise ParameterError("max_steps and first_chunk must be >= 10")
    settings = {"n_walkers": n_walkers, "n_ensembles": n_ensembles, "max_steps": max_steps,
                "first_chunk": first_chunk, "seed": seed, "moves": moves}
    seeds = np.random.SeedSequence(seed).spawn(n_ensembles + 1)
    counts0 = post.counts
    meta = None
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        fp = _fingerprint(post, settings)
        meta = read_meta(checkpoint)
        if meta is not None:
            check_fingerprint(checkpoint, meta["fingerprint"], fp)
            start = start or MAPResult(**meta["start"])
    if start is None:
        start = find_map(post, seed=np.random.default_rng(seeds[-1]))
    if checkpoint is not None and meta is None:
        checkpoint.parent.mkdir(parents=True, exist_ok=True)
        write_meta(checkpoint, {"fingerprint": fp, "start": {
            "z": start.z, "theta": start.theta, "log_prob": start.log_prob,
            "covariance": start.covariance, "laplace_ok": start.laplace_ok,
            "n_evals": start.n_evals, "candidates": start.candidates}})

    samplers = []
    for e in range(n_ensembles):
        backend = (CheckpointBackend(checkpoint, f"ensemble_{e}", flush_seconds=flush_seconds)
                   if checkpoint is not None else emcee.backends.Backend())
        sampler = emcee.EnsembleSampler(n_walkers, ndim, post.log_prob_batch, vectorize=True,
                                        moves=_moves(moves), backend=backend)
        if backend.iteration == 0:
            rng = np.random.default_rng(seeds[e])
            p0 = initial_ensemble(post, start, n_walkers, rng)
            sampler.random_state = np.random.RandomState(int(rng.integers(2**31 - 1))).get_state()
        else:
            p0 = None
        samplers.append([sampler, p0])

    bar = None
    if progress:
        from tqdm.auto import tqdm

        # a terminal gets a live bar; a log file an update every 10 s, not thousands
        bar = tqdm(total=max_steps * n_ensembles, desc=f"sampling {post.model.name}",
                   unit="step", initial=sum(s.iteration for s, _ in samplers),
                   mininterval=0.2 if sys.stderr.isatty() else 10.0)
    report = None
    try:
        for boundary in chunk_boundaries(first_chunk, max_steps):
            for pair in samplers:
                sampler, p0 = pair
                todo = boundary - sampler.iteration
                if todo <= 0:
                    continue
                # continue from the stored last state (positions, log p, random state):
                # after a resume that is the checkpoint, so the run goes on identically
                state = p0 if sampler.iteration == 0 else sampler.get_last_sample()
                for _ in sampler.sample(state, iterations=todo, store=True):
                    if bar is not None:
                        bar.update(1)
                if isinstance(sampler.backend, CheckpointBackend):
                    sampler.backend.flush()
            chains = [s.get_chain() for s, _ in samplers]
            report = assess(chains, rhat_threshold=rhat_threshold, min_ess=min_ess,
                            tau_factor=tau_factor)
            if bar is not None:
                bar.set_postfix_str(f"R-hat {report.rhat_max:.3f}, ESS "
                                    f"{report.ess_bulk_min:.0f}, tau {report.tau_max:.0f}")
            if report.converged:
                break
    finally:
        if bar is not None:
            bar.close()
    assert report is not None  # chunk_boundaries is never empty (internal invariant)
    burn = report.burn
    chains = np.stack([s.get_chain()[burn:report.n_steps] for s, _ in samplers])
    logp = np.stack([s.get_log_prob()[burn:report.n_steps] for s, _ in samplers])
    acc = np.stack([s.backend.accepted / max(s.iteration, 1) for s, _ in samplers])
    c1 = post.counts
    counts = EvalCounts(c1.evaluations - counts0.evaluations,
                        c1.prior_rejected - counts0.prior_rejected, c1.failed - counts0.failed)
    return SamplingResult(post.space, chains, logp, report, start, counts, acc,
                          time.perf_counter() - t0, post.model.name, post.likelihood.name,
                          int(seed), settings)
