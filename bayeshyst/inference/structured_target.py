"""The posterior as the structured moves see it, and their acceptance counts.

:class:`StructuredTarget` says which coordinates ``z_n`` the moves of
:mod:`bayeshyst.inference.moves` propose and completes a proposal with an exact draw of
the linear block (:class:`~bayeshyst.inference.linear.LinearStructure`), keeping the log
density of that draw for the reverse term of the next Metropolis–Hastings ratio; the MAP
search (:mod:`bayeshyst.inference.optimize`) evaluates the marginal posterior through it
too. :class:`MoveStats` counts proposals and acceptances per move (stored in
checkpoints, reported in the sampling result).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.posterior import Posterior

__all__ = ["MoveStats", "StructuredTarget"]


@dataclass
class MoveStats:
    """Proposals and acceptances per move (walker-proposals), for one ensemble."""

    proposed: dict[str, int] = field(default_factory=dict)
    accepted: dict[str, int] = field(default_factory=dict)

    def add(self, name: str, proposed: int, accepted: int) -> None:
        """Count ``proposed`` walker-proposals of move ``name``, ``accepted`` of them taken."""
        self.proposed[name] = self.proposed.get(name, 0) + int(proposed)
        self.accepted[name] = self.accepted.get(name, 0) + int(accepted)

    def rates(self) -> dict[str, float]:
        """Acceptance rate per move (moves never proposed are left out)."""
        return {k: self.accepted.get(k, 0) / v for k, v in self.proposed.items() if v}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready counts (what a checkpoint stores)."""
        return {"proposed": dict(self.proposed), "accepted": dict(self.accepted)}

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> MoveStats:
        """Counts stored by :meth:`to_dict` (empty for None)."""
        d = d or {}
        return cls({k: int(v) for k, v in d.get("proposed", {}).items()},
                   {k: int(v) for k, v in d.get("accepted", {}).items()})

    @staticmethod
    def merge(stats: list[MoveStats]) -> MoveStats:
        """The counts of several ensembles added up."""
        out = MoveStats()
        for s in stats:
            for k, v in s.proposed.items():
                out.add(k, v, s.accepted.get(k, 0))
        return out

    def __str__(self) -> str:
        return ", ".join(f"{k} {r:.2f}" for k, r in sorted(self.rates().items())) or "none"


class StructuredTarget:
    """The posterior as the moves see it.

    It says which coordinates the moves propose, and how a proposal is completed with the
    linear block.

    Parameters
    ----------
    post : Posterior
    structure : LinearStructure or None
        The linear block; None when the posterior has none (then ``other_idx`` is every
        coordinate and proposals are evaluated by simulation).
    """

    def __init__(self, post: Posterior, structure: LinearStructure | None) -> None:
        self.post = post
        self.structure = structure
        self.other_idx = (np.arange(post.ndim) if structure is None
                          else structure.other_idx)
        # log q of the points completions produced, by their coordinates: the reverse
        # term of the next proposal from there (a recomputation gives the same bits)
        self._logq: dict[bytes, float] = {}

    @property
    def n_other(self) -> int:
        """Dimension of the proposed coordinates ``z_n``."""
        return int(self.other_idx.size)

    def _prior(self, z: np.ndarray) -> np.ndarray:
        lp = np.atleast_1d(self.post.space.log_prior(z)).astype(float)
        return np.where(np.isfinite(lp), lp, -np.inf)

    def log_prob(self, z: np.ndarray, st: Any = None) -> np.ndarray:
        """Log posterior (W,) of complete points, from the Grams when there is a block."""
        if self.structure is None:
            return self.post.log_prob_batch(z)
        st = self.structure.stats(z) if st is None else st
        lp = self._prior(z)
        inside = np.isfinite(lp)
        lp[inside] += self.structure.log_likelihood(st.take(np.flatnonzero(inside)), z[inside])
        self.post.record_counts(z.shape[0], int(np.count_nonzero(~inside)),
                                int(np.count_nonzero(inside & ~np.isfinite(lp))))
        return np.where(np.isfinite(lp), lp, -np.inf)

    def complete(self, z_prop: np.ndarray, random: np.random.RandomState
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Draw the linear block of the proposals ``z_prop`` (W, ndim) given their ``z_n``.

        Returns the completed points, their log posterior and the log density (in
        ``z``) of the drawn block under its conditional proposal; without a linear
        block the points are returned as they are, with zeros for the last.
        """
        w = z_prop.shape[0]
        if self.structure is None:
            return z_prop, self.post.log_prob_batch(z_prop), np.zeros(w)
        s = self.structure
        z = z_prop.copy()
        # walkers outside the prior in z_n are rejected without running the model
        inside = np.isfinite(self._prior(z))
        logq = np.full(w, -np.inf)
        lp = np.full(w, -np.inf)
        idx = np.flatnonzero(inside)
        if idx.size:
            zi = z[idx]
            st = s.stats(zi)
            cond = s.conditional(st, zi)
            beta = cond.draw(random)
            zb, logjac = s.z_of(beta)
            good = cond.ok & np.all(np.isfinite(zb), axis=1)
            zi[:, s.lin_idx] = np.where(good[:, None], zb, zi[:, s.lin_idx])
            z[idx] = zi
            lq = cond.log_density(beta) - logjac
            lpi = self._prior(zi)
            ok = good & np.isfinite(lpi)
            lpi[ok] += s.log_likelihood(st.take(np.flatnonzero(ok)), zi[ok])
            lpi[~ok] = -np.inf
            lp[idx] = np.where(np.isfinite(lpi), lpi, -np.inf)
            logq[idx] = np.where(ok, lq, -np.inf)
            if len(self._logq) > 4096:
                self._logq.clear()
            for j in np.flatnonzero(ok):
                self._logq[zi[j].tobytes()] = float(lq[j])
        self.post.record_counts(w, int(np.count_nonzero(~inside)),
                                int(np.count_nonzero(inside & ~np.isfinite(lp))))
        return z, lp, logq

    def log_q_current(self, z: np.ndarray) -> np.ndarray:
        """Log density (W,) of the current linear blocks under their conditional proposal.

        It is the reverse term of a completed proposal's MH ratio.
        """
        if self.structure is None:
            return np.zeros(z.shape[0])
        keys = [row.tobytes() for row in z]
        out = np.array([self._logq.get(k, np.nan) for k in keys])
        todo = np.flatnonzero(np.isnan(out))
        if todo.size:
            s = self.structure
            zt = z[todo]
            cond = s.conditional(s.stats(zt), zt)
            beta = s.beta_of(zt)
            _, logjac = s.z_of(beta)
            out[todo] = cond.log_density(beta) - logjac
        return out
