"""Cost of the model discrepancy: per likelihood evaluation and per converged fit.

Measured in one run, each with and without ``discrepancy="hsgp"`` (the reduced-rank GP of
:mod:`bayeshyst.discrepancy`), the ratio printed against the run without it:

1. log-likelihood evaluations per second of the vectorised ensemble
   (``Posterior.log_prob_batch``, W = 64 walkers) and of the linear block's Gram path
   (``LinearStructure.stats`` + ``log_likelihood``, what the structured moves use);
2. time to a converged posterior (MAP search, the discrepancy's anchoring and scale
   search, sampling; default criteria) for ``pi_play(n_operators=8)`` on the bundled
   five-frequency record and for Bouc–Wen on a 6 000-sample loop.

Target (issue 19): a fit with the discrepancy costs <= 2x the fit without it.

Usage::

    python benchmarks/bench_discrepancy.py [--quick] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bayeshyst.data.io import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.linear import LinearStructure
    from bayeshyst.inference.optimize import find_map
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.settings import SamplerSettings
    from benchmarks._results import write_section
    from benchmarks.bench_inference import _rate, make_data

    load0 = os.getloadavg()[0]
    cases = [("pi_play(8), 5 frequencies", load(ROOT / "data" / "virtual_multifreq.csv"),
              "pi_play(n_operators=8)"),
             ("bouc_wen, 6 000 samples", make_data(), "bouc_wen")]
    rows = []
    for label, data, model in cases:
        evals, fits = {}, {}
        for disc in ("none", "hsgp"):
            post = Posterior(data, model, discrepancy=None if disc == "none" else "hsgp")
            start = find_map(post, seed=0) if disc == "none" else None
            z0 = start.z if start is not None else post.space.sample_prior(
                np.random.default_rng(0), 1)[0]
            z = z0 + 0.01 * np.random.default_rng(1).standard_normal((64, post.ndim))
            batch = _rate(lambda p=post, zz=z: p.log_prob_batch(zz), 3 if args.quick else 20, 64)
            s = LinearStructure(post, reference=z0)

            def gram(s=s, zz=z):
                s._cache.clear()
                s._constant = None
                return s.log_likelihood(s.stats(zz), zz)

            grams = _rate(gram, 3 if args.quick else 20, 64)
            t0 = time.perf_counter()
            fit = fit_model(data, model, sampler=SamplerSettings(seed=0),
                            discrepancy=disc)
            wall = time.perf_counter() - t0
            evals[disc] = (batch, grams)
            fits[disc] = (wall, fit.converged, fit.sampling.convergence.n_steps,
                          fit.overall.rmse)
            print(f"{label:28} {disc:5} ensemble {batch:10,.0f}/s  grams {grams:10,.0f}/s  "
                  f"fit {wall:7.2f} s converged={fit.converged} "
                  f"steps={fit.sampling.convergence.n_steps} rmse={fit.overall.rmse:.4g}",
                  flush=True)
        rows.append((label, evals, fits))
        print(f"{label:28} ratios gp/none: ensemble evaluation "
              f"{evals['none'][0] / evals['hsgp'][0]:.2f}x slower, Gram path "
              f"{evals['none'][1] / evals['hsgp'][1]:.2f}x slower, converged fit "
              f"{fits['hsgp'][0] / fits['none'][0]:.2f}x the time", flush=True)
    load1 = os.getloadavg()[0]
    if args.write:
        import numba

        lines = [
            f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, {os.cpu_count()} "
            f"cores, numba {numba.__version__}; load average {load0:.1f} at the start, "
            f"{load1:.1f} at the end. Evaluations: W = 64 walkers near the MAP; fits: "
            "`fit_model` with default settings (seed 0), MAP search and, with the "
            "discrepancy, its anchoring and held-out scale search included.",
            "",
            "| posterior | discrepancy | ensemble evals/s | Gram-path evals/s | fit s | "
            "converged | steps | RMSE |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for label, evals, fits in rows:
            for disc in ("none", "hsgp"):
                b, g = evals[disc]
                w, c, n, r = fits[disc]
                lines.append(f"| {label} | {disc} | {b:,.0f} | {g:,.0f} | {w:.2f} | {c} | {n} "
                             f"| {r:.4g} |")
        lines.append("")
        lines += [f"- {label}: with the discrepancy an ensemble evaluation is "
                  f"{evals['none'][0] / evals['hsgp'][0]:.2f}x slower, the Gram path "
                  f"{evals['none'][1] / evals['hsgp'][1]:.2f}x slower, a converged fit takes "
                  f"{fits['hsgp'][0] / fits['none'][0]:.2f}x the time."
                  for label, evals, fits in rows]
        write_section("discrepancy", "Model discrepancy (cost)", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
