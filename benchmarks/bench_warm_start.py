"""A candidate fit started from the smaller model's walkers: when the warm-up freezes.

The diagnosis loop fits each candidate effect starting from the current fit's final
walkers (the added parameters drawn apart from their Laplace conditional). Those
walkers are spread like the *smaller* model's posterior; the larger one is wider where
the added effect trades off with the base model's parameters, and the ensemble spreads
into it for a thousand steps or more. The structured moves' independence proposal is
fitted to the ensemble during a warm-up; frozen while the walkers are still spreading,
it is too narrow where they end up, and they hold still there for hundreds of steps
(the 150 V piezo's round-3 candidates on its shape correction ran out of 10 000 steps
with tau 190-430). Measured in one run on the same posterior and starting walkers:

1. **baseline**: the warm-up frozen as before (at the first extension point where the
   proposal moves enough walkers or a re-fit stopped raising that fraction);
2. the warm-up of :func:`bayeshyst.inference.warmup.keep_adapting`, which also goes on
   while the ensemble's draws still move away from those the proposal was fitted to.

The case: the 150 V piezo record (``../shared/data``; exits 2 with one line when it is
absent) at 100 samples per cycle, ``bouc_wen+change_point`` with the HSGP shape
correction (fitted first), then ``bouc_wen+change_point+creep`` with that correction,
started from its walkers, as the loop fits it. Printed per warm-up: steps, time,
convergence, R-hat, least bulk ESS, ESS per second and the ratio against the baseline.

Usage::

    python benchmarks/bench_warm_start.py [--seed 0] [--steps 10000] [--write]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SMALLER = "bouc_wen+change_point"
LARGER = "bouc_wen+change_point+creep"


def _frozen_as_before(chains, idx, last_fit, boundary, last_rate):
    """The warm-up rule before ``keep_adapting``: the move rate alone decides."""
    from bayeshyst.inference.warmup import MIN_MOVE_RATE, WarmupDecision, move_rate

    rate = min(move_rate(c[last_fit:boundary], idx) for c in chains)
    return WarmupDecision(rate < MIN_MOVE_RATE and rate >= last_rate + 0.05, rate, math.nan)


def _carried(post_small, res_small, post_large, start_large) -> np.ndarray:
    """The smaller fit's last walkers in the larger space; added parameters at the MAP."""
    last = res_small.chains[:, -1].reshape(-1, post_small.ndim)
    out = np.repeat(start_large.z[None], last.shape[0], axis=0)
    for name in post_large.space.names:
        if name in post_small.space:
            out[:, post_large.space.slice_of(name)] = last[:, post_small.space.slice_of(name)]
    return out


def _row(label: str, res, wall: float) -> dict:
    rep = res.convergence
    return {"label": label, "steps": int(rep.n_steps), "time_s": wall,
            "converged": bool(res.converged), "rhat": float(rep.rhat_max),
            "ess": float(rep.ess_bulk_min), "ess_per_s": float(rep.ess_bulk_min) / wall,
            "tau": float(rep.tau_max)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    ap.add_argument("--steps", type=int, default=10_000,
                    help="step budget of each candidate fit (default 10 000, the "
                         "measured-data analysis's)")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import bayeshyst.inference.sampling as sampling
    from analyses._common import Cut, load_measured
    from bayeshyst.errors import DataError
    from bayeshyst.inference.discrepancy_fit import attach_discrepancy
    from bayeshyst.inference.optimize import find_map
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.settings import SamplerSettings
    from benchmarks._results import write_section

    try:
        data = load_measured("piezo_150v", Cut(samples_per_cycle=100))
    except DataError as exc:
        print(f"bench_warm_start: the piezo data are not available: {exc}", file=sys.stderr)
        return 2
    load0 = os.getloadavg()[0]
    settings = SamplerSettings(max_steps=args.steps, seed=args.seed)
    rng = np.random.default_rng(args.seed)
    small0 = Posterior(data, SMALLER)
    small, _, start_small = attach_discrepancy(small0, find_map(small0, seed=rng), "hsgp")
    res_small = sampling.sample_posterior(small, settings, start=start_small)
    print(f"{SMALLER} with its shape correction: {res_small.convergence}", flush=True)
    large0 = Posterior(data, LARGER)
    # the candidate keeps the smaller fit's correction (it nests that fit), as the loop
    large, _, start = attach_discrepancy(large0, find_map(large0, seed=rng), small.discrepancy)
    walkers = _carried(small, res_small, large, start)
    rows = []
    rule = sampling.keep_adapting
    for label, keep in (("frozen by the move rate (baseline)", _frozen_as_before),
                        ("keep_adapting", rule)):
        sampling.keep_adapting = keep
        try:
            t0 = time.perf_counter()
            res = sampling.sample_posterior(large, settings, start=start, initial=walkers)
            rows.append(_row(label, res, time.perf_counter() - t0))
        finally:
            sampling.keep_adapting = rule
        print(rows[-1], flush=True)
    base = rows[0]
    lines = [f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
             f"{os.cpu_count()} cores, Python {platform.python_version()}; load average "
             f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end. 150 V piezo, "
             f"{data.n_samples} samples, `{LARGER}` with the shape correction, started from "
             f"`{SMALLER}`'s walkers; seed {args.seed}, {args.steps} steps at most.", "",
             "| warm-up | steps | time (s) | converged | R-hat max | bulk ESS min | tau max "
             "| ESS/s | ESS/s vs baseline |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = "1 (baseline)" if r is base else f"{r['ess_per_s'] / base['ess_per_s']:.0f}x"
        lines.append(f"| {r['label']} | {r['steps']} | {r['time_s']:.1f} | "
                     f"{'yes' if r['converged'] else 'no'} | {r['rhat']:.3f} | {r['ess']:.0f} "
                     f"| {r['tau']:.0f} | {r['ess_per_s']:.2f} | {ratio} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        write_section("warm_start", "A candidate started from the smaller model's walkers",
                      text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
