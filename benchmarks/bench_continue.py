"""A longer run from the short run's last walkers against one from the start again.

The diagnosis samples an unconverged fit again with twice the steps
(``budget_doublings``). This benchmark measures, in the same run and for several seeds,
what the second run costs when it goes on from each ensemble's last walkers
(``sample_posterior(walkers=res.last_walkers)``, what the loop now does) against
starting again where the short run started (what it did before): the steps the second
run needs to converge and its wall time. Each case starts its walkers far from the
posterior, as a candidate started from its parent's walkers does when the added
effect moves the other parameters, and gives the short run too few steps to get there.

Usage::

    python benchmarks/bench_continue.py [--seeds 5] [--write]
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _cases():
    """(label, posterior, start, far walkers of seed s, short budgets)."""
    from bayeshyst.data import load
    from bayeshyst.demo import bundled_data
    from bayeshyst.inference.optimize import find_map
    from bayeshyst.inference.posterior import Posterior
    from tests.synthetic import pi_data

    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    # tempered, so the ensemble moves the weights (no exact linear block)
    pi = Posterior(rec, model, beta=0.5).fix("noise.sigma", 0.05)
    bw = Posterior(load(bundled_data()).select([50.0]), "bouc_wen", "gaussian")
    out = []
    # short budgets: one far from converged, one that ran out near convergence (what a
    # run that ends at R-hat 1.013, as the 150 V candidate's did, looks like)
    for label, post, off, short in (("pi_play(3), tempered, 30 sd off", pi, 30.0, (60, 150)),
                                    ("bouc_wen, bundled 50 Hz, 8 sd off", bw, 8.0,
                                     (60, 250))):
        start = find_map(post, seed=0)
        sd = np.sqrt(np.diag(start.covariance))

        def far(seed, start=start, sd=sd, off=off):
            rng = np.random.default_rng(seed)
            return start.z + (off + rng.standard_normal((64, start.z.size))) * sd

        out.append((label, post, start, far, short))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per case")
    ap.add_argument("--write", action="store_true", help="record in benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    lines = ["| case | seed | short run (steps, converged) | again from the start: steps, s "
             "| from its last walkers: steps, s | time ratio |", "|---|---|---|---|---|---|"]
    ratios: dict[str, list[float]] = {}
    for label, post, start, far, budgets in _cases():
        for short_steps, seed in itertools.product(budgets, range(args.seeds)):
            walkers = far(seed)
            short = sample_posterior(post, SamplerSettings(seed=seed, max_steps=short_steps,
                                                           first_chunk=short_steps),
                                     start=start, initial=walkers)
            longer = SamplerSettings(seed=seed + 100, max_steps=2400)
            t0 = time.perf_counter()
            again = sample_posterior(post, longer, start=start, initial=walkers)
            t_again = time.perf_counter() - t0
            t0 = time.perf_counter()
            cont = sample_posterior(post, longer, start=short.start,
                                    walkers=short.last_walkers)
            t_cont = time.perf_counter() - t0
            ratio = t_again / t_cont
            ratios.setdefault(f"{label}, short run {short_steps} steps", []).append(ratio)

            def steps(r):
                return f"{r.convergence.n_steps}{'' if r.converged else ' (not converged)'}"

            lines.append(f"| {label} | {seed} | {short.convergence.n_steps}, "
                         f"{'yes' if short.converged else 'no'} | {steps(again)}, "
                         f"{t_again:.1f} | {steps(cont)}, {t_cont:.1f} | {ratio:.2f}x |")
            print(lines[-1], flush=True)
    lines += [""] + [f"{label}: median time ratio {statistics.median(r):.2f}x "
                     f"(geometric mean {math.exp(np.mean(np.log(r))):.2f}x) over {len(r)} "
                     f"seeds" for label, r in ratios.items()]
    lines += ["", f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
              f"{platform.python_version()}; load average {os.getloadavg()[0]:.1f} at the "
              "end. Second runs have a budget of 2 400 steps; both start at the MAP the "
              "short run started at (the continued one at the short run's own, which a "
              "restart may have moved). Ratio > 1: going on is faster."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("continue", "Budget doubling: going on from the last walkers", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
