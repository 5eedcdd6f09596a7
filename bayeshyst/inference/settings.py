"""How a posterior is sampled: :class:`SamplerSettings`, the one record every command takes.

``fit``, ``compare``, ``diagnose``, ``compensate``, ``report`` and ``study`` all sample
posteriors; they take one :class:`SamplerSettings` (and the command line maps its flags
onto it once, in :func:`bayeshyst.cli.sampler_settings`) instead of repeating a dozen
keywords with defaults of their own. A task that needs its own seed or checkpoint
derives it with :meth:`SamplerSettings.replace`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bayeshyst.errors import ParameterError

__all__ = ["MOVES", "SamplerSettings"]

#: Move sets: ``structured`` (exact Gibbs draws of the linear block, an adaptive
#: independence proposal and differential evolution, :mod:`bayeshyst.inference.moves`),
#: ``de`` (emcee's differential-evolution and snooker moves on every coordinate: the
#: engine before the structured moves, kept as the benchmarks' baseline), ``stretch``
#: (emcee's default affine-invariant move).
MOVES = ("structured", "de", "stretch")


@dataclass(frozen=True)
class SamplerSettings:
    """Settings of :func:`~bayeshyst.inference.sampling.sample_posterior`.

    Attributes
    ----------
    n_walkers : int or None
        Walkers per ensemble (rounded up to even). Default for the structured moves:
        ``max(24, 4 d + 4, min(48, 0.025 min_ess))``, ``d`` the coordinates they
        propose (the linear block is drawn, not proposed). The independence proposal is
        re-fitted from the walkers' draws, and a curved posterior needs a mixture
        fitted to a few thousand of them: Bouc–Wen on one misfitting record (the
        virtual actuator at 50 Hz) converged in 390 steps (3.8 s) with 24 walkers and
        in 760 (6.6 s) with 12. The last term gives ``min_ess`` two and a half times
        over in 100 kept steps at tau = 2. ``max(32, 4 ndim)`` for ``de`` and
        ``stretch``.
    n_ensembles : int
        Independent ensembles (>= 2, so R-hat can compare them).
    moves : {"structured", "de", "stretch"}
        The move set (:data:`MOVES`).
    max_steps : int
        Step budget per ensemble; a run that has not converged by then says so.
    first_chunk : int
        Steps before the first convergence check; checks then follow at fixed step
        counts (:func:`~bayeshyst.inference.sampling.chunk_boundaries`).
    warmup : int or None
        Steps during which the structured moves' independence proposal is re-fitted to
        the ensemble (then frozen; these steps are always discarded). Default
        ``min(50, max_steps // 2)``: started at the MAP with its Gauss–Newton covariance,
        the proposal needs a few hundred ensemble draws to learn the posterior's shape
        (Bouc–Wen, 6 000 samples, 24 walkers: 50 warm-up steps converged in 200 steps
        with 4 000-4 300 ESS, 100 in 200-250 steps with 2 800-4 700); ignored by ``de``
        and ``stretch``.
    rhat_threshold, min_ess, tau_factor : float
        Convergence criteria: rank-normalised R-hat below ``rhat_threshold`` across
        walkers and ensembles, bulk and tail ESS at least ``min_ess``, at least
        ``tau_factor`` integrated autocorrelation times kept after burn-in.
    seed : int
        Seeds the MAP search and every ensemble: same seed, same draws.
    checkpoint : Path or None
        HDF5 file written during the run and resumed from when it exists.
    progress : bool
        Show a progress bar on stderr.
    flush_seconds : float
        Longest interval between checkpoint writes (s).
    """

    n_walkers: int | None = None
    n_ensembles: int = 2
    moves: str = "structured"
    max_steps: int = 20_000
    first_chunk: int = 100
    warmup: int | None = None
    rhat_threshold: float = 1.01
    min_ess: float = 400.0
    tau_factor: float = 50.0
    seed: int = 0
    checkpoint: Path | None = None
    progress: bool = False
    flush_seconds: float = 2.0

    def __post_init__(self) -> None:
        def whole(name: str, lo: int, allow_none: bool = False) -> None:
            v = getattr(self, name)
            if v is None and allow_none:
                return
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ParameterError(f"sampler setting {name} must be an integer >= {lo}, "
                                     f"got {v!r}")

        whole("n_walkers", 4, allow_none=True)
        whole("n_ensembles", 2)
        whole("max_steps", 10)
        whole("first_chunk", 10)
        whole("warmup", 0, allow_none=True)
        whole("seed", 0)
        if self.moves not in MOVES:
            raise ParameterError(f"sampler setting moves must be one of {', '.join(MOVES)}, "
                                 f"got {self.moves!r}")
        for name, lo in (("rhat_threshold", 1.0), ("min_ess", 0.0), ("tau_factor", 0.0),
                         ("flush_seconds", 0.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or v <= lo:
                raise ParameterError(f"sampler setting {name} must be a number > {lo}, "
                                     f"got {v!r}")
        if self.warmup is not None and self.warmup >= self.max_steps:
            raise ParameterError(f"sampler setting warmup ({self.warmup}) must be below "
                                 f"max_steps ({self.max_steps})")
        if self.checkpoint is not None and not isinstance(self.checkpoint, Path):
            object.__setattr__(self, "checkpoint", Path(self.checkpoint))

    @property
    def warmup_steps(self) -> int:
        """Adaptation steps of the structured moves (0 for the other move sets)."""
        if self.moves != "structured":
            return 0
        w = min(50, self.max_steps // 2) if self.warmup is None else self.warmup
        return int(min(w, self.max_steps - 1))

    def walkers(self, n_proposed: int, ndim: int) -> int:
        """Walkers per ensemble (even) for a posterior of ``ndim`` coordinates.

        The moves propose ``n_proposed`` of the coordinates.
        """
        if self.n_walkers is not None:
            w = self.n_walkers
        elif self.moves == "structured":
            w = max(24, 4 * n_proposed + 4, min(48, math.ceil(0.025 * self.min_ess)))
        else:
            w = max(32, 4 * ndim)
        return int(w) + int(w) % 2

    def replace(self, **changes: Any) -> SamplerSettings:
        """A copy with ``changes`` (validated like the original)."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise ParameterError(f"unknown sampler settings {unknown}; settings: "
                                 f"{[f.name for f in dataclasses.fields(self)]}")
        return dataclasses.replace(self, **changes)

    def fingerprint(self) -> dict[str, str]:
        """What the draws depend on; a checkpoint written with other values is not resumed.

        The checkpoint path, progress bar and flush interval are left out: the draws do
        not depend on them.
        """
        skip = {"checkpoint", "progress", "flush_seconds"}
        return {f.name: str(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name not in skip}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings (the checkpoint as a string or None)."""
        d = dataclasses.asdict(self)
        d["checkpoint"] = None if self.checkpoint is None else str(self.checkpoint)
        return d

    def __str__(self) -> str:
        walkers = "auto" if self.n_walkers is None else str(self.n_walkers)
        return (f"{self.moves} moves, {self.n_ensembles} ensembles x {walkers} walkers, "
                f"<= {self.max_steps} steps (first check at {self.first_chunk}), "
                f"R-hat < {self.rhat_threshold:g}, ESS >= {self.min_ess:g}, "
                f">= {self.tau_factor:g} tau, seed {self.seed}")
